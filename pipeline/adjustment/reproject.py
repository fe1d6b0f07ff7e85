"""Image coordinates of a block's points computed with its cameras, and reprojection errors.

The bundle's own collinearity with the block's cameras and AP models; used to check conversions
against COLMAP's, BAL's and libmv's projections and to predict target positions.
"""

from __future__ import annotations

import numpy as np

from .collinearity import project_observations
from .settings import BundleSettings, camera_meta

__all__ = ["project_block", "reprojection_px", "reprojection_summary"]


def project_block(block, photo, point) -> np.ndarray:
    """Image coordinates (mm, ``(k, 2)``) of ``block.points[point]`` in ``block.photos[photo]``
    with the block's cameras and AP models — the bundle's own collinearity
    (:func:`.collinearity.project_observations`).  Used to check conversions against
    COLMAP's, BAL's and libmv's projections and to predict target positions.
    """
    cams, ph = block.cameras, block.photos
    cam_params = np.column_stack([cams.c, cams.xp, cams.yp, cams.ap]) if len(cams) else np.zeros((0, 3))
    pr = project_observations(np.asarray(photo, int), np.asarray(point, int), block.points.XYZ, ph.X0, ph.opk,
                              ph.camera, cam_params, cams.ap_model, camera_meta(block, BundleSettings()),
                              jacobians=False)
    return pr.xy


def reprojection_px(block) -> np.ndarray:
    """Image residuals ``observed − computed`` in pixels ``(k, 2)`` of a block with pixel cameras."""
    obs = block.observations
    xy = project_block(block, obs.photo, obs.point)
    return (obs.xy - xy) / block.cameras.pixel_mm[block.photos.camera[obs.photo]][:, None]


def reprojection_summary(block) -> dict:
    """Mean and RMS of the reprojection error (pixels) over active observations."""
    v = reprojection_px(block)[block.observations.active]
    e = np.linalg.norm(v, axis=1)
    return {"mean_px": float(e.mean()) if e.size else float("nan"),
            "rms_px": float(np.sqrt((e**2).mean())) if e.size else float("nan"),
            "max_px": float(e.max()) if e.size else float("nan")}
