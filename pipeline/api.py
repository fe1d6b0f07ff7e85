"""Everything a stage (a plugin) needs, from one module.

::

    from baarda.pipeline.api import Stage, StageResult, TableData, option, InputError

The stage protocol and its context, typed options, the errors, the data model and the contracts
stages exchange (``Block``, ``AdjustmentArtefact``, ``Snapshot``), the statistics library, and the
recording helpers a ``log`` method uses (one role palette, one photo→view conversion, point
ellipsoids).  ``docs/plugins.md`` shows a whole stage built on it; ``baarda.pipeline.testing``
holds the test helpers.  ``adjust(block, BundleConfig(...))`` runs the bundle workflow without the runner
(``docs/library.md``).  The names here stay; the modules behind them may move.
"""

from __future__ import annotations

from . import stats
from .adjustment import (APSelectionConfig, BundleConfig, BundleReport, EccentricityConfig, OutputConfig, RigConfig,
                         RobustConfig, ScaleBar, SolverConfig, StatTestsConfig, VarianceComponentsConfig)
from .adjustment import adjust_block as adjust
from .adjustment import RigResult, SensorResult, parameter_covariance, project_block, rig_result
from .contracts import AdjustmentArtefact
from .errors import AdjustmentError, BaardaError, InputError
from .model import Block, CircleTargets
from .options import NoOptions, option
from .recording import (ROLE_COLORS, entity_part, log_block, log_text, log_values, point_ellipsoids,
                        role_colors, thin, view_from_photo, view_vectors, viewer_text)
from .stage import Context, Progress, RowBound, SourceStage, Stage, StageResult, TableData, ValidationContext
from .stats.snapshot import Snapshot

# libraries and engine modules stages share (independent models, COLMAP models in and out)
from . import imodels
from .rigs import attach_rigs, read_frame_table, read_rig_table
from .colmap import block_from_reconstruction, read_colmap, read_reconstruction, reconstruction_from_block, write_colmap

__all__ = [
    # the protocol
    "Stage", "SourceStage", "StageResult", "TableData", "Context", "Progress", "option", "NoOptions",
    "ValidationContext", "RowBound",
    # the bundle workflow as a library (docs/library.md)
    "adjust", "BundleConfig", "BundleReport", "SolverConfig", "StatTestsConfig", "RobustConfig",
    "VarianceComponentsConfig", "APSelectionConfig", "OutputConfig", "EccentricityConfig", "ScaleBar",
    "parameter_covariance",
    "RigConfig", "rig_result", "RigResult", "SensorResult", "attach_rigs", "read_rig_table", "read_frame_table",
    "project_block",
    # errors
    "InputError", "AdjustmentError", "BaardaError",
    # data and contracts
    "Block", "CircleTargets", "AdjustmentArtefact", "Snapshot", "stats",
    # recordings
    "ROLE_COLORS", "role_colors", "view_from_photo", "view_vectors", "entity_part", "log_block", "log_text",
    "log_values", "point_ellipsoids", "thin", "viewer_text",
]

__all__ += [
    # the independent-model library; COLMAP models ↔ Block (pycolmap imported on use)
    "imodels", "read_colmap", "read_reconstruction", "block_from_reconstruction", "reconstruction_from_block",
    "write_colmap",
]
