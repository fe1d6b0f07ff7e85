"""Paper 000 (Park & Yeu), sample data of Tables 1 and 2: regression E(y) = −2 − x, P = I, σ = 0.5.

Expected values are the printed tables (seed 000), with SPEC §1's correction of Table 1 row 4
(v = −0.95, ∇0 = 2.27; the OCR printed −0.05 and 2.67).  The paper's ∇0 column uses δ0 = 4.123
(= √17, Baarda's λ0 = 17, the "4.123" its text quotes); with the exact δ0(0.1 %, 80 %) = 4.1321
three cells round differently (2.31/8.16 instead of 2.30/8.14 in Table 1, 3.14 instead of 3.13 in
Table 2) — tested below.
"""

import numpy as np
import pytest
from scipy import stats

from baarda.pipeline.stats import (LinearModel, critical_normal, data_snooping, delta0, global_test,
                            iterated_data_snooping, mdb, pope_iterated, recursive_residuals, rrr)

X1 = np.array([-4, -3, -2, -1, 0, 10.0])
Y1 = np.array([2.5, 0.7, -0.1, -1.5, -1.6, -7.0])
X2 = np.r_[X1, 8.0]
Y2 = np.r_[Y1, -9.8]
SIGMA = 0.5

# columns: v, (Qvv)ii, ∇̂y, w, ∇0  (printed, 2 decimals)
TABLE1 = np.array([
    [1.19, 0.71, 1.68, 2.83, 2.45],
    [0.01, 0.76, 0.01, 0.03, 2.36],
    [-0.17, 0.80, -0.21, -0.38, 2.30],
    [-0.95, 0.83, -1.15, -2.09, 2.27],  # OCR: −0.05 … 2.67 (SPEC §1 correction)
    [-0.43, 0.83, -0.52, -0.95, 2.26],
    [0.35, 0.06, 5.48, 2.77, 8.14],
])
TABLE2 = np.array([
    [1.02, 0.71, 1.42, 2.41, 2.44],
    [-0.03, 0.76, -0.04, -0.07, 2.36],
    [-0.07, 0.80, -0.09, -0.16, 2.30],
    [-0.72, 0.83, -0.86, -1.57, 2.26],
    [-0.06, 0.85, -0.07, -0.14, 2.24],
    [2.09, 0.43, 4.83, 6.35, 3.13],
    [-2.22, 0.60, -3.69, -5.72, 2.66],
])
DELTA0_PAPER = np.sqrt(17.0)  # 4.1231, "Baarda 4.123"


def regression(x, y):
    return LinearModel(np.c_[np.ones_like(x), x], y, sigma0=SIGMA)


def table(x, y, d0):
    snap = regression(x, y).adjust().snapshot
    ds = data_snooping(snap)
    qvv = snap.r  # P = I: (Qvv)_ii = r_i
    return np.c_[snap.v, qvv, ds.nabla_hat, ds.w, mdb(snap, d0)], ds


@pytest.mark.parametrize("x, y, printed", [(X1, Y1, TABLE1), (X2, Y2, TABLE2)], ids=["table1", "table2"])
def test_tables_reproduced_to_printed_precision(x, y, printed):
    got, _ = table(x, y, DELTA0_PAPER)
    # half a unit of the last printed digit (+ float slack); w of row 4 in Table 1 is −2.09497
    np.testing.assert_array_less(np.abs(got - printed), 0.005 + 1e-9)


def test_exact_delta0_changes_only_three_mdb_cells():
    assert delta0(0.001, 0.80) == pytest.approx(4.1321, abs=1e-4)
    t1, _ = table(X1, Y1, delta0())
    t2, _ = table(X2, Y2, delta0())
    bad1 = np.argwhere(np.abs(t1 - TABLE1) > 0.005 + 1e-9).tolist()
    bad2 = np.argwhere(np.abs(t2 - TABLE2) > 0.005 + 1e-9).tolist()
    assert bad1 == [[2, 4], [5, 4]] and bad2 == [[5, 4]]
    assert [round(t1[2, 4], 2), round(t1[5, 4], 2), round(t2[5, 4], 2)] == [2.31, 8.16, 3.14]


