"""Geometry shared by every stage: rotations, poses, image coordinates, projections, transformations.

Pure numerics (numpy only).  Conventions: ``docs/conventions.md``.

* :mod:`.rotations` — ``R_cam_from_world`` from ω, φ, κ and back, batched, with derivatives;
* :mod:`.pose` — poses between computer-vision frames (y down, z forward) and baarda's;
* :mod:`.image` — pixels ↔ mm, one signature: ``(coordinates, size, pixel_mm, convention)``.
"""

from .image import PIXEL_CONVENTIONS, mm_from_pixels, pixels_from_mm
from .pose import D_FLIP, cv_from_pose, pose_from_cv
from .rotations import opk_from_rotation, rotation_and_derivatives, rotation_from_opk, rotation_from_opk_many

__all__ = ["rotation_from_opk", "rotation_from_opk_many", "opk_from_rotation", "rotation_and_derivatives",
           "pose_from_cv", "cv_from_pose", "D_FLIP", "mm_from_pixels", "pixels_from_mm",
           "PIXEL_CONVENTIONS"]
