"""Calibration quality in the manner of mrcal: projection uncertainty over the format and
cross-validation of two calibrations from disjoint photo subsets.

Projection uncertainty (mrcal's "mean-pcam" method).  A pixel ``q`` of the format is unprojected
with the adjusted camera to a ray, and a point ``p`` is placed on it at ``distance`` from the
projection centre (in the camera frame).  A perturbed solution changes (a) the camera parameters
``[c, xp, yp, ap…]`` and (b) the photos' orientations, which define where the camera frame sits
relative to the target (the reference frame).  The point is carried into the target frame through
each photo's adjusted orientation, ``P_i = X0_i + R_iᵀ p``, back into the camera frame through the
perturbed orientation, ``p'_i = R'_i (P_i − X0'_i)``, averaged over the photos, ``p' = mean p'_i``,
and projected with the perturbed camera: ``q' = q(p'; b')``.  ``Σ_q = J Σ Jᵀ`` with the joint
covariance ``Σ`` of the camera parameters and the photos' orientations (from the bundle's cofactor
columns) and ``J`` by central differences at a step of 1/100 of each parameter's σ.  With
``frame="camera"`` only the camera parameters are propagated (the point fixed in the camera frame;
independent of the distance).

Cross-validation: the photos of one camera are split into two disjoint sets, each is adjusted with
the bundle's settings (the other photos' observations left out), and the same pixels are compared:
``Δq = q(d · unproject(q; b₁); b₂) − q``.  To first order ``Δq = J(δb₂ − δb₁)`` with the two
solutions independent, so its covariance is ``Σ₁ + Σ₂`` of the camera-parameter-only propagation
("camera" frame) — the prediction the differences are checked against.  As mrcal's
``projection_diff`` does, the rotation between the two camera frames is also fitted (at infinity)
and the differences after the fit are compared with ``(I − H)(Σ₁ + Σ₂)(I − H)ᵀ``, ``H`` the hat
matrix of the three rotation parameters over the grid.

Pure numerics: arrays and results in, arrays out.  See ``docs/calibration-quality.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from baarda.pipeline.geometry.rotations import rotation_from_opk_many, rotation_from_rotvec

from ..camera import get_ap_model
from .adjust import adjust
from .rig import photo_columns

__all__ = ["project_camera", "unproject", "format_grid", "joint_covariance", "projection_jacobians",
           "projection_covariance", "worst_sigma", "ProjectionUncertainty", "projection_uncertainty",
           "split_photos", "CrossValidation", "cross_validate", "camera_photos"]


# -- the camera alone ------------------------------------------------------------------------
def project_camera(p_cam, cam_params, model: str, meta=None) -> np.ndarray:
    """Image coordinates (n, 2) of camera-frame points ``p_cam`` (n, 3) (z < 0 in front),
    ``cam_params = [c, xp, yp, ap…]`` — the collinearity equations of ``docs/conventions.md``."""
    p = np.asarray(p_cam, float)
    cp = np.asarray(cam_params, float)
    c, xp, yp = cp[0], cp[1], cp[2]
    xb = -c * p[:, 0] / p[:, 2]
    yb = -c * p[:, 1] / p[:, 2]
    out = np.column_stack([xp + xb, yp + yb])
    m = get_ap_model(model)
    if m.n_params:
        n = len(p)
        prm = np.broadcast_to(cp[3:3 + m.n_params], (n, m.n_params)).copy()
        dx, dy = m.distortion(xb, yb, prm, np.full(n, c), dict(meta or {}))
        out[:, 0] += dx
        out[:, 1] += dy
    return out


def unproject(xy, cam_params, model: str, meta=None, *, iterations: int = 50, tol: float = 1e-12) -> np.ndarray:
    """Unit camera-frame directions (n, 3), z < 0, whose projection is ``xy`` (n, 2): Newton on the
    ideal reduced coordinates ``x̄ + Δ(x̄) = xy − (xp, yp)`` with the model's ``jacobian_xy``.
    Pixels where it does not converge, or where the distortion folds over (``det(I + ∂Δ/∂x̄) ≤ 0``:
    outside the model's valid region), get NaN."""
    xy = np.asarray(xy, float)
    cp = np.asarray(cam_params, float)
    c = cp[0]
    target = xy - cp[1:3]
    xb = target.copy()
    ok = np.ones(len(xy), bool)
    m = get_ap_model(model)
    if m.n_params:
        n = len(xy)
        prm = np.broadcast_to(cp[3:3 + m.n_params], (n, m.n_params)).copy()
        cc = np.full(n, c)
        meta = dict(meta or {})
        for _ in range(iterations):
            dx, dy = m.distortion(xb[:, 0], xb[:, 1], prm, cc, meta)
            r = target - xb - np.column_stack([dx, dy])
            D = m.jacobian_xy(xb[:, 0], xb[:, 1], prm, cc, meta) + np.eye(2)
            bad = ~np.isfinite(D).all(axis=(1, 2)) | ~np.isfinite(r).all(axis=1) | (np.abs(np.linalg.det(D)) < 1e-12)
            D[bad] = np.eye(2)
            r[bad] = 0.0
            ok &= ~bad
            step = np.linalg.solve(D, r[:, :, None])[:, :, 0]
            xb = xb + step
            if np.max(np.abs(step)) < tol * max(1.0, c):
                break
        dx, dy = m.distortion(xb[:, 0], xb[:, 1], prm, cc, meta)
        r = target - xb - np.column_stack([dx, dy])
        D = m.jacobian_xy(xb[:, 0], xb[:, 1], prm, cc, meta) + np.eye(2)
        with np.errstate(invalid="ignore"):
            ok &= (np.abs(r).max(axis=1) < 1e-9 * max(1.0, c)) & (np.linalg.det(D) > 0)
        xb[~ok] = np.nan
    d = np.column_stack([xb[:, 0], xb[:, 1], np.full(len(xy), -c)])
    return d / np.linalg.norm(d, axis=1)[:, None]


def format_grid(format_mm, nx: int = 40, ny: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cell centres of an ``nx × ny`` grid over a format ``(width, height)`` centred on the origin:
    ``(x (nx,), y (ny,), xy (ny·nx, 2))``, rows of ``xy`` running over x first, y from top to bottom."""
    w, h = float(format_mm[0]), float(format_mm[1])
    if ny is None:
        ny = max(2, int(round(nx * h / w)))
    x = (np.arange(nx) + 0.5) / nx * w - w / 2
    y = h / 2 - (np.arange(ny) + 0.5) / ny * h
    X, Y = np.meshgrid(x, y)
    return x, y, np.column_stack([X.ravel(), Y.ravel()])


# -- covariance out of a bundle result -------------------------------------------------------
def camera_photos(res, j: int) -> np.ndarray:
    """Indices of the photos of camera ``j`` that took part in the adjustment ``res``."""
    return np.flatnonzero((res.block_in.photos.camera == j) & res.photo_used)


def joint_covariance(res, j: int, photos) -> np.ndarray:
    """Covariance (3+p + 6N, 3+p + 6N) of ``[c, xp, yp, ap…]`` of camera ``j`` and
    ``[X0, Y0, Z0, ω, φ, κ]`` of each of ``photos`` (N), a-posteriori as the result's
    covariances; rows of parameters that were not unknowns are 0."""
    prob = res.problem
    P = len(res.cam_param_names[j])
    if res.rig is not None:          # photos of rigs: through their frame's and sensor's unknowns (docs/rigs.md)
        return _joint_covariance_rig(res, j, photos, P)
    g = np.r_[prob.g_cam[j, :P], prob.g_eo[np.asarray(photos, int)].ravel()]
    free = g >= 0
    out = np.zeros((len(g), len(g)))
    if free.any():
        Q = np.asarray(res.cofactor_columns(g[free]))[g[free]]
        out[np.ix_(free, free)] = res.variance_factor * 0.5 * (Q + Q.T)
    return out


def _joint_covariance_rig(res, j: int, photos, P: int) -> np.ndarray:
    """:func:`joint_covariance` of a block with rigs: the covariance of the camera's parameters and
    the 12 frame and sensor unknowns of each photo, propagated to the photos' orientations."""
    prob = res.problem
    photos = np.asarray(photos, int)
    N = len(photos)
    cols, T = photo_columns(prob, res.state, photos)
    g = np.r_[prob.g_cam[j, :P], cols.ravel()]
    free = g >= 0
    C = np.zeros((len(g), len(g)))
    if free.any():
        Q = np.asarray(res.cofactor_columns(g[free]))[g[free]]
        C[np.ix_(free, free)] = res.variance_factor * 0.5 * (Q + Q.T)
    J = np.zeros((P + 6 * N, P + 12 * N))
    J[:P, :P] = np.eye(P)
    for i in range(N):
        J[P + 6 * i:P + 6 * i + 6, P + 12 * i:P + 12 * i + 12] = T[i]
    return J @ C @ J.T


# -- propagation -----------------------------------------------------------------------------
def _mean_pcam(p, X0, R, X0p, Rp):
    """Points ``p`` (n, 3) fixed in the target frame through the photos (X0, R), back through
    (X0p, Rp), averaged over the photos."""
    P = X0[:, None, :] + np.einsum("mji,nj->mni", R, p)                   # (N, n, 3) target frame
    back = np.einsum("mij,mnj->mni", Rp, P - X0p[:, None, :])
    return back.mean(axis=0)


def projection_jacobians(xy, distance: float, cam_params, model: str, meta=None, *, X0=None, opk=None,
                         sigmas=None) -> tuple[np.ndarray, np.ndarray | None]:
    """``(J_cam (n, 2, 3+p), J_eo (n, 2, 6N) or None)``: derivatives of the re-projected position of
    the point at ``distance`` on the ray of each pixel ``xy`` (n, 2) with respect to the camera
    parameters and (when ``X0``, ``opk`` (N, 3) are given) the photos' orientations
    ``[X0, Y0, Z0, ω, φ, κ]`` (mean-pcam, see the module).  Central differences with steps
    ``sigmas / 100`` (``sigmas``: the parameters' σ, camera first; 0 → derivative 0)."""
    cp = np.asarray(cam_params, float)
    P = len(cp)
    p = distance * unproject(xy, cp, model, meta)
    with_eo = X0 is not None
    N = len(X0) if with_eo else 0
    s = np.ones(P + 6 * N) * 1e-6 if sigmas is None else np.asarray(sigmas, float)
    n = len(p)
    J_cam = np.zeros((n, 2, P))
    for k in range(P):
        h = 0.01 * s[k]
        if h <= 0:
            continue
        a, b = cp.copy(), cp.copy()
        a[k] += h
        b[k] -= h
        J_cam[:, :, k] = (project_camera(p, a, model, meta) - project_camera(p, b, model, meta)) / (2 * h)
    if not with_eo:
        return J_cam, None
    X0 = np.asarray(X0, float)
    opk = np.asarray(opk, float)
    R = rotation_from_opk_many(opk)
    J_eo = np.zeros((n, 2, 6 * N))
    for i in range(N):
        for t in range(6):
            h = 0.01 * s[P + 6 * i + t]
            if h <= 0:
                continue
            pts = []
            for sign in (1.0, -1.0):
                X0p, opkp = X0.copy(), opk.copy()
                if t < 3:
                    X0p[i, t] += sign * h
                else:
                    opkp[i, t - 3] += sign * h
                pp = _mean_pcam(p, X0, R, X0p, rotation_from_opk_many(opkp))
                pts.append(project_camera(pp, cp, model, meta))
            J_eo[:, :, 6 * i + t] = (pts[0] - pts[1]) / (2 * h)
    return J_cam, J_eo


def projection_covariance(J_cam, J_eo, cov) -> np.ndarray:
    """(n, 2, 2) covariance of the projected positions: ``J Σ Jᵀ`` with ``J = [J_cam J_eo]``
    (``J_eo`` None: ``cov`` is the camera block only, or its leading block is used)."""
    J = J_cam if J_eo is None else np.concatenate([J_cam, J_eo], axis=2)
    S = np.asarray(cov, float)[:J.shape[2], :J.shape[2]]
    return np.einsum("nik,kl,njl->nij", J, S, J)


def worst_sigma(C) -> np.ndarray:
    """σ in the worst direction, ``√λ_max`` of each 2 × 2 covariance (n, 2, 2) — mrcal's default."""
    a, b, d = C[:, 0, 0], 0.5 * (C[:, 0, 1] + C[:, 1, 0]), C[:, 1, 1]
    lam = 0.5 * (a + d) + np.sqrt(np.maximum(0.25 * (a - d) ** 2 + b * b, 0.0))
    return np.sqrt(np.maximum(lam, 0.0))


@dataclass
class ProjectionUncertainty:
    """A projection-uncertainty map of one camera.  Image quantities in mm (the block's unit)."""

    x: np.ndarray          # (nx,) grid column centres
    y: np.ndarray          # (ny,) grid row centres (top to bottom)
    xy: np.ndarray         # (ny·nx, 2)
    cov: np.ndarray        # (ny·nx, 2, 2)
    sigma: np.ndarray      # (ny, nx) worst-direction σ
    distance: float
    frame: str             # "mean-pcam" or "camera"
    n_photos: int

    def at(self, x: float, y: float) -> float:
        """σ at the grid cell nearest to (x, y)."""
        return float(self.sigma[np.argmin(np.abs(self.y - y)), np.argmin(np.abs(self.x - x))])


def projection_uncertainty(res, j: int, distance: float, *, nx: int = 40, ny: int | None = None,
                           frame: str = "mean-pcam", format_mm=None) -> ProjectionUncertainty:
    """The projection-uncertainty map of camera ``j`` of a bundle result ``res`` (its covariances):
    a grid over the camera's format, the point at ``distance`` (object unit) on each pixel's ray."""
    if frame not in ("mean-pcam", "camera"):
        raise ValueError(f"frame must be 'mean-pcam' or 'camera', not {frame!r}")
    fmt = res.block_in.cameras.format_mm[j] if format_mm is None else format_mm
    x, y, xy = format_grid(fmt, nx, ny)
    cp = res.state.cam_params[j, :len(res.cam_param_names[j])]
    model = str(res.block_in.cameras.ap_model[j])
    meta = res.camera_meta[j]
    photos = camera_photos(res, j) if frame == "mean-pcam" else np.zeros(0, int)
    cov = joint_covariance(res, j, photos)
    sig = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    if frame == "mean-pcam":
        J_cam, J_eo = projection_jacobians(xy, distance, cp, model, meta, X0=res.state.X0[photos],
                                           opk=res.state.opk[photos], sigmas=sig)
    else:
        J_cam, J_eo = projection_jacobians(xy, distance, cp, model, meta, sigmas=sig)
    C = projection_covariance(J_cam, J_eo, cov)
    return ProjectionUncertainty(x=x, y=y, xy=xy, cov=C, sigma=worst_sigma(C).reshape(len(y), len(x)),
                                 distance=float(distance), frame=frame, n_photos=len(photos))


# -- cross-validation ------------------------------------------------------------------------
def split_photos(photos, how: str = "even-odd") -> tuple[np.ndarray, np.ndarray]:
    """Two disjoint subsets of the photo indices ``photos`` (in their order): ``even-odd``
    (1st, 3rd, … / 2nd, 4th, …) or ``halves`` (first half / second half)."""
    photos = np.asarray(photos, int)
    if how == "even-odd":
        return photos[0::2], photos[1::2]
    if how == "halves":
        h = (len(photos) + 1) // 2
        return photos[:h], photos[h:]
    raise ValueError(f"split must be 'even-odd' or 'halves', not {how!r}")


@dataclass
class CrossValidation:
    """Two calibrations of one camera from disjoint photo subsets compared on a grid (mm)."""

    x: np.ndarray
    y: np.ndarray
    diff: np.ndarray          # (ny, nx, 2) q(d·unproject(q; b1); b2) − q
    sigma1: np.ndarray        # (ny, nx) worst-direction σ of each calibration (camera frame)
    sigma2: np.ndarray
    sigma_pred: np.ndarray    # (ny, nx) √(σ1² + σ2²)
    mahalanobis2: np.ndarray  # (ny, nx) Δqᵀ (Σ1 + Σ2)⁻¹ Δq, ~χ²(2) if the prediction holds
    photos: tuple             # (indices of set 1, indices of set 2)
    results: tuple            # the two BundleResults
    rotation: np.ndarray | None = None       # (3,) rad, the rotation (vector) fitted between the camera frames
    diff_fit: np.ndarray | None = None       # (ny, nx, 2) Δq after the fit
    sigma_fit: np.ndarray | None = None      # (ny, nx) its predicted worst-direction σ, (I − H)(Σ₁+Σ₂)(I − H)ᵀ
    mahalanobis2_fit: np.ndarray | None = None

    @property
    def ratio_fit(self) -> np.ndarray:
        return np.hypot(self.diff_fit[..., 0], self.diff_fit[..., 1]) / self.sigma_fit

    @property
    def rms_fit(self) -> float:
        return float(np.sqrt(np.nanmean(np.sum(self.diff_fit ** 2, axis=-1))))

    @property
    def fraction_above_2sigma_fit(self) -> float:
        r = self.ratio_fit[np.isfinite(self.ratio_fit)]
        return float(np.mean(r > 2.0)) if r.size else float("nan")

    @property
    def norm(self) -> np.ndarray:
        return np.hypot(self.diff[..., 0], self.diff[..., 1])

    @property
    def ratio(self) -> np.ndarray:
        """|Δq| / √(σ1² + σ2²) per grid cell."""
        return self.norm / self.sigma_pred

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.nanmean(self.norm ** 2)))

    @property
    def fraction_above_2sigma(self) -> float:
        r = self.ratio[np.isfinite(self.ratio)]
        return float(np.mean(r > 2.0)) if r.size else float("nan")


