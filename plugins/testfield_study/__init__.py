"""Paper 001's method comparison on the simulated test field (Tables 4 and 5): numerics in
:mod:`.study`, the ``method-study`` stage in :mod:`.stage`.  See docs/method-study.md."""

from .study import (PAPER_PERCENT, PAPER_TABLE5, VARIANTS, MethodStudyConfig, compare, conclusions,
                    field_geometry, method_study, run_realisation, summarise)

__all__ = ["MethodStudyConfig", "method_study", "run_realisation", "summarise", "compare", "conclusions",
           "field_geometry", "VARIANTS", "PAPER_TABLE5", "PAPER_PERCENT"]
