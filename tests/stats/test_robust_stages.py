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
    res = run_stage(BundleAdjustment, {"block": bad_block}, {"robust": {"method": method}}, tmp_path=tmp_path)
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
    with pytest.raises((ValueError, InputError), match="excludes tests.blunders = 'ids'"):
        run_stage(BundleAdjustment, {"block": bad_block}, {"robust": {"method": "huber"}, "tests": {"blunders": "ids"}},
                  tmp_path=tmp_path)


# ------------------------------------------------------------------ blunder-rejection robust-*
from baarda.pipeline.contracts import AdjustmentArtefact
from baarda.plugins.blunder_rejection.stage import BlunderRejection
from tests.blunder_rejection.test_table4 import adjust as paper000


def test_blunder_rejection_robust_on_paper000_data1(tmp_path):
    """Paper 000's Data 1 (Helmert screening of a stereo pair): IDS rejects X9, X5, Y5; the Danish
    weights of exactly those rows vanish, Huber down-weights them most (and X3 just below 0.5)."""
    inputs = paper000("data1", tmp_path)
    out = {}
    for m in ("robust-danish", "robust-huber"):
        res = run_stage(BlunderRejection, inputs, {"method": m, "action": "remove"}, tmp_path=tmp_path)
        out[m] = res.artefacts["blunders"].methods[m]
        cols = res.tables["observations"].columns
        assert f"{m.replace('-', '_')}_weight" in cols and m + ": IRLS" in res.report
        ids = res.artefacts["block"].observation_ids()
        assert {("R", "5"), ("R", "9")} <= {ids[i] for i in np.flatnonzero(~res.artefacts["block"].observations.active)}
    assert out["robust-danish"].rejected_labels == ["X9", "X5", "Y5"]
    assert all(d.value < 1e-6 for d in out["robust-danish"].decisions)
    assert out["robust-huber"].rejected_labels[:3] == ["X9", "X5", "Y5"]
    assert inputs["block"].observations.active.all()


def test_blunder_rejection_robust_on_the_bundle_artefact(tmp_path, bad_block):
    b = run_stage(BundleAdjustment, {"block": bad_block}, {}, tmp_path=tmp_path)
    res = run_stage(BlunderRejection, {"adjustment": b.artefacts["adjustment"], "block": b.artefacts["block"]},
                    {"method": "robust-danish"}, tmp_path=tmp_path)
    r = res.artefacts["blunders"].methods["robust-danish"]
    assert r.rejected[0] == 75 and r.summary["how"].startswith("bundle")


class _OnlyRefit:
    def __init__(self, m):
        self.m = m

    def refit(self, active):
        return self.m.refit(active)


def test_blunder_rejection_robust_needs_a_weighted_refit(tmp_path):
    inputs = paper000("data1", tmp_path)
    art = inputs["adjustment"]
    other = AdjustmentArtefact("other", art.snapshot, _OnlyRefit(art.model), art.obs_rows)
    with pytest.raises(InputError, match="method 'robust-huber' cannot run: a _OnlyRefit offers no weighted refit"):
        run_stage(BlunderRejection, {**inputs, "adjustment": other}, {"method": "robust-huber"}, tmp_path=tmp_path)


# ------------------------------------------------------------------ helmert-screening robust
from tests.screening.test_paper000 import screen as paper000_screen


@pytest.mark.parametrize("method", ["danish", "huber"])
def test_screening_reports_robust_weights(tmp_path, method):
    plain = paper000_screen("data1", tmp_path)
    res = paper000_screen("data1", tmp_path, robust={"method": method})
    t = res.tables["robust"].columns
    down = [r for r, d in zip(t["row"], t["downweighted"]) if d]
    assert {"X9", "X5", "Y5"} <= set(down)
    assert "### Robust estimation (" + method in res.report and res.summary["robust"]["method"] == method
    # report only: the screening's own flags and block are unchanged
    np.testing.assert_array_equal(res.artefacts["block"].observations.active,
                                  plain.artefacts["block"].observations.active)
    assert "robust" not in plain.tables and "robust" not in plain.summary


# ------------------------------------------------------------------ independent-models robust
from baarda.pipeline.synthetic.normalcase import make_block as normal_case
from baarda.plugins.independent_models.stage import IndependentModels
from tests.independent_models.test_stage import _weighted


@pytest.mark.parametrize("method", ["danish", pytest.param("huber", marks=pytest.mark.slow)])   # Huber: ~130 iterations, 15 s
def test_independent_models_reports_robust_weights(tmp_path, method):
    """An x-parallax blunder of 0.08 mm (20 σ) on point 105 in photo 12 (the y-parallax check cannot
    see it): the robust model block down-weights point 105's coordinates in model 12-13 first."""
    block, _ = normal_case(n_strips=2, n_photos=4, noise_mm=0.004, rng=np.random.default_rng(9))
    block = _weighted(block)
    obs = block.observations
    xy = obs.xy.copy()
    k = np.flatnonzero((obs.photo == 1) & (obs.point == obs.point[obs.photo == 1][5]))[0]
    xy[k, 0] += 0.08
    res = run_stage(IndependentModels, {"block": block.replace(observations=obs.replace(xy=xy))},
                    {"robust": {"method": method}}, tmp_path=tmp_path)
    s = res.summary["robust"]
    assert s["converged"] and s["method"] == method
    assert "point 105" in s["downweighted"][0]["label"] and "12-13" in " ".join(
        d["label"] for d in s["downweighted"][:3])
    assert "### Robust estimation (" + method in res.report
    t = res.tables["robust"].columns
    assert sum(t["downweighted"]) == s["n_downweighted"]


