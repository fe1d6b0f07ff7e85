"""The eccentricity of circular targets, in the image of a block's current orientation (``docs/targets.md``).

An image observation of a circular target (``Block.circles``) is the centre of the imaged ellipse,
which differs from the image of the circle's centre (:mod:`baarda.pipeline.geometry.circles`).  The
correction of each such observation is computed here from the block's current cameras, orientations
and points (the adjusted ones during the bundle's iteration, :func:`.workflow.adjust_block`)::

    Δ = proj(X0 + Rᵀ q_e) − proj(X)

``q_e`` the camera-frame ray of the ellipse centre (the pinhole closed form), ``proj`` the bundle's
own collinearity with the camera's AP model: the distortion (and affinity) acts on the ellipse
centre after the conic is projected (``distortion = "centre"``).  ``distortion = "rim"`` instead
projects ``RIM_POINTS`` points of the circle's rim through the camera model and takes the centre of
the conic fitted to them (least squares, as a detector fits an ellipse to the distorted outline):
it keeps the curvature of the distortion across the target that the closed form leaves out.  The
corrected observation is ``l − Δ``.

Target normals: those the block gives (``CircleTargets.normal``, the object system); where NaN, the
normal of the best-fitting plane through the target and its 8 nearest circular targets, from the
current coordinates (:func:`~baarda.pipeline.geometry.circles.plane_normals`).  A target whose
normal cannot be found (fewer than 3 circular targets, or a line of them) is not corrected.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from baarda.pipeline.geometry.circles import ellipse_centre_direction, plane_normals
from baarda.pipeline.geometry.rotations import rotation_from_opk_many

from .collinearity import project_observations
from .settings import BundleSettings, camera_meta

__all__ = ["Eccentricity", "eccentricity_corrections", "NEIGHBOURS", "RIM_POINTS", "conic_centres"]

RIM_POINTS = 64
"""Points of the rim projected per observation with ``distortion = "rim"``."""

NEIGHBOURS = 8
"""Circular targets whose best-fitting plane gives a target's normal when the block gives none."""


@dataclass(frozen=True, eq=False)
class Eccentricity:
    """Eccentricity corrections of a block's observations (arrays read-only).

    ``correction`` (k, 2) mm per observation row (ellipse centre − image of the circle's centre; 0
    where not applied); ``applied`` (k,) bool; ``normal`` (n, 3) the unit normal used per object point
    (NaN for points that are no circular target or have none); ``estimated`` (n,) bool: the normal
    came from the neighbours' plane."""

    correction: np.ndarray
    applied: np.ndarray
    normal: np.ndarray
    estimated: np.ndarray


def _frozen(a) -> np.ndarray:
    a = np.array(a, copy=True)
    a.flags.writeable = False
    return a


def conic_centres(xy: np.ndarray) -> np.ndarray:
    """Centres ``(k, 2)`` of the least-squares conics through ``xy (k, n, 2)`` (n ≥ 6 points each): the
    smallest right singular vector of ``[x², xy, y², x, y, 1]`` on coordinates centred and scaled per
    conic; NaN where the conic has no centre."""
    xy = np.asarray(xy, float)
    c0 = xy.mean(axis=1, keepdims=True)
    s = np.abs(xy - c0).max(axis=(1, 2), keepdims=True)
    s = np.where(s > 0, s, 1.0)
    y = (xy - c0) / s
    x1, y1 = y[..., 0], y[..., 1]
    A = np.stack([x1 * x1, x1 * y1, y1 * y1, x1, y1, np.ones_like(x1)], axis=-1)
    a, b, c, d, e, _ = np.moveaxis(np.linalg.svd(A, full_matrices=False)[2][:, -1], -1, 0)
    det = 4 * a * c - b * b
    with np.errstate(invalid="ignore", divide="ignore"):
        u = (b * e - 2 * c * d) / det
        v = (b * d - 2 * a * e) / det
    return np.column_stack([u, v]) * s[:, 0] + c0[:, 0]


