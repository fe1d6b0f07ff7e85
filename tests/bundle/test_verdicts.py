"""The bundle's verdicts: the global test at alpha_global (two-sided 5 % by default, the B-method on
request), and one decision per image point — flagged (kept) whatever `blunders` says, rejected only
when removed."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats as sps

from baarda.pipeline.adjustment import BundleConfig, StatTestsConfig, adjust_block
from baarda.pipeline.stats import alpha_prime
from baarda.pipeline.synthetic.closerange import make_block


@pytest.fixture(scope="module")
def bad_block():
    block, _ = make_block(n_photos=6, n_points=30, model="brown", noise_mm=0.001, rng=np.random.default_rng(3))
    obs = block.observations
    xy = obs.xy.copy()
    xy[11, 1] += 0.025                               # 25 σ on image point 11, y
    return block.replace(observations=obs.replace(xy=xy))


def test_global_test_level_is_the_option(bad_block):
    rep = adjust_block(bad_block)
    g = rep.global_test
    assert (g.method, g.alpha) == ("two-sided", 0.05)
    dof = rep.result.dof
    assert g.critical == pytest.approx(sps.chi2.isf(0.025, dof) / dof, rel=1e-12)
    assert g.T == pytest.approx(rep.sigma0_hat ** 2, rel=1e-12)
    b = adjust_block(bad_block, BundleConfig(tests=StatTestsConfig(alpha_global="B-method")))
    assert b.global_test.method == "B-method"
    assert b.global_test.alpha == pytest.approx(alpha_prime(0.001, 0.8, dof))
    assert b.global_test.T == g.T                     # the same adjustment, another level


def test_flagged_without_blunder_handling_and_rejected_with_ids(bad_block):
    rep = adjust_block(bad_block)                     # blunders = "none": nothing removed, 11 flagged
    assert rep.config.tests.blunders == "none"
    flagged_points = set(np.flatnonzero(rep.snooping.flagged) // 2)
    assert 11 in flagged_points
    assert set(np.flatnonzero(rep.decision == "flagged")) == flagged_points
    assert not (rep.decision == "rejected").any()
    assert rep.output_block.observations.active[11]   # kept
    ids = adjust_block(bad_block, BundleConfig(tests=StatTestsConfig(blunders="ids")))
    assert ids.decision[11] == "rejected" and not ids.output_block.observations.active[11]
