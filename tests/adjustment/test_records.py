"""The typed records the adjustment hands on (issue 21, "no dict passed between modules as a
record"): Convergence, Timings, CheckPoints, the route's cofactors, ParameterVectors — frozen,
read-only, and the same numbers the adjustment computed."""

import dataclasses

import numpy as np
import pytest

from baarda.pipeline.accuracy import CheckPoints, check_point_rmse
from baarda.pipeline.adjustment import (Convergence, Iteration, ParameterVectors, Timings, BundleSettings, adjust,
                                        effect_vectors)
from baarda.pipeline.synthetic.closerange import make_block, perturb


@pytest.fixture(scope="module")
def block():
    rng = np.random.default_rng(5)
    blk, truth = make_block(n_photos=5, n_points=16, noise_mm=0.002, rng=rng, n_control=5)
    role = blk.points.role.astype(object)
    role[[6, 9, 12]] = "check"
    pts = blk.points.replace(role=role, XYZ=np.where((role == "check")[:, None], truth["XYZ"] + 0.001,
                                                     blk.points.XYZ))
    return perturb(blk.replace(points=pts), rng)


@pytest.fixture(scope="module", params=["dense", "sparse"])
def result(block, request):
    res = adjust(block, BundleSettings(solver=request.param))
    assert res.solver_route == request.param
    return res


def test_convergence_is_a_frozen_column_table(result):
    h = result.history
    assert isinstance(h, Convergence) and len(h) == result.iterations + 1
    assert isinstance(h[0], Iteration) and (h[0].iteration, h[0].lam) == (0, 0.0) and np.isnan(h[0].max_step_sigma)
    assert h.iteration.tolist() == list(range(len(h))) and h[-1].vtpv == result.vtpv
    assert [s.vtpv for s in h] == h.vtpv.tolist() and h[1:] == tuple(h)[1:]
    assert np.all(np.diff(h.vtpv) <= 1e-9 * h.vtpv[0])                 # accepted steps never raise vᵀPv
    with pytest.raises(ValueError):
        h.vtpv[0] = 0.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        h.vtpv = None


def test_timings_keep_the_summary_keys(result):
    t = result.timings
    assert isinstance(t, Timings)
    s = result.summary()["timings"]
    assert list(s) == ["setup", "linearize", "solve", "residuals", "initial_values", "covariance", "total"]
    assert all(0 <= v <= t.total for v in s.values()) and s["total"] == t.total
    with pytest.raises(dataclasses.FrozenInstanceError):
        t.total = 0.0


def test_check_points_are_adjusted_minus_surveyed(result, block):
    c = result.check
    k = np.flatnonzero(block.points.role == "check")
    assert isinstance(c, CheckPoints) and c and c.ids == tuple(block.points.ids[k].tolist())
    np.testing.assert_array_equal(c.errors, result.state.XYZ[k] - block.points.XYZ[k])
    ref = check_point_rmse(result.state.XYZ[k], block.points.XYZ[k])
    assert c.rmse() == {key: v for key, v in ref.items() if key != "errors"} and c.n == 3
    assert 0.0005 < c.Sxy < 0.002                                    # the 1 mm the surveyed values were moved
    assert result.summary()["check_points"] == {**c.rmse(), "ids": list(c.ids)}
    assert not c.errors.flags.writeable
    with pytest.raises(ValueError, match="2 check-point ids for 3 errors"):
        CheckPoints.from_errors(["a", "b"], np.zeros((3, 3)))
    assert not CheckPoints.from_errors([], np.zeros((0, 3)))


def test_cofactor_blocks_of_either_route_are_the_columns(result):
    prob, cof = result.problem, result.cofactors
    n_g = prob.n_g
    eo = prob.g_eo[np.flatnonzero((prob.g_eo >= 0).all(axis=1))[:2]]      # within one photo's orientation
    mixed = np.array([[eo[0, 0], eo[1, 2], n_g], [eo[1, 5], n_g, eo[0, 3]]])   # across photos, one fixed
    cols = np.vstack([eo[:, :3], mixed])
    Q = cof.blocks(cols)
    full = np.zeros((n_g + 1, n_g + 1))
    full[:n_g, :n_g] = cof.columns(np.arange(n_g))
    np.testing.assert_allclose(Q, full[cols[:, :, None], cols[:, None, :]], rtol=1e-7, atol=1e-12 * np.abs(full).max())
    assert np.all(Q[2:, :, :][[0, 1], [2, 1]] == 0)                   # a fixed unknown's row


def test_effect_vectors_are_a_record(result):
    oi = np.flatnonzero(result.obs_active)
    ev = effect_vectors(result, [2 * oi[0], 2 * oi[3] + 1])
    assert isinstance(ev, ParameterVectors) and ev.eo.shape == (2, len(result.block_in.photos), 6)
    assert len(ev.cameras) == len(result.block_in.cameras) and ev.points.shape[:2] == (2, len(result.block_in.points))
    with pytest.raises(dataclasses.FrozenInstanceError):
        ev.eo = None
