"""Network design (pre-analysis): the ``design`` and ``design-montecarlo`` stages (``docs/design.md``)."""
