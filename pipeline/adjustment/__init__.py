"""The adjustment core: the self-calibrating bundle block adjustment.

Modules, in the order of the mathematics: :mod:`.settings` (what is asked), :mod:`.collinearity`
(the observation equations and their Jacobians), :mod:`.problem` (set-up: unknowns, whitening,
priors, datum), :mod:`.layout` (the column layout of the unknowns), :mod:`.normal` (normal
equations, the reduced camera system's pieces), :mod:`.route` (the dense and the sparse route,
one interface, chosen once), :mod:`.factor` (the solution), :mod:`.sparse` (the sparse route's
Cholesky), :mod:`.lm` (the Levenberg–Marquardt iteration, its records in :mod:`.records`), :mod:`.precision` (cofactors,
redundancy numbers), :mod:`.diagnose` (a singular system named), :mod:`.initial` (resection,
intersection, initial values), :mod:`.apselect` (additional-parameter selection), :mod:`.adjust`
(the entry point and its result), :mod:`.reproject` (a block's reprojection errors),
:mod:`.variance` (variance components per observation group), :mod:`.reliability` (external
reliability, covariances of chosen parameters, the linearised model for RRR), :mod:`.rig` (camera rigs: frames and sensor poses,
docs/rigs.md), :mod:`.workflow` (the
whole bundle workflow: :func:`adjust_block` with a :class:`BundleConfig`, docs/library.md).

Everything other code needs is imported from this package::

    from baarda.pipeline.adjustment import adjust, BundleSettings, Distance, BundleResult
    from baarda.pipeline.adjustment import resection, intersection, initial_values, select_aps
    from baarda.pipeline.adjustment import project_observations, project_block, reprojection_summary

Pure numerics: arrays and blocks in, results out; no files, no rerun.  Camera models live in
:mod:`baarda.pipeline.camera`.  See ``docs/bundle.md``.
"""

from .adjust import BundleResult, adjust, padded_ap, result_of
from .apselect import APSelection, select_aps
from .collinearity import EO_NAMES, IOP_NAMES, project_observations
from .diagnose import parameter_names
from .eccentricity import Eccentricity, eccentricity_corrections
from .initial import ResectionResult, initial_values, intersection, resection
from .lm import ITERATION_CALLBACK, solve_bundle
from .memory import release_freed
from .phases import PHASE_CALLBACK, PhaseEvent
from .problem import BundleProblem
from .records import Convergence, Iteration, IterationEvent, Timings
from .reliability import (GlobalRowStats, OwnEffects, ParameterVectors, effect_vectors, global_rows, linearised_model,
                          own_point_effects_in_datum,
                          own_effects, parameter_covariance, row_mdb)
from .rig import SENSOR_NAMES, RigResult, RigStructure, SensorResult, initial_rig_state, rig_result, rig_structure
from .reproject import project_block, reprojection_px, reprojection_summary
from .settings import BundleSettings, BundleState, Distance, camera_meta
from .variance import (GroupPart, LinearComponents, VarianceComponents, VarianceGroup, estimate_components,
                       group_parts, image_group_labels, linear_components)
from .workflow import (EO_LABELS, APSelectionConfig, BundleConfig, BundleReport, EccentricityConfig,
                       EccentricityRounds, OutputConfig, RigConfig, RobustConfig, ScaleBar, SolverConfig,
                       StatTestsConfig, VarianceComponentsConfig, adjust_block, bundle_settings, configure_block)

__all__ = [
    "release_freed",
    "adjust", "BundleResult", "result_of", "BundleSettings", "BundleState", "Distance", "padded_ap", "camera_meta",
    "select_aps", "APSelection", "project_observations", "EO_NAMES", "IOP_NAMES", "parameter_names",
    "resection", "ResectionResult", "intersection", "initial_values", "solve_bundle", "ITERATION_CALLBACK", "PHASE_CALLBACK", "PhaseEvent",
    "BundleProblem", "Convergence", "Iteration", "IterationEvent", "Timings",
    "project_block", "reprojection_px", "reprojection_summary",
    "estimate_components", "VarianceComponents", "VarianceGroup", "linear_components", "LinearComponents",
    "group_parts", "GroupPart", "image_group_labels",
    "own_effects", "OwnEffects", "own_point_effects_in_datum", "effect_vectors", "ParameterVectors", "parameter_covariance",
    "linearised_model", "row_mdb",
    "global_rows", "GlobalRowStats",
    "adjust_block", "BundleConfig", "BundleReport", "configure_block", "bundle_settings", "ScaleBar",
    "SolverConfig", "StatTestsConfig", "RobustConfig", "VarianceComponentsConfig", "APSelectionConfig",
    "OutputConfig", "EO_LABELS", "EccentricityConfig", "EccentricityRounds", "Eccentricity",
    "eccentricity_corrections",
    "RigConfig", "rig_result", "RigResult", "SensorResult", "rig_structure", "RigStructure", "SENSOR_NAMES", "initial_rig_state",
]
