"""Initial values: space resection per photo and intersection per point, alternated.

* :func:`resection` — exterior orientation of one photo from ≥ 4 points with known object
  coordinates (linear DLT for ≥ 6 non-coplanar points, a plane homography for (nearly) coplanar
  points), then Gauss–Newton refinement of X0, ω, φ, κ (interior orientation and APs held).
* :func:`intersection` — object points from ≥ 2 oriented photos (least-squares ray
  intersection, then Gauss–Newton refinement), vectorised over points.
* :func:`initial_values` — for a block with missing orientations/coordinates: resect every photo
  that sees enough known points, intersect every point seen by ≥ 2 oriented photos, repeat.

Image coordinates in mm with ``c > 0`` (``docs/conventions.md``); distortion from the camera's AP
model is removed before the linear solutions (exactly for a model that corrects the measured
coordinates, ``brown-backward``; by fixed-point iteration otherwise) and modelled exactly in the
refinement.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from baarda.pipeline.errors import AdjustmentError
from baarda.pipeline.geometry import opk_from_rotation, rotation_from_opk_many
from baarda.pipeline.geometry.rotations import nearest_rotation, rotation_and_derivatives
from baarda.pipeline.model import Block

from ..camera import get_ap_model
from .collinearity import Projector, project_observations
from .phases import phase_step
from .settings import BundleSettings, camera_meta

__all__ = ["resection", "intersection", "initial_values", "ResectionResult"]


@dataclass
class ResectionResult:
    X0: np.ndarray          # (3,)
    opk: np.ndarray         # (3,) radians
    rms: float              # rms image residual, mm
    iterations: int
    method: str             # "dlt" | "plane" | "given"
    residuals: np.ndarray   # (n, 2) observed − computed, mm


def _undistort(xy, c, xp, yp, model="none", ap=None, meta=None, iters=5):
    """Ideal reduced coordinates x̄ from observed xy by fixed-point iteration of the AP model."""
    xy = np.asarray(xy, float)
    xb = xy - [xp, yp]
    mdl = get_ap_model(model)
    if mdl.n_params == 0 or ap is None:
        return xb
    prm = np.broadcast_to(np.asarray(ap, float)[:mdl.n_params], (len(xy), mdl.n_params))
    cc = np.full(len(xy), c)
    return _ideal(mdl, xb, prm, cc, meta or {}, iters)


def _ideal(mdl, xb, prm, c, meta, iters=5):
    """Ideal reduced coordinates of observed reduced ones ``xb``: exact for a model that gives the
    correction of measured coordinates (``correct``, e.g. ``brown-backward``), else fixed-point
    iteration ``x̄ = xb − Δ(x̄)``."""
    if callable(getattr(mdl, "correct", None)):
        gx, gy = mdl.correct(xb[:, 0], xb[:, 1], prm, c, meta)
        return np.column_stack([gx, gy])
    ideal = xb.copy()
    for _ in range(iters):
        dx, dy = mdl.distortion(ideal[:, 0], ideal[:, 1], prm, c, meta)
        ideal = xb - np.column_stack([dx, dy])
    return ideal


def _dlt(n_img, XYZ):
    """Calibrated DLT: n_img (n, 2) = (U/W, V/W); returns (R_cam_from_world, X0)."""
    ctr = XYZ.mean(axis=0)
    sc = np.sqrt(np.mean(np.sum((XYZ - ctr) ** 2, axis=1))) or 1.0
    Xn = (XYZ - ctr) / sc
    n = len(Xn)
    Xh = np.hstack([Xn, np.ones((n, 1))])
    A = np.zeros((2 * n, 12))
    u, v = n_img[:, 0], n_img[:, 1]
    A[0::2, 0:4] = Xh
    A[0::2, 8:12] = -u[:, None] * Xh
    A[1::2, 4:8] = Xh
    A[1::2, 8:12] = -v[:, None] * Xh
    _, _, Vt = np.linalg.svd(A)
    P = Vt[-1].reshape(3, 4)
    M = P[:, :3]
    if np.linalg.det(M) < 0:
        P = -P
        M = -M
    R, S = nearest_rotation(M, return_singular_values=True)
    t = P[:, 3] / S.mean()
    # d = R Xn + t must have W < 0 (in front); otherwise the solution is mirrored through X0
    W = Xn @ R[2] + t[2]
    if np.median(W) > 0:
        raise np.linalg.LinAlgError("DLT: points behind the camera")
    X0n = -R.T @ t
    return R, X0n * sc + ctr


def _plane(n_img, XYZ):
    """Resection from (nearly) coplanar points via a homography."""
    ctr = XYZ.mean(axis=0)
    _, _, Vt = np.linalg.svd(XYZ - ctr)
    e1, e2, e3 = Vt[0], Vt[1], np.cross(Vt[0], Vt[1])
    sc = np.sqrt(np.mean(np.sum((XYZ - ctr) ** 2, axis=1))) or 1.0
    a = (XYZ - ctr) @ e1 / sc
    b = (XYZ - ctr) @ e2 / sc
    n = len(a)
    A = np.zeros((2 * n, 9))
    P3 = np.column_stack([a, b, np.ones(n)])
    u, v = n_img[:, 0], n_img[:, 1]
    A[0::2, 0:3] = P3
    A[0::2, 6:9] = -u[:, None] * P3
    A[1::2, 3:6] = P3
    A[1::2, 6:9] = -v[:, None] * P3
    _, _, Vt2 = np.linalg.svd(A)
    Hm = Vt2[-1].reshape(3, 3)
    best = None
    for sign in (1.0, -1.0):
        H = sign * Hm
        s = 0.5 * (np.linalg.norm(H[:, 0]) + np.linalg.norm(H[:, 1]))
        r1, r2, t = H[:, 0] / s, H[:, 1] / s, H[:, 2] / s
        Rp = nearest_rotation(np.column_stack([r1, r2, np.cross(r1, r2)]))
        W = a * Rp[2, 0] + b * Rp[2, 1] + t[2]
        if np.median(W) >= 0:
            continue
        E = np.vstack([e1, e2, e3])        # rows: plane axes in world
        R = Rp @ E                          # R_cam_from_world
        X0 = ctr - sc * (R.T @ t)
        best = (R, X0)
    if best is None:
        raise np.linalg.LinAlgError("plane resection: no solution in front of the camera")
    return best


def resection(xy, XYZ, c, xp=0.0, yp=0.0, *, ap_model="none", ap=None, meta=None, X0=None, opk=None,
              max_iter=30, tol=1e-10) -> ResectionResult:
    """Space resection of one photo: exterior orientation from image points of known object points.

    Parameters
    ----------
    xy : (n, 2) image coordinates, mm.  XYZ : (n, 3) object coordinates (n ≥ 4; ≥ 3 with a start).
    c, xp, yp : interior orientation (mm, c > 0); ap_model / ap / meta : the camera's AP model.
    X0, opk : optional start; without it a closed-form solution is computed (DLT or plane).

    Returns
    -------
    :class:`ResectionResult` (X0, ω φ κ in radians, rms in mm).
    """
    xy = np.asarray(xy, float).reshape(-1, 2)
    XYZ = np.asarray(XYZ, float).reshape(-1, 3)
    n = len(xy)
    if n != len(XYZ):
        raise ValueError("resection: xy and XYZ must have the same length")
    method = "given"
    if X0 is None or opk is None or not np.all(np.isfinite(np.r_[X0, opk])):
        if n < 4:
            raise AdjustmentError(f"resection needs at least 4 points with known coordinates (got {n})")
        ideal = _undistort(xy, c, xp, yp, ap_model, ap, meta)
        nimg = -ideal / c                   # (U/W, V/W)
        ctr = XYZ.mean(axis=0)
        sv = np.linalg.svd(XYZ - ctr, compute_uv=False)
        planar = n < 6 or sv[2] < 0.05 * sv[0]
        cand = []
        for meth, fn in (("plane", _plane), ("dlt", _dlt)) if planar else (("dlt", _dlt), ("plane", _plane)):
            if meth == "dlt" and n < 6:
                continue
            try:
                R, X0c = fn(nimg, XYZ)
                cand.append((meth, X0c, opk_from_rotation(R)))
            except np.linalg.LinAlgError:
                continue
        if not cand:
            raise AdjustmentError("resection failed: the points are degenerate (collinear, or behind the camera)")
    else:
        cand = [("given", np.asarray(X0, float), np.asarray(opk, float))]
    best = None
    for meth, X0c, opkc in cand:
        try:
            out = _refine_eo(xy, XYZ, c, xp, yp, ap_model, ap, meta, X0c, opkc, max_iter, tol)
        except np.linalg.LinAlgError:
            continue
        if best is None or out[2] < 0.9 * best[2] - 1e-12:   # prefer the first (expected) method on ties
            best = out + (meth,)
    if best is None:
        raise AdjustmentError("resection did not converge (degenerate point configuration)")
    X0r, opkr, rms, it, res, meth = best
    return ResectionResult(X0=X0r, opk=opkr, rms=rms, iterations=it, method=meth, residuals=res)


def _cam_arrays(c, xp, yp, ap_model, ap):
    mdl = get_ap_model(ap_model)
    params = np.zeros((1, 3 + mdl.n_params))
    params[0, :3] = [c, xp, yp]
    if ap is not None and mdl.n_params:
        params[0, 3:] = np.asarray(ap, float)[:mdl.n_params]
    return params


def _refine_eo(xy, XYZ, c, xp, yp, ap_model, ap, meta, X0, opk, max_iter, tol):
    n = len(xy)
    params = _cam_arrays(c, xp, yp, ap_model, ap)
    X0 = np.asarray(X0, float).copy()
    opk = np.asarray(opk, float).copy()
    obs_ph = np.zeros(n, int)
    obs_pt = np.arange(n)
    lam = 0.0
    pr = project_observations(obs_ph, obs_pt, XYZ, X0[None], opk[None], np.zeros(1, int), params,
                              [ap_model], [meta or {}], jacobians=False)
    cost = np.sum((xy - pr.xy) ** 2)
    it = 0
    for it in range(1, max_iter + 1):
        pr = project_observations(obs_ph, obs_pt, XYZ, X0[None], opk[None], np.zeros(1, int), params,
                                  [ap_model], [meta or {}])
        r = (xy - pr.xy).reshape(-1)
        J = pr.J_eo.reshape(-1, 6)
        N = J.T @ J
        g = J.T @ r
        while True:
            Nd = N + lam * np.diag(np.diag(N))
            dx = np.linalg.solve(Nd, g)
            X0n, opkn = X0 + dx[:3], opk + dx[3:]
            pn = project_observations(obs_ph, obs_pt, XYZ, X0n[None], opkn[None], np.zeros(1, int), params,
                                      [ap_model], [meta or {}], jacobians=False)
            cn = np.sum((xy - pn.xy) ** 2)
            if cn <= cost * (1 + 1e-12) or lam > 1e10:
                break
            lam = 1e-3 if lam == 0 else lam * 10
        X0, opk, cost_old, cost = X0n, opkn, cost, cn
        lam = lam / 10 if lam > 1e-6 else 0.0
        if np.max(np.abs(dx[3:])) < tol and np.max(np.abs(dx[:3])) < tol * max(1.0, np.linalg.norm(X0)):
            break
    pr = project_observations(obs_ph, obs_pt, XYZ, X0[None], opk[None], np.zeros(1, int), params,
                              [ap_model], [meta or {}], jacobians=False)
    if np.median(pr.W) >= 0:
        raise np.linalg.LinAlgError("points behind the camera")
    res = xy - pr.xy
    return X0, opk, float(np.sqrt(np.mean(np.sum(res ** 2, axis=1)))), it, res


def intersection(xy, photo, X0, opk, c, xp=None, yp=None, *, point=None, ap_model=None, ap=None, meta=None,
                 refine=True, max_iter=10):
    """Spatial intersection: object points from image points in oriented photos (vectorised).

    Parameters
    ----------
    xy : (k, 2) image coordinates, mm.  photo : (k,) index into X0/opk.
    X0 (m, 3), opk (m, 3) : orientation of the photos.  c, xp, yp : scalars or (m,) per photo.
    point : (k,) point index of every ray (default: all rays belong to one point).
    ap_model, ap, meta : per photo (sequences of length m) or one for all.

    Returns
    -------
    XYZ (n_points, 3); nan for points with fewer than two rays.
    """
    xy = np.asarray(xy, float).reshape(-1, 2)
    photo = np.asarray(photo, int).reshape(-1)
    k = len(xy)
    point = np.zeros(k, int) if point is None else np.asarray(point, int).reshape(-1)
    X0 = np.asarray(X0, float).reshape(-1, 3)
    opk = np.asarray(opk, float).reshape(-1, 3)
    m = len(X0)
    cm = np.broadcast_to(np.asarray(c, float), (m,))
    xpm = np.broadcast_to(np.asarray(0.0 if xp is None else xp, float), (m,))
    ypm = np.broadcast_to(np.asarray(0.0 if yp is None else yp, float), (m,))
    models = np.broadcast_to(np.asarray("none" if ap_model is None else ap_model, dtype=object), (m,)).astype(str)
    pmax = max(get_ap_model(nm).n_params for nm in set(models.tolist()))
    params = np.zeros((m, 3 + pmax))
    params[:, 0], params[:, 1], params[:, 2] = cm, xpm, ypm
    if ap is not None and pmax:
        a = np.asarray(ap, float)
        a = np.broadcast_to(a, (m,) + a.shape[-1:]) if a.ndim == 1 else a
        params[:, 3:3 + a.shape[1]] = a[:, :pmax]
    metas = [meta or {}] * m if (meta is None or isinstance(meta, dict)) else list(meta)
    R = rotation_from_opk_many(opk)
    # ideal reduced coordinates (undistorted), per ray
    ideal = xy - params[photo, 1:3]
    for nm in set(models.tolist()):
        mdl = get_ap_model(nm)
        if mdl.n_params == 0:
            continue
        sel = models[photo] == nm
        prm = params[photo[sel], 3:3 + mdl.n_params]
        ideal[sel] = _ideal(mdl, ideal[sel].copy(), prm, params[photo[sel], 0], metas[int(photo[sel][0])])
    d_cam = np.column_stack([ideal, -params[photo, 0]])
    u = np.einsum("kji,kj->ki", R[photo], d_cam)           # Rᵀ d
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    A = np.eye(3)[None] - u[:, :, None] * u[:, None, :]
    b = np.einsum("kij,kj->ki", A, X0[photo])
    npt = int(point.max()) + 1 if k else 0
    As = np.stack([np.bincount(point, A.reshape(-1, 9)[:, t], minlength=npt) for t in range(9)], axis=1).reshape(npt, 3, 3)
    bs = np.stack([np.bincount(point, b[:, t], minlength=npt) for t in range(3)], axis=1)
    rays = np.bincount(point, minlength=npt)
    XYZ = np.full((npt, 3), np.nan)
    ok = rays >= 2
    ok &= np.abs(np.linalg.det(As)) > 1e-12 * np.maximum(np.einsum("pii->p", As), 1e-300) ** 3
    if ok.any():
        XYZ[ok] = np.linalg.solve(As[ok], bs[ok][:, :, None])[:, :, 0]
    if refine and ok.any():
        XYZ = _refine_points(xy, photo, point, XYZ, ok, X0, opk, params, models, metas, max_iter)
    return XYZ


def _refine_points(xy, photo, point, XYZ, ok, X0, opk, params, models, metas, max_iter):
    sel = ok[point]
    ph, pt, l = photo[sel], point[sel], xy[sel]
    npt = len(XYZ)
    R, dR = rotation_and_derivatives(opk)
    # the rays' grouping worked out once; only the points' Jacobians (no camera columns)
    proj = Projector(ph, pt, np.arange(len(X0)), models, metas, cam_cols=np.zeros(0, int))
    for it in range(max_iter):
        phase_step("initial values: intersection", it, max_iter, "iterations")
        pr = proj.jacobians(proj.project(np.nan_to_num(XYZ), X0, opk, params, R=R), dR=dR)
        r = l - pr.xy
        J = pr.J_point
        JJ = np.einsum("kia,kib->kab", J, J).reshape(-1, 9)
        Jr = np.einsum("kia,ki->ka", J, r)
        N = np.stack([np.bincount(pt, JJ[:, t], minlength=npt) for t in range(9)], axis=1).reshape(npt, 3, 3)
        g = np.stack([np.bincount(pt, Jr[:, t], minlength=npt) for t in range(3)], axis=1)
        dX = np.zeros_like(XYZ)
        try:
            dX[ok] = np.linalg.solve(N[ok], g[ok][:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:
            break
        XYZ = XYZ + dX
        if np.nanmax(np.abs(dX[ok])) < 1e-12 * max(1.0, float(np.nanmax(np.abs(XYZ[ok])))):
            break
    return XYZ


def initial_values(block: Block, *, ap_meta=None, max_rounds: int = 50, warn=None) -> Block:
    """A copy of ``block`` with every missing orientation and point coordinate computed.

    Known values (finite X0/opk, finite XYZ of control/check/tie points) are kept.  Photos are
    resected from points with coordinates (control first), points intersected from oriented
    photos, alternately until nothing changes.  Raises :class:`AdjustmentError` naming the photos
    or points that stay undetermined.
    """
    photos, points, obs, cams = block.photos, block.points, block.observations, block.cameras
    metas = camera_meta(block, BundleSettings(ap_meta=ap_meta or {}))
    X0 = np.array(photos.X0, float)
    opk = np.array(photos.opk, float)
    XYZ = np.array(points.XYZ, float)
    act = np.asarray(obs.active, bool)
    o_ph, o_pt, o_xy = obs.photo[act], obs.point[act], obs.xy[act]
    oriented = np.isfinite(X0).all(axis=1) & np.isfinite(opk).all(axis=1)
    known = np.isfinite(XYZ).all(axis=1)
    used_ph = np.zeros(len(photos), bool)
    used_ph[o_ph] = True
    used_pt = np.zeros(len(points), bool)
    used_pt[o_pt] = True
    cam = photos.camera
    for _ in range(max_rounds):
        changed = False
        # resection of every photo that sees ≥ 4 known points
        todo = np.flatnonzero(used_ph & ~oriented)
        for n_done, i in enumerate(todo):
            phase_step("initial values: resection", n_done, len(todo), "photos")
            sel = (o_ph == i) & known[o_pt]
            if sel.sum() < 4:
                continue
            j = cam[i]
            try:
                res = resection(o_xy[sel], XYZ[o_pt[sel]], cams.c[j], cams.xp[j], cams.yp[j],
                                ap_model=cams.ap_model[j], ap=cams.ap[j], meta=metas[j])
            except AdjustmentError:
                continue
            X0[i], opk[i] = res.X0, res.opk
            oriented[i] = True
            changed = True
        # intersection of every unknown point seen by ≥ 2 oriented photos
        sel = oriented[o_ph] & ~known[o_pt] & used_pt[o_pt]
        if sel.any():
            idx = np.flatnonzero(sel)
            new = intersection(o_xy[idx], o_ph[idx], X0, opk, cams.c[cam], cams.xp[cam], cams.yp[cam],
                               point=o_pt[idx], ap_model=cams.ap_model[cam], ap=cams.ap[cam],
                               meta=[metas[j] for j in cam])
            newpts = np.flatnonzero(np.isfinite(new).all(axis=1) & ~known[: len(new)])
            if newpts.size:
                XYZ[newpts] = new[newpts]
                known[newpts] = True
                changed = True
        if not changed:
            break
    missing_ph = np.flatnonzero(used_ph & ~oriented)
    if missing_ph.size:
        i = missing_ph[0]
        nk = int(((o_ph == i) & known[o_pt]).sum())
        raise AdjustmentError(
            f"no initial orientation for photo {str(photos.ids[i])!r}: it sees {nk} point(s) with known coordinates, "
            "resection needs 4 — give approximate X0/ω φ κ or more control points")
    missing_pt = np.flatnonzero(used_pt & ~known)
    if missing_pt.size:
        p = missing_pt[0]
        raise AdjustmentError(
            f"no initial coordinates for point {str(points.ids[p])!r}: it is seen by fewer than two oriented photos")
    return block.replace(photos=photos.replace(X0=X0, opk=opk), points=points.replace(XYZ=XYZ))
