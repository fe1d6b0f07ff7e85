"""Collinearity projection with additional parameters and its analytic Jacobians (vectorised).

Conventions (``docs/conventions.md``)::

    [U, V, W]ᵀ = R_cam_from_world(ω, φ, κ) (X − X0)
    x̄ = −c U/W,  ȳ = −c V/W
    x = xp + x̄ + Δx(x̄, ȳ; ap),   y = yp + ȳ + Δy(x̄, ȳ; ap)

Camera parameter vector per camera: ``[c, xp, yp, ap_1 … ap_p]``.  Exterior orientation per
photo: ``[X0, Y0, Z0, ω, φ, κ]``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from pipeline.geometry import rotation_from_opk_many

from .apmodels import get_ap_model

__all__ = ["rotation_and_derivatives", "Projection", "project_observations", "IOP_NAMES", "EO_NAMES"]

IOP_NAMES = ("c", "xp", "yp")
EO_NAMES = ("X0", "Y0", "Z0", "omega", "phi", "kappa")


def bmm(A, B):
    """Batched small matrix product ``A @ B`` over the leading axis (explicit sum over the inner
    dimension — much faster than einsum/matmul for 2×3-sized blocks)."""
    inner = A.shape[-1]
    if inner > 4:
        return np.matmul(A, B)
    out = A[..., :, 0, None] * B[..., None, 0, :]
    for t in range(1, inner):
        out += A[..., :, t, None] * B[..., None, t, :]
    return out


def bmv(A, x):
    """Batched ``A @ x`` for (k, a, b) × (k, b)."""
    out = A[..., 0] * x[..., 0, None]
    for t in range(1, A.shape[-1]):
        out += A[..., t] * x[..., t, None]
    return out


def _elem(a, axis):
    """Elementary rotations R1, R2, R3 (conventions doc) and their derivatives, batched."""
    c, s = np.cos(a), np.sin(a)
    n = a.shape[0]
    R = np.zeros((n, 3, 3))
    D = np.zeros((n, 3, 3))
    if axis == 1:
        R[:, 0, 0] = 1
        R[:, 1, 1], R[:, 1, 2], R[:, 2, 1], R[:, 2, 2] = c, s, -s, c
        D[:, 1, 1], D[:, 1, 2], D[:, 2, 1], D[:, 2, 2] = -s, c, -c, -s
    elif axis == 2:
        R[:, 1, 1] = 1
        R[:, 0, 0], R[:, 0, 2], R[:, 2, 0], R[:, 2, 2] = c, -s, s, c
        D[:, 0, 0], D[:, 0, 2], D[:, 2, 0], D[:, 2, 2] = -s, -c, c, -s
    else:
        R[:, 2, 2] = 1
        R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1] = c, s, -s, c
        D[:, 0, 0], D[:, 0, 1], D[:, 1, 0], D[:, 1, 1] = -s, c, -c, -s
    return R, D


def rotation_and_derivatives(opk: np.ndarray):
    """``R_cam_from_world (m, 3, 3)`` and ``dR (m, 3, 3, 3)`` with ``dR[:, a]`` = ∂R/∂(ω, φ, κ)[a]."""
    opk = np.asarray(opk, float).reshape(-1, 3)
    R1, D1 = _elem(opk[:, 0], 1)
    R2, D2 = _elem(opk[:, 1], 2)
    R3, D3 = _elem(opk[:, 2], 3)
    R32 = R3 @ R2
    R = R32 @ R1
    dR = np.stack([R32 @ D1, R3 @ D2 @ R1, D3 @ R2 @ R1], axis=1)
    return R, dR


@dataclass
class Projection:
    """Projected image coordinates and (optionally) their Jacobians, one row per observation.

    xy (k, 2); xbar (k, 2) ideal reduced coordinates; W (k,) depth (negative in front);
    J_eo (k, 2, 6) w.r.t. X0 Y0 Z0 ω φ κ; J_point (k, 2, 3) w.r.t. X Y Z;
    J_cam (k, 2, 3 + p) w.r.t. c, xp, yp, ap_1 … ap_p (p = width of ``cam_params`` − 3).
    """

    xy: np.ndarray
    xbar: np.ndarray
    W: np.ndarray
    J_eo: np.ndarray | None = None
    J_point: np.ndarray | None = None
    J_cam: np.ndarray | None = None


def project_observations(obs_photo: np.ndarray, obs_point: np.ndarray, XYZ: np.ndarray,
                         X0: np.ndarray, opk: np.ndarray, photo_camera: np.ndarray,
                         cam_params: np.ndarray, cam_models: Sequence[str],
                         cam_meta: Sequence[Mapping] | None = None, *, jacobians: bool = True,
                         R_dR=None) -> Projection:
    """Project the observed points and (optionally) differentiate.

    Parameters
    ----------
    obs_photo, obs_point : (k,) indices into photos and points.
    XYZ : (n, 3) object points; X0 (m, 3), opk (m, 3) exterior orientation.
    photo_camera : (m,) camera index of each photo.
    cam_params : (K, 3 + p) ``[c, xp, yp, ap…]`` per camera (unused AP columns ignored).
    cam_models : (K,) registered AP model names; cam_meta : (K,) dicts (``b``, ``r0`` …).
    R_dR : optional precomputed ``rotation_and_derivatives(opk)``.
    """
    obs_photo = np.asarray(obs_photo, int)
    obs_point = np.asarray(obs_point, int)
    cam_params = np.asarray(cam_params, float)
    k = obs_photo.shape[0]
    ptot = cam_params.shape[1]
    if R_dR is None:
        R_dR = rotation_and_derivatives(opk) if jacobians else (rotation_from_opk_many(opk), None)
    R, dR = R_dR
    cam = np.asarray(photo_camera, int)[obs_photo]
    D = XYZ[obs_point] - X0[obs_photo]                # (k, 3)
    Rk = R[obs_photo]
    d = bmv(Rk, D)
    U, V, W = d[:, 0], d[:, 1], d[:, 2]
    c = cam_params[cam, 0]
    xbar = -c * U / W
    ybar = -c * V / W
    xy = np.empty((k, 2))
    xy[:, 0] = cam_params[cam, 1] + xbar
    xy[:, 1] = cam_params[cam, 2] + ybar
    Jxy = None
    J_ap = None
    J_c_model = None
    if jacobians:
        Jxy = np.zeros((k, 2, 2))
        Jxy[:, 0, 0] = 1.0
        Jxy[:, 1, 1] = 1.0
        J_ap = np.zeros((k, 2, ptot - 3))
        J_c_model = np.zeros((k, 2))
    models = np.asarray(cam_models, dtype=str)
    metas = list(cam_meta) if cam_meta is not None else [{} for _ in range(len(models))]
    for name in np.unique(models[cam]) if k else []:
        model = get_ap_model(name)
        p = model.n_params
        if p == 0:
            continue
        cams_m = np.flatnonzero(models == name)
        sel_mask = np.isin(cam, cams_m)
        # meta may differ per camera: evaluate camera by camera when it does
        groups = [cams_m] if _same_meta([metas[j] for j in cams_m]) else [[j] for j in cams_m]
        for grp in groups:
            sel = np.flatnonzero(sel_mask & np.isin(cam, grp)) if len(groups) > 1 else np.flatnonzero(sel_mask)
            if sel.size == 0:
                continue
            meta = metas[grp[0]]
            prm = cam_params[cam[sel], 3:3 + p]
            xb, yb, cc = xbar[sel], ybar[sel], c[sel]
            dx, dy = model.distortion(xb, yb, prm, cc, meta)
            xy[sel, 0] += dx
            xy[sel, 1] += dy
            if jacobians:
                J_ap[sel, :, :p] = model.jacobian_params(xb, yb, prm, cc, meta)
                Jxy[sel] += model.jacobian_xy(xb, yb, prm, cc, meta)
                J_c_model[sel] = model.jacobian_c(xb, yb, prm, cc, meta)
    out = Projection(xy=xy, xbar=np.column_stack([xbar, ybar]), W=W)
    if not jacobians:
        return out
    # ∂(x̄, ȳ)/∂d  (k, 2, 3)
    G = np.zeros((k, 2, 3))
    G[:, 0, 0] = -c / W
    G[:, 0, 2] = c * U / (W * W)
    G[:, 1, 1] = -c / W
    G[:, 1, 2] = c * V / (W * W)
    JG = bmm(Jxy, G)                                  # (k, 2, 3) ∂(x, y)/∂d
    J_point = bmm(JG, Rk)                             # ∂/∂X = JG R
    J_eo = np.empty((k, 2, 6))
    J_eo[:, :, :3] = -J_point
    dd = bmv(dR[obs_photo], D[:, None, :])            # (k, 3 angles, 3): ∂d/∂angle
    J_eo[:, :, 3:] = bmm(JG, np.transpose(dd, (0, 2, 1)))
    J_cam = np.zeros((k, 2, ptot))
    # ∂(x̄, ȳ)/∂c = (x̄, ȳ)/c  (chain through the AP model) + the model's own ∂/∂c
    xbc = np.column_stack([xbar / c, ybar / c])
    J_cam[:, :, 0] = bmv(Jxy, xbc) + J_c_model
    J_cam[:, 0, 1] = 1.0
    J_cam[:, 1, 2] = 1.0
    J_cam[:, :, 3:] = J_ap
    out.J_eo, out.J_point, out.J_cam = J_eo, J_point, J_cam
    return out


def _same_meta(metas) -> bool:
    if len(metas) <= 1:
        return True
    first = metas[0]
    for m in metas[1:]:
        if set(m) != set(first):
            return False
        for key in m:
            if not np.array_equal(np.asarray(m[key]), np.asarray(first[key])):
                return False
    return True
