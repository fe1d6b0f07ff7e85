"""Error ellipsoids / ellipses against closed forms and Monte Carlo coverage."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from baarda.pipeline.stats.ellipses import (ellipse_columns, error_ellipsoids, height_intervals, plan_ellipses,
                                            quantile_factor)


def _cov(rng, n):
    R = Rotation.random(n, random_state=rng).as_matrix()
    s = rng.uniform(0.1, 3.0, (n, 3))
    return np.einsum("nij,nj,nkj->nik", R, s ** 2, R), R, s


def test_ellipsoid_closed_form_and_reconstruction():
    rng = np.random.default_rng(1)
    C, R, s = _cov(rng, 50)
    C0 = C.copy()
    semi, axes = error_ellipsoids(C)
    assert np.array_equal(C, C0)                                    # input untouched
    assert np.allclose(semi, -np.sort(-s, axis=1))                  # known semi-axes, descending
    assert np.allclose(np.einsum("nij,nj,nkj->nik", axes, semi ** 2, axes), C)
    assert np.allclose(np.linalg.det(axes), 1.0)
    # 95 %: χ²₃ quantile 7.8147 → factor 2.7955
    semi95, _ = error_ellipsoids(C, 0.95)
    assert np.allclose(semi95 / semi, np.sqrt(7.814727903251178))


def test_plan_ellipse_closed_form():
    # σx = 2, σy = 1 rotated by +30° about Z: a = 2, b = 1, bearing 30°
    t = np.radians(30.0)
    Rz = np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]])
    C = Rz @ np.diag([4.0, 1.0, 9.0]) @ Rz.T
    a, b, th = plan_ellipses(C)
    assert a[0] == pytest.approx(2.0) and b[0] == pytest.approx(1.0) and th[0] == pytest.approx(30.0)
    a, b, th = plan_ellipses(np.diag([1.0, 4.0, 1.0]))              # major axis along Y: 90°
    assert th[0] == pytest.approx(90.0) and a[0] == pytest.approx(2.0)
    assert height_intervals(C)[0] == pytest.approx(3.0)
    assert height_intervals(C, 0.95)[0] == pytest.approx(3.0 * 1.959963984540054)
    assert quantile_factor(0.3934693402873666, 2) == pytest.approx(1.0)   # 1-σ ellipse: 39.3 %


def test_monte_carlo_coverage():
    """Samples of N(0, C): the fraction inside the ellipsoid / plan ellipse / height interval is
    the confidence (binomial sd ≈ 0.0015 for 100 000 draws)."""
    rng = np.random.default_rng(7)
    C, _, _ = _cov(rng, 1)
    x = rng.multivariate_normal(np.zeros(3), C[0], size=100_000)
    p = 0.9
    semi, axes = error_ellipsoids(C, p)
    u = x @ axes[0]
    assert np.mean(np.sum((u / semi[0]) ** 2, axis=1) <= 1) == pytest.approx(p, abs=0.006)
    a, b, th = plan_ellipses(C, p)
    t = np.radians(th[0])
    e1, e2 = x[:, 0] * np.cos(t) + x[:, 1] * np.sin(t), -x[:, 0] * np.sin(t) + x[:, 1] * np.cos(t)
    assert np.mean((e1 / a[0]) ** 2 + (e2 / b[0]) ** 2 <= 1) == pytest.approx(p, abs=0.006)
    assert np.mean(np.abs(x[:, 2]) <= height_intervals(C, p)[0]) == pytest.approx(p, abs=0.006)


def test_non_finite_and_fixed_points():
    C = np.stack([np.full((3, 3), np.nan), np.diag([0.0, 0.0, 4.0])])
    cols = ellipse_columns(C)
    assert np.isnan(cols["ellipsoid_a1"][0]) and np.isnan(cols["plan_a"][0])
    assert cols["ellipsoid_a1"][1] == pytest.approx(2.0) and cols["ellipsoid_a3"][1] == 0.0
    assert cols["plan_a"][1] == 0.0 and cols["height_half"][1] == pytest.approx(2.0)
    with pytest.raises(ValueError, match="confidence"):
        error_ellipsoids(C, 1.5)
