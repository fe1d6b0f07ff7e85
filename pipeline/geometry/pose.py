"""Poses between computer-vision conventions (y down, z forward) and baarda's (y up, z back).

Frames
------
COLMAP, OpenCV and libmv use a camera frame with x right, **y down, z forward** (a point in front
of the camera has ``z > 0``) and ``p_cam = R · X + t``.  baarda's image-space frame has x right,
**y up, z back** (``docs/conventions.md``).  The two differ by ``D = diag(1, −1, −1)``::

    R_cam_from_world (baarda) = D · R_cam_from_world (COLMAP),   X0 = −R_colmapᵀ · t
"""

from __future__ import annotations

import numpy as np

from .rotations import opk_from_rotation, rotation_from_opk_many

D_FLIP = np.diag([1.0, -1.0, -1.0])
"""Camera frame y-down/z-forward (OpenCV, COLMAP, libmv) ↔ baarda's y-up/z-back."""


def pose_from_cv(R_cv_cam_from_world, t) -> tuple[np.ndarray, np.ndarray]:
    """``(X0 (3,), opk (3,))`` of a y-down/z-forward pose ``p_cam = R X + t`` (COLMAP, OpenCV, libmv)."""
    R = np.asarray(R_cv_cam_from_world, float)
    t = np.asarray(t, float).reshape(3)
    return -R.T @ t, opk_from_rotation(D_FLIP @ R)


def cv_from_pose(X0, opk) -> tuple[np.ndarray, np.ndarray]:
    """``(R (m, 3, 3), t (m, 3))`` y-down/z-forward ``cam_from_world`` of baarda poses ``X0, opk (m, 3)``."""
    R = D_FLIP @ rotation_from_opk_many(opk)
    t = -np.einsum("mij,mj->mi", R, np.asarray(X0, float).reshape(-1, 3))
    return R, t
