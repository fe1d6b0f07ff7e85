"""RRR machinery: the Monte Carlo critical value against closed forms and fresh simulations."""

import numpy as np
import pytest
from scipy import stats

from baarda.pipeline.stats import LinearModel, rrr
from .stats_helpers import helmert_design

X1 = np.array([-4, -3, -2, -1, 0, 10.0])


def line(y, p=None):
    return LinearModel(np.c_[np.ones(6), X1], y, p, sigma0=0.5)


def test_fixed_suspect_mc_matches_beta_quantile():
    """Without selection, a recursive residual's share of k squares is Beta(1/2, (k−1)/2)."""
    m = line(np.zeros(6))
    for suspect, alpha in ((5, 0.01), (0, 0.05)):
        r = rrr(m, 1, alpha=alpha, n_sim=200_000, rng=3, suspects=[suspect])
        k = int(r.k_terms[0])
        assert k == 4
        exact = stats.beta.isf(alpha, 0.5, (k - 1) / 2)
        assert r.H_naive[0] == pytest.approx(exact)
        assert r.H_ci[0] - 1e-3 <= exact <= r.H_ci[1] + 1e-3


def test_selection_raises_the_critical_value():
    m = line(np.zeros(6))
    sel = rrr(m, 1, alpha=0.05, n_sim=100_000, rng=4)
    fixed = rrr(m, 1, alpha=0.05, n_sim=100_000, rng=4, suspects=[5])
    assert sel.H > fixed.H + 0.01


def test_family_wise_level_on_fresh_clean_data():
    """Apply RRR with baarda's H to 1 000 new clean data sets (10-point line, ρ = 2): it rejects
    something in α of them; the naive (selection-blind) Beta value rejects the first suspect alone
    in almost half of them."""
    alpha, N = 0.05, 1000
    x = np.array([-4, -3, -2, -1, 0, 1, 2, 3, 4, 10.0])

    def model(y):
        return LinearModel(np.c_[np.ones(x.size), x], y, sigma0=0.5)

    ref = rrr(model(np.zeros(x.size)), 2, alpha=alpha, n_sim=100_000, rng=5)
    assert ref.H_naive[0] == pytest.approx(stats.beta.isf(alpha, 0.5, (7 - 1) / 2))
    g = np.random.default_rng(6)
    hits = naive_hits = 0
    for _ in range(N):
        y = -2 - x + 0.5 * g.standard_normal(x.size)
        r = rrr(model(y), 2, alpha=alpha, critical=ref.H, n_sim=0)
        hits += bool(r.rejected.any())
        naive_hits += bool(r.H_exp[0] >= ref.H_naive[0])  # first suspect alone: a lower bound
    sd = np.sqrt(alpha * (1 - alpha) / N)
    assert abs(hits / N - alpha) < 4 * sd
    assert naive_hits / N > 0.3


def test_full_P_path_equals_diagonal_path():
    """The correlated-P implementation (subset covariances) and the whitened fast path agree."""
    A, labels, group = helmert_design()
    g = np.random.default_rng(8)
    p = g.uniform(0.5, 2.0, A.shape[0])
    l = A @ np.array([1.0, 0.01, -22, -100]) + g.standard_normal(A.shape[0]) / np.sqrt(p)
    l[8] += 6.0
    d = rrr(LinearModel(A, l, p, labels=labels), 3, n_sim=3000, rng=9, alpha=0.01)
    f = rrr(LinearModel(A, l, np.diag(p), labels=labels), 3, n_sim=3000, rng=9, alpha=0.01)
    assert d.suspect_labels == f.suspect_labels
    np.testing.assert_allclose(d.H_exp, f.H_exp, rtol=1e-6)
    assert d.H == pytest.approx(f.H, rel=1e-6)
    assert d.rejected_labels == f.rejected_labels == ["x5"]


def test_rrr_finds_gross_errors_in_a_helmert_transformation():
    A, labels, group = helmert_design()
    g = np.random.default_rng(10)
    l = A @ np.array([1.0, 0.01, -22, -100]) + 0.01 * g.standard_normal(18)
    l[[8, 9, 16]] += [0.2, 0.2, 0.3]  # x5, y5, x9 (20σ, 20σ, 30σ)
    r = rrr(LinearModel(A, l, sigma0=0.01, labels=labels), 4, alpha=0.001, n_sim=50_000, rng=11)
    assert set(r.rejected_labels) == {"x5", "y5", "x9"}


def test_rrr_argument_checks():
    m = line(np.zeros(6))
    with pytest.raises(ValueError, match="n − rho > u"):
        rrr(m, 4, n_sim=10)
    with pytest.raises(ValueError):
        rrr(m, 3, n_sim=0)


def test_block_diagonal_design_any_order():
    """Stacked independent 2-D Helmert transformations (one block per stereo pair): the clean set
    ordered pair by pair cannot start the recursion, yet RRR works and its statistics equal the
    direct least-squares sums of squares (order-free)."""
    from baarda.pipeline.stats import LinearModel, recursive_residuals, rrr

    rng = np.random.default_rng(5)
    blocks, ls = [], []
    for k in range(3):
        xy = rng.uniform(0, 100, (8, 2))
        A = np.zeros((16, 4))
        A[0::2] = np.column_stack([xy[:, 0], -xy[:, 1], np.ones(8), np.zeros(8)])
        A[1::2] = np.column_stack([xy[:, 1], xy[:, 0], np.zeros(8), np.ones(8)])
        blocks.append(A)
        ls.append(A @ rng.normal(size=4) + rng.normal(0, 0.01, 16))
    A = np.zeros((48, 12))
    for k, B in enumerate(blocks):
        A[16 * k:16 * (k + 1), 4 * k:4 * (k + 1)] = B
    l = np.concatenate(ls)
    l[37] += 0.2  # a gross error in the third pair
    res = rrr(LinearModel(A, l, sigma0=0.01), rho=5, alpha=0.001, n_sim=2000, rng=np.random.default_rng(0))
    assert res.suspects[0] == 37 and res.rejected[0]
    # H_exp of the first suspect = 1 − RSS(C) / RSS(C ∪ {s}) by plain least squares
    clean = [i for i in range(48) if i not in res.suspects]

    def rss(rows):
        x, *_ = np.linalg.lstsq(A[rows], l[rows], rcond=None)
        return float(np.sum((l[rows] - A[rows] @ x) ** 2))

    assert res.H_exp_clean[0] == pytest.approx(1 - rss(clean) / rss(clean + [37]), rel=1e-9)
    w = recursive_residuals(A, l, order=np.array(clean + [37]))
    assert np.sum(w ** 2) == pytest.approx(rss(clean + [37]), rel=1e-9)
