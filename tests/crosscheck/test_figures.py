"""Figures of pycolmap-crosscheck: the keys of a real (small) run, and the numbers drawn are the
stage's — its point and photo tables divided by baarda's σ, the costs of both solvers, the
residuals of both solutions."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from baarda.pipeline.adjustment import BundleSettings, adjust  # noqa: E402
from baarda.pipeline.synthetic.aerial import perturb_start, simulate_convergent  # noqa: E402
from baarda.pipeline.testing import run_stage  # noqa: E402
from baarda.plugins.crosscheck.figures import _columns, normalised_differences, residual_data  # noqa: E402
from baarda.plugins.crosscheck.stage import PycolmapCrossCheck  # noqa: E402




@pytest.fixture(scope="module")
def run(tmp_path_factory):
    rng = np.random.default_rng(3)
    noisy, _ = simulate_convergent(rng, n_photos=8, n_points=80, model="none", free_intrinsics=("c", "xp", "yp"),
                                   noise_px=0.5, n_control=8)
    start = perturb_start(noisy, rng, position=0.15, angle=0.01, point=0.1, c=0.05, zero_distortion=True)
    res = adjust(start, BundleSettings())
    return res, run_stage(PycolmapCrossCheck, {"block": start, "bundle": res}, {}, tmp_path=tmp_path_factory.mktemp("cc"))


def _counts(ax):
    return sum(p.get_height() for p in ax.patches)


def test_keys_and_the_numbers_drawn(run):
    res, out = run
    cc = out.data["cc"]
    figs = PycolmapCrossCheck().plots(out, None)
    assert list(figs) == ["differences", "costs", "residuals"]
    assert all(isinstance(v, tuple) and v[1] for v in figs.values())       # every figure has a caption
    pts, ctr, cam = figs["differences"][0].axes
    # object points: every coordinate of every adjusted point, in baarda's σ
    pv = cc.plan.point_variable
    t = out.tables["points"].columns
    assert "dX" not in t and any(c.startswith("dX_") for c in t)             # the column carries its unit
    d = np.column_stack(_columns(out.tables["points"], "dX", "dY", "dZ"))
    assert np.allclose(d, cc.solution.XYZ[pv] - res.state.XYZ[pv])
    v, in_sigma = normalised_differences(d, res.point_sigmas()[pv])
    assert in_sigma and np.allclose(v, (np.abs(d) / res.point_sigmas()[pv]).ravel())
    assert _counts(pts) + int((v == 0).sum()) == v.size == 3 * int(pv.sum())
    assert "/ σ" in pts.get_xlabel() and np.max(v) < 1e-3               # equivalent problems: rounding only
    ph = cc.plan.photo_variable
    assert _counts(ctr) + int((normalised_differences(
        np.column_stack(_columns(out.tables["photos"], "dX0", "dY0", "dZ0")),
        res.eo_sigmas()[ph][:, :3])[0] == 0).sum()) == 3 * int(ph.sum())
    # camera parameters: difference / σ of each refined parameter, as the stage's rows
    ys = np.concatenate([ln.get_ydata() for ln in cam.get_lines() if ln.get_marker() == "o"])
    assert np.allclose(np.sort(ys), np.sort([r["difference_sigma"] for r in cc.cameras]))
    # costs: pycolmap's start and end and baarda's end, as the stage computed them
    q = cc.quantities["cost"]
    heights = [p.get_height() for p in figs["costs"][0].axes[0].patches]
    assert heights == pytest.approx([q["pycolmap_initial"], q["pycolmap"], q["baarda"]], rel=1e-15)
    assert q["pycolmap_initial"] > q["baarda"]
    # residuals: both solutions' histograms over the same observations
    a, b = figs["residuals"][0].axes
    vb, vp, dv = residual_data(cc, res)
    used = cc.plan.obs_used
    assert len(vb) == cc.quantities["residuals"]["n"] == int(used.sum())
    assert np.allclose(vb * cc.plan.sigma_mm[0], res.residuals[used])
    assert np.allclose(vp * cc.plan.sigma_mm[0], cc.solution.residuals[used])
    assert np.max(np.abs(dv)) == pytest.approx(cc.quantities["residuals"]["max"], rel=1e-12)   # the stage's number
    assert _counts(b) + int((dv == 0).sum()) == dv.size
    assert str(cc.quantities["residuals"]["unit"]) in b.get_xlabel()
    assert [t.get_text() for t in a.get_legend().get_texts()] == ["baarda", "pycolmap"]


def test_without_sigma_the_differences_are_in_object_units():
    d = np.array([[1e-9, -2e-9, 0.0]])
    v, in_sigma = normalised_differences(d, None)
    assert not in_sigma and np.allclose(v, [1e-9, 2e-9, 0.0])
    v, in_sigma = normalised_differences(d, np.array([[1.0, 0.0, 1.0]]))    # a zero σ: not in σ
    assert not in_sigma
    v, in_sigma = normalised_differences(d, np.array([[1e-3, 1e-3, 2e-3]]))
    assert in_sigma and np.allclose(v, [1e-6, 2e-6, 0.0])
