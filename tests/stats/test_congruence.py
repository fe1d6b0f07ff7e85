"""Deformation analysis (baarda.pipeline.stats.congruence) against closed forms and Monte Carlo."""

import numpy as np
import pytest
from scipy import stats

from baarda.pipeline.stats.congruence import (congruence, lambda0_multi, s_transform, similarity_basis,
                                              variance_ratio_test)


def _levelling(rng, h_true, pairs, sigma=1.0):
    """One epoch of a free levelling network: height differences l = h_j − h_i + e."""
    n = len(h_true)
    A = np.zeros((len(pairs), n))
    for r, (i, j) in enumerate(pairs):
        A[r, i], A[r, j] = -1.0, 1.0
    l = A @ h_true + rng.normal(0, sigma, len(pairs))
    N = A.T @ A
    Q = np.linalg.pinv(N)                    # inner-constraint (free network) cofactor
    h = Q @ A.T @ l
    v = A @ h - l
    return A, l, h, Q, float(v @ v)


PAIRS = [(0, 1), (1, 2), (2, 3), (3, 4), (4, 0), (0, 2), (1, 3), (2, 4), (1, 4)]


def test_levelling_congruence_equals_joint_minus_separate():
    """Ω of the congruence test = Ω(joint adjustment with one set of heights) − Ω1 − Ω2."""
    rng = np.random.default_rng(1)
    h_true = np.array([10.0, 11.5, 9.2, 10.7, 12.1])
    h2_true = h_true + np.array([0, 0, 0, 3.0, 0])            # point 3 rises
    A, l1, h1, Q1, om1 = _levelling(rng, h_true, PAIRS)
    _, l2, h2, Q2, om2 = _levelling(rng, h2_true, PAIRS)
    AA = np.vstack([A, A])
    ll = np.concatenate([l1, l2])
    hj = np.linalg.pinv(AA.T @ AA) @ AA.T @ ll
    om_joint = float(np.sum((AA @ hj - ll) ** 2))
    res = congruence(h1, Q1, h2, Q2, kind="translation", localise=False)
    assert res.dof0 == 4
    assert res.T0 * res.dof0 == pytest.approx(om_joint - om1 - om2, rel=1e-10)
    # the datum of either epoch does not matter: shift epoch 2 by a constant
    res2 = congruence(h1, Q1, h2 + 100.0, Q2, kind="translation", localise=False)
    assert res2.T0 == pytest.approx(res.T0, rel=1e-10)


def test_localisation_finds_the_moved_benchmark():
    rng = np.random.default_rng(2)
    h_true = np.array([10.0, 11.5, 9.2, 10.7, 12.1])
    A, l1, h1, Q1, _ = _levelling(rng, h_true, PAIRS, sigma=0.001)
    _, l2, h2, Q2, _ = _levelling(rng, h_true + np.array([0, 0, 0, 0.02, 0]), PAIRS, sigma=0.001)
    res = congruence(h1, Q1, h2, Q2, sigma0=0.001, kind="translation")
    assert not res.accepted0 and res.moved == (3,)
    assert res.points[3].moved and res.points[3].d[0] == pytest.approx(0.02, abs=5 * np.sqrt(res.points[3].Q[0, 0]) * 0.001)
    assert res.T <= stats.chi2.isf(0.05, res.dof) / res.dof


def _net2d(rng, X0, sigma):
    """A linearised 2-D trilateration network (free: rank defect 3), one epoch."""
    n = len(X0)
    rows = []
    for i in range(n):
        for j in range(i + 1, n):
            u = (X0[j] - X0[i]) / np.linalg.norm(X0[j] - X0[i])
            a = np.zeros(2 * n)
            a[2 * i:2 * i + 2], a[2 * j:2 * j + 2] = -u, u
            rows.append(a)
    A = np.array(rows)
    return A, np.linalg.pinv(A.T @ A) * sigma ** 0  # cofactor (σ0 separate)


def test_2d_free_network_against_joint_adjustment():
    rng = np.random.default_rng(3)
    X0 = rng.uniform(0, 100, (6, 2))
    A, Q = _net2d(rng, X0, 1.0)
    dx_true = np.zeros(12)
    dx_true[4:6] = [0.5, -0.3]
    l1 = rng.normal(0, 1, A.shape[0])
    l2 = A @ dx_true + rng.normal(0, 1, A.shape[0])
    x1, x2 = Q @ A.T @ l1, Q @ A.T @ l2
    om = [float(np.sum((A @ x - l) ** 2)) for x, l in ((x1, l1), (x2, l2))]
    AA, ll = np.vstack([A, A]), np.concatenate([l1, l2])
    xj = np.linalg.pinv(AA.T @ AA) @ AA.T @ ll
    om_joint = float(np.sum((AA @ xj - ll) ** 2))
    res = congruence(X0 + x1.reshape(-1, 2), Q, X0 + x2.reshape(-1, 2), Q, kind="rigid", basis_at=X0,
                     localise=False)
    assert res.dof0 == 12 - 3
    assert res.T0 * res.dof0 == pytest.approx(om_joint - om[0] - om[1], rel=1e-8)


