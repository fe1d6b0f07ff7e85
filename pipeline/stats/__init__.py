"""baarda's statistics library: testing theory for every adjustment (see docs/statistics.md).

Every adjustment reports a :class:`Snapshot`; the tests below work on snapshots only, O(n).
:class:`LinearModel` is the reference linear Gauss–Markov adjustment (small/medium, dense).
"""

from baarda.pipeline.stats import tau_distribution
from baarda.pipeline.stats.arrays import snapshot_from_arrays
from baarda.pipeline.stats.baarda import (ALPHA_GLOBAL, B_METHOD, global_critical, global_level,
                                          DataSnoopingResult, ExternalReliability, GlobalTestResult,
                                   controlled, data_snooping, estimated_errors,
                                   external_reliability, global_test, mdb, w_test)
from baarda.pipeline.stats.critical import (alpha_prime, critical_normal, delta0, global_power,
                                     w_power)
from baarda.pipeline.stats.ids import IDSResult, IDSStep, SnoopingConfig, SnoopingLevels, iterated_data_snooping
from baarda.pipeline.stats.joint import JointTestResult, joint_test_2d
from baarda.pipeline.stats.linear import (LinearAdjustment, LinearModel, factor_normal_equations,
                                   solve_normal)
from baarda.pipeline.stats.pope import (PopeIteratedResult, PopeResult, PopeStep, pope_iterated,
                                 pope_test)
from baarda.pipeline.stats.robust import (DEFAULT_C, ROBUST_METHODS, RobustConfig, RobustResult, RobustTuning, irls,
                                          robust_rho, robust_weights, scale_covariance,
                                          weighted_linear_refit, weighted_refit)
from baarda.pipeline.stats.rrr import RRRResult, recursive_residuals, rrr
from baarda.pipeline.stats.snapshot import GroupBlocks, Refittable, Snapshot
from baarda.pipeline.stats.tau_distribution import critical_max as tau_critical_max
from baarda.pipeline.stats.tau_distribution import tau_critical

__all__ = [
    "Snapshot", "Refittable", "GroupBlocks", "snapshot_from_arrays",
    "LinearModel", "LinearAdjustment", "factor_normal_equations", "solve_normal",
    "delta0", "critical_normal", "alpha_prime", "global_power", "w_power",
    "ALPHA_GLOBAL", "B_METHOD", "global_critical", "global_level",
    "GlobalTestResult", "global_test", "w_test", "estimated_errors", "mdb", "controlled",
    "DataSnoopingResult", "data_snooping", "ExternalReliability", "external_reliability",
    "tau_distribution", "tau_critical", "tau_critical_max",
    "PopeResult", "PopeStep", "PopeIteratedResult", "pope_test", "pope_iterated",
    "IDSResult", "IDSStep", "iterated_data_snooping", "SnoopingLevels", "SnoopingConfig",
    "RRRResult", "rrr", "recursive_residuals",
    "JointTestResult", "joint_test_2d",
    "ROBUST_METHODS", "DEFAULT_C", "RobustTuning", "RobustConfig", "RobustResult", "irls", "robust_weights", "robust_rho",
    "weighted_linear_refit", "scale_covariance", "weighted_refit",
]
