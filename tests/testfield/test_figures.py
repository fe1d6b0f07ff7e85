"""Figures of the test-field studies: the keys of real (small) runs, and the curves drawn are the
study's tables and the paper's Tables 2–5 as the study modules hold them."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from baarda.pipeline.testing import run_stage  # noqa: E402
from baarda.plugins.testfield.control_study import PAPER_TABLE2, PAPER_TABLE3, PAPER_TABLE4, ControlStudy  # noqa: E402
from baarda.plugins.testfield.method_study import (BUNDLE, BUNDLE_AP, IM, PAPER_TABLE5, SINGLE_AP,  # noqa: E402
                                                   VARIANTS)
from baarda.plugins.testfield.method_study_stage import MethodStudy  # noqa: E402




def _line(ax, label):
    return next(ln for ln in ax.get_lines() if ln.get_label() == label)


def _dots(ax):
    """x of the claim dots (markers 'o'), top row first."""
    pts = [(ln.get_ydata()[0], ln.get_xdata()[0]) for ln in ax.get_lines()
           if ln.get_marker() == "o" and len(ln.get_xdata()) == 1]
    return [x for _, x in sorted(pts, reverse=True)]


def test_control_study_curves_and_conclusions(tmp_path):
    r = run_stage(ControlStudy, {}, {"repetitions": 1, "cases": [4, 5], "seed": 2}, tmp_path=tmp_path)
    figs = ControlStudy().plots(r, None)
    assert list(figs) == ["cases", "conclusions"] and all(v[1] for v in figs.values())
    sxy, sz, s0 = figs["cases"][0].axes
    t2, t3, single = (r.data["tables"][k] for k in ("table2", "table3", "single"))
    for ax, key, i2, i3, i4 in ((sxy, "Sxy", 4, 2, 2), (sz, "Sz", 5, 3, 3)):
        assert list(_line(ax, "without APs").get_xdata()) == [4, 5]
        assert np.allclose(_line(ax, "without APs").get_ydata(), [row[key] for row in t2])
        assert np.allclose(_line(ax, "with APs").get_ydata(), [row[key] for row in t3])
        assert np.allclose(_line(ax, "paper, without APs (Table 2)").get_ydata(), [PAPER_TABLE2[c][i2] for c in (4, 5)])
        assert np.allclose(_line(ax, "paper, with APs (Table 3)").get_ydata(), [PAPER_TABLE3[c][i3] for c in (4, 5)])
        assert _line(ax, "single model 4.0 m, with APs").get_ydata()[0] == single[0][key]
        assert _line(ax, "paper, single model (Table 4)").get_ydata()[0] == PAPER_TABLE4["single model"][i4]
        assert ax.get_yscale() == "log" and "cm" in ax.get_ylabel()
    assert np.allclose(_line(s0, "without APs").get_ydata(), [row["sigma0_um"] for row in t2])
    assert np.allclose(_line(s0, "paper, without APs (Table 2)").get_ydata(), [PAPER_TABLE2[c][1] for c in (4, 5)])
    ax = figs["conclusions"][0].axes[0]
    want = [c["keys"][k]["change_pct"] for c in r.data["conclusions"] for k in ("Sxy", "Sz") if k in c["keys"]]
    assert _dots(ax) == pytest.approx(want)
    assert len(ax.get_yticklabels()) == len(want)


def test_method_study_methods_and_conclusions(tmp_path):
    r = run_stage(MethodStudy, {}, {"repetitions": 2, "seed": 4}, tmp_path=tmp_path)
    study = r.data
    assert study["config"].case == 5                  # the paper's case: Tables 4 and 5 apply
    figs = MethodStudy().plots(r, None)
    assert list(figs) == ["methods", "conclusions"] and all(v[1] for v in figs.values())
    var = study["variants"]
    names = [v for v in VARIANTS if var.get(v, {}).get("realisations")]
    assert names == list(VARIANTS)
    paper = {BUNDLE: (PAPER_TABLE2[5][4], PAPER_TABLE2[5][5]), BUNDLE_AP: (PAPER_TABLE3[5][2], PAPER_TABLE3[5][3]),
             IM: PAPER_TABLE5["independent models"][2:4], SINGLE_AP: PAPER_TABLE4["single model"][2:4]}
    for ax, k, key in zip(figs["methods"][0].axes, (0, 1), ("Sxy", "Sz")):
        assert np.allclose(_line(ax, "baarda: pooled RMSE").get_ydata(), [var[v][key] for v in names])
        assert np.allclose(_line(ax, "predicted by the adjustment").get_ydata(), [var[v][f"pred_{key}"] for v in names])
        got = _line(ax, "paper").get_ydata()
        assert np.allclose(got, [paper.get(v, (np.nan, np.nan))[k] for v in names], equal_nan=True)
        assert np.isnan(got[names.index("single model 4.0 m, no APs")])        # the paper has no such row
        seg = ax.collections[0].get_segments()                                # the 10–90 % spread
        assert np.allclose([s[:, 1] for s in seg], [[var[v][f"{key}_q10"], var[v][f"{key}_q90"]] for v in names])
    ax = figs["conclusions"][0].axes[0]
    cs = study["conclusions"]
    assert _dots(ax) == pytest.approx([c["comparison"]["change_pct"] for c in cs])
    cross = _line(ax, "paper")
    assert list(cross.get_xdata()) == pytest.approx([c["paper_pct"] for c in cs])


def test_method_study_of_another_case_has_no_table_4_and_5_values(tmp_path):
    r = run_stage(MethodStudy, {}, {"repetitions": 1, "seed": 4, "case": 2, "single_model": False,
                                    "methods": [BUNDLE, IM]}, tmp_path=tmp_path)
    figs = MethodStudy().plots(r, None)
    assert list(figs) == ["methods"]                  # no claim without the bundle with APs
    got = _line(figs["methods"][0].axes[0], "paper").get_ydata()
    assert got[0] == PAPER_TABLE2[2][4] and np.isnan(got[1])     # Table 5 is the paper's case 5 only
