"""Monte Carlo checks of the test statistics on non-trivial correlated designs (seeded).

Bounds are binomial: |rate − p| ≤ 4 √(p(1−p)/N) per row (4σ so that 18–30 rows at once stay
reliable; the seeds are fixed, so a pass is reproducible).
"""

import numpy as np
import pytest
from scipy import stats

from baarda.pipeline.stats import (critical_normal, delta0, joint_test_2d, mdb, tau_critical,
                            tau_critical_max, tau_distribution, w_test)

from .stats_helpers import cov_of, operators, stacked


def binomial_ok(count, N, p, k=4.0):
    return abs(count / N - p) <= k * np.sqrt(p * (1 - p) / N)


def simulate(model, N, seed):
    """N noise vectors e ~ N(0, σ0² P⁻¹) (rows)."""
    L = np.linalg.cholesky(cov_of(model))
    return np.random.default_rng(seed).standard_normal((N, model.n)) @ L.T


def w_rates(model, alpha0, beta0, N, seed):
    snap = model.adjust().snapshot
    R, G = operators(model)
    E = simulate(model, N, seed)
    big = stacked(snap, E @ G.T, E @ R.T)
    w = w_test(big).reshape(N, model.n)
    k = critical_normal(alpha0)
    false_alarm = np.sum(np.abs(w) > k, axis=0)
    # power: bias ∇0l_i in row i alone shifts Pv by G[:, i] ∇0l_i (linearity)
    nab = mdb(snap, delta0(alpha0, beta0))
    shift = np.diag(G) * nab / (snap.sigma0 * np.sqrt(snap.PQvvP))
    power = np.sum(np.abs(w + shift[None, :]) > k, axis=0)
    # the per-row statistic v_i/(σ0 √Qvv_ii) (ignores the correlation) is N(0,1) too but weaker
    Qvv_diag = np.einsum("ij,jk,ik->i", R, cov_of(model), R) / snap.sigma0 ** 2
    v_shift = np.diag(R) * nab / (snap.sigma0 * np.sqrt(Qvv_diag))
    naive = (E @ R.T) / (snap.sigma0 * np.sqrt(Qvv_diag))
    naive_power = np.sum(np.abs(naive + v_shift[None, :]) > k, axis=0)
    return false_alarm, power, naive_power, shift


@pytest.mark.parametrize("design", ["helmert", "poly"])
@pytest.mark.parametrize("alpha0, N", [(0.01, 50_000), pytest.param(0.001, 200_000, marks=pytest.mark.slow)])
def test_w_test_false_alarm_and_power_at_mdb(design, alpha0, N, request):
    model = request.getfixturevalue(design)
    fa, pw, naive_pw, shift = w_rates(model, alpha0, 0.80, N, seed=11)
    print(f"\n{design}, α0 = {alpha0}, N = {N}: false-alarm rate per row {fa.min() / N:.5f}–{fa.max() / N:.5f}, "
          f"power at the MDB {pw.min() / N:.4f}–{pw.max() / N:.4f} (β0 = 0.80)")
    np.testing.assert_allclose(shift, delta0(alpha0, 0.80), rtol=1e-9)  # MDB ↔ δ0
    assert all(binomial_ok(c, N, alpha0) for c in fa), fa / N
    assert all(binomial_ok(c, N, 0.80) for c in pw), pw / N
    # the test can fail: the correlation-blind statistic misses the 80 % power on some rows
    assert not all(binomial_ok(c, N, 0.80) for c in naive_pw)


@pytest.mark.slow
@pytest.mark.parametrize("design", ["helmert", "poly"])
def test_w_test_false_alarm_and_power_at_0p1_percent_large(design, request):
    model = request.getfixturevalue(design)
    N = 2_000_000
    for seed in (12, 13):
        fa, pw, _, _ = w_rates(model, 0.001, 0.80, N, seed=seed)
        assert all(binomial_ok(c, N, 0.001) for c in fa), fa / N
        assert all(binomial_ok(c, N, 0.80) for c in pw), pw / N


