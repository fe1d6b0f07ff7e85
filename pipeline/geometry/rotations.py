"""Rotations and small geometric helpers, exactly as ``docs/conventions.md`` fixes them.

``R_cam_from_world = R3(kappa) @ R2(phi) @ R1(omega)``; ``p_cam = R_cam_from_world @ (X - X0)``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def rotation_from_opk(omega: float, phi: float, kappa: float) -> np.ndarray:
    """``R_cam_from_world`` (3, 3) from ω, φ, κ in radians (one triple of :func:`rotation_from_opk_many`)."""
    return rotation_from_opk_many(np.array([omega, phi, kappa], float))[0]


def rotation_from_opk_many(opk: np.ndarray) -> np.ndarray:
    """``R_cam_from_world = R3(κ) R2(φ) R1(ω)`` of every row: ``opk (m, 3)`` → ``(m, 3, 3)``."""
    opk = np.asarray(opk, dtype=float).reshape(-1, 3)
    so, co = np.sin(opk[:, 0]), np.cos(opk[:, 0])
    sp, cp = np.sin(opk[:, 1]), np.cos(opk[:, 1])
    sk, ck = np.sin(opk[:, 2]), np.cos(opk[:, 2])
    R = np.empty((opk.shape[0], 3, 3))
    R[:, 0, 0] = cp * ck
    R[:, 0, 1] = co * sk + so * sp * ck
    R[:, 0, 2] = so * sk - co * sp * ck
    R[:, 1, 0] = -cp * sk
    R[:, 1, 1] = co * ck - so * sp * sk
    R[:, 1, 2] = so * ck + co * sp * sk
    R[:, 2, 0] = sp
    R[:, 2, 1] = -so * cp
    R[:, 2, 2] = co * cp
    return R


def opk_from_rotation(R_cam_from_world: np.ndarray) -> np.ndarray:
    """ω, φ, κ (radians, shape (3,)) of a rotation matrix; φ in [−π/2, π/2].

    Inverse of :func:`rotation_from_opk` away from the gimbal lock φ = ±90°.
    """
    return opk_from_rotation_many(R_cam_from_world)[0]


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


def opk_from_rotation_many(R) -> np.ndarray:
    """ω, φ, κ (radians) of every rotation matrix: ``R (m, 3, 3)`` → ``(m, 3)``; φ in [−π/2, π/2]."""
    R = np.asarray(R, float).reshape(-1, 3, 3)
    phi = np.arcsin(np.clip(R[:, 2, 0], -1, 1))
    omega = np.arctan2(-R[:, 2, 1], R[:, 2, 2])
    kappa = np.arctan2(-R[:, 1, 0], R[:, 0, 0])
    return np.stack([omega, phi, kappa], axis=1)


def rotation_from_rotvec(r) -> np.ndarray:
    """Rotation matrices ``(m, 3, 3)`` of angle-axis (Rodrigues) vectors ``r (m, 3)``: the rotation
    by ``|r|`` about ``r / |r|`` (``P = R X``), as BAL, OpenCV and COLMAP use them."""
    return Rotation.from_rotvec(np.asarray(r, float).reshape(-1, 3)).as_matrix()


def nearest_rotation(M, return_singular_values: bool = False):
    """The rotation closest to ``M (3, 3)`` in the Frobenius norm (``U Vᵀ``, or ``U diag(1, 1, −1) Vᵀ``, of the SVD
    ``M = U S Vᵀ``); with ``return_singular_values`` also ``S``."""
    U, S, Vt = np.linalg.svd(np.asarray(M, float))
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1.0, 1.0, -1.0]) @ Vt
    return (R, S) if return_singular_values else R


def rotation_angle(opk_a, opk_b) -> np.ndarray:
    """Angle (rad) of the rotation between orientations ``opk_a`` and ``opk_b`` (m, 3), accurate
    near 0 (atan2 of the skew-symmetric and the trace part of ``R_a R_bᵀ``)."""
    D = rotation_from_opk_many(opk_a) @ np.transpose(rotation_from_opk_many(opk_b), (0, 2, 1))
    s = 0.5 * np.stack([D[:, 2, 1] - D[:, 1, 2], D[:, 0, 2] - D[:, 2, 0], D[:, 1, 0] - D[:, 0, 1]], axis=1)
    return np.arctan2(np.linalg.norm(s, axis=1), (np.einsum("mii->m", D) - 1.0) / 2.0)
