"""adjust_block: the bundle workflow as a library function (pipeline/adjustment/workflow.py) — one
schema with the stage, inputs never changed, a frozen report, errors naming the option."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from baarda.pipeline.adjustment import (BundleConfig, RobustConfig, SolverConfig, StatTestsConfig,
                                        VarianceComponentsConfig, adjust_block)
from baarda.pipeline.errors import AdjustmentError, InputError
from baarda.pipeline.options import parse_options
from baarda.pipeline.synthetic.closerange import make_block
from baarda.pipeline.testing import run_stage
from baarda.plugins.bundle.stage import BundleAdjustment


@pytest.fixture(scope="module")
def bad_block():
    block, _ = make_block(n_photos=6, n_points=30, model="brown", noise_mm=0.001, rng=np.random.default_rng(3))
    obs = block.observations
    xy = obs.xy.copy()
    xy[11, 1] += 0.025                               # 25 σ on image point 11, y
    return block.replace(observations=obs.replace(xy=xy))


def _copy(block):
    return {"xy": block.observations.xy.copy(), "cov": block.observations.cov.copy(),
            "active": block.observations.active.copy(), "sigma_ap": block.cameras.sigma_ap.copy(),
            "ap_model": block.cameras.ap_model.copy()}


def test_the_stage_options_are_the_library_config():
    assert BundleAdjustment.Options is BundleConfig
    cfg = parse_options(BundleConfig, {"datum": "control", "tests": {"blunders": "ids", "alpha0": 0.01},
                                       "solver": {"max_iter": 7}})
    assert cfg == BundleConfig(tests=StatTestsConfig(blunders="ids", alpha0=0.01), solver=SolverConfig(max_iter=7))


def test_every_moved_flat_name_points_at_a_field():
    for flat, path in BundleConfig.MOVED.items():
        group, name = path.split(".")
        sub = {f.name: f for f in dataclasses.fields(BundleConfig)}[group].type
        sub = getattr(__import__("baarda.pipeline.adjustment", fromlist=[sub]), sub)
        assert name in {f.name for f in dataclasses.fields(sub)}, (flat, path)


@pytest.mark.parametrize("make, field", [
    (lambda: SolverConfig(max_iter=0), "max_iter"),
    (lambda: VarianceComponentsConfig(iterations=0), "iterations"),
    (lambda: BundleConfig(sigma0=0.0), "sigma0"),
])
def test_declared_bounds_hold_for_a_config_built_in_python(make, field):
    """The bundle's own groups and the statistics library's meet their bounds the same way
    (options.check_bounds: a ValueError naming the field; from a project file, parse_options names
    the file, line and dotted option instead)."""
    with pytest.raises(ValueError, match=f"^{field}: must be"):
        make()


@pytest.mark.parametrize("make, field", [
    (lambda: StatTestsConfig(alpha0=1.5), "alpha0"),
    (lambda: StatTestsConfig(max_rejections=-1), "max_rejections"),
    (lambda: RobustConfig(c=-1.0), "c"),
])
def test_declared_bounds_of_the_statistics_library_groups(make, field):
    """The tests group's alpha0 … ids_stop and the robust group are the statistics library's
    SnoopingConfig and RobustConfig (shared with other stages): options.check_bounds, a ValueError
    naming the field."""
    with pytest.raises(ValueError, match=f"^{field}: must be"):
        make()


def test_rules_between_fields():
    with pytest.raises(ValueError, match="excludes tests.blunders = 'ids'"):
        BundleConfig(robust=RobustConfig(method="huber"), tests=StatTestsConfig(blunders="ids"))
    with pytest.raises(ValueError, match="solver.covariance = true"):
        BundleConfig(variance_components=VarianceComponentsConfig(mode="apply"), solver=SolverConfig(covariance=False))


def test_ids_rejects_the_blunder_and_changes_nothing_it_was_given(bad_block):
    before = _copy(bad_block)
    cfg = BundleConfig(ap_model="brown", tests=StatTestsConfig(blunders="ids"))
    rep = adjust_block(bad_block, cfg)
    for k, v in _copy(bad_block).items():
        np.testing.assert_array_equal(v, before[k])
    assert rep.ids.removed == [23] and rep.decision[11] == "rejected"
    assert list(rep.flagged_observations) == [11]
    assert not rep.output_block.observations.active[11] and bad_block.observations.active[11]
    assert not hasattr(rep.result, "extras") and not hasattr(rep.before_ids.result, "extras")   # no stage bag
    assert not rep.decision.flags.writeable and not rep.rejected_rows.flags.writeable
    with pytest.raises(dataclasses.FrozenInstanceError):
        rep.ids = None
    assert rep.sigma0_hat == rep.result.sigma0_hat
    assert rep.global_test.T == pytest.approx(rep.sigma0_hat ** 2, rel=1e-12)    # after the rejection
    assert rep.external is not None and rep.joint is not None


def test_robust_and_variance_components(bad_block):
    rep = adjust_block(bad_block, BundleConfig(robust=RobustConfig(method="danish"),
                                               variance_components=VarianceComponentsConfig(mode="estimate")))
    assert rep.decision[11] == "downweighted" and rep.vc is not None and rep.vc.converged
    # the output block keeps the a-priori σ: the weights are the estimator's
    np.testing.assert_array_equal(rep.output_block.observations.cov, bad_block.observations.cov)


def test_progress_messages_and_the_stage_numbers(bad_block, tmp_path):
    said = []
    cfg = BundleConfig(tests=StatTestsConfig(blunders="data-snooping"))
    rep = adjust_block(bad_block, cfg, progress=said.append)
    assert said and said[0].startswith("adjusting 6 photos")
    out = run_stage(BundleAdjustment, {"block": bad_block}, {"tests": {"blunders": "data-snooping"}},
                    tmp_path=tmp_path)
    assert out.artefacts["bundle"].sigma0_hat == rep.result.sigma0_hat
    assert list(out.tables["observations"].columns["decision"]) == rep.decision.tolist()


def test_option_errors_name_the_option(bad_block):
    with pytest.raises(InputError) as e:
        adjust_block(bad_block, BundleConfig(ap_models={"nope": "brown"}))
    assert e.value.field == "ap_models"
    with pytest.raises(InputError) as e:
        adjust_block(bad_block, BundleConfig(output=dataclasses.replace(BundleConfig().output,
                                                                        covariance_of=["point nope"])))
    assert e.value.field == "output.covariance_of"


def test_an_adjustment_error_carries_the_configured_block(bad_block):
    with pytest.raises(AdjustmentError) as e:
        adjust_block(bad_block, BundleConfig(ap_model="ebner12", solver=SolverConfig(max_iter=1)))
    assert e.value.block.cameras.ap_model[0] == "ebner12" and e.value.state is not None


@pytest.mark.parametrize("kw", [{"fix": ["K4"]}, {"free": ["K9"]}, {"sigma": {"P3": 0.1}}])
def test_parameter_names_checked_against_the_given_model(kw):
    """With ap_model given, a name in fix/free/sigma that the model lacks is refused when the config is
    built (so `baarda validate` says it); without ap_model the block's models decide, at the stage."""
    with pytest.raises(ValueError, match="not a parameter of the camera model"):
        BundleConfig(ap_model="brown", **kw)
    BundleConfig(**kw)
    BundleConfig(ap_model="brown", fix=["K3"], free=["P1"], sigma={"K1": 0.1})
