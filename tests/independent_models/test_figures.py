"""Figures of independent-models: the keys of a real (small) run, and the numbers drawn are the
stage's (check-point errors, y-parallaxes, model-point residuals) and, beside them, the check-point
errors of an earlier bundle of the run (the bundle result's own)."""

from __future__ import annotations

import re

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from baarda.pipeline.adjustment import BundleSettings, adjust  # noqa: E402
from baarda.pipeline.stage import Context, Finding, StageResult  # noqa: E402
from baarda.pipeline.synthetic.normalcase import make_block  # noqa: E402
from baarda.pipeline.testing import run_stage  # noqa: E402
from baarda.plugins.independent_models.figures import model_residual_rms, y_parallax_points  # noqa: E402
from baarda.plugins.independent_models.stage import IndependentModels  # noqa: E402

from .test_stage import _weighted  # noqa: E402




@pytest.fixture(scope="module")
def run(tmp_path_factory):
    block, _ = make_block(n_strips=2, n_photos=4, noise_mm=0.004, rng=np.random.default_rng(9))
    block = _weighted(block)
    obs = block.observations
    xy = obs.xy.copy()
    k = np.flatnonzero((obs.photo == 1) & (obs.point == obs.point[obs.photo == 1][5]))[0]
    xy[k, 1] += 0.08                                  # a y-parallax blunder in the first strip's second photo
    block = block.replace(observations=obs.replace(xy=xy))
    out = run_stage(IndependentModels, {"block": block}, {}, tmp_path=tmp_path_factory.mktemp("im"))
    return block, str(block.points.ids[obs.point[k]]), out


def _bars(ax, label):
    return [p for c in ax.containers if c.get_label() == label for p in c.patches]


def test_keys_and_check_points_alone(run):
    _, _, out = run
    figs = IndependentModels().plots(out, None)
    assert list(figs) == ["checkpoints", "y_parallax", "model_residuals"]
    assert all(isinstance(v, tuple) and v[1] for v in figs.values())
    plan, bx, by, bz = figs["checkpoints"][0].axes
    chk = out.data["result"].block.check
    assert [t.get_text() for t in bz.get_xticklabels()] == [str(i) for i in chk.ids]
    for ax, c in ((bx, 0), (by, 1), (bz, 2)):
        assert np.allclose([p.get_height() for p in _bars(ax, "independent models")], chk.errors[:, c])
    q = plan.collections[0]                           # the vectors at the surveyed positions
    t = out.tables["check_points"].columns
    assert np.allclose(np.hypot(q.U, q.V) / np.hypot(q.U, q.V).max(),
                       np.hypot(t["dX_m"], t["dY_m"]) / np.hypot(t["dX_m"], t["dY_m"]).max())


def test_beside_an_earlier_bundle(run, tmp_path):
    block, _, out = run
    res = adjust(block, BundleSettings())
    with_bundle = run_stage(IndependentModels, {"block": block, "bundle": res}, {}, tmp_path=tmp_path)
    ctx = Context(stage_id="independent-models", project_dir=tmp_path,
                  findings=(Finding.of("adjust", "bundle", StageResult(summary={"headline": "x"})),))
    assert "beside the bundle's (adjust)" in IndependentModels().plots(with_bundle, ctx)["checkpoints"][1]
    figs = IndependentModels().plots(with_bundle, None)          # no findings: labelled plain "bundle"
    assert "beside the bundle's (bundle)" in figs["checkpoints"][1]
    assert "beside" not in IndependentModels().plots(out, ctx)["checkpoints"][1]     # no bundle artefact read
    plan, bx, by, bz = figs["checkpoints"][0].axes
    ids = [t.get_text() for t in bz.get_xticklabels()]
    got = {ids[round(p.get_x() + p.get_width() / 2)]: p.get_height() for p in _bars(bz, "bundle")}
    want = dict(zip(res.check.ids, np.asarray(res.check.errors)[:, 2]))
    assert got == pytest.approx(want) and len(got) == res.check.n


def test_y_parallaxes_and_residuals_are_the_stage_numbers(run):
    _, pid, out = run
    data = y_parallax_points(out.data["result"], out.data["stats"])
    t = out.tables["ro_points"].columns
    assert np.allclose(np.concatenate([d[2] for d in data]), t["py_um"])
    assert [i for d in data for i in d[1]] == [str(i) for i in t["point"]]
    # flagged: the points of the stage's flagged labels ("model 12-13 point 105 py"), the blunder among them
    flagged = {(d[0], i) for d in data for i, f in zip(d[1], d[4]) if f}
    labels = {(m["model"], re.fullmatch(r"model \S+ point (\S+) py", lab).group(1))
              for m in out.summary["per_model"] for lab in m["flagged"]}
    assert flagged == labels and pid in {i for _, i in flagged}
    fig = IndependentModels().plots(out, None)["y_parallax"][0]
    ax = fig.axes[0]
    red = [ln for ln in ax.get_lines() if ln.get_label() == "flagged (w-test)" or
           (ln.get_color() == "#c0392b" and ln.get_label().startswith("_"))]
    assert sum(len(ln.get_ydata()) for ln in red) == len(flagged)
    assert sorted(np.concatenate([ln.get_ydata() for ln in ax.get_lines() if len(ln.get_ydata()) and
                                  ln.get_marker() == "o"])) == pytest.approx(sorted(t["py_um"]))
    r = out.tables["residuals"].columns
    axes = IndependentModels().plots(out, None)["model_residuals"][0].axes
    assert len(axes) == 2                              # model points, projection centres
    for ax, pc in zip(axes, (False, True)):
        ids, rms = model_residual_rms(out.tables["residuals"], pc)
        m0 = (np.asarray(r["model"]).astype(str) == ids[0]) & ((np.asarray(r["role"]) == "pc") == pc)
        assert m0.any() and rms[0, 2] == pytest.approx(np.sqrt(np.mean(np.asarray(r["vz_m"], float)[m0] ** 2)))
        assert np.allclose([p.get_height() for p in ax.patches], 1000 * rms.T.ravel())    # m → mm, x bars first