def test_residuals_are_observed_minus_computed_and_dof():
    m = regression(X1, Y1)
    adj = m.adjust()
    xhat, *_ = np.linalg.lstsq(np.c_[np.ones(6), X1], Y1, rcond=None)
    np.testing.assert_allclose(adj.x, xhat, rtol=1e-12)
    np.testing.assert_allclose(adj.v, Y1 - (xhat[0] + xhat[1] * X1), atol=1e-12)
    assert adj.dof == 4 and adj.snapshot.r.sum() == pytest.approx(4.0)


def test_effect_of_the_gross_error_on_the_residuals():
    """Paper: ∇_s V = [0.14 0.06 −0.01 −0.09 −0.17 0.06]ᵀ · 5.0 = [0.70 0.30 −0.05 −0.45 −0.85 0.30]ᵀ."""
    y_clean = Y1 - 5.0 * (np.arange(6) == 5)
    dv = regression(X1, Y1).adjust().v - regression(X1, y_clean).adjust().v
    col = dv / 5.0  # column 6 of Qvv
    np.testing.assert_allclose(np.round(col, 2), [0.14, 0.06, -0.01, -0.09, -0.17, 0.06])
    np.testing.assert_allclose(np.round(col, 2) * 5.0, [0.70, 0.30, -0.05, -0.45, -0.85, 0.30],
                               atol=1e-12)


def test_data_snooping_misses_data1_finds_data2():
    _, ds1 = table(X1, Y1, DELTA0_PAPER)
    assert ds1.critical == pytest.approx(3.29, abs=0.005)
    assert ds1.largest == 0  # point 1, not point 6
    assert not ds1.flagged.any()
    assert ds1.mdb[5] > 5.0  # the 10σ error is below the MDB of point 6
    _, ds2 = table(X2, Y2, DELTA0_PAPER)
    assert ds2.largest == 5 and abs(ds2.w[5]) > 3.29
    assert ds2.flagged_labels == ["6", "7"]


def test_global_test_numbers():
    s1 = regression(X1, Y1).adjust().snapshot
    s2 = regression(X2, Y2).adjust().snapshot
    # the paper's level: the B-method α′ (one-sided)
    g1, g2 = global_test(s1, alpha="B-method"), global_test(s2, alpha="B-method")
    # independent: vᵀv / (dof σ²) from lstsq, F critical from χ²
    for g, x, y in ((g1, X1, Y1), (g2, X2, Y2)):
        A = np.c_[np.ones_like(x), x]
        v = y - A @ np.linalg.lstsq(A, y, rcond=None)[0]
        assert g.T == pytest.approx(v @ v / ((len(y) - 2) * SIGMA ** 2), rel=1e-12)
        assert g.critical == pytest.approx(stats.chi2.ppf(1 - g.alpha, g.dof) / g.dof, rel=1e-10)
    assert not g1.rejected and g2.rejected
    assert g1.T == pytest.approx(2.669, abs=1e-3) and g2.T == pytest.approx(8.686, abs=1e-3)
    # the default two-sided test at 5 % agrees here: F(0.975; 4, ∞) = 2.786
    d1, d2 = global_test(s1), global_test(s2)
    assert not d1.rejected and d2.rejected and d1.critical == pytest.approx(2.786, abs=1e-3)


def test_ids_data2_removes_observation_6_first():
    m = regression(X2, Y2)
    res = iterated_data_snooping(m, m.adjust().snapshot)
    assert res.removed_labels == ["6"]
    h0, h1 = res.history
    assert (h0.label, h0.removed, h0.dof, h0.global_rejected) == ("6", True, 5, True)
    assert h0.w_max == pytest.approx(6.35, abs=0.005)
    assert h0.T == pytest.approx(8.686, abs=1e-3) and h0.critical == pytest.approx(2.889, abs=1e-3)
    # after removing 6: dof 4, global test accepts → stop
    assert (h1.dof, h1.global_rejected, h1.removed) == (4, False, False)
    assert h1.T == pytest.approx(0.776, abs=1e-3) and h1.critical == pytest.approx(3.385, abs=1e-3)
    assert "global test accepts" in res.stop_reason
    # data 1: nothing exceeds K
    m1 = regression(X1, Y1)
    assert iterated_data_snooping(m1, m1.adjust().snapshot).removed == []


