"""Iterated procedures (IDS, iterated Pope) and edge cases of the row-wise tests."""

import numpy as np
import pytest

from baarda.pipeline.stats import (LinearModel, Snapshot, data_snooping, iterated_data_snooping,
                            joint_test_2d, mdb, pope_iterated, pope_test, snapshot_from_arrays,
                            tau_critical, w_test)
from .stats_helpers import helmert_design

BETA = np.array([1.0, 0.01, -22.0, -100.0])


def helmert_with_blunders(seed, blunders, sigma=0.01):
    A, labels, group = helmert_design()
    g = np.random.default_rng(seed)
    l = A @ BETA + sigma * g.standard_normal(A.shape[0])
    for i, b in blunders.items():
        l[i] += b
    return LinearModel(A, l, sigma0=sigma, labels=labels, group=group)


def test_ids_removes_two_blunders_and_stops_on_the_global_test():
    m = helmert_with_blunders(1, {8: 0.15, 16: -0.2})  # x5 +15σ, x9 −20σ
    res = iterated_data_snooping(m, m.adjust().snapshot)
    assert sorted(res.removed_labels) == ["x5", "x9"]
    assert [h.dof for h in res.history] == [14, 13, 12]
    assert res.history[-1].global_rejected is False and not res.history[-1].removed
    # history is consistent: each step's T is the global test of that adjustment
    act = np.ones(18, bool)
    for h in res.history:
        s = m.refit(act)
        assert h.T == pytest.approx(s.vtpv / (s.dof * s.sigma0 ** 2))
        if h.removed:
            act[h.row] = False
    assert not res.active[[8, 16]].any()


def test_ids_max_iter_and_gate_first():
    m = helmert_with_blunders(1, {8: 0.15, 16: -0.2})
    s = m.adjust().snapshot
    assert iterated_data_snooping(m, s, max_iter=1).removed_labels == ["x9"]
    clean = helmert_with_blunders(2, {})
    r = iterated_data_snooping(clean, clean.adjust().snapshot, gate_first=True)
    assert r.removed == [] and len(r.history) == 1


def test_ids_w_test_stop_goes_on_where_the_global_test_accepts():
    """A-priori σ 10 % pessimistic (as when scaled from the residuals): Kok's rule removes the
    first blunder, then the global test accepts with the second (+5σ) still at |w| > 5; the
    w-test rule removes it too and stops at the first |w| ≤ K."""
    n = 300
    t = np.linspace(-1, 1, n)
    A = np.column_stack([np.ones(n), t, t ** 2])
    l = A @ [1.0, 0.5, -0.2] + 0.01 * np.random.default_rng(4).standard_normal(n)
    l[[40, 200]] += [0.07, -0.05]
    m = LinearModel(A, l, sigma0=0.011, labels=[f"l{i}" for i in range(n)])
    s = m.adjust().snapshot
    kok = iterated_data_snooping(m, s)
    assert kok.removed_labels == ["l40"] and kok.stop_reason.startswith("global test accepts")
    left = data_snooping(kok.snapshot)
    assert kok.snapshot.labels[left.largest] == "l200" and abs(left.w[left.largest]) > 5
    wt = iterated_data_snooping(m, s, stop="w-test")
    assert wt.removed_labels[:2] == ["l40", "l200"]
    final = data_snooping(wt.snapshot)
    assert np.abs(final.w[wt.snapshot.active]).max() <= wt.critical
    assert wt.stop_reason.startswith("no |w| above K") and "stop = 'w-test'" in wt.stop_reason
    # every removal but the last left a |w| above K behind it
    assert all(abs(h.w_max) > wt.critical for h in wt.history if h.removed)
    with pytest.raises(ValueError, match="stop must be"):
        iterated_data_snooping(m, s, stop="never")


def test_pope_iterated_uses_sigma0_hat_and_current_dof():
    m = helmert_with_blunders(3, {8: 0.15, 16: -0.2}, sigma=0.01)
    s = m.adjust().snapshot
    # σ0 a priori wrong by a factor 10: w is useless, τ does not care
    wrong = LinearModel(m.A, m.l, sigma0=0.1, labels=m.labels)
    assert not data_snooping(wrong.adjust().snapshot).flagged.any()
    res = pope_iterated(wrong, wrong.adjust().snapshot, alpha=0.001)
    assert sorted(res.removed_labels) == ["x5", "x9"]
    step0 = res.history[0]
    assert step0.critical == pytest.approx(tau_critical(0.001, 14))
    assert res.history[1].dof == 13 and res.history[1].critical == pytest.approx(tau_critical(0.001, 13))
    # τ = w σ0 / σ̂0 and is invariant to σ0
    np.testing.assert_allclose(pope_test(s).tau, pope_test(wrong.adjust().snapshot).tau, rtol=1e-9)
    np.testing.assert_allclose(pope_test(s).tau, w_test(s) * s.sigma0 / s.sigma0_hat, rtol=1e-12)


def test_familywise_pope_is_stricter():
    m = helmert_with_blunders(4, {8: 0.05})
    s = m.adjust().snapshot
    a, b = pope_test(s, 0.01), pope_test(s, 0.01, familywise=True)
    assert b.critical > a.critical and b.alpha < a.alpha


def test_uncontrolled_rows_are_not_tested():
    # the 3rd point determines the quadratic term alone: r = 0 there
    x = np.array([0.0, 1.0, 2.0, 3.0, 10.0])
    A = np.c_[np.ones(5), x, np.r_[0, 0, 0, 0, 1.0]]
    s = LinearModel(A, np.array([0.1, 1.0, 2.1, 2.9, 50.0])).adjust().snapshot
    assert s.r[4] == pytest.approx(0.0, abs=1e-12)
    ds = data_snooping(s)
    assert ds.w[4] == 0.0 and not ds.flagged[4] and ds.largest != 4
    assert np.isinf(mdb(s)[4])


def test_joint_test_needs_blocks_and_skips_singular_ones():
    s = Snapshot(v=np.ones(4), Pv=np.ones(4), PQvvP=np.ones(4), r=np.ones(4), sigma_l=np.ones(4),
                 vtpv=4.0, dof=2, group=[0, 0, 1, 1])
    with pytest.raises(ValueError, match="PQvvP_blocks"):
        joint_test_2d(s)
    s2 = snapshot_from_arrays(np.ones(4), 2, Qvv_blocks=np.array([[[1, 0.2], [0.2, 1]], [[1, 1], [1, 1]]]),
                              group=[0, 0, 1, 1])
    jt = joint_test_2d(s2)
    assert np.isfinite(jt.T[0]) and np.isnan(jt.T[1]) and not jt.flagged[1]
    assert jt.T[0] == pytest.approx(np.ones(2) @ np.linalg.solve([[1, 0.2], [0.2, 1]], np.ones(2)))


def test_snapshot_from_arrays_validates_groups():
    with pytest.raises(ValueError, match="exactly two rows"):
        snapshot_from_arrays(np.ones(3), 1, Qvv_blocks=np.ones((1, 2, 2)), group=[0, 0, 0])
    with pytest.raises(ValueError, match="qvv or Qvv_blocks"):
        snapshot_from_arrays(np.ones(3), 1)
