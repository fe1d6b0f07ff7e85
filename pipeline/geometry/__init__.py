"""Geometry shared by every stage: rotations, poses, image coordinates, projections, transformations.

Pure numerics (numpy only).  Conventions: ``docs/conventions.md``.

* :mod:`.rotations` — ``R_cam_from_world`` from ω, φ, κ and back, batched, with derivatives;
* :mod:`.pose` — poses between computer-vision frames (y down, z forward) and baarda's;
* :mod:`.image` — pixels ↔ mm, one signature: ``(coordinates, size, pixel_mm, convention)``;
* :mod:`.transforms` — 2-D Helmert and affine designs, the 3-D similarity (closed form, Jacobian).
"""

from .image import PIXEL_CONVENTIONS, mm_from_pixels, pixels_from_mm
from .pose import D_FLIP, cv_from_pose, pose_from_cv
from .rotations import (nearest_rotation, opk_from_rotation, opk_from_rotation_many, rotation_and_derivatives,
                        rotation_angle, rotation_from_opk, rotation_from_opk_many, rotation_from_rotvec)
from .transforms import similarity_motions

__all__ = ["rotation_from_opk", "rotation_from_opk_many", "opk_from_rotation", "opk_from_rotation_many",
           "rotation_and_derivatives", "rotation_from_rotvec", "nearest_rotation", "rotation_angle",
           "pose_from_cv", "cv_from_pose", "D_FLIP", "mm_from_pixels", "pixels_from_mm",
           "PIXEL_CONVENTIONS", "similarity_motions"]