def _rim(centre: np.ndarray, normal: np.ndarray, radius: np.ndarray, n: int) -> np.ndarray:
    """``(s, n, 3)`` points on circles (object system) of the given centres, unit normals and radii."""
    a = np.where((np.abs(normal[:, :1]) < 0.9), [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(normal, a)
    u /= np.linalg.norm(u, axis=1)[:, None]
    v = np.cross(normal, u)
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return (centre[:, None] + radius[:, None, None] * (np.cos(t)[None, :, None] * u[:, None]
                                                       + np.sin(t)[None, :, None] * v[:, None]))


def eccentricity_corrections(block, settings: BundleSettings | None = None, distortion: str = "centre"
                             ) -> Eccentricity:
    """Corrections of the observations of ``block.circles``' points at the block's current values.

    ``settings`` supplies the AP models' constants (``ap_meta``) as in the adjustment.
    ``distortion``: ``"centre"`` (the closed form, the camera model applied to the ellipse centre) or
    ``"rim"`` (the centre of the conic fitted to the rim projected through the camera model).  A block
    without circular targets gives zero corrections.
    """
    if distortion not in ("centre", "rim"):
        raise ValueError(f"distortion must be 'centre' or 'rim', got {distortion!r}")
    obs, pts, ph, cams = block.observations, block.points, block.photos, block.cameras
    k, n = len(obs), len(pts)
    corr = np.zeros((k, 2))
    applied = np.zeros(k, bool)
    normal = np.full((n, 3), np.nan)
    estimated = np.zeros(n, bool)
    circles = block.circles
    if circles is None or not len(circles) or not k:
        return Eccentricity(_frozen(corr), _frozen(applied), _frozen(normal), _frozen(estimated))
    lookup = {pid: i for i, pid in enumerate(pts.ids.tolist())}
    rows = np.array([lookup.get(pid, -1) for pid in circles.ids.tolist()], int)
    keep = rows >= 0
    rows, diam, given = rows[keep], circles.diameter[keep], circles.normal[keep]
    radius = np.full(n, np.nan)
    radius[rows] = 0.5 * diam
    has = np.isfinite(given).all(axis=1)
    normal[rows[has]] = given[has] / np.linalg.norm(given[has], axis=1)[:, None]
    if (~has).any():
        est, ok = plane_normals(pts.XYZ[rows], NEIGHBOURS)
        sel = ~has & ok
        normal[rows[sel]] = est[sel]
        estimated[rows[sel]] = True
    use = (np.isfinite(radius[obs.point]) & np.isfinite(normal[obs.point]).all(axis=1)
           & np.isfinite(pts.XYZ[obs.point]).all(axis=1) & ph.has_orientation[obs.photo])
    idx = np.flatnonzero(use)
    if not idx.size:
        return Eccentricity(_frozen(corr), _frozen(applied), _frozen(normal), _frozen(estimated))
    p, q = obs.photo[idx], obs.point[idx]
    R = rotation_from_opk_many(ph.opk)[p]                                    # (s, 3, 3) camera from world
    d = np.einsum("sij,sj->si", R, pts.XYZ[q] - ph.X0[p])                    # circle centres, camera frame
    m = np.einsum("sij,sj->si", R, normal[q])
    front = d[:, 2] < 0
    qe = ellipse_centre_direction(d, m, radius[q])
    Q = ph.X0[p] + np.einsum("sji,sj->si", R, qe)                            # a point on the ellipse centre's ray
    cam_params = np.column_stack([cams.c, cams.xp, cams.yp, cams.ap]) if len(cams) else np.zeros((0, 3))
    meta = camera_meta(block, settings or BundleSettings())
    s = len(idx)
    if distortion == "centre":
        both = np.concatenate([Q, pts.XYZ[q]])
        xy = project_observations(np.concatenate([p, p]), np.arange(2 * s), both, ph.X0, ph.opk, ph.camera,
                                  cam_params, cams.ap_model, meta, jacobians=False).xy
        delta = xy[:s] - xy[s:]
    else:
        n_r = RIM_POINTS
        rim = _rim(pts.XYZ[q], normal[q], radius[q], n_r).reshape(-1, 3)
        both = np.concatenate([rim, pts.XYZ[q]])
        xy = project_observations(np.concatenate([np.repeat(p, n_r), p]), np.arange(len(both)), both, ph.X0,
                                  ph.opk, ph.camera, cam_params, cams.ap_model, meta, jacobians=False).xy
        delta = conic_centres(xy[:s * n_r].reshape(s, n_r, 2)) - xy[s * n_r:]
    good = front & np.isfinite(delta).all(axis=1)
    corr[idx[good]] = delta[good]
    applied[idx[good]] = True
    return Eccentricity(_frozen(corr), _frozen(applied), _frozen(normal), _frozen(estimated))
