"""LinearModel and the snapshot formulas against independent computations."""

import numpy as np
import pytest
import scipy.linalg as sla
import scipy.sparse as sp

from baarda.pipeline.errors import AdjustmentError
from baarda.pipeline.stats import (LinearModel, data_snooping, estimated_errors, external_reliability,
                            joint_test_2d, mdb, snapshot_from_arrays, w_test)
from .stats_helpers import cov_of


def correlated_data(model, seed=5):
    L = np.linalg.cholesky(cov_of(model))
    e = L @ np.random.default_rng(seed).standard_normal(model.n)
    e[6] += 8 * model.sigma0  # a blunder in x4 so that the numbers are not all small
    return model.l + e


def whitened_w(A, l, W, sigma0):
    """Diagonal-formula w-test of the whitened model W A, W l, P = I (plain numpy)."""
    At, lt = W @ A, W @ l
    x = np.linalg.lstsq(At, lt, rcond=None)[0]
    v = lt - At @ x
    H = At @ np.linalg.solve(At.T @ At, At.T)
    q = np.diag(np.eye(len(l)) - H)
    return v / (sigma0 * np.sqrt(q))


def test_full_P_w_test_equals_whitened_diagonal_formulas(helmert):
    """With P = WᵀW and W upper triangular, column i of W only touches rows ≤ i, so the outlier
    direction e_i of the first row of every x/y pair maps onto a single whitened row; with W lower
    triangular the same holds for the second row.  The diagonal formulas of the whitened model then
    give w of those rows — an independent computation of (Pv)_i / (σ0 √(PQvvP)_ii)."""
    l = correlated_data(helmert)
    m = LinearModel(helmert.A, l, helmert.P, sigma0=helmert.sigma0, group=helmert.group)
    w = w_test(m.adjust().snapshot)
    P = helmert.P
    U = sla.cholesky(P, lower=False)  # P = Uᵀ U, U upper
    J = np.eye(P.shape[0])[::-1]
    Lw = J @ sla.cholesky(J @ P @ J, lower=False) @ J  # P = Lwᵀ Lw, Lw lower
    np.testing.assert_allclose(U.T @ U, P, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(Lw.T @ Lw, P, rtol=1e-10, atol=1e-10)
    wu = whitened_w(helmert.A, l, U, helmert.sigma0) * np.sign(np.diag(U))
    wl = whitened_w(helmert.A, l, Lw, helmert.sigma0) * np.sign(np.diag(Lw))
    # tolerance: v = l − A x̂ cancels ~100 mm coordinates down to ~0.01 mm (σ0) with cond(N) ≈ 3e6,
    # so both computations carry ~1e-7 relative rounding noise
    np.testing.assert_allclose(w[0::2], wu[0::2], rtol=1e-6)  # x rows
    np.testing.assert_allclose(w[1::2], wl[1::2], rtol=1e-6)  # y rows
    # and the correlation matters: the diagonal formula on the unwhitened v differs
    adj = m.adjust()
    Qvv = cov_of(helmert) / helmert.sigma0 ** 2 - helmert.A @ adj.Qxx @ helmert.A.T
    naive = adj.v / (helmert.sigma0 * np.sqrt(np.diag(Qvv)))
    assert np.max(np.abs(naive - w)) > 0.1


def test_full_P_quantities_against_dense_formulas(poly):
    l = correlated_data(poly)
    snap = LinearModel(poly.A, l, poly.P, sigma0=poly.sigma0).adjust().snapshot
    A, P = poly.A, poly.P
    N = A.T @ P @ A
    x = np.linalg.solve(N, A.T @ P @ l)
    v = l - A @ x
    Qvv = np.linalg.inv(P) - A @ np.linalg.solve(N, A.T)
    np.testing.assert_allclose(snap.v, v, atol=1e-10)
    np.testing.assert_allclose(snap.Pv, P @ v, atol=1e-9)
    np.testing.assert_allclose(snap.PQvvP, np.diag(P @ Qvv @ P), rtol=1e-9)
    np.testing.assert_allclose(snap.r, np.diag(Qvv @ P), rtol=1e-9, atol=1e-12)
    assert snap.r.sum() == pytest.approx(snap.dof)
    assert snap.vtpv == pytest.approx(v @ P @ v)
    np.testing.assert_allclose(estimated_errors(snap), (P @ v) / np.diag(P @ Qvv @ P), rtol=1e-9)


def test_estimated_error_is_the_leave_one_out_prediction():
    """∇̂l_i = v_i / r_i equals l_i minus its prediction from the others (P diagonal)."""
    g = np.random.default_rng(2)
    A = np.c_[np.ones(10), g.normal(size=(10, 2))]
    l = g.normal(size=10)
    p = g.uniform(0.5, 3, 10)
    m = LinearModel(A, l, p, sigma0=0.7)
    e = estimated_errors(m.adjust().snapshot)
    w = w_test(m.adjust().snapshot)
    for i in range(10):
        act = np.ones(10, bool)
        act[i] = False
        s = m.refit(act)
        assert s.v[i] == 0 and s.r[i] == 0 and not s.active[i]
        assert s.v_pred[i] == pytest.approx(e[i], rel=1e-10)
        # the removed row's w if put back alone = its w in the full adjustment
        assert w_test(s, include_inactive=True)[i] == pytest.approx(w[i], rel=1e-9)
        assert estimated_errors(s, include_inactive=True)[i] == pytest.approx(e[i], rel=1e-10)


def test_inactive_rows_with_full_P_use_the_marginal_covariance(helmert):
    l = correlated_data(helmert)
    m = LinearModel(helmert.A, l, helmert.P, sigma0=helmert.sigma0, group=helmert.group)
    act = np.ones(m.n, bool)
    act[[6, 11]] = False  # x4 and y6
    s = m.refit(act)
    C = cov_of(helmert)
    keep = np.flatnonzero(act)
    Pa = np.linalg.inv(C[np.ix_(keep, keep)]) * helmert.sigma0 ** 2
    ref = LinearModel(helmert.A[keep], l[keep], Pa, sigma0=helmert.sigma0).adjust()
    np.testing.assert_allclose(s.v[keep], ref.v, atol=1e-10)
    np.testing.assert_allclose(w_test(s)[keep], w_test(ref.snapshot), rtol=1e-9)
    # predicted-residual σ, independently: e_o = l_o − a_o K l_a is linear in l, Var = c Σ cᵀ
    K = np.linalg.solve(helmert.A[keep].T @ Pa @ helmert.A[keep], helmert.A[keep].T @ Pa)
    for o in (6, 11):
        c = np.zeros(m.n)
        c[o] = 1.0
        c[keep] -= helmert.A[o] @ K
        assert s.sigma_v_pred[o] == pytest.approx(np.sqrt(c @ C @ c), rel=1e-8)
    # joint test: points 4 and 6 lost a row and are not tested
    jt = joint_test_2d(s)
    assert set(jt.groups.tolist()) == set(range(9)) - {3, 5}


def test_sparse_A_gives_the_same_snapshot(helmert):
    l = correlated_data(helmert)
    for P in (None, np.diag(helmert.P), helmert.P):
        d = LinearModel(helmert.A, l, P, group=helmert.group).adjust().snapshot
        s = LinearModel(sp.csr_matrix(helmert.A), l, P, group=helmert.group).adjust().snapshot
        for k in ("v", "Pv", "PQvvP", "r", "sigma_l"):
            np.testing.assert_allclose(getattr(s, k), getattr(d, k), rtol=1e-10, atol=1e-12)
        for g, b in d.PQvvP_blocks.items():
            np.testing.assert_allclose(s.PQvvP_blocks[g], b, rtol=1e-10, atol=1e-12)


def test_rank_deficiency_names_the_unknowns():
    x = np.array([0.0, 1, 2, 3])
    A = np.c_[np.ones(4), x, 2 * x + 1, np.zeros(4)]
    with pytest.raises(AdjustmentError, match="d undetermined"):
        LinearModel(A, x, names=["a", "b", "c", "d"]).adjust()
    with pytest.raises(AdjustmentError, match=r"a, b, c undetermined"):
        LinearModel(A[:, :3], x, names=["a", "b", "c"]).adjust()
    # a Helmert without enough points: one point fixes translation but not scale/rotation
    A = np.array([[1.0, -2, 1, 0], [2, 1, 0, 1]])
    with pytest.raises(AdjustmentError, match="rank 2 of 4"):
        LinearModel(A, [0.0, 0.0]).adjust()
    # removing rows can make a regular model singular
    m = LinearModel(np.c_[np.ones(4), x], x)
    with pytest.raises(AdjustmentError):
        m.adjust([True, False, False, False])


def test_inputs_are_not_modified(helmert):
    A = helmert.A.copy()
    l = correlated_data(helmert)
    P = helmert.P.copy()
    l0, A0, P0 = l.copy(), A.copy(), P.copy()
    m = LinearModel(A, l, P, group=helmert.group)
    act = np.ones(m.n, bool)
    act[3] = False
    act0 = act.copy()
    s = m.refit(act)
    data_snooping(s)
    np.testing.assert_array_equal(A, A0)
    np.testing.assert_array_equal(l, l0)
    np.testing.assert_array_equal(P, P0)
    np.testing.assert_array_equal(act, act0)
    with pytest.raises(ValueError):
        s.v[0] = 1.0  # snapshots are read-only


def test_external_reliability(poly):
    l = correlated_data(poly)
    for P in (np.diag(poly.P).copy(), poly.P):
        m = LinearModel(poly.A, l, P, sigma0=poly.sigma0)
        adj = m.adjust()
        nab = mdb(adj.snapshot)
        F = np.array([[1.0, 10.0, 100.0, 1000.0]])  # the fitted value at x = 10
        er = external_reliability(m, adj, nab)
        dx_all, bar = er  # unpacks as a pair
        # independent: adjust with the MDB added to row i and compare the unknowns
        for i in (0, 5, 11):
            li = l.copy()
            li[i] += nab[i]
            dx = LinearModel(poly.A, li, P, sigma0=poly.sigma0).adjust().x - adj.x
            np.testing.assert_allclose(er.dx[i], dx, rtol=1e-8, atol=1e-10)
            np.testing.assert_allclose(er.on(F)[i], F @ dx, rtol=1e-8)
            N = poly.A.T @ (np.diag(P) if P.ndim == 1 else P) @ poly.A
            assert er.bar_delta0[i] == pytest.approx(np.sqrt(dx @ N @ dx) / poly.sigma0, rel=1e-8)
        if P.ndim == 1:  # Baarda's closed form for uncorrelated observations
            r = adj.snapshot.r
            np.testing.assert_allclose(er.bar_delta0, np.sqrt((1 - r) / r) * 4.1321, rtol=1e-4)


def test_snapshot_from_arrays_matches_linear_model(helmert):
    """A 'bundle-like' caller hands v, 2×2 weight blocks and 2×2 Qvv blocks."""
    l = correlated_data(helmert)
    m = LinearModel(helmert.A, l, helmert.P, sigma0=helmert.sigma0, group=helmert.group)
    adj = m.adjust()
    ref = adj.snapshot
    Qvv = cov_of(helmert) / helmert.sigma0 ** 2 - helmert.A @ adj.Qxx @ helmert.A.T
    idx = np.arange(0, 18, 2)
    Pb = np.stack([helmert.P[i:i + 2, i:i + 2] for i in idx])
    Qb = np.stack([Qvv[i:i + 2, i:i + 2] for i in idx])
    s = snapshot_from_arrays(adj.v, ref.dof, P_blocks=Pb, Qvv_blocks=Qb, group=helmert.group,
                             sigma0=helmert.sigma0, labels=helmert.labels)
    for k in ("Pv", "PQvvP", "r", "sigma_l"):
        np.testing.assert_allclose(getattr(s, k), getattr(ref, k), rtol=1e-9, atol=1e-12)
    assert s.vtpv == pytest.approx(ref.vtpv)
    np.testing.assert_allclose(joint_test_2d(s).T, joint_test_2d(ref).T, rtol=1e-9)
    np.testing.assert_allclose(data_snooping(s).w, data_snooping(ref).w, rtol=1e-9)
    # diagonal form
    d = LinearModel(helmert.A, l, sigma0=2.0).adjust()
    s2 = snapshot_from_arrays(d.v, d.dof, qvv=d.snapshot.r, sigma0=2.0)
    np.testing.assert_allclose(w_test(s2), w_test(d.snapshot), rtol=1e-12)


def test_snapshot_functions_scale_to_bundle_size():
    """30 000 rows (15 000 image points): everything vectorised, no Python loop per row."""
    import time
    g = np.random.default_rng(0)
    n = 30_000
    group = np.repeat(np.arange(n // 2), 2)
    Qb = np.tile(np.array([[0.8, 0.1], [0.1, 0.7]]), (n // 2, 1, 1))
    v = g.normal(size=n) * 0.9
    t0 = time.perf_counter()
    s = snapshot_from_arrays(v, n - 3000, Qvv_blocks=Qb, group=group, p=np.ones(n))
    ds = data_snooping(s)
    jt = joint_test_2d(s)
    elapsed = time.perf_counter() - t0
    assert ds.w.shape == (n,) and jt.T.shape == (n // 2,)
    assert elapsed < 2.0


def test_joint_test_of_a_block_with_one_direction_is_not_made():
    """A 2×2 Qvv block of correlation |ρ| → 1 (a two-ray point: its residuals in one direction) has
    no 2-D test: T is nan, not a number made of rounding; a block of |ρ| = 0.999 is tested with the
    closed form vᵀ B⁻¹ v."""
    from baarda.pipeline.stats.arrays import snapshot_from_arrays
    from baarda.pipeline.stats.joint import joint_test_2d

    q = 0.3
    blocks, v = [], []
    for one_minus_rho2 in (1e-12, 1e-8, 1e-3):
        rho = np.sqrt(1 - one_minus_rho2)
        blocks.append([[q, rho * q], [rho * q, q]])
        v += [0.4, 0.41]
    snap = snapshot_from_arrays(np.array(v), dof=3, Qvv_blocks=np.array(blocks), group=np.repeat([0, 1, 2], 2))
    res = joint_test_2d(snap)
    assert np.isnan(res.T[:2]).all() and not res.flagged[:2].any()
    B = np.array(blocks[2])
    assert res.T[2] == pytest.approx(np.array(v[4:]) @ np.linalg.solve(B, np.array(v[4:])), rel=1e-9)
