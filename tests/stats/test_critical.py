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


def _snap(vtpv, dof, sigma0=1.0):
    n = dof + 2
    return Snapshot(v=np.zeros(n), Pv=np.zeros(n), PQvvP=np.ones(n), r=np.ones(n), sigma_l=np.ones(n),
                    vtpv=vtpv, dof=dof, sigma0=sigma0)


def test_global_test_is_two_sided_at_five_percent_by_default():
    g = global_test(_snap(12.0, 5))
    assert (g.method, g.alpha) == ("two-sided", 0.05)
    # closed forms: χ²(α/2; dof)/dof and χ²(1 − α/2; dof)/dof, p = 2 min(F, 1 − F)
    assert g.critical_lower == pytest.approx(stats.chi2.ppf(0.025, 5) / 5, rel=1e-12)
    assert g.critical == pytest.approx(stats.chi2.isf(0.025, 5) / 5, rel=1e-12)
    assert g.critical == pytest.approx(stats.f.isf(0.025, 5, 1e12), rel=1e-6)
    F = stats.chi2.cdf(12.0, 5)
    assert g.p_value == pytest.approx(2 * min(F, 1 - F), rel=1e-12)
    assert g.T == pytest.approx(12.0 / 5) and not g.rejected and g.verdict == "accepted"
    # the interval of σ̂0 (unit of σ0): rejected exactly when σ̂0 lies outside it
    lo, hi = g.interval
    assert (lo, hi) == pytest.approx((np.sqrt(g.critical_lower), np.sqrt(g.critical)), rel=1e-12)
    g3 = global_test(_snap(12.0, 5, sigma0=3.0))
    assert g3.interval == pytest.approx((3 * lo, 3 * hi), rel=1e-12)


@pytest.mark.parametrize("dof", [1, 4, 66, 3000])
def test_global_test_rejects_too_large_and_too_small(dof):
    lo, hi = global_test(_snap(float(dof), dof)).interval
    big = global_test(_snap(1.01 * hi ** 2 * dof, dof))
    small = global_test(_snap(0.99 * lo ** 2 * dof, dof))
    assert big.rejected and big.too_large and big.verdict == "rejected (σ̂0 too large)"
    assert small.rejected and small.too_small and small.verdict == "rejected (σ̂0 too small)"
    assert big.p_value < 0.05 and small.p_value < 0.05
    # the B-method is one-sided: a small σ̂0 is never rejected
    assert not global_test(_snap(0.99 * lo ** 2 * dof, dof), alpha="B-method").rejected


def test_global_test_b_method_on_request():
    g = global_test(_snap(12.0, 5), alpha="B-method")
    assert g.method == "B-method" and g.alpha == pytest.approx(alpha_prime(0.001, 0.8, 5))
    assert g.critical == pytest.approx(stats.chi2.isf(g.alpha, 5) / 5)
    assert g.p_value == pytest.approx(stats.chi2.sf(12.0, 5))
    assert g.critical_lower == 0.0
    assert global_test(_snap(12.0, 5), alpha=None).alpha == g.alpha      # None: as before the option
    with pytest.raises(ValueError):
        global_test(_snap(12.0, 5), alpha="Baarda")
    with pytest.raises(ValueError):
        global_test(_snap(12.0, 5), alpha=1.0)


@pytest.mark.parametrize("alpha,dof", [(0.05, 3), (0.05, 500), (0.10, 40)])
def test_global_test_false_alarm_rate_is_alpha(alpha, dof):
    """Monte Carlo under H0 (seeded): σ̂0² from dof standard normal residuals is rejected α of the time."""
    rng = np.random.default_rng(1000 + dof)
    n = 40_000
    vtpv = rng.chisquare(dof, n)
    g = global_test(_snap(float(dof), dof), alpha=alpha)
    T = vtpv / dof
    rejected = (T < g.critical_lower) | (T > g.critical)
    assert abs(rejected.mean() - alpha) < 4 * np.sqrt(alpha * (1 - alpha) / n)
    # global_test's own verdict and p-value on the first draws: the same decisions, P(p < α) = α
    first = [global_test(_snap(float(q), dof), alpha=alpha) for q in vtpv[:600]]
    assert [r.rejected for r in first] == rejected[:600].tolist()
    assert [r.p_value < alpha for r in first] == rejected[:600].tolist()


def test_bad_levels_are_rejected():
    with pytest.raises(ValueError):
        delta0(0.0, 0.8)
    with pytest.raises(ValueError):
        alpha_prime(0.001, 0.8, 0)


def test_global_test_text_prints_the_verdict_as_metrology_packages_do():
    from baarda.pipeline.protocol import global_test_protocol, global_test_text

    g = global_test_protocol(global_test(_snap(12.0, 5)))
    assert g["interval"] == pytest.approx([np.sqrt(stats.chi2.ppf(0.025, 5) / 5), np.sqrt(stats.chi2.isf(0.025, 5) / 5)])
    assert global_test_text(g) == ("T = σ̂0²/σ0² = 2.400, p = 0.0696 (two-sided χ², α = 5 %; 95 % interval "
                                   "of σ̂0: 0.4077 – 1.602): accepted")
    huge = global_test_protocol(global_test(_snap(1e6, 5)))
    assert huge["p_value"] == 0.0 and "p < 1e-300" in global_test_text(huge)
    assert global_test_text(huge).endswith("REJECTED (σ̂0 too large)")
    b = global_test_text(global_test_protocol(global_test(_snap(12.0, 5), alpha="B-method")))
    assert "B-method, one-sided, α′ = 0.013" in b and "F-critical" in b
