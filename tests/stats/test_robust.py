"""Robust estimation (pipeline/stats/robust.py): weight functions against their closed forms and
the IRLS driver against independent optimisers (scipy's least_squares with Huber loss, a direct
minimisation of the M-estimator's objective, the exact L1 regression by linear programming)."""

import numpy as np
import pytest
from scipy import optimize

from baarda.pipeline.stats import (DEFAULT_C, LinearModel, irls, robust_rho, robust_weights,
                                   scale_covariance, weighted_linear_refit)

from .stats_helpers import helmert_model


# ------------------------------------------------------------------ weight functions
def test_huber_weights_closed_form():
    u = np.array([0.0, 1.0, -1.5, 1.5000001, 3.0, -6.0, 150.0])
    w = robust_weights(u, "huber", 1.5)
    expect = [1, 1, 1, 1.5 / 1.5000001, 0.5, 0.25, 0.01]
    np.testing.assert_allclose(w, expect, rtol=1e-12)
    assert robust_weights(3.0, "huber", None) == pytest.approx(0.5)   # default c = 1.5


def test_danish_weights_closed_form():
    c = 2.5
    u = np.array([0.0, 2.5, -2.5, 3.0, 5.0, -7.5])
    w = robust_weights(u, "danish", c)
    expect = [1, 1, 1, np.exp(1 - 1.44), np.exp(1 - 4), np.exp(1 - 9)]
    np.testing.assert_allclose(w, expect, rtol=1e-12)
    # ω < 0.5 exactly beyond c √(1 + ln 2) (the report's threshold near the w-test's 3.29)
    edge = c * np.sqrt(1 + np.log(2))
    assert robust_weights(edge, "danish", c) == pytest.approx(0.5, rel=1e-12)
    assert DEFAULT_C["danish"] == c


def test_l1_weights_closed_form():
    w = robust_weights([0.0, 1e-5, 0.5, -4.0], "l1", 1e-3)
    np.testing.assert_allclose(w, [1e3, 1e3, 2.0, 0.25])


@pytest.mark.parametrize("method,c", [("huber", 1.5), ("danish", 2.5), ("huber", 0.7), ("danish", 1.0),
                                      ("l1", 1e-3)])
