"""Independent-model block adjustment on a synthetic normal-case block."""

import dataclasses

import numpy as np
import pytest

from baarda.pipeline.errors import AdjustmentError, InputError
from baarda.pipeline.model import Points
from baarda.pipeline.stats import data_snooping, iterated_data_snooping
from baarda.pipeline.accuracy import check_point_rmse
from baarda.pipeline.imodels.block import ModelCoordinates, adjust_model_block
from baarda.pipeline.imodels.workflow import form_pairs, independent_model_block

from baarda.pipeline.synthetic.normalcase import make_block


def _truth_errors(result, block, truth):
    blk = result.block
    pts = blk.role != "pc"
    i = block.points.index_of(blk.point_ids[pts])
    e_pts = np.abs(blk.XYZ[pts] - truth["XYZ"][i]).max()
    j = block.photos.index_of([k[3:] for k in blk.point_ids[~pts]])
    e_pc = np.abs(blk.XYZ[~pts] - truth["X0"][j]).max()
    return e_pts, e_pc


@pytest.mark.parametrize("method,parameters", [("coplanarity", "dependent"), ("coplanarity", "independent"),
                                               ("collinearity", "dependent"), ("collinearity", "independent")])
def test_noise_free_block_recovers_truth(method, parameters):
    block, truth = make_block(n_strips=2, n_photos=4)
    res = independent_model_block(block, method=method, parameters=parameters)
    assert len(res.models) == 6
    e_pts, e_pc = _truth_errors(res, block, truth)
    assert e_pts < 1e-12 and e_pc < 1e-12  # metres, object extent ≈ 2 m
    assert res.block.sigma0_hat < 1e-6  # σ = 4 µm a priori: residuals are rounding only
    rm = res.check
    assert rm.n == int((block.points.role == "check").sum()) and rm.Sz < 1e-12


def test_converges_from_poor_initial_values():
    block, truth = make_block(n_strips=2, n_photos=4, noise_mm=0.004, rng=np.random.default_rng(7))
    ref = independent_model_block(block)
    rng = np.random.default_rng(1)
    p0 = ref.block.params.copy()
    p0[:, 0] *= 1 + 0.05 * rng.standard_normal(len(p0))
    p0[:, 1:4] += 0.03 * rng.standard_normal((len(p0), 3))
    p0[:, 4:] += 0.05 * rng.standard_normal((len(p0), 3))
    X0 = {k: v + 0.05 * rng.standard_normal(3) for k, v in zip(ref.block.point_ids, ref.block.XYZ)}
    again = adjust_model_block(ref.models, block.points, initial={"params": p0, "XYZ": X0})
    assert again.iterations > 3
    assert np.abs(again.XYZ - ref.block.XYZ).max() < 1e-10
    assert abs(again.sigma0_hat - ref.block.sigma0_hat) < 1e-8


def test_noise_statistics_plausible():
    block, truth = make_block(n_strips=2, n_photos=4, noise_mm=0.004, rng=np.random.default_rng(3))
    res = independent_model_block(block)
    assert 0.7 < res.block.sigma0_hat < 1.3
    s = res.block.snapshot
    assert abs(s.r.sum() - s.dof) < 1e-6
    # redundancy: n observations − 7 per model − 3 per adjusted unknown point (no weighted control)
    n_unknown_pts = int(res.block.in_adjustment.sum()) - int((res.block.role == "full").sum())
    n_z = int((res.block.role == "z").sum())
    assert s.dof == s.n - 7 * 6 - 3 * n_unknown_pts + n_z
    # check points: errors of the size the propagated precision predicts (σ of a few 0.01 mm)
    assert res.check.Sxy < 2e-4 and res.check.Sz < 5e-4