# ------------------------------------------------------------------ one schema per parameter
import dataclasses

from baarda.pipeline import stats
from baarda.pipeline.adjustment import BundleConfig, StatTestsConfig
from baarda.pipeline.options import parse_options
from baarda.plugins.blunder_rejection.decide import BlunderOptions
from baarda.plugins.independent_models.stage import IndependentModelsOptions
from baarda.plugins.screening.stage import ScreeningOptions


def _field(cls, name):
    return {f.name: f for f in dataclasses.fields(cls)}[name]


def test_the_robust_and_snooping_options_are_declared_once():
    """bundle, helmert-screening and independent-models nest the statistics library's RobustConfig;
    blunder-rejection nests its RobustTuning (c, standardise; the weight function is its method);
    the bundle's tests group and blunder-rejection share SnoopingConfig's alpha0 … ids_stop,
    helmert-screening and independent-models its base SnoopingLevels (alpha0, beta0)."""
    for cls in (BundleConfig, ScreeningOptions, IndependentModelsOptions):
        assert _field(cls, "robust").type in ("RobustConfig", "stats.RobustConfig")
        assert isinstance(cls().robust, stats.RobustConfig)
    assert type(BlunderOptions().robust) is stats.RobustTuning
    assert issubclass(stats.RobustConfig, stats.RobustTuning)
    for name in ("c", "standardise"):
        assert _field(stats.RobustConfig, name) is _field(stats.RobustTuning, name)
    for name in ("alpha0", "beta0", "max_rejections", "ids_stop"):
        assert _field(StatTestsConfig, name) is _field(stats.SnoopingConfig, name)
        assert _field(BlunderOptions, name) is _field(stats.SnoopingConfig, name)
    for name in ("alpha0", "beta0"):
        for cls in (ScreeningOptions, IndependentModelsOptions, stats.SnoopingConfig):
            assert _field(cls, name) is _field(stats.SnoopingLevels, name)


@pytest.mark.parametrize("cls, raw, message", [
    (ScreeningOptions, {"robust": "huber"}, "robust is now written as robust.method"),
    (ScreeningOptions, {"robust_c": 2.0}, "robust_c is now written as robust.c"),
    (IndependentModelsOptions, {"robust": "danish"}, "robust is now written as robust.method"),
    (IndependentModelsOptions, {"robust_c": 2.0}, "robust_c is now written as robust.c"),
    (BlunderOptions, {"robust_c": 2.0}, "robust_c is now written as robust.c"),
    (BlunderOptions, {"robust_standardise": "apriori"}, "robust_standardise is now written as robust.standardise"),
])
def test_old_flat_robust_names_say_their_new_spelling(cls, raw, message):
    with pytest.raises(InputError, match=f"^p.toml:4, field '{list(raw)[0]}': {message} "
                                         r"\(in a \[stage.options.robust\] table\)$"):
        parse_options(cls, raw, path="p.toml", line=4)


def test_nested_robust_tables_parse():
    o = parse_options(ScreeningOptions, {"robust": {"method": "huber", "c": 2.0}})
    assert o.robust == stats.RobustConfig(method="huber", c=2.0)
    b = parse_options(BlunderOptions, {"method": "robust-l1", "robust": {"standardise": "current"}})
    assert b.robust == stats.RobustTuning(standardise="current")


@pytest.mark.parametrize("make, name", [
    (lambda: BlunderOptions(alpha0=1.5), "alpha0"),
    (lambda: BlunderOptions(alpha_rrr=0.0), "alpha_rrr"),
    (lambda: BlunderOptions(rho=-1), "rho"),
    (lambda: BlunderOptions(n_sim=-5), "n_sim"),
    (lambda: BlunderOptions(max_rejections=-1), "max_rejections"),
    (lambda: BlunderOptions(rrr_critical=-0.1), "rrr_critical"),
    (lambda: stats.RobustTuning(c=-1.0), "c"),
    (lambda: stats.SnoopingConfig(beta0=1.0), "beta0"),
    (lambda: ScreeningOptions(threshold_mm=0.0), "threshold_mm"),
    (lambda: ScreeningOptions(alpha_pope=1.0), "alpha_pope"),
    (lambda: IndependentModelsOptions(sigma_pc_scale=0.0), "sigma_pc_scale"),
    (lambda: IndependentModelsOptions(beta0=0.0), "beta0"),
])
def test_declared_bounds_of_options_built_in_python(make, name):
    with pytest.raises(ValueError, match=f"^{name}: must be"):
        make()


def test_blunder_rejection_bounds_from_a_project_name_the_field():
    with pytest.raises(InputError, match=r"^p.toml:7, field 'robust.c': must be at least 0, got -1$"):
        parse_options(BlunderOptions, {"robust": {"c": -1.0}}, path="p.toml", line=7)
    with pytest.raises(InputError, match=r"^p.toml:7, field 'rho': must be at least 0, got -2$"):
        parse_options(BlunderOptions, {"rho": -2}, path="p.toml", line=7)
    with pytest.raises(InputError, match="n_sim = 0 needs an explicit rrr_critical"):
        parse_options(BlunderOptions, {"n_sim": 0}, path="p.toml", line=7)


def test_screening_robust_standardise_reaches_the_irls(tmp_path):
    res = paper000_screen("data1", tmp_path, robust={"method": "huber", "standardise": "apriori", "c": 2.0})
    s = res.summary["robust"]
    assert s["standardise"] == "apriori" and s["c"] == 2.0
