"""The comparison stage: findings of every stage, check-point RMSE per method, chart."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import pytest

from baarda.pipeline.options import option
from baarda.pipeline.recording import read_recording
from baarda.pipeline.stage import Stage, StageResult, TableData
from baarda.pipeline.testing import check_stage, make_plugin_manager, run_project_text
from baarda.plugins.comparison.stage import Comparison


def _fake(errors, name, realisations=None):
    class Fake(Stage):
        summary = f"fake adjustment {name}"
        writes = (name,)

        @dataclass(frozen=True)
        class Options:
            pass

        def run(self, inputs, options, ctx):
            e = np.asarray(errors, float)
            s = {k: float(np.sqrt(np.mean(e[:, i] ** 2))) for i, k in enumerate(("Sx", "Sy", "Sz"))}
            s["Sxy"] = float(np.sqrt((s["Sx"] ** 2 + s["Sy"] ** 2) / 2))
            if realisations:
                s["realisations"] = realisations
            return StageResult(artefacts={name: 1}, summary={"check_points": {"n": len(e), "unit": "m", **s},
                                                             "headline": f"{name} did its job"},
                               tables={"check_points": TableData({"point": [str(i) for i in range(len(e))],
                                                                  "dX": e[:, 0], "dY": e[:, 1], "dZ": e[:, 2]})})
    return Fake


def test_comparison_across_stages(tmp_path):
    a = np.array([[0.001, -0.002, 0.004], [0.003, 0.001, -0.002]])
    b = 2 * a
    pm = make_plugin_manager({"a": _fake(a, "one"), "b": _fake(b, "two"), "comparison": Comparison})
    text = '[project]\nname = "cmp"\n[[stage]]\nuse = "a"\n[[stage]]\nuse = "b"\n[[stage]]\nuse = "comparison"\n' \
           '[stage.options]\nscale = 100.0\nunit_label = "cm"\n'
    out = run_project_text(text, tmp_path, plugins=pm)
    assert out.ok, out.message
    res = out.stages[-1].summary
    sz_a = 100 * np.sqrt(np.mean(a[:, 2] ** 2))
    assert res["methods"]["a"]["Sz"] == pytest.approx(sz_a)
    assert res["methods"]["b"]["Sz"] == pytest.approx(2 * sz_a)
    report = (out.run_dir / "report.md").read_text()
    assert "one did its job" in report and "two did its job" in report
    # b's errors are twice a's: +100 %, printed with one decimal
    assert "| a | 2 | 0.2236 | 0.1581 | 0.1936 | 0.3162 | 0.0 | 0.0 |" in report
    assert "| b | 2 | 0.4472 | 0.3162 | 0.3873 | 0.6325 | 100.0 | 100.0 |" in report
    assert "realisations" not in report
    img = cv2.imread(str(out.run_dir / "comparison_checkpoints.png"))
    assert img is not None and img.shape[0] > 100
    rec = read_recording(out.run_dir / "comparison.rrd")
    assert {"/comparison/checkpoints_chart", "/comparison/rmse/Sz"} <= {e.path for e in rec.entities}


def test_pooled_realisations_show_in_n(tmp_path):
    """A study pooling 20 realisations of 6 check points says so ("6 × 20"), not just 6."""
    a = np.array([[0.001, -0.002, 0.004]] * 6)
    b = 1.5 * a
    pm = make_plugin_manager({"a": _fake(a, "one"), "b": _fake(b, "two", realisations=20), "comparison": Comparison})
    text = '[project]\nname = "cmp"\n[[stage]]\nuse = "a"\n[[stage]]\nuse = "b"\n[[stage]]\nuse = "comparison"\n'
    out = run_project_text(text, tmp_path, plugins=pm)
    assert out.ok, out.message
    report = (out.run_dir / "report.md").read_text()
    # four significant digits: Sxy = √((1² + 2²)/2) mm = 1.581 mm, and 1.5 × that for b
    assert "| a | 6 | 0.001 | 0.002 | 0.001581 | 0.004 | 0.0 | 0.0 |" in report
    assert "| b | 6 × 20 | 0.0015 | 0.003 | 0.002372 | 0.006 | 50.0 | 50.0 |" in report
    assert "n × r: n check points in each of r realisations, pooled" in report
    methods = out.stages[-1].summary["methods"]
    assert methods["b"]["n"] == 6 and methods["b"]["realisations"] == 20
    assert "realisations" not in methods["a"]


def test_comparison_without_check_points(tmp_path):
    pm = make_plugin_manager({"comparison": Comparison})
    out = run_project_text('[project]\nname = "x"\n[[stage]]\nuse = "comparison"\n', tmp_path, plugins=pm)
    assert out.ok and "No stage of this run compared" in (out.run_dir / "report.md").read_text()


def test_protocol():
    check_stage(Comparison)
