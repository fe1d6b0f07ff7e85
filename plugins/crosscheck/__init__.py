"""pycolmap cross-check of the bundle (stage ``pycolmap-crosscheck``) and simulated blocks.

Public API::

    from plugins.crosscheck import crosscheck, exceeded, Tolerances, CrossCheck, CrossCheckError
    from plugins.crosscheck import plan_crosscheck, CrossCheckPlan, SolverSettings
    from plugins.crosscheck import simulate_convergent, simulate_aerial, perturb_start

See ``docs/crosscheck.md``.
"""

from .compare import CrossCheck, CrossCheckError, Tolerances, crosscheck, exceeded, start_values
from .plan import CrossCheckPlan, plan_crosscheck
from .pycolmap_ba import SolverSettings
from .simulate import perturb_start, simulate_aerial, simulate_convergent

__all__ = ["crosscheck", "exceeded", "start_values", "Tolerances", "CrossCheck", "CrossCheckError",
           "plan_crosscheck", "CrossCheckPlan", "SolverSettings", "simulate_convergent", "simulate_aerial",
           "perturb_start"]
