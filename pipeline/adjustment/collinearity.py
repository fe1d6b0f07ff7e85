"""Collinearity projection with additional parameters and its analytic Jacobians (vectorised).

Conventions (``docs/conventions.md``)::

    [U, V, W]ᵀ = R_cam_from_world(ω, φ, κ) (X − X0)
    x̄ = −c U/W,  ȳ = −c V/W
    x = xp + x̄ + Δx(x̄, ȳ; ap),   y = yp + ȳ + Δy(x̄, ȳ; ap)

A camera whose model is a *ray model* (``pipeline/camera/ray_models.py``: fisheye, omnidirectional)
is projected from ``[U, V, W]`` itself, ``x = xp + f(U, V, W; c, ap)``, and so are its Jacobians
(the model's ``∂(x, y)/∂(U, V, W)`` chained into pose and point).

Camera parameter vector per camera: ``[c, xp, yp, ap_1 … ap_p]``.  Exterior orientation per
photo: ``[X0, Y0, Z0, ω, φ, κ]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from baarda.pipeline.geometry.rotations import rotation_and_derivatives, rotation_from_opk_many

from ..camera import get_ap_model
from ..camera.ray_models import is_ray_model, ray_eo_point_jacobians, ray_projection
from . import corrected, kernels

__all__ = ["Projection", "Projector", "project_observations", "IOP_NAMES", "EO_NAMES"]

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


@dataclass
class Projection:
    """Projected image coordinates and (optionally) their Jacobians, one row per observation.

    xy (k, 2); xbar (k, 2) ideal reduced coordinates (of a ray model: ``xy − (xp, yp)``); W (k,) depth (negative in front);
    J_eo (k, 2, 6) w.r.t. X0 Y0 Z0 ω φ κ; J_point (k, 2, 3) w.r.t. X Y Z;
    J_cam (k, 2, 3 + p) w.r.t. c, xp, yp, ap_1 … ap_p (p = width of ``cam_params`` − 3), or only
    the columns a :class:`Projector` was asked for (``cam_cols``).
    """

    xy: np.ndarray
    xbar: np.ndarray
    W: np.ndarray
    J_eo: np.ndarray | None = None
    J_point: np.ndarray | None = None
    J_cam: np.ndarray | None = None
    # what the Jacobians need (kept by Projector.project, not part of the result's meaning)
    _d: np.ndarray | None = field(default=None, repr=False)          # (k, 3) camera-frame vector U, V, W
    _c: np.ndarray | None = field(default=None, repr=False)          # (k,) principal distance
    _R: np.ndarray | None = field(default=None, repr=False)          # (m, 3, 3)
    _opk: np.ndarray | None = field(default=None, repr=False)
    _cam_params: np.ndarray | None = field(default=None, repr=False)


class Projector:
    """The collinearity equations of one fixed set of observations.

    Everything that depends only on *which* observations are projected — camera of each
    observation, the groups of observations sharing an AP model (and meta) — is worked out once,
    so that an iteration only does arithmetic.  ``project`` evaluates the image coordinates and
    keeps what ``jacobians`` needs; ``jacobians`` adds the analytic derivatives (rotation
    derivatives per photo: ``∂d/∂angle = s × d`` with the axial vector ``s`` of ``∂R/∂angle Rᵀ``).

    ``cam_cols`` (optional) restricts ``J_cam`` to those camera-parameter columns
    (indices into ``[c, xp, yp, ap_1 …]``).  ``marks`` (optional, (k, 2) the measured image
    coordinates): cameras with a backward model use DBAT's residual definition (:mod:`.corrected`).
    """

    def __init__(self, obs_photo, obs_point, photo_camera, cam_models: Sequence[str],
                 cam_meta: Sequence[Mapping] | None = None, *, cam_cols=None, marks=None):
        self.obs_photo = np.asarray(obs_photo, np.intp)
        self.obs_point = np.asarray(obs_point, np.intp)
        self.photo_camera = np.asarray(photo_camera, np.intp)
        k = self.obs_photo.shape[0]
        self.k = k
        self.cam = self.photo_camera[self.obs_photo] if k else np.zeros(0, np.intp)
        models = np.asarray(cam_models, dtype=str)
        metas = list(cam_meta) if cam_meta is not None else [{} for _ in range(len(models))]
        self.cam_cols = None if cam_cols is None else np.asarray(cam_cols, int)
        # observation groups with one AP model and one meta; sel None = every observation
        self.groups = []
        for name in (np.unique(models[self.cam]) if k else []):
            model = get_ap_model(name)
            if model.n_params == 0 and not is_ray_model(model):
                continue
            cams_m = np.flatnonzero(models == name)
            grps = [cams_m] if _same_meta([metas[j] for j in cams_m]) else [[j] for j in cams_m]
            for grp in grps:
                mask = np.isin(self.cam, grp)
                if not mask.any():
                    continue
                sel = None if mask.all() else np.flatnonzero(mask)
                self.groups.append((model, sel, metas[grp[0]]))
        self.marks = None if marks is None else np.asarray(marks, float)
        self.groups, self.mark_groups = corrected.split_groups(self.groups, self.marks)

    def _rows(self, sel):
        """(photo, point) index of the observations of a group (for error messages)."""
        return (self.obs_photo, self.obs_point) if sel is None else (self.obs_photo[sel], self.obs_point[sel])

    # ------------------------------------------------------------------------------------------
    def project(self, XYZ, X0, opk, cam_params, *, R=None) -> Projection:
        """Image coordinates of every observation (no Jacobians yet)."""
        cam_params = np.asarray(cam_params, float)
        opk = np.asarray(opk, float)
        if R is None:
            R = rotation_from_opk_many(opk)
        d, xbar, xy = kernels.project(XYZ, X0, R, self.obs_point, self.obs_photo, self.cam, cam_params)
        W = d[:, 2]
        cp = cam_params[self.cam]
        c = cp[:, 0]
        for model, sel, meta in self.groups:
            p = model.n_params
            if is_ray_model(model):                   # projects from the ray (U, V, W) itself
                s = slice(None) if sel is None else sel
                rxy = ray_projection(model, d[s], cp[s, 3:3 + p], c[s], meta, self._rows(sel))
                xbar[s] = rxy
                xy[s] = cp[s, 1:3] + rxy
            elif sel is None:
                dx, dy = model.distortion(xbar[:, 0], xbar[:, 1], cp[:, 3:3 + p], c, meta)
                xy[:, 0] += dx
                xy[:, 1] += dy
            else:
                dx, dy = model.distortion(xbar[sel, 0], xbar[sel, 1], cp[sel, 3:3 + p], c[sel], meta)
                xy[sel, 0] += dx
                xy[sel, 1] += dy
        corrected.add_correction(self.mark_groups, self.marks, cp, xy)
        return Projection(xy=xy, xbar=xbar, W=W, _d=d, _c=c, _R=R, _opk=opk, _cam_params=cam_params)

    def jacobians(self, pr: Projection, *, dR=None) -> Projection:
        """Add ``J_eo``, ``J_point``, ``J_cam`` to ``pr`` (a result of :meth:`project`), in place."""
        k = self.k
        cam_params = pr._cam_params
        ptot = cam_params.shape[1]
        cols = np.arange(ptot) if self.cam_cols is None else self.cam_cols
        if dR is None:
            _, dR = rotation_and_derivatives(pr._opk)
        d, c = pr._d, pr._c
        xb, yb = pr.xbar[:, 0], pr.xbar[:, 1]
        # the model's image derivative D = ∂Δ/∂(x̄, ȳ) (Jxy = I + D), ∂Δ/∂ap and ∂Δ/∂c
        ap_cols = cols[cols >= 3] - 3
        J_cam = np.zeros((k, 2, len(cols)))
        Jxy = None
        Jc_model = None
        rays = []
        for model, sel, meta in self.groups:
            p = model.n_params
            want = ap_cols[ap_cols < p]
            s = slice(None) if sel is None else sel
            prm = cam_params[self.cam[s], 3:3 + p]
            if is_ray_model(model):
                _, _, Jd, Jp, Jcr = model.ray_jacobians(d[s], prm, c[s], meta, want)
                rays.append((s, Jd, Jcr))
            else:
                Jp, Dxy, Jcm = model.jacobians(xb[s], yb[s], prm, c[s], meta, want)
            if len(want):
                pos = np.flatnonzero((cols >= 3) & (cols - 3 < p))
                if sel is None:
                    J_cam[:, :, pos] = Jp
                else:
                    J_cam[np.ix_(sel, [0, 1], pos)] = Jp
            if is_ray_model(model):
                continue
            if Jxy is None:
                Jxy = np.zeros((k, 2, 2))
            Jxy[s] = Dxy
            if Jcm is not None:
                if Jc_model is None:
                    Jc_model = np.zeros((k, 2))
                Jc_model[s] = Jcm
        # ∂(x̄, ȳ)/∂d = f [[1, 0, −U/W], [0, 1, −V/W]], f = −c/W; JG = (I + D) ∂(x̄, ȳ)/∂d;
        # ∂/∂X = JG R; ∂d/∂angle = ∂R/∂angle (X − X0) = S_a d with S_a = ∂R/∂angle Rᵀ skew (axial
        # vector s_a): J_angle[:, i, a] = JG_i · (s_a × d) = s_a · (d × JG_i)
        S = np.einsum("maij,mkj->maik", dR, pr._R)        # (m, 3, 3, 3)
        sv = np.stack([S[:, :, 2, 1], S[:, :, 0, 2], S[:, :, 1, 0]], axis=2)   # (m, 3 angles, 3)
        J_point, J_eo, J_c = kernels.eo_point_jacobians(d, pr.xbar, c, Jxy, pr._R, sv, self.obs_photo)
        for s, Jd, Jcr in rays:                       # ray models: ∂(x, y)/∂d is the model's own
            J_point[s], J_eo[s] = ray_eo_point_jacobians(Jd, d[s], pr._R, sv, self.obs_photo[s])
            J_c[s] = Jcr
        # camera: ∂/∂c = (I + D)(x̄, ȳ)/c + the model's own ∂Δ/∂c; ∂/∂xp = (1, 0), ∂/∂yp = (0, 1)
        for j, t in enumerate(cols.tolist()):
            if t == 0:
                J_cam[:, :, j] = J_c
                if Jc_model is not None:
                    J_cam[:, :, j] += Jc_model
            elif t == 1:
                J_cam[:, 0, j] = 1.0
            elif t == 2:
                J_cam[:, 1, j] = 1.0
        corrected.add_correction_jacobians(self.mark_groups, self.marks, cam_params[self.cam], cols, J_cam)
        pr.J_eo, pr.J_point, pr.J_cam = J_eo, J_point, J_cam
        return pr


def project_observations(obs_photo: np.ndarray, obs_point: np.ndarray, XYZ: np.ndarray,
                         X0: np.ndarray, opk: np.ndarray, photo_camera: np.ndarray,
                         cam_params: np.ndarray, cam_models: Sequence[str],
                         cam_meta: Sequence[Mapping] | None = None, *, jacobians: bool = True,
                         R_dR=None, marks=None) -> Projection:
    """Project the observed points and (optionally) differentiate.

    Parameters
    ----------
    obs_photo, obs_point : (k,) indices into photos and points.
    XYZ : (n, 3) object points; X0 (m, 3), opk (m, 3) exterior orientation.
    photo_camera : (m,) camera index of each photo.
    cam_params : (K, 3 + p) ``[c, xp, yp, ap…]`` per camera (unused AP columns ignored).
    cam_models : (K,) registered AP model names; cam_meta : (K,) dicts (``b``, ``r0`` …).
    R_dR : optional precomputed ``rotation_and_derivatives(opk)``.
    marks : optional (k, 2) measured image coordinates: DBAT's residual definition for backward
        models (``xy`` is then the mark minus DBAT's residual, :mod:`.corrected`).
    """
    pj = Projector(obs_photo, obs_point, photo_camera, cam_models, cam_meta, marks=marks)
    R, dR = R_dR if R_dR is not None else (None, None)
    pr = pj.project(np.asarray(XYZ, float), np.asarray(X0, float), opk, cam_params, R=R)
    return pj.jacobians(pr, dR=dR) if jacobians else pr


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
