"""Camera models (additional parameters) and conversions between baarda's camera and other tools'.

* :mod:`.models` — the AP models (``none``, ``ebner12``, ``brown``, ``aicon``);
* :mod:`.registry` — models by name, built-in and third-party, through the entry-point group
  ``baarda.camera_models``;
* :mod:`.ray_models` — models that project from the ray (fisheye, omnidirectional, division;
  COLMAP's and photogrammetric fisheye projections), :class:`RayModel` to subclass for another;
* :mod:`.convert` — OpenCV / COLMAP camera parameters ↔ baarda's ``brown`` and ray models.

Pure numerics (numpy only).  See ``docs/camera-models.md``.
"""

from .models import APModel, LinearAPModel
from .ray_models import RayModel, RayOutsideModel
from .registry import REGISTRY, CameraModelRegistry, ap_model_names, get_ap_model, register_ap_model

__all__ = ["APModel", "LinearAPModel", "RayModel", "RayOutsideModel", "register_ap_model", "get_ap_model",
           "ap_model_names", "REGISTRY", "CameraModelRegistry"]