def test_partial_and_weighted_control():
    block, truth = make_block(n_strips=2, n_photos=4)
    pts = block.points
    role = pts.role.copy()
    full = np.flatnonzero(role == "full")
    role[full[:2]] = "xy"
    sigma = np.full((len(pts), 3), np.inf)
    sigma[role == "full"] = 0.001
    sigma[role == "xy", :2] = 0.0
    sigma[role == "z", 2] = 0.002
    block = block.replace(points=Points(ids=pts.ids, XYZ=pts.XYZ, role=role, sigma=sigma))
    res = independent_model_block(block)
    e_pts, e_pc = _truth_errors(res, block, truth)
    assert e_pts < 1e-11 and e_pc < 1e-11
    # weighted control coordinates are rows of the adjustment: 2 full × 3 + 2 z
    assert res.block.control_point.size == 8


def test_control_blunder_found_by_iterated_data_snooping():
    block, truth = make_block(n_strips=2, n_photos=4, noise_mm=0.004, rng=np.random.default_rng(5))
    pts = block.points
    XYZ = pts.XYZ.copy()
    sigma = np.array(pts.sigma)
    ctrl = np.flatnonzero(pts.role == "full")
    sigma[ctrl] = 0.0002
    sigma[pts.role == "z", 2] = 0.0002
    bad = ctrl[1]
    XYZ[bad, 2] += 0.004  # 20 σ in Z of a control point
    block = block.replace(points=Points(ids=pts.ids, XYZ=XYZ, role=pts.role, sigma=sigma))
    res = independent_model_block(block)
    ds = data_snooping(res.block.snapshot)
    assert ds.labels[ds.largest] == f"control {pts.ids[bad]} Z"
    ids = iterated_data_snooping(res.block, res.block.snapshot)
    assert ids.removed_labels[0] == f"control {pts.ids[bad]} Z"
    again = res.block.rerun(ids.active)
    assert abs(again.XYZ[list(again.point_ids).index(pts.ids[bad]), 2] - truth["XYZ"][bad, 2]) < 5e-4


def test_single_model_is_an_absolute_orientation():
    block, truth = make_block(n_strips=1, n_photos=2, control="corners")
    res = independent_model_block(block)
    assert len(res.models) == 1
    e_pts, _ = _truth_errors(res, block, truth)
    assert e_pts < 1e-12


def test_check_point_rmse_formula():
    adj = np.array([[1.0, 2.0, 3.0], [2.0, 2.0, 2.0]])
    sur = np.array([[1.1, 1.8, 3.0], [2.0, 2.1, np.nan]])
    rm = check_point_rmse(adj, sur)
    assert np.isclose(rm["Sx"], np.sqrt((0.01 + 0) / 2))
    assert np.isclose(rm["Sy"], np.sqrt((0.04 + 0.01) / 2))
    assert np.isclose(rm["Sz"], 0.0)  # one finite Z difference
    assert np.isclose(rm["Sxy"], np.sqrt((rm["Sx"] ** 2 + rm["Sy"] ** 2) / 2)) and rm["n"] == 2


# ------------------------------------------------------------------------ pairing

def test_pairing_consecutive_and_strips():
    block, _ = make_block(n_strips=2, n_photos=4, with_pairs=False)
    pairs, notes = form_pairs(block, "auto")
    assert pairs == [(0, 1), (1, 2), (2, 3), (4, 5), (5, 6), (6, 7)]
    assert notes and "14 and 21" in notes[0]
    pairs, _ = form_pairs(block, "consecutive", strips=[["11", "12", "13"], ["22", "23"]])
    assert pairs == [(0, 1), (1, 2), (5, 6)]
    with pytest.raises(InputError, match="strip 2"):
        form_pairs(block, "consecutive", strips=[["11", "12"], ["99"]])
    with pytest.raises(InputError, match="no stereo pairs"):
        form_pairs(block, "pairs")


# ------------------------------------------------------------------------ degenerate input

def _models(block):
    return independent_model_block(block).models


def test_model_without_tie():
    block, _ = make_block(n_strips=1, n_photos=4)
    models = _models(block)
    m = models[2]
    lone = dataclasses.replace(m, point_ids=np.array([f"x{k}" for k in m.point_ids]))
    with pytest.raises(AdjustmentError, match="model 13-14 has no tie to the block"):
        adjust_model_block(models[:2] + [lone], block.points)


