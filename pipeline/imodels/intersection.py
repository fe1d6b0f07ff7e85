"""Collinearity and space intersection (object points from two or more oriented rays).

Conventions (``docs/conventions.md``): ``[U, V, W]ᵀ = R_cam_from_world (X − X0)``,
``x = xp − c U/W``, ``y = yp − c V/W`` (mm, c > 0, a point in front of the camera has W < 0),
residuals observed − computed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["project_with_jacobian", "space_intersection", "Intersection"]


def project_with_jacobian(X: np.ndarray, X0: np.ndarray, R_cam_from_world: np.ndarray, c: float,
                          xp: float = 0.0, yp: float = 0.0):
    """Collinearity projection of points ``X (n, 3)`` and its derivative by ``[U, V, W]``.

    Returns
    -------
    xy : (n, 2) image coordinates, mm.
    d_xy_d_uvw : (n, 2, 3) ``∂(x, y)/∂(U, V, W)``; chain with ``R`` for ``∂/∂X`` (``−R`` for
        ``∂/∂X0``) and with ``dR/dangle (X − X0)`` for the angles.
    uvw : (n, 3) the camera-frame vectors.
    """
    X = np.asarray(X, dtype=float).reshape(-1, 3)
    uvw = (X - np.asarray(X0, float)) @ np.asarray(R_cam_from_world, float).T
    U, V, W = uvw[:, 0], uvw[:, 1], uvw[:, 2]
    xy = np.column_stack([xp - c * U / W, yp - c * V / W])
    d = np.zeros((X.shape[0], 2, 3))
    d[:, 0, 0] = -c / W
    d[:, 0, 2] = c * U / W ** 2
    d[:, 1, 1] = -c / W
    d[:, 1, 2] = c * V / W ** 2
    return xy, d, uvw


@dataclass(frozen=True, eq=False)
class Intersection:
    """Result of :func:`space_intersection` for ``n`` points seen in ``k`` photos.

    XYZ : (n, 3) intersected points (nan where fewer than two valid rays or ill-conditioned).
    cov : (n, 3, 3) covariance of XYZ propagated from the image covariance (orientation fixed).
    v : (n, k, 2) image residuals, observed − computed (nan for missing rays).
    ok : (n,) bool, point determined.
    in_front : (n, k) bool, the point lies in front of the camera (W < 0) for each valid ray.
    iterations : int.
    """

    XYZ: np.ndarray
    cov: np.ndarray
    v: np.ndarray
    ok: np.ndarray
    in_front: np.ndarray
    iterations: int


def space_intersection(xy, R_cam_from_world, X0, c, xp=0.0, yp=0.0, *, cov=None, valid=None,
                       max_iter: int = 30, tol: float = 1e-12) -> Intersection:
    """Least-squares space intersection of image rays (collinearity, orientation fixed).

    Parameters
    ----------
    xy : (n, k, 2) image coordinates of n points in k photos, mm.
    R_cam_from_world : (k, 3, 3); X0 : (k, 3) projection centres.
    c, xp, yp : scalars or (k,) interior orientation, mm.
    cov : (n, k, 2, 2) a-priori image covariance, mm² (default identity: ``cov`` of the result is
        then a cofactor matrix).
    valid : (n, k) bool, which rays exist (default all).

    The start is the point closest to all rays (closed form); Gauss–Newton then minimizes the
    weighted image residuals.  Inputs are not modified.
    """
    xy = np.asarray(xy, dtype=float)
    n, k = xy.shape[:2]
    R = np.asarray(R_cam_from_world, float).reshape(k, 3, 3)
    X0 = np.asarray(X0, float).reshape(k, 3)
    c, xp, yp = (np.broadcast_to(np.asarray(a, float), (k,)) for a in (c, xp, yp))
    valid = np.ones((n, k), bool) if valid is None else np.asarray(valid, bool).reshape(n, k)
    valid = valid & np.all(np.isfinite(xy), axis=2)
    if cov is None:
        P = np.broadcast_to(np.eye(2), (n, k, 2, 2)).copy()
    else:
        P = np.linalg.inv(np.asarray(cov, float).reshape(n, k, 2, 2))
    P[~valid] = 0.0
    xy0 = np.where(valid[..., None], xy, 0.0)

    # closed-form start: minimize the sum of squared distances to the rays
    u = np.stack([xy0[..., 0] - xp, xy0[..., 1] - yp, np.broadcast_to(-c, (n, k))], axis=2)
    d = np.einsum("kji,nkj->nki", R, u)  # R^T u: ray directions in the world frame
    d /= np.linalg.norm(d, axis=2, keepdims=True)
    proj = np.eye(3) - d[..., :, None] * d[..., None, :]  # (n, k, 3, 3)
    proj[~valid] = 0.0
    A = proj.sum(axis=1)
    b = np.einsum("nkij,kj->ni", proj, X0)
    ok = valid.sum(axis=1) >= 2
    ev = np.linalg.eigvalsh(np.where(ok[:, None, None], A, np.eye(3)))
    ok &= ev[:, 0] > 1e-12 * np.maximum(ev[:, 2], 1e-300)
    X = np.full((n, 3), np.nan)
    X[ok] = np.linalg.solve(A[ok], b[ok][..., None])[..., 0]

    scale = max(float(np.max(np.abs(X0 - X0.mean(axis=0)))), 1.0)
    it = 0
    Ninv = np.full((n, 3, 3), np.nan)
    for it in range(1, max_iter + 1):
        J = np.zeros((n, k, 2, 3))
        res = np.zeros((n, k, 2))
        for j in range(k):
            m = ok & valid[:, j]
            if not m.any():
                continue
            xy_c, dd, _ = project_with_jacobian(X[m], X0[j], R[j], c[j], xp[j], yp[j])
            J[m, j] = dd @ R[j]
            res[m, j] = xy[m, j] - xy_c
        JtP = np.einsum("nkai,nkab->nkib", J, P)
        N = np.einsum("nkib,nkbj->nij", JtP, J)
        g = np.einsum("nkib,nkb->ni", JtP, res)
        ev = np.linalg.eigvalsh(np.where(ok[:, None, None], N, np.eye(3)))
        ok &= ev[:, 0] > 1e-14 * np.maximum(ev[:, 2], 1e-300)
        dX = np.zeros((n, 3))
        if ok.any():
            Ninv[ok] = np.linalg.inv(N[ok])
            dX[ok] = np.einsum("nij,nj->ni", Ninv[ok], g[ok])
        X[ok] += dX[ok]
        if not ok.any() or np.max(np.abs(dX[ok])) < tol * scale:
            break
    X[~ok] = np.nan
    Ninv[~ok] = np.nan

    v = np.full((n, k, 2), np.nan)
    in_front = np.zeros((n, k), bool)
    for j in range(k):
        m = ok & valid[:, j]
        if m.any():
            xy_c, _, uvw = project_with_jacobian(X[m], X0[j], R[j], c[j], xp[j], yp[j])
            v[m, j] = xy[m, j] - xy_c
            in_front[m, j] = uvw[:, 2] < 0
    return Intersection(XYZ=X, cov=Ninv, v=v, ok=ok, in_front=in_front, iterations=it)
