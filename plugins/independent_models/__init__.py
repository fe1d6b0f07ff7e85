"""The ``independent-models`` stage: its report text and figures.  The numerics (relative
orientation, model coordinates, 3-D similarity, the Ackermann block adjustment) are the library
:mod:`baarda.pipeline.imodels`.  See ``docs/independent-models.md``."""
