"""The adjustment on synthetic blocks: truth from perturbed starts, redundancy, datum, messages."""

import numpy as np
import pytest

from baarda.pipeline.errors import AdjustmentError, InputError
from baarda.pipeline.adjustment import BundleSettings, Distance, adjust

from baarda.pipeline.synthetic.closerange import make_block, perturb


@pytest.mark.parametrize("model", ["none", "brown", "aicon", "ebner12"])
def test_noise_free_block_returns_truth(model):
    blk, truth = make_block(model=model, n_photos=10, n_points=60)
    start = perturb(blk, np.random.default_rng(3))
    res = adjust(start)
    assert res.iterations < 15
    assert np.abs(res.state.X0 - truth["X0"]).max() < 1e-10
    assert np.abs(res.state.opk - truth["opk"]).max() < 1e-10
    assert np.abs(res.state.XYZ - truth["XYZ"]).max() < 1e-10
    cam = res.state.cam_params[0, :len(truth["cam"])]
    assert np.allclose(cam, truth["cam"], rtol=1e-8, atol=1e-14)
    assert res.vtpv < 1e-15
    # Σ r_i = redundancy (trace of Qvv P) — checks every Qvv block at once
    assert res.redundancy.sum() == pytest.approx(res.dof, rel=1e-9)


def test_missing_initial_values_are_computed():
    blk, truth = make_block(model="none", n_photos=8, n_points=50, n_control=10)
    ph, pts = blk.photos, blk.points
    XYZ = pts.XYZ.copy()
    XYZ[pts.role == "tie"] = np.nan
    start = blk.replace(photos=ph.replace(X0=np.full_like(ph.X0, np.nan), opk=np.full_like(ph.opk, np.nan)),
                        points=pts.replace(XYZ=XYZ))
    res = adjust(start)
    assert np.abs(res.state.XYZ - truth["XYZ"]).max() < 1e-9
    assert np.abs(res.state.X0 - truth["X0"]).max() < 1e-9


def test_refit_returns_a_new_result_and_never_changes_this_one():
    """``BundleResult.refit`` (the Refittable contract IDS and Pope use) leaves the result it is
    called on as it was; the new adjustment is reachable from the returned snapshot."""
    from baarda.pipeline.adjustment import result_of

    block, _ = make_block(n_photos=6, n_points=30, model="none", noise_mm=0.001, rng=np.random.default_rng(4))
    res = adjust(block, BundleSettings(datum="control"))
    before = (res.state.XYZ.copy(), res.snapshot.v.copy(), res.row_active.copy(), dict(res.__dict__))
    active = res.row_active.reshape(-1).copy()
    active[:2] = False
    snap = res.refit(active)
    new = result_of(snap, None)
    assert new is not None and new is not res and not new.row_active[0].any()
    np.testing.assert_array_equal(res.state.XYZ, before[0])
    np.testing.assert_array_equal(res.snapshot.v, before[1])
    np.testing.assert_array_equal(res.row_active, before[2])
    assert set(res.__dict__) == set(before[3]) and all(res.__dict__[k] is before[3][k] for k in before[3])
    assert snap.dof == res.snapshot.dof - 2
