"""Error ellipsoids and ellipses of points from their 3×3 covariance matrices (pure numerics).

For a point with covariance ``C`` (n, 3, 3):

* the **ellipsoid** ``xᵀ C⁻¹ x = k²``: semi-axes ``k √λ_j`` along the eigenvectors of ``C``
  (descending), ``k = √χ²₃(p)`` for the confidence ``p`` (``k = 1``: the standard ellipsoid);
* the **plan ellipse** from the XY block: semi-axes ``k₂ √λ`` with
  ``λ = (σx² + σy²)/2 ± √(((σx² − σy²)/2)² + σxy²)`` and the bearing ``θ = ½ atan2(2σxy, σx² − σy²)``
  of the major axis, counter-clockwise from +X towards +Y (degrees, in (−90°, 90°]), ``k₂ = √χ²₂(p)``;
* the **height** interval ``±k₁ σz``, ``k₁ = √χ²₁(p)`` (= Φ⁻¹((1 + p)/2)).

``confidence = None`` gives the 1-σ figures (k = 1 in every case).  Non-finite covariances (points
not adjusted) give nan; a fixed coordinate (zero variance) gives a zero axis.
"""

from __future__ import annotations

import numpy as np

__all__ = ["quantile_factor", "error_ellipsoids", "plan_ellipses", "height_intervals", "ellipse_columns"]


def quantile_factor(confidence: float | None, dof: int) -> float:
    """``√χ²_dof(confidence)``; 1 for ``confidence = None`` (the standard ellipse/ellipsoid)."""
    if confidence is None:
        return 1.0
    from scipy.stats import chi2

    p = float(confidence)
    if not 0.0 < p < 1.0:
        raise ValueError(f"confidence must lie strictly between 0 and 1, got {confidence}")
    return float(np.sqrt(chi2.ppf(p, dof)))


def _as_cov(cov) -> np.ndarray:
    C = np.array(cov, dtype=float, copy=True)
    if C.ndim == 2:
        C = C[None]
    if C.shape[-2:] != (3, 3):
        raise ValueError(f"covariances must be (n, 3, 3), got {C.shape}")
    return 0.5 * (C + np.swapaxes(C, 1, 2))


def error_ellipsoids(cov, confidence: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(semi_axes (n, 3), axes (n, 3, 3))``: semi-axes in descending order and the unit vectors
    along them as the columns of ``axes`` (right-handed; the first non-zero component of each
    positive), at ``confidence`` (χ² with 3 degrees of freedom)."""
    C = _as_cov(cov)
    n = len(C)
    k = quantile_factor(confidence, 3)
    semi = np.full((n, 3), np.nan)
    axes = np.full((n, 3, 3), np.nan)
    ok = np.isfinite(C).all(axis=(1, 2))
    if ok.any():
        w, V = np.linalg.eigh(C[ok])
        w, V = w[:, ::-1], V[:, :, ::-1]
        # sign convention: the largest-magnitude component of each axis positive, then right-handed
        big = np.take_along_axis(V, np.argmax(np.abs(V), axis=1)[:, None, :], axis=1)[:, 0, :]
        V = V * np.where(big < 0, -1.0, 1.0)[:, None, :]
        flip = np.linalg.det(V) < 0
        V[flip, :, 2] *= -1.0
        semi[ok] = k * np.sqrt(np.clip(w, 0.0, None))
        axes[ok] = V
    return semi, axes


def plan_ellipses(cov, confidence: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(a, b, bearing_deg)`` (each (n,)) of the XY block: semi-major, semi-minor axis and the
    direction of the major axis from +X towards +Y, at ``confidence`` (χ², 2 degrees of freedom)."""
    C = _as_cov(cov)
    k = quantile_factor(confidence, 2)
    sxx, syy, sxy = C[:, 0, 0], C[:, 1, 1], C[:, 0, 1]
    m = 0.5 * (sxx + syy)
    d = np.sqrt((0.5 * (sxx - syy)) ** 2 + sxy ** 2)
    a = k * np.sqrt(np.clip(m + d, 0.0, None))
    b = k * np.sqrt(np.clip(m - d, 0.0, None))
    theta = np.degrees(0.5 * np.arctan2(2.0 * sxy, sxx - syy))
    theta = np.where(theta <= -90.0, theta + 180.0, theta)
    return a, b, theta


def height_intervals(cov, confidence: float | None = None) -> np.ndarray:
    """(n,) half-width ``k₁ σz`` of the height interval (χ², 1 degree of freedom)."""
    C = _as_cov(cov)
    return quantile_factor(confidence, 1) * np.sqrt(np.clip(C[:, 2, 2], 0.0, None))


def ellipse_columns(cov, confidence: float | None = None, suffix: str = "") -> dict[str, np.ndarray]:
    """Columns for a points table: ``ellipsoid_a1/a2/a3`` (semi-axes, descending),
    ``ellipsoid_axis1_{x,y,z}`` (direction of the largest), ``plan_a``, ``plan_b``,
    ``plan_bearing_deg``, ``height_half``; the lengths in the units of the coordinates, their names
    ending in ``suffix`` (the coordinates' unit suffix, e.g. ``"_m"``, ``docs/conventions.md``)."""
    semi, axes = error_ellipsoids(cov, confidence)
    a, b, th = plan_ellipses(cov, confidence)
    out = {f"ellipsoid_a{j + 1}{suffix}": semi[:, j] for j in range(3)}
    out.update({f"ellipsoid_axis1_{c}": axes[:, j, 0] for j, c in enumerate("xyz")})
    out.update({f"plan_a{suffix}": a, f"plan_b{suffix}": b, "plan_bearing_deg": th,
                f"height_half{suffix}": height_intervals(cov, confidence)})
    return out