def cross_validate(res, j: int, *, split: str = "even-odd", distance: float = 1.0, nx: int = 40,
                   ny: int | None = None, format_mm=None) -> CrossValidation:
    """Adjust the block of ``res`` twice, once with each half of camera ``j``'s photos (the other
    half's observations left out, every other camera's kept), with ``res``'s settings and active
    observations, and compare camera ``j`` of the two solutions (see the module)."""
    photos = camera_photos(res, j)
    sets = split_photos(photos, split)
    if min(len(s) for s in sets) < 2:
        raise ValueError(f"cross-validation needs at least 2 photos in each half, camera {j} has {len(photos)}")
    obs = res.block_in.observations
    results = []
    for keep in sets:
        drop = np.setdiff1d(photos, keep)
        act = res.obs_active & ~np.isin(obs.photo, drop)
        results.append(adjust(res.block_in, res.settings, obs_active=act, start=res.state, compute_initial=False))
    fmt = res.block_in.cameras.format_mm[j] if format_mm is None else format_mm
    x, y, xy = format_grid(fmt, nx, ny)
    model = str(res.block_in.cameras.ap_model[j])
    P = len(res.cam_param_names[j])
    maps = [projection_uncertainty(r, j, distance, nx=nx, ny=ny, frame="camera", format_mm=fmt) for r in results]
    b1 = results[0].state.cam_params[j, :P]
    b2 = results[1].state.cam_params[j, :P]
    p = distance * unproject(xy, b1, model, results[0].camera_meta[j])
    d = project_camera(p, b2, model, results[1].camera_meta[j]) - xy
    C = maps[0].cov + maps[1].cov
    fin = np.isfinite(d).all(axis=1) & np.isfinite(C).all(axis=(1, 2))
    m2 = np.full(len(d), np.nan)
    m2[fin] = np.einsum("ni,nij,nj->n", d[fin], np.linalg.pinv(C[fin]), d[fin])
    shape = (len(y), len(x))
    s1, s2 = maps[0].sigma, maps[1].sigma
    rot, dfit, sfit, m2fit = _rotation_fit(xy, p, results, j, model, b1, b2, fin)
    return CrossValidation(x=x, y=y, diff=d.reshape(*shape, 2), sigma1=s1, sigma2=s2,
                           sigma_pred=np.sqrt(s1 ** 2 + s2 ** 2), mahalanobis2=m2.reshape(shape),
                           photos=tuple(sets), results=tuple(results), rotation=rot,
                           diff_fit=dfit.reshape(*shape, 2), sigma_fit=sfit.reshape(shape),
                           mahalanobis2_fit=m2fit.reshape(shape))


