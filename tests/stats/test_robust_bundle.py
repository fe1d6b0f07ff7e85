"""Robust estimation on a simulated bundle (pipeline/synthetic/closerange): the weights enter the
bundle through the image covariances (stats.robust.weighted_refit / scale_covariance)."""

import numpy as np
import pytest

from baarda.pipeline.adjustment import BundleSettings, adjust
from baarda.pipeline.stats import irls, scale_covariance, weighted_refit
from baarda.pipeline.synthetic.closerange import make_block


@pytest.fixture(scope="module")
def blundered():
    block, truth = make_block(n_photos=8, n_points=40, noise_mm=0.001, model="brown")
    obs = block.observations
    xy = obs.xy.copy()
    xy[17, 0] += 0.02                      # 20 σ on the x of observation 17 (scalar row 34)
    block = block.replace(observations=obs.replace(xy=xy))
    return block, truth, adjust(block, BundleSettings())


def test_unit_weights_reproduce_the_adjustment(blundered):
    _, _, res = blundered
    refit, how = weighted_refit(res)
    assert how.startswith("bundle")
    out = refit(np.ones(2 * len(res.residuals)))
    np.testing.assert_allclose(out.v, res.snapshot.v, atol=1e-9)


@pytest.mark.parametrize("method", ["huber", "danish"])
def test_blunder_downweighted_and_points_improved(blundered, method):
    block, truth, res = blundered
    rob = irls(weighted_refit(res)[0], res.snapshot, method)
    assert rob.converged and rob.downweighted[0] == 34
    assert rob.weights[34] < (0.1 if method == "huber" else 1e-20)
    err = lambda st: np.sqrt(np.mean((st.XYZ - truth["XYZ"]) ** 2))
    assert err(rob.fit.result.state) < err(res.state)


def test_danish_weight_zero_is_removal(blundered):
    """A Danish weight of 1e-35 (floored at 1e-8) acts as removing the row: the same bundle with row
    34 inactive and the other rows at the final weights gives the same residuals elsewhere."""
    block, _, res = blundered
    rob = irls(weighted_refit(res)[0], res.snapshot, "danish", tol=1e-8)
    w = np.array(rob.weights)
    w[34] = 1.0
    b = block.replace(observations=block.observations.replace(cov=scale_covariance(block.observations.cov, w)))
    act = np.ones((len(res.residuals), 2), bool)
    act[17, 0] = False
    ref = adjust(b, BundleSettings(), row_active=act, start=res.state, compute_initial=False, covariance=False)
    keep = act.reshape(-1)
    np.testing.assert_allclose(rob.fit.v[keep], ref.residuals.reshape(-1)[keep], atol=2e-6)
