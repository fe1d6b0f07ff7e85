"""Independent-model block triangulation (SPEC §3): relative orientation, model coordinates,
3-D similarity and the Ackermann block adjustment — a numerical library (numpy/scipy only); the
``independent-models`` stage (``baarda.plugins.independent_models``) formats and records it.
See ``docs/independent-models.md``."""

from .block import ModelBlockAdjustment, ModelCoordinates, adjust_model_block
from .intersection import Intersection, space_intersection
from .relor import RelativeOrientation, model_covariance, relative_orientation
from .similarity import SimilarityTransform, similarity_closed_form, similarity_transform
from .workflow import IndependentModelResult, ModelBlockOptions, form_pairs, independent_model_block, model_coordinates

__all__ = [
    "relative_orientation", "RelativeOrientation", "model_covariance",
    "space_intersection", "Intersection",
    "similarity_closed_form", "similarity_transform", "SimilarityTransform",
    "adjust_model_block", "ModelCoordinates", "ModelBlockAdjustment",
    "independent_model_block", "IndependentModelResult", "ModelBlockOptions", "form_pairs", "model_coordinates",
]