def _rotation_fit(xy, p, results, j, model, b1, b2, fin):
    """mrcal's ``projection_diff`` with a fitted implied rotation: ``Δq(ω) = q(R(ω) p; b₂) − q``
    with ω minimising ``Σ |Δq|²`` over the valid cells (Gauss–Newton), and the prediction of the
    fitted differences, ``(I − H) (J₁Σ₁J₁ᵀ + J₂Σ₂J₂ᵀ) (I − H)ᵀ`` with ``H`` the rotation's hat matrix."""
    meta2 = results[1].camera_meta[j]
    pv = p[fin]
    n = len(pv)

    def resid(w):
        R = rotation_from_rotvec(w)[0]
        return (project_camera(pv @ R.T, b2, model, meta2) - xy[fin]).ravel()

    def jac(w):
        A = np.zeros((2 * n, 3))
        for t in range(3):
            e = np.zeros(3)
            e[t] = 1e-7
            A[:, t] = (resid(w + e) - resid(w - e)) / 2e-7
        return A

    w = np.zeros(3)
    for _ in range(5):
        A = jac(w)
        dw = np.linalg.lstsq(A, -resid(w), rcond=None)[0]
        w = w + dw
        if np.abs(dw).max() < 1e-13:
            break
    A = jac(w)
    dfit = np.full((len(xy), 2), np.nan)
    dfit[fin] = resid(w).reshape(-1, 2)
    # J₁Σ₁J₁ᵀ + J₂Σ₂J₂ᵀ = G Gᵀ with G = [J₁L₁, J₂L₂] (Σ = L Lᵀ), and (I − H) G = G − Q Qᵀ G with
    # Q an orthonormal basis of the rotation's columns: only the 2 × 2 blocks of the cells are formed
    G = []
    for res_k, bk in zip(results, (b1, b2)):
        cov = joint_covariance(res_k, j, np.zeros(0, int))
        J, _ = projection_jacobians(xy[fin], 1.0, bk, model, res_k.camera_meta[j],
                                    sigmas=np.sqrt(np.clip(np.diag(cov), 0, None)))
        lam, V = np.linalg.eigh(cov)
        G.append(J.reshape(2 * n, -1) @ (V * np.sqrt(np.clip(lam, 0, None))))
    G = np.hstack(G)
    Q = np.linalg.qr(A)[0]
    MG = (G - Q @ (Q.T @ G)).reshape(n, 2, -1)
    blocks = np.einsum("nik,njk->nij", MG, MG)
    sfit = np.full(len(xy), np.nan)
    sfit[fin] = worst_sigma(blocks)
    m2 = np.full(len(xy), np.nan)
    m2[fin] = np.einsum("ni,nij,nj->n", dfit[fin], np.linalg.pinv(blocks), dfit[fin])
    return w, dfit, sfit, m2
