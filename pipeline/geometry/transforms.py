"""Coordinate transformations as pure functions: the 2-D Helmert and affine designs, the 3-D
similarity (closed form, application, Jacobian).

2-D (rows ordered x1, y1, x2, y2, …)::

    Helmert (4 parameters a, b, tx, ty):   x' = a x − b y + tx,   y' = b x + a y + ty
    affine  (6 parameters):                x' = a0 + a1 x + a2 y, y' = b0 + b1 x + b2 y

3-D similarity (7 parameters ``scale, ω, φ, κ, tx, ty, tz``)::

    X = s · Mᵀ · x + T,      M = R_src_from_dst = R3(κ) R2(φ) R1(ω)

``M`` is built from ω, φ, κ exactly like a camera's ``R_cam_from_world`` (``docs/conventions.md``).
"""

from __future__ import annotations

import numpy as np

from baarda.pipeline.errors import AdjustmentError

from .rotations import opk_from_rotation, rotation_and_derivatives

__all__ = ["helmert_design", "affine_design", "PARAMETER_NAMES", "rotation_and_derivatives_one",
           "similarity_closed_form", "apply_similarity", "similarity_jacobian", "similarity_motions"]


def similarity_motions(D: np.ndarray, k: int = 7) -> np.ndarray:
    """Change of positions ``D`` (N, 3; relative to the motions' centre, in any scaling) under the
    first ``k`` infinitesimal similarity motions: (N, 3, k) — translations X, Y, Z, rotations
    ``ε × D`` about X, Y, Z, scale ``D``.  The datum's inner constraints, its diagnosis and the
    free network's exact-similarity step all use these columns."""
    D = np.asarray(D, float).reshape(-1, 3)
    out = np.zeros((len(D), 3, 7))
    out[:, [0, 1, 2], [0, 1, 2]] = 1.0
    out[:, 1, 3], out[:, 2, 3] = -D[:, 2], D[:, 1]
    out[:, 0, 4], out[:, 2, 4] = D[:, 2], -D[:, 0]
    out[:, 0, 5], out[:, 1, 5] = -D[:, 1], D[:, 0]
    out[:, :, 6] = D
    return out[:, :, :k]


def helmert_design(xy_left: np.ndarray) -> np.ndarray:
    """Design matrix (2n, 4) of the 2-D Helmert transformation ``x' = a x − b y + tx``,
    ``y' = b x + a y + ty`` (unknowns ``a, b, tx, ty``) at the points ``xy_left (n, 2)``; rows
    x1, y1, x2, y2, …"""
    xy = np.asarray(xy_left, float).reshape(-1, 2)
    n = xy.shape[0]
    A = np.zeros((2 * n, 4))
    A[0::2, 0], A[0::2, 1], A[0::2, 2] = xy[:, 0], -xy[:, 1], 1.0
    A[1::2, 0], A[1::2, 1], A[1::2, 3] = xy[:, 1], xy[:, 0], 1.0
    return A


def affine_design(xy: np.ndarray) -> np.ndarray:
    """Design matrix (2n, 6) of the 2-D affine transformation (unknowns ``a0, a1, a2, b0, b1, b2``)."""
    XY = np.asarray(xy, float).reshape(-1, 2)
    n = XY.shape[0]
    one, zero = np.ones(n), np.zeros(n)
    X, Y = XY[:, 0], XY[:, 1]
    A = np.empty((2 * n, 6))
    A[0::2] = np.column_stack([one, X, Y, zero, zero, zero])
    A[1::2] = np.column_stack([zero, zero, zero, one, X, Y])
    return A


PARAMETER_NAMES = ("scale", "omega", "phi", "kappa", "tx", "ty", "tz")


def rotation_and_derivatives_one(opk) -> tuple[np.ndarray, np.ndarray]:
    """``R (3, 3)`` and ``dR (3, 3, 3)`` (``dR[k] = ∂R/∂opk[k]``) of one ω, φ, κ triple."""
    R, dR = rotation_and_derivatives(np.asarray(opk, float).reshape(1, 3))
    return R[0], dR[0]


def similarity_closed_form(x_src, X_dst, weights=None, *, what: str = "similarity transformation"):
    """Closed-form least-squares similarity (Umeyama 1991; Horn 1987).

    Parameters
    ----------
    x_src, X_dst : (n, 3) corresponding points, n ≥ 3 and not collinear.
    weights : (n,) non-negative point weights (default equal).

    Returns
    -------
    params : (7,) ``scale, ω, φ, κ, tx, ty, tz`` with ``X ≈ s Mᵀ x + T``.
    """
    x = np.asarray(x_src, float).reshape(-1, 3)
    X = np.asarray(X_dst, float).reshape(-1, 3)
    w = np.ones(x.shape[0]) if weights is None else np.asarray(weights, float).reshape(-1)
    ok = np.all(np.isfinite(x), axis=1) & np.all(np.isfinite(X), axis=1) & (w > 0)
    x, X, w = x[ok], X[ok], w[ok]
    if x.shape[0] < 3:
        raise AdjustmentError(f"{what}: needs at least 3 points with known coordinates in both "
                              f"systems, got {x.shape[0]}")
    w = w / w.sum()
    mx, mX = w @ x, w @ X
    dx, dX = x - mx, X - mX
    S = (dX * w[:, None]).T @ dx  # Σ w (X − μX)(x − μx)ᵀ
    U, D, Vt = np.linalg.svd(S)
    var_x = float(w @ np.sum(dx ** 2, axis=1))
    if D[1] <= 1e-10 * max(D[0], 1e-300) or var_x <= 0:
        raise AdjustmentError(f"{what}: the common points are collinear (or coincide); "
                              "a 3-D similarity needs three points not on one line")
    E = np.diag([1.0, 1.0, np.sign(np.linalg.det(U) * np.linalg.det(Vt)) or 1.0])
    R_dst_from_src = U @ E @ Vt
    s = float(np.sum(D * np.diag(E)) / var_x)
    T = mX - s * R_dst_from_src @ mx
    return np.r_[s, opk_from_rotation(R_dst_from_src.T), T]


def apply_similarity(params, x_src) -> np.ndarray:
    """``X = s Mᵀ x + T`` for (n, 3) or (3,) points."""
    s = params[0]
    M = rotation_and_derivatives_one(np.asarray(params[1:4], float))[0]
    return s * np.asarray(x_src, float) @ M + np.asarray(params[4:7], float)


def similarity_jacobian(params, x_src) -> tuple[np.ndarray, np.ndarray]:
    """Transformed points (n, 3) and ``∂X/∂params`` (n, 3, 7)."""
    x = np.asarray(x_src, float).reshape(-1, 3)
    s = float(params[0])
    M, dM = rotation_and_derivatives_one(np.asarray(params[1:4], float))
    Mx = x @ M  # rows of Mᵀ x
    J = np.zeros((x.shape[0], 3, 7))
    J[:, :, 0] = Mx
    for k in range(3):
        J[:, :, 1 + k] = s * x @ dM[k]
    J[:, :, 4:] = np.eye(3)
    return s * Mx + np.asarray(params[4:7], float), J
