"""Circular targets under perspective: the centre of the imaged ellipse (eccentricity) and target normals.

The image of a circle is an ellipse whose centre is **not** the image of the circle's centre (the
perspective eccentricity of circular targets; Dold 1996; Ahn, Warnecke & Kotowski 1999; Luhmann
2014).  Closed form: in the camera frame (``[U, V, W]ᵀ = R (X − X0)``, ``docs/conventions.md``) a
circle of radius ``r`` with centre ``d = (U, V, W)`` in the plane of unit normal ``m`` is the conic
``diag(1, 1, −r²)`` of the plane mapped by ``H = [u v d]`` (``u``, ``v`` orthonormal in the plane).
Its dual conic in the image is

    D = H diag(r², r², −1) Hᵀ = r² (I − m mᵀ) − d dᵀ

and the centre of a conic is the pole of the line at infinity ``(0, 0, 1)``: the direction
``D[:, 2]``.  Hence the ellipse centre in reduced coordinates (``U/W``, ``V/W``)::

    u_e = (U W + r² m_x m_z) / (W² − r² (1 − m_z²)),   v_e = (V W + r² m_y m_z) / (W² − r² (1 − m_z²))

and the eccentricity ``u_e − U/W = r² (m_x m_z W + U (1 − m_z²)) / (W (W² − r² (1 − m_z²)))``
(likewise in v): zero for a target parallel to the image plane (``m = ±e_z``), growing with the
square of the radius over the distance.  The sign of ``m`` does not matter (``m mᵀ``).

This is the pinhole part; a camera's distortion acts on the ellipse centre after it (the bundle
projects the ray of the ellipse centre with the camera's own model: ``baarda.pipeline.adjustment``,
``docs/targets.md``).  Pure numpy, no input is modified.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ellipse_centre_direction", "reduced_eccentricity", "plane_normals"]


def ellipse_centre_direction(d: np.ndarray, m: np.ndarray, radius) -> np.ndarray:
    """Camera-frame direction ``(k, 3)`` of the ellipse centre, scaled so that its third component is
    the circle centre's depth ``W`` (the point on the ray at the centre's depth).

    d (k, 3) circle centres in the camera frame; m (k, 3) unit normals of their planes (camera frame);
    radius scalar or (k,) (the unit of ``d``).
    """
    d = np.asarray(d, float).reshape(-1, 3)
    m = np.asarray(m, float).reshape(-1, 3)
    r2 = np.broadcast_to(np.asarray(radius, float) ** 2, (len(d),))
    W = d[:, 2]
    den = W ** 2 - r2 * (1.0 - m[:, 2] ** 2)                    # −D[2, 2]
    out = np.empty_like(d)
    out[:, 0] = (d[:, 0] * W + r2 * m[:, 0] * m[:, 2]) / den * W  # −D[0, 2] / −D[2, 2] · W
    out[:, 1] = (d[:, 1] * W + r2 * m[:, 1] * m[:, 2]) / den * W
    out[:, 2] = W
    return out


def reduced_eccentricity(d: np.ndarray, m: np.ndarray, radius) -> np.ndarray:
    """Eccentricity ``(k, 2)`` in reduced coordinates (``U/W``, ``V/W``): ellipse centre − image of the
    circle's centre (multiply by ``−c`` for the ideal image coordinates x̄, ȳ)."""
    d = np.asarray(d, float).reshape(-1, 3)
    e = ellipse_centre_direction(d, m, radius)
    return e[:, :2] / e[:, 2:3] - d[:, :2] / d[:, 2:3]


def plane_normals(XYZ: np.ndarray, neighbours: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Unit normal ``(n, 3)`` of each point's local plane: the best-fitting plane (least squares, the
    smallest singular vector) through the point and its ``neighbours`` nearest points.

    Returns ``(normals, ok)``; ``ok`` False (normal NaN) where fewer than 3 points are finite or the
    neighbourhood is (nearly) a line: its second singular value below 1e-3 of the first.
    """
    XYZ = np.asarray(XYZ, float).reshape(-1, 3)
    n = len(XYZ)
    normals = np.full((n, 3), np.nan)
    ok = np.zeros(n, bool)
    good = np.flatnonzero(np.isfinite(XYZ).all(axis=1))
    if good.size < 3:
        return normals, ok
    from scipy.spatial import cKDTree

    P = XYZ[good]
    k = min(int(neighbours) + 1, len(P))
    _, idx = cKDTree(P).query(P, k=k)
    idx = np.asarray(idx).reshape(len(P), k)
    for row, nb in zip(good, idx):
        Q = P[nb] - P[nb].mean(axis=0)
        _, s, vt = np.linalg.svd(Q, full_matrices=False)
        if len(s) < 3 or s[1] <= 1e-3 * s[0]:
            continue
        normals[row] = vt[2] / np.linalg.norm(vt[2])
        ok[row] = True
    return normals, ok
