"""The adjustment core: the self-calibrating bundle (problem set-up, normal equations, solve,
precision, datum diagnosis, initial values, AP selection).

Public API::

    from baarda.pipeline.adjustment import adjust, BundleSettings, Distance, BundleResult
    from baarda.pipeline.adjustment import resection, intersection, initial_values
    from baarda.pipeline.adjustment import register_ap_model, get_ap_model, APModel, LinearAPModel
    from baarda.pipeline.adjustment import project_observations
"""

from .adjust import BundleResult, adjust, check_point_rmse
from ..camera.models import APModel, LinearAPModel, ap_model_names, get_ap_model, register_ap_model
from .collinearity import project_observations
from .initial import initial_values, intersection, resection
from .reproject import project_block, reprojection_px, reprojection_summary
from .solver import BundleSettings, BundleState, Distance

__all__ = [
    "adjust", "BundleResult", "BundleSettings", "BundleState", "Distance", "check_point_rmse",
    "APModel", "LinearAPModel", "register_ap_model", "get_ap_model", "ap_model_names",
    "project_observations", "project_block", "reprojection_px", "reprojection_summary", "resection", "intersection", "initial_values",
]
