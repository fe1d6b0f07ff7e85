"""Figures of dbat-report and dbat-marks: the keys a real run gives, and the numbers drawn are the
stage's (its quality dict, its pairs) and DBAT's published report (the same numbers
test_projects.py asserts against)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from baarda.pipeline.adjustment import BundleSettings, adjust  # noqa: E402
from baarda.pipeline.model import Observations  # noqa: E402
from baarda.pipeline.plots import vector_scale  # noqa: E402
from baarda.pipeline.testing import run_stage  # noqa: E402
from baarda.plugins.dbat import dbat_block, read_dbat  # noqa: E402
from baarda.plugins.dbat.figures import PUBLISHED, published  # noqa: E402
from baarda.plugins.dbat.stage import DbatMarks, DbatReport  # noqa: E402

from .test_projects import CAMCAL, SXB_CHECK, SXB_CONTROL  # noqa: E402




def _report(shared_data, name, tmp_path, inputs=None):
    block = dbat_block(read_dbat(shared_data / name))
    res = adjust(block, BundleSettings(datum="control"))
    r = run_stage(DbatReport, {"bundle": res, **(inputs or {})}, {}, tmp_path=tmp_path)
    return block, res, r


def _line(ax, label):
    return next(ln for ln in ax.get_lines() if ln.get_label() == label)


def test_published_values_are_those_the_project_tests_use():
    assert PUBLISHED["camcaldemo.xml"]["camera"] == CAMCAL
    assert PUBLISHED["sxb.xml"]["check"] == {k: v[0] for k, v in SXB_CHECK.items()}
    assert PUBLISHED["sxb.xml"]["control"] == {k: v[:3] for k, v in SXB_CONTROL.items()}
    # only the very script: the name and its number of marks
    assert published("/x/camcaldemo.xml", 2074) is PUBLISHED["camcaldemo.xml"]
    assert published("/x/camcaldemo.xml", 2073) is None and published("/x/other.xml", 2074) is None
    assert published(None, None) is None


def test_camcal_camera_against_dbat_and_an_earlier_report(shared_data, tmp_path):
    block, res, r = _report(shared_data, "dbat-camcal/camcaldemo.xml", tmp_path)
    assert r.data["marks"] == len(block.observations) == 2074
    q = r.artefacts["dbat_report"]
    figs = DbatReport().plots(r, None)
    assert set(figs) == {"camera", "correlation", "angles"}         # fixed control, no check points: no "points"
    a, b = figs["camera"][0].axes
    names = [t.get_text() for t in a.get_xticklabels()]
    assert names == list(CAMCAL)                                     # the estimated parameters, sk fixed
    y = _line(a, "this − DBAT's published report").get_ydata()
    want = [(q["camera"][k][0] - CAMCAL[k][0]) / CAMCAL[k][1] for k in names]
    assert np.allclose(y, want) and np.max(np.abs(y)) < 0.35        # docs/dbat.md: within 0.3 σ
    heights = [p.get_height() for p in b.patches]
    assert np.allclose(heights, [q["camera"][k][1] / CAMCAL[k][1] - 1 for k in names])
    # the correlation matrix drawn is the bundle's
    im = figs["correlation"][0].axes[0].get_images()[0].get_array()
    k2, k3 = names.index("K2"), names.index("K3")
    assert im[k2, k3] == pytest.approx(q["correlation"][q["names"].index("K2"), q["names"].index("K3")])
    # angles: one histogram entry per used point and kind
    counts = sum(p.get_height() for p in figs["angles"][0].axes[0].patches)
    assert counts == int((q["rays"] > 0).sum())
    # an earlier report: this − earlier over the two σ combined
    earlier = {"camera": {k: (v[0] + 2 * v[1], v[1]) for k, v in q["camera"].items()}}
    r2 = run_stage(DbatReport, {"bundle": res, "dbat_report": earlier}, {}, tmp_path=tmp_path)
    a2 = DbatReport().plots(r2, None)["camera"][0].axes[0]
    y2 = _line(a2, "this − the earlier dbat-report").get_ydata()
    assert np.allclose(y2, -2 / np.sqrt(2), atol=1e-9)


def test_sxb_control_and_check_points(shared_data, tmp_path):
    _, _, r = _report(shared_data, "dbat-sxb/sxb.xml", tmp_path)
    q = r.artefacts["dbat_report"]
    figs = DbatReport().plots(r, None)
    assert {"points", "angles"} <= set(figs) and "camera" not in figs    # the camera is fixed: nothing to compare
    fig = figs["points"][0]
    plan, bx, by, bz = fig.axes
    ids = [t.get_text() for t in bz.get_xticklabels()]
    ctrl, chk = q["control"], q["check"]
    assert ids == [str(i) for i in ctrl["ids"]] + [str(i) for i in chk["ids"]]
    for ax, c in ((bx, 0), (by, 1), (bz, 2)):
        bars = [p.get_height() for p in ax.patches]
        assert np.allclose(bars, np.r_[ctrl["diff"][:, c], chk["diff"][:, c]])
        cross = _line(ax, "DBAT's published report")
        pos = np.round(cross.get_xdata()).astype(int)
        got = dict(zip([ids[p] for p in pos], cross.get_ydata()))
        for pid, v in SXB_CHECK.items():
            assert got[pid] == pytest.approx(v[0][c])
        prior = dict(zip(ctrl["ids"], ctrl["prior"]))
        for pid, v in SXB_CONTROL.items():
            assert got[pid] == pytest.approx(v[c] - prior[pid][c])
        # and baarda agrees with DBAT to the printed digits (docs/dbat.md)
        assert np.allclose([got[p] for p in SXB_CHECK], [dict(zip(chk["ids"], chk["diff"]))[p][c] for p in SXB_CHECK],
                           atol=1.5e-3)


def test_marks_figure_draws_the_pairs(shared_data, tmp_path):
    marks = dbat_block(read_dbat(shared_data / "dbat-camcal" / "camcaldemo.xml"))
    p = marks.cameras.pixel_mm[0]
    o = marks.observations
    shift = np.array([0.3, -0.2])                                    # pixels, x right, y down
    noise = np.random.default_rng(5).normal(0, 0.05, (len(o), 2))
    other = marks.replace(observations=Observations.make(o.photo, o.point, o.xy + (shift + noise) * [p, -p],
                                                         sigma=0.1 * p))
    r = run_stage(DbatMarks, {"dbat_marks": marks, "block": other}, {}, tmp_path=tmp_path)
    n, b = len(o), shift + noise.mean(axis=0)
    assert r.summary["headline"].startswith(f"{n} of {n} marks paired with the block's {n} image points ({n} same id); "
                                            f"bias ({b[0]:+.3f}, {b[1]:+.3f}) px, RMS (0.3")
    figs = DbatMarks().plots(r, None)
    assert list(figs) == ["differences"]
    vec, hist, scat = figs["differences"][0].axes
    q = vec.collections[0]
    pairs = r.artefacts["dbat_marks_comparison"]["pairs"]
    duv = pairs["duv"]
    k = vector_scale(pairs["uv_mark"], duv, 0.04)
    assert len(q.U) == len(o) and np.allclose(q.U / k, duv[:, 0]) and np.allclose(q.V / k, duv[:, 1])
    assert np.allclose(duv, shift + noise, atol=1e-9)
    assert sum(pt.get_height() for pt in hist.patches) == 2 * len(o)
    assert np.allclose(scat.get_lines()[0].get_xdata(), duv[:, 0])


def test_residual_figure_finds_the_projects_photos(shared_data):
    """A DBAT project's images (listed by image number) are drawn behind the bundle's residuals:
    photo id → its own file, for every photo of sxb (the files are named by the photo ids)."""
    from pathlib import Path

    block = dbat_block(read_dbat(shared_data / "dbat-sxb" / "sxb.xml"))
    files = block.photos.images()
    assert set(files) == set(block.photos.ids.tolist())
    assert all(Path(f).is_file() and Path(f).stem == pid for pid, f in files.items())
