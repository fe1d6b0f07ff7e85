"""δ0, critical values and the B-method level α′ (closed forms and an independent root search)."""

import numpy as np
import pytest
from scipy import optimize, stats

from baarda.pipeline.stats import alpha_prime, critical_normal, delta0, global_test, w_power
from baarda.pipeline.stats.snapshot import Snapshot


def test_delta0_and_critical_values():
    assert critical_normal(0.001) == pytest.approx(3.2905, abs=1e-4)
    assert delta0(0.001, 0.80) == pytest.approx(3.2905 + 0.8416, abs=1e-4)
    assert delta0(0.001, 0.80) ** 2 == pytest.approx(17.075, abs=1e-3)  # Baarda's λ0
    assert delta0(0.01, 0.80) == pytest.approx(3.4175, abs=1e-4)
    # the w-test has (essentially exactly) power β0 at δ0
    assert w_power(delta0(0.001, 0.8), 0.001) == pytest.approx(0.80, abs=1e-9)


def test_alpha_prime_one_dof_is_alpha0():
    assert alpha_prime(0.001, 0.80, 1) == pytest.approx(0.001, rel=1e-9)
    # δ0 = k + Φ⁻¹(β0) neglects the far tail Φ(−k − δ0); α′(dof = 1) is the level at which the
    # two-sided test has power β0 *with* that tail — visible only for large α0
    for a0, b0 in ((0.001, 0.80), (0.01, 0.80), (0.05, 0.90)):
        d0 = delta0(a0, b0)
        k = optimize.brentq(lambda k: stats.norm.sf(k - d0) + stats.norm.cdf(-k - d0) - b0,
                            0.1, 10, xtol=1e-14)
        assert alpha_prime(a0, b0, 1) == pytest.approx(2 * stats.norm.sf(k), rel=1e-8)
        assert alpha_prime(a0, b0, 1) == pytest.approx(a0, rel=2e-6)


def test_alpha_prime_increases_with_dof():
    dofs = [1, 2, 3, 5, 10, 20, 50, 100, 1000, 30000]
    a = [alpha_prime(0.001, 0.80, d) for d in dofs]
    assert np.all(np.diff(a) > 0)
    assert a[-1] < 0.80  # bounded by β0: for dof → ∞ the test cannot do better than chance + λ0


@pytest.mark.parametrize("dof", [2, 4, 5, 14, 200])
def test_alpha_prime_noncentrality_equals_delta0_squared(dof):
    a = alpha_prime(0.001, 0.80, dof)
    crit = stats.chi2.isf(a, dof)
    # independent root search: the non-centrality at which the test at α′ has power β0
    lam = optimize.brentq(lambda L: stats.ncx2.sf(crit, dof, L) - 0.80, 1e-6, 1e3, xtol=1e-12)
    assert lam == pytest.approx(delta0(0.001, 0.80) ** 2, rel=1e-7)
    # … and a Monte Carlo of the power at λ0
    g = np.random.default_rng(dof)
    shift = np.zeros(dof)
    shift[0] = delta0()
    X = g.standard_normal((200_000, dof)) + shift
    power = np.mean(np.sum(X * X, axis=1) > crit)
    assert abs(power - 0.80) < 4 * np.sqrt(0.16 / 200_000)


def test_global_test_uses_alpha_prime_by_default():
    s = Snapshot(v=np.zeros(7), Pv=np.zeros(7), PQvvP=np.ones(7), r=np.ones(7), sigma_l=np.ones(7),
                 vtpv=12.0, dof=5, sigma0=1.0)
    g = global_test(s)
    assert g.alpha == pytest.approx(alpha_prime(0.001, 0.8, 5))
    assert g.critical == pytest.approx(stats.chi2.isf(g.alpha, 5) / 5)
    assert g.p_value == pytest.approx(stats.chi2.sf(12.0, 5))
    g2 = global_test(s, alpha=0.05)
    assert g2.critical == pytest.approx(stats.f.isf(0.05, 5, 1e12), rel=1e-6)


def test_bad_levels_are_rejected():
    with pytest.raises(ValueError):
        delta0(0.0, 0.8)
    with pytest.raises(ValueError):
        alpha_prime(0.001, 0.8, 0)