def test_weight_is_psi_over_u(method, c):
    """ω(u)·u = ρ'(u): central differences of ρ on a grid avoiding the kinks."""
    u = np.linspace(-12, 12, 2401)
    u = u[(np.abs(np.abs(u) - c) > 1e-3) & (np.abs(u) > 1e-2)]
    h = 1e-6
    dr = (robust_rho(u + h, method, c) - robust_rho(u - h, method, c)) / (2 * h)
    np.testing.assert_allclose(robust_weights(u, method, c) * u, dr, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("method", ["huber", "danish"])
def test_continuous_at_c(method):
    c = DEFAULT_C[method]
    for f in (robust_weights, robust_rho):
        lo, hi = f(c - 1e-9, method, c), f(c + 1e-9, method, c)
        assert abs(lo - hi) < 1e-8


def test_bad_method_and_c():
    with pytest.raises(ValueError, match="huber, danish, l1"):
        robust_weights(1.0, "tukey")
    with pytest.raises(ValueError, match="positive"):
        robust_weights(1.0, "huber", -1.0)


# ------------------------------------------------------------------ a regression with an outlier
def _line(seed=1, n=25, blunder=12.0):
    g = np.random.default_rng(seed)
    t = np.sort(g.uniform(0, 10, n))
    A = np.c_[np.ones(n), t, 0.05 * t ** 2]
    sig = g.uniform(0.5, 2.0, n)
    l = A @ np.array([2.0, -0.7, 0.3]) + sig * g.standard_normal(n)
    l[7] += blunder * sig[7]
    return A, l, sig


def _model(A, l, sig):
    return LinearModel(A, l, 1.0 / sig ** 2, sigma0=1.0)


def test_huber_apriori_matches_scipy_least_squares():
    A, l, sig = _line()
    m = _model(A, l, sig)
    snap = m.adjust().snapshot
    res = irls(weighted_linear_refit(m), snap, "huber", 1.5, standardise="apriori", tol=1e-12, max_iter=200)
    assert res.converged
    x = np.linalg.lstsq(A * np.sqrt(res.weights / sig ** 2)[:, None], l * np.sqrt(res.weights / sig ** 2),
                        rcond=None)[0]
    ref = optimize.least_squares(lambda p: (l - A @ p) / sig, np.zeros(3), loss="huber", f_scale=1.5,
                                 xtol=1e-15, ftol=1e-15, gtol=1e-15)
    np.testing.assert_allclose(x, ref.x, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(l - A @ x, res.fit.v, atol=1e-9)
    assert res.downweighted[0] == 7 and res.weights[7] < 0.2
    # least squares is pulled by the outlier, Huber much less
    x_ls = np.linalg.lstsq(A / sig[:, None], l / sig, rcond=None)[0]
    keep = np.arange(len(l)) != 7
    x_clean = np.linalg.lstsq(A[keep] / sig[keep, None], l[keep] / sig[keep], rcond=None)[0]
    assert np.linalg.norm(x - x_clean) < 0.5 * np.linalg.norm(x_ls - x_clean)


def test_huber_redundancy_minimises_its_objective():
    """standardise = redundancy: the fixed point minimises Σ r_i ρ(v_i / (σ_i √r_i)) (convex)."""
    A, l, sig = _line(seed=4)
    m = _model(A, l, sig)
    snap = m.adjust().snapshot
    res = irls(weighted_linear_refit(m), snap, "huber", 1.5, tol=1e-12, max_iter=300)
    assert res.converged and 7 in res.downweighted
    r = np.asarray(snap.r)
    s = sig * np.sqrt(r)
    np.testing.assert_allclose(res.scale, s)
    obj = lambda p: np.sum(r * robust_rho((l - A @ p) / s, "huber", 1.5))
    x0 = np.linalg.lstsq(A / sig[:, None], l / sig, rcond=None)[0]
    ref = optimize.minimize(obj, x0, method="BFGS", options={"gtol": 1e-10})
    v = np.asarray(res.fit.v)
    x = np.linalg.lstsq(A, l - v, rcond=None)[0]
    np.testing.assert_allclose(x, ref.x, rtol=1e-5, atol=1e-6)
    assert obj(x) <= ref.fun + 1e-9


def test_danish_removes_the_outlier():
    """The redescending Danish weight of a 12σ blunder underflows: the estimate is the weighted
    least-squares estimate without that observation, and the fixed point is stationary for its
    objective (finite-difference gradient)."""
    A, l, sig = _line(seed=2)
    m = _model(A, l, sig)
    snap = m.adjust().snapshot
    res = irls(weighted_linear_refit(m), snap, "danish", tol=1e-10)
    assert res.converged and list(res.downweighted) == [7] and res.weights[7] < 1e-6
    keep = np.arange(len(l)) != 7
    ref = LinearModel(A[keep], l[keep], res.weights[keep] / sig[keep] ** 2).adjust()
    np.testing.assert_allclose(np.asarray(res.fit.v)[keep], ref.v, atol=1e-6)
    s, r = res.scale, np.asarray(snap.r)
    obj = lambda p: np.sum(r * robust_rho((l - A @ p) / s, "danish", DEFAULT_C["danish"]))
    x = np.linalg.lstsq(A, l - np.asarray(res.fit.v), rcond=None)[0]
    grad = optimize.approx_fprime(x, obj, 1e-7)
    assert np.max(np.abs(grad)) < 1e-4


def test_l1_matches_linear_programming():
    """L1 by IRLS with a small floor against the exact L1 regression min Σ |l − A x|/σ (linprog)."""
    A, l, sig = _line(seed=3, n=20)
    n, u = A.shape
    m = _model(A, l, sig)
    snap = m.adjust().snapshot
    res = irls(weighted_linear_refit(m), snap, "l1", 1e-7, standardise="apriori", tol=1e-9, max_iter=2000)
    # variables x (u, free), e+ (n), e- (n) ≥ 0: A x + e+ − e- = l, minimise Σ (e+ + e-)/σ
    Aeq = np.c_[A, np.eye(n), -np.eye(n)]
    cost = np.r_[np.zeros(u), 1 / sig, 1 / sig]
    lp = optimize.linprog(cost, A_eq=Aeq, b_eq=l, bounds=[(None, None)] * u + [(0, None)] * (2 * n),
                          method="highs")
    assert lp.status == 0
    x = np.linalg.lstsq(A, l - np.asarray(res.fit.v), rcond=None)[0]
    l1 = np.sum(np.abs(l - A @ x) / sig)
    assert l1 == pytest.approx(lp.fun, rel=1e-6)
    np.testing.assert_allclose(x, lp.x[:u], rtol=1e-4, atol=1e-4)


def test_clean_data_and_large_c_is_least_squares():
    A, l, sig = _line(blunder=0.0)
    m = _model(A, l, sig)
    snap = m.adjust().snapshot
    res = irls(weighted_linear_refit(m), snap, "huber", 50.0)
    assert res.iterations == 0 and res.converged and res.fit is snap
    assert res.downweighted.size == 0 and np.all(res.weights == 1)


def test_inactive_rows_and_read_only():
    A, l, sig = _line()
    m = _model(A, l, sig)
    act = np.ones(len(l), bool)
    act[3] = False
    snap = m.adjust(act).snapshot
    l0 = l.copy()
    res = irls(weighted_linear_refit(m, act), snap, "danish")
    assert not res.judged[3] and res.weights[3] == 1 and np.isnan(res.u[3])
    assert not res.fit.active[3]
    assert np.array_equal(l, l0)
    with pytest.raises(ValueError):
        res.weights[0] = 2.0
    s = res.summary()
    assert s["n_downweighted"] == len(s["downweighted"]) and s["downweighted"][0]["row"] == 7


def test_full_weight_matrix_weighting():
    """Correlated rows: the weighted model's P is W^½ P W^½, and scale_covariance's inverse is it."""
    m = helmert_model()
    w = np.linspace(0.2, 1.0, m.n)
    snap = weighted_linear_refit(m)(w)
    Pw = np.sqrt(np.outer(w, w)) * m.P
    ref = LinearModel(m.A, m.l, Pw, m.sigma0, m.labels, m.group).adjust().snapshot
    np.testing.assert_allclose(snap.v, ref.v, atol=1e-12)
    np.testing.assert_allclose(snap.r, ref.r, atol=1e-12)
    C = np.linalg.inv(m.P)
    blocks = np.array([C[2 * i:2 * i + 2, 2 * i:2 * i + 2] for i in range(m.n // 2)])
    Cw = scale_covariance(blocks, w)
    for i in range(m.n // 2):
        Pi = np.linalg.inv(blocks[i])
        Wi = np.sqrt(np.outer(w[2 * i:2 * i + 2], w[2 * i:2 * i + 2]))
        np.testing.assert_allclose(np.linalg.inv(Cw[i]), Wi * Pi, rtol=1e-10)
    assert not np.shares_memory(Cw, blocks)