def test_pope_on_paper_samples_finds_nothing():
    """σ0 unknown: with 4–5 dof the τ bound √dof is barely above τ_c; nothing is flagged."""
    for x, y in ((X1, Y1), (X2, Y2)):
        m = regression(x, y)
        assert pope_iterated(m, m.adjust().snapshot, 0.001).removed == []


# ----------------------------------------------------------------------------------- RRR
@pytest.fixture(scope="module")
def rrr_data1():
    return rrr(regression(X1, Y1), 3, alpha=0.001, n_sim=100_000, rng=1982)


def test_rrr_suspects_and_H_exp(rrr_data1):
    r = rrr_data1
    assert r.suspect_labels == ["6", "1", "4"]
    np.testing.assert_allclose(r.nabla_hat, [5.48, 1.68, -1.15], atol=0.005)
    # each suspect against the clean set {2, 3, 5}: paper 0.996 for 6, SPEC ≈ 0.998 for 1 and 4
    assert np.round(r.H_exp_clean, 3).tolist() == [0.996, 0.998, 0.998]
    assert r.history[0]["clean"] == ["2", "3", "5"]
    assert r.k_terms.tolist() == [2, 3, 4]


def test_rrr_h_exp_from_recursive_residual_definition():
    """H_exp = w_last² / Σ w_k² with w_k built one row at a time (not via RSS differences)."""
    A = np.c_[np.ones(6), X1]
    for s, expected in ((5, 0.996), (0, 0.998), (3, 0.998)):
        order = [1, 2, 4, s]
        w = recursive_residuals(A[order], Y1[order], sigma0=SIGMA)
        assert w.size == 2
        assert round(w[-1] ** 2 / np.sum(w ** 2), 3) == expected
        # any order of the clean set gives the same H_exp
        w2 = recursive_residuals(A[[4, 1, 2, s]], Y1[[4, 1, 2, s]], sigma0=SIGMA)
        assert w2[-1] ** 2 / np.sum(w2 ** 2) == pytest.approx(w[-1] ** 2 / np.sum(w ** 2), rel=1e-10)


def test_rrr_decision_with_monte_carlo_critical_value(rrr_data1):
    """baarda's H (whole procedure simulated) is far above 0.996: RRR rejects nothing here.

    The clean set {2, 3, 5} has one degree of freedom, so H_exp of the first suspect is the share of
    one of two squares: Beta(1/2, 1/2) without selection, whose 99.9 % point is 0.9999975, and
    larger still with the selection of the largest |∇̂l|.
    """
    r = rrr_data1
    assert 0.99999 < r.H < 1.0
    assert r.H_ci[0] <= r.H <= r.H_ci[1]
    assert r.rejected.tolist() == [False, False, False]
    assert r.H_naive[0] == pytest.approx(np.sin(0.999 * np.pi / 2) ** 2, rel=1e-12)
    assert r.p_value[0] > 0.05  # not even significant at 5 % once the selection is accounted for
    assert r.p_value[0] > r.p_naive[0]  # selection makes large shares more likely
    # 6 passes and rejoins the clean set, so 1 and 4 are then tested with more redundancy
    assert r.history[1]["clean"] == ["2", "3", "5", "6"]
    assert r.H_exp[1] == pytest.approx(0.894, abs=1e-3)


def test_paper_critical_value_0993_is_the_naive_5_percent_point():
    """0.993 ≈ Beta(1/2, 1/2) quantile at 95 % (0.9938), not at 99.9 %; with it all three suspects go."""
    assert stats.beta.ppf(0.95, 0.5, 0.5) == pytest.approx(0.9938, abs=1e-4)
    r = rrr(regression(X1, Y1), 3, critical=0.993, n_sim=0)
    assert r.rejected_labels == ["6", "1", "4"]
    np.testing.assert_allclose(r.H_exp, r.H_exp_clean)  # nothing rejoined


def test_rrr_is_reproducible_and_pure():
    m = regression(X1, Y1)
    a = rrr(m, 3, n_sim=5000, rng=7)
    b = rrr(m, 3, n_sim=5000, rng=np.random.default_rng(7))
    assert a.H == b.H
    np.testing.assert_array_equal(m.l, Y1)


def test_critical_values_quoted_by_the_paper():
    assert critical_normal(0.001) == pytest.approx(3.29, abs=0.005)
    assert delta0(0.01, 0.80) == pytest.approx(3.42, abs=0.005)