def test_model_with_too_weak_a_tie():
    block, _ = make_block(n_strips=1, n_photos=4)
    models = _models(block)
    m = models[2]
    shared = set(models[1].point_ids)
    keep = [k for k in m.point_ids if k not in shared][:0] + [k for k in m.point_ids if k in shared][:2]
    ids = np.array([k if k in keep else f"x{k}" for k in m.point_ids])
    weak = dataclasses.replace(m, point_ids=ids)
    with pytest.raises(AdjustmentError, match="model 13-14 is tied to the block by only 2 point"):
        adjust_model_block(models[:2] + [weak], block.points)


def test_missing_datum():
    block, _ = make_block(n_strips=1, n_photos=3)
    pts = block.points
    tie = Points.make(pts.ids, pts.XYZ, np.where(pts.role == "check", "check", "tie"))
    with pytest.raises(AdjustmentError, match="datum missing"):
        independent_model_block(block.replace(points=tie))
    # two full points and nothing else: a rotation about their line is free
    role = np.array(["tie"] * len(pts), dtype=object)
    role[np.flatnonzero(pts.role == "full")[:2]] = "full"
    two = Points.make(pts.ids, pts.XYZ, role.astype(str))
    with pytest.raises(AdjustmentError, match="datum missing|undetermined|rank"):
        independent_model_block(block.replace(points=two))


def test_pair_with_too_few_points_names_the_model():
    block, _ = make_block(n_strips=1, n_photos=3)
    obs = block.observations
    # keep only 4 points common to photos 12 and 13
    common = sorted(set(obs.point[obs.photo == 1]) & set(obs.point[obs.photo == 2]))
    drop = np.isin(obs.point, common[4:]) & (obs.photo == 2)
    block = block.replace(observations=obs.replace(active=~drop))
    with pytest.raises(AdjustmentError, match="model 12-13.*at least 5 points.*got 4"):
        independent_model_block(block)
    res = independent_model_block(block, skip_failed_models=True, pairing="pairs")
    assert [p[0] for p in res.pairs] == ["11-12"] and "model 12-13 skipped" in res.notes[0]


def test_reserved_point_prefix():
    block, _ = make_block(n_strips=1, n_photos=2)
    pts = block.points
    ids = pts.ids.copy().astype(object)
    ids[0] = "pc:1"
    block = block.replace(points=Points(ids=ids.astype(str), XYZ=pts.XYZ, role=pts.role, sigma=pts.sigma))
    with pytest.raises(InputError, match="pc:1"):
        independent_model_block(block)


def test_model_coordinates_validation():
    with pytest.raises(ValueError, match="duplicate"):
        ModelCoordinates("m", ["a", "a"], np.zeros((2, 3)), np.zeros((2, 3, 3)))


def test_grouped_statistics_equal_the_reference_linear_model():
    """The block's structured snapshot equals baarda.pipeline.stats.LinearModel on the same linearisation,
    with rows removed (one coordinate of a point, a whole point, a control coordinate)."""
    block, truth = make_block(n_strips=1, n_photos=3, noise_mm=0.004, rng=np.random.default_rng(2))
    pts = block.points
    sigma = np.array(pts.sigma)
    sigma[pts.role == "full"] = 0.0003
    block = block.replace(points=Points(ids=pts.ids, XYZ=pts.XYZ, role=pts.role, sigma=sigma))
    res = independent_model_block(block).block
    act = res.snapshot.active.copy()
    act[[4, 9, 10, 11, len(act) - 2]] = False
    again = res.rerun(act)
    ref = again.linear_model().adjust(act).snapshot
    mine = again.snapshot
    assert mine.dof == ref.dof
    assert np.isclose(mine.vtpv, ref.vtpv, rtol=1e-9)
    for k in ("v", "Pv", "PQvvP", "r", "sigma_l", "v_pred"):
        a, b = getattr(mine, k), getattr(ref, k)
        assert np.allclose(a, b, rtol=1e-7, atol=1e-9 * np.abs(b).max()), k
    out = ~act
    assert np.allclose(mine.sigma_v_pred[out], ref.sigma_v_pred[out], rtol=1e-7)
