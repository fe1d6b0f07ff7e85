"""Rerun logging of a block's cameras and points (used by the COLMAP, BAL/libmv and target stages).

Only called from stages' ``log`` methods.  Photos are logged as ``Transform3D`` (baarda's
``R_cam_from_world``, relation child-from-parent) plus ``Pinhole`` with ``camera_xyz = RUB`` (x right,
y up, z back: baarda's image-space frame) under ``<root>/photos/<id>``; object points as
``Points3D`` under ``<root>/points``.
"""

from __future__ import annotations

import numpy as np

from baarda.pipeline.geometry import rotation_from_opk_many


def entity_part(text: str) -> str:
    """An entity-path part for an id such as ``"DSC_5305.jpg"``."""
    import rerun as rr

    return rr.escape_entity_path_part(str(text))


def log_block(rec, block, root: str = "block", max_photos: int = 500) -> None:
    """Log points and oriented photos of ``block`` (at most ``max_photos`` photos)."""
    import rerun as rr

    pts = block.points
    ok = np.isfinite(pts.XYZ).all(axis=1)
    if ok.any():
        colors = np.where((pts.role[ok] == "tie")[:, None], [[160, 160, 160]], [[230, 60, 40]]).astype(np.uint8)
        rec.log(f"{root}/points", rr.Points3D(pts.XYZ[ok], colors=colors, radii=rr.Radius.ui_points(2.0)),
                static=True)
    ph, cams = block.photos, block.cameras
    oriented = np.flatnonzero(ph.has_orientation)[:max_photos]
    if oriented.size == 0:
        return
    R = rotation_from_opk_many(ph.opk[oriented])
    for k, Rk in zip(oriented, R):
        path = f"{root}/photos/{entity_part(ph.ids[k])}"
        t = -Rk @ ph.X0[k]
        rec.log(path, rr.Transform3D(translation=t, mat3x3=Rk, relation=rr.TransformRelation.ChildFromParent),
                static=True)
        cam = ph.camera[k]
        pitch = cams.pixel_mm[cam]
        w, h = cams.resolution[cam]
        if np.isfinite(pitch) and pitch > 0 and w > 0 and h > 0:
            f = cams.c[cam] / pitch
            cx = (w - 1) / 2 + cams.xp[cam] / pitch
            cy = (h - 1) / 2 - cams.yp[cam] / pitch
            rec.log(path, rr.Pinhole(image_from_camera=[[f, 0, cx], [0, f, cy], [0, 0, 1]], resolution=[w, h],
                                     camera_xyz=rr.ViewCoordinates.RUB, image_plane_distance=None), static=True)