def test_s_transform_moves_the_datum_to_chosen_points():
    rng = np.random.default_rng(4)
    X = rng.uniform(0, 10, (5, 3))
    L = rng.normal(size=(15, 15))
    Q = L @ L.T
    x = rng.normal(size=15)
    datum = [0, 1, 2, 3]
    xs, Qs, S = s_transform(x, Q, X, datum, kind="similarity")
    G = similarity_basis(X, "similarity")
    E = np.zeros(15)
    E[:12] = 1
    # the datum points' part carries no similarity component: Gᵀ E x' = 0, Gᵀ E Q' = 0
    assert np.allclose(G.T @ (E * xs), 0, atol=1e-10)
    assert np.allclose(G.T @ (E[:, None] * Qs), 0, atol=1e-9)
    # S is a projector that annihilates the datum directions
    assert np.allclose(S @ S, S, atol=1e-10) and np.allclose(S @ G, 0, atol=1e-10)
    with pytest.raises(ValueError, match="do not determine"):
        s_transform(x, Q, X, [0, 1], kind="similarity")


def test_mdd_power_and_false_alarms_by_monte_carlo():
    """False-alarm rate of the global test = α; a displacement of one MDD is found with power β0."""
    rng = np.random.default_rng(5)
    X0 = rng.uniform(0, 100, (7, 2))
    A, Q = _net2d(rng, X0, 1.0)
    sigma = 0.01
    Lq = np.linalg.cholesky(Q + 1e-12 * np.eye(14))
    datum = [0, 1, 2, 3, 4, 5]           # point 6 is the object point under test
    base = congruence(X0, Q, X0, Q, sigma0=sigma, alpha_point=0.05, kind="rigid", basis_at=X0, datum_points=datum, localise=False)
    p6 = base.points[6]
    w, V = np.linalg.eigh(np.linalg.inv(p6.Q))
    worst = V[:, 0] * p6.mdd
    n_sim = 500
    false_alarm = detected = 0
    for _ in range(n_sim):
        x1 = (Lq @ rng.normal(size=14)) * sigma
        x2 = (Lq @ rng.normal(size=14)) * sigma
        r0 = congruence(X0 + x1.reshape(-1, 2), Q, X0 + x2.reshape(-1, 2), Q, sigma0=sigma, alpha_point=0.05, kind="rigid",
                        basis_at=X0, datum_points=datum, localise=False)
        false_alarm += not r0.accepted0
        x2b = x2.copy()
        x2b[12:14] += worst
        r1 = congruence(X0 + x1.reshape(-1, 2), Q, X0 + x2b.reshape(-1, 2), Q, sigma0=sigma, alpha_point=0.05, kind="rigid",
                        basis_at=X0, datum_points=datum, localise=False)
        detected += r1.points[6].p < 0.05
    mc = lambda p: 4 * np.sqrt(p * (1 - p) / n_sim)  # noqa: E731
    assert abs(false_alarm / n_sim - 0.05) < mc(0.05)
    assert abs(detected / n_sim - 0.80) < mc(0.80)


def test_lambda0_and_variance_ratio():
    lam = lambda0_multi(0.001, 0.80, 1)
    assert np.sqrt(lam) == pytest.approx(4.13, abs=0.01)          # δ0 of the B-method
    r = variance_ratio_test(1.0, 50, 1.0, 60)
    assert not r["differ"] and r["p"] > 0.9
    assert variance_ratio_test(2.0, 50, 1.0, 60)["differ"]


def test_inner_constraints_on_a_subset_give_the_same_test():
    """Free networks whose datum is held by a subset of points (Q singular along E G, not G): same Ω."""
    rng = np.random.default_rng(6)
    h_true = np.array([10.0, 11.5, 9.2, 10.7, 12.1])
    A, l1, h1, Q1, _ = _levelling(rng, h_true, PAIRS)
    _, l2, h2, Q2, _ = _levelling(rng, h_true + np.array([0, 2.0, 0, 0, 0]), PAIRS)
    full = congruence(h1, Q1, h2, Q2, kind="translation", localise=False)
    x1, Q1s, _ = s_transform(h1, Q1, h1, [0, 2, 4], kind="translation")
    x2, Q2s, _ = s_transform(h2, Q2, h1, [0, 2, 4], kind="translation")
    sub = congruence(x1, Q1s, x2, Q2s, kind="translation", localise=False)
    assert sub.T0 == pytest.approx(full.T0, rel=1e-9)


def test_rigid_datum_for_scale_free_networks_is_refused():
    rng = np.random.default_rng(7)
    X = rng.uniform(0, 10, (6, 3))
    G = similarity_basis(X, "similarity")
    L = rng.normal(size=(18, 18))
    S = np.eye(18) - G @ G.T                      # cofactors singular along all 7 similarity directions
    Q = S @ (L @ L.T) @ S
    with pytest.raises(ValueError, match="not covered by a rigid datum"):
        congruence(X, Q, X + 0.01, Q, kind="rigid")
    congruence(X, Q, X + 0.01, Q, kind="similarity")
