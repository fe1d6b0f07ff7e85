"""pycolmap cross-check of the bundle (stage ``pycolmap-crosscheck``) and simulated blocks.

Public API::

    from baarda.plugins.crosscheck import crosscheck, exceeded, Tolerances, CrossCheck, CrossCheckError
    from baarda.plugins.crosscheck import plan_crosscheck, CrossCheckPlan, SolverSettings

See ``docs/crosscheck.md``.
"""

from .compare import CrossCheck, CrossCheckError, Tolerances, crosscheck, exceeded, start_values
from .plan import CrossCheckPlan, plan_crosscheck
from .pycolmap_ba import SolverSettings

__all__ = ["crosscheck", "exceeded", "start_values", "Tolerances", "CrossCheck", "CrossCheckError",
           "plan_crosscheck", "CrossCheckPlan", "SolverSettings"]
