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
