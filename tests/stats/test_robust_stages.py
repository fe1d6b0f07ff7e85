"""Robust estimation in the stages: the bundle's ``robust`` option and blunder-rejection's
``robust-*`` methods (report, results, CSV column, the block's a-priori σ untouched)."""

import json

import numpy as np
import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.testing import run_stage
from baarda.pipeline.synthetic.closerange import make_block
from baarda.plugins.bundle.stage import BundleAdjustment


@pytest.fixture(scope="module")
def bad_block():
    blk, _ = make_block(model="none", n_photos=8, n_points=40, noise_mm=0.001, rng=np.random.default_rng(7))
    obs = blk.observations
    xy = obs.xy.copy()
    xy[37, 1] += 0.02                  # 20 σ in y
    return blk.replace(observations=obs.replace(xy=xy))


@pytest.mark.parametrize("method", ["huber", "danish"])
def test_bundle_robust_downweights_the_blunder(tmp_path, bad_block, method):
    res = run_stage(BundleAdjustment, {"block": bad_block}, {"robust": method}, tmp_path=tmp_path)
    t = res.tables["observations"].columns
    dec = np.array(t["decision"])
    assert dec[37] == "downweighted"
    assert t["robust_wy"][37] < 0.1 and t["robust_wx"][37] == pytest.approx(1.0)
    s = res.summary["robust"]
    assert s["method"] == method and s["converged"] and s["downweighted"][0]["row"] == 2 * 37 + 1
    assert "robust estimation: " + method in res.report and "Down-weighted" in res.report
    json.dumps(res.summary, default=float)       # results.json can hold it
    b = res.artefacts["bundle"]
    assert abs(b.sigma0_hat - 1) < 0.2
    # the output block keeps the a-priori covariances; the bundle's own block_in has the weighted ones
    np.testing.assert_array_equal(res.artefacts["block"].observations.cov, bad_block.observations.cov)
    assert b.block_in.observations.cov[37, 1, 1] > 10 * bad_block.observations.cov[37, 1, 1]


def test_bundle_robust_excludes_ids(tmp_path, bad_block):
    with pytest.raises((ValueError, InputError), match="excludes blunders = 'ids'"):
        run_stage(BundleAdjustment, {"block": bad_block}, {"robust": "huber", "blunders": "ids"}, tmp_path=tmp_path)