def test_joint_2d_test_false_alarm(helmert):
    snap = helmert.adjust().snapshot
    R, G = operators(helmert)
    N = 20_000
    E = simulate(helmert, N, seed=21)
    big = stacked(snap, E @ G.T, E @ R.T)
    res = joint_test_2d(big, alpha=0.01)
    assert res.T.size == 9 * N
    flagged = res.flagged.reshape(N, 9).sum(axis=0)
    assert all(binomial_ok(c, N, 0.01) for c in flagged), flagged / N
    # T ~ χ²(2): mean 2 per point
    assert np.allclose(res.T.reshape(N, 9).mean(axis=0), 2.0, atol=4 * 2 / np.sqrt(N))
    # the same statistic without the x–y cofactor (diagonal blocks only) is not χ²(2)
    w = w_test(big).reshape(N, 18)
    Td = w[:, 0::2] ** 2 + w[:, 1::2] ** 2
    assert not all(binomial_ok(c, N, 0.01) for c in np.sum(Td > res.critical, axis=0))


# --------------------------------------------------------------------------------- Pope's τ
@pytest.fixture(scope="module")
def tau_sample():
    """τ of the paper-000 regression design (n = 6, u = 2, r = 4) over 40 000 noise vectors."""
    from baarda.pipeline.stats import LinearModel
    x = np.array([-4, -3, -2, -1, 0, 10.0])
    model = LinearModel(np.c_[np.ones(6), x], np.zeros(6), sigma0=0.5)
    snap = model.adjust().snapshot
    R, G = operators(model)
    N = 40_000
    E = simulate(model, N, seed=31)
    V = E @ R.T
    big = stacked(snap, E @ G.T, V)
    w = w_test(big).reshape(N, 6)
    s0h = np.sqrt(np.sum(V * (E @ G.T), axis=1) / snap.dof)
    return w * (snap.sigma0 / s0h)[:, None], snap.dof


def test_tau_closed_forms():
    r = 4
    t = np.linspace(-1.99, 1.99, 41)
    # τ²/r ~ Beta(1/2, (r−1)/2): independent closed form of the CDF
    F_beta = 0.5 + np.sign(t) * 0.5 * stats.beta.cdf(t * t / r, 0.5, (r - 1) / 2)
    np.testing.assert_allclose(tau_distribution.cdf(t, r), F_beta, atol=1e-12)
    # density integrates to the CDF
    grid = np.linspace(-2, 2, 200_001)
    cdf_num = np.cumsum(tau_distribution.pdf(grid, r)) * (grid[1] - grid[0])
    assert cdf_num[-1] == pytest.approx(1.0, abs=1e-3)
    np.testing.assert_allclose(tau_distribution.ppf(tau_distribution.cdf(t, r), r), t, atol=1e-9)


def test_tau_cdf_against_simulation(tau_sample):
    tau, r = tau_sample
    N = tau.shape[0]
    assert np.all(np.abs(tau) <= np.sqrt(r) + 1e-12)
    for i in (0, 3, 5):  # uneven leverage: r_i from 0.06 to 0.83, same τ law
        for q in np.linspace(-1.9, 1.9, 9):
            F = float(tau_distribution.cdf(q, r))
            assert binomial_ok(np.sum(tau[:, i] <= q), N, F), (i, q)


def test_tau_critical_values_against_simulation(tau_sample):
    tau, r = tau_sample
    N = tau.shape[0]
    for alpha in (0.05, 0.01):
        c = tau_critical(alpha, r)
        for i in range(6):
            assert binomial_ok(np.sum(np.abs(tau[:, i]) > c), N, alpha), (alpha, i)
        # Šidák bound for the largest |τ|: level at most α, and not absurdly conservative
        cm = tau_critical_max(alpha, r, 6)
        rate = np.mean(np.max(np.abs(tau), axis=1) > cm)
        assert 0.5 * alpha < rate <= alpha + 4 * np.sqrt(alpha / N)
    # Student's t with r − 1 dof is wrong for τ (|τ| ≤ √r = 2 < t_c): it would never reject
    assert stats.t.isf(0.025, r - 1) > np.sqrt(r)
