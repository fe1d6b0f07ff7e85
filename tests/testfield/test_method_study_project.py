"""fixtures/study/study.toml end to end: every stage runs, the report ends with the comparison
section and its chart, the method study's variants are in the comparison."""

from __future__ import annotations

import re
import time

import cv2
import pytest

from baarda.pipeline.runner import run_project


def _check_run(out, repetitions):
    assert out.ok, out.message
    ids = [s.id for s in out.stages]
    assert ids == ["source", "helmert-screening", "blunder-rejection", "bundle", "pycolmap-crosscheck",
                   "independent-models", "method-study", "method-study-systematic", "comparison"]
    report = (out.run_dir / "report.md").read_text(encoding="utf-8")
    sections = re.findall(r"^## (.+)$", report, flags=re.M)
    assert sections[-1] == "comparison (comparison)"
    last = report[report.rindex("## comparison"):]
    assert "![check-point errors per method](comparison_checkpoints.png)" in last
    # nothing but the comparison's own text and its file list after the chart
    tail = last[last.index("![check-point errors"):].splitlines()
    assert all(not ln.startswith("#") for ln in tail)
    img = cv2.imread(str(out.run_dir / "comparison_checkpoints.png"))
    assert img is not None and img.shape[0] > 100 and img.shape[1] > 100
    methods = next(s for s in out.stages if s.id == "comparison").summary["methods"]
    for name in ("bundle", "independent-models", "method-study: bundle, no APs", "method-study: bundle, APs",
                 "method-study: independent models", "method-study: single model 4.0 m"):
        assert name in methods, name
    assert not any(m.startswith("method-study-systematic") for m in methods)   # in_comparison = false
    study = next(s for s in out.stages if s.id == "method-study").summary
    assert study["repetitions"] == repetitions[0] and study["case"] == 5 and study["sigma_image_um"] == 40.0
    # the planted gross error (y of target 15 in photo 15) is removed before the bundle, which then
    # finds nothing more; so pycolmap solves the same observations (cost equal to 1e-4)
    blunders = next(s for s in out.stages if s.id == "blunder-rejection").summary
    assert blunders["acted_on"] == [["15", "15"]]
    bundle = next(s for s in out.stages if s.id == "bundle").summary
    assert bundle["ids"]["removed"] == [] and bundle["global_test"]["rejected"] is False
    cost = next(s for s in out.stages if s.id == "pycolmap-crosscheck").summary["quantities"]["cost"]
    assert cost["pycolmap"] == pytest.approx(cost["baarda"], rel=1e-4)
    assert (out.run_dir / "comparison.rrd").exists() and (out.run_dir / "method-study.rrd").exists()


def test_study_project_runs_with_fewer_realisations(repo_root, tmp_path):
    text = (repo_root / "fixtures/study/study.toml").read_text(encoding="utf-8")
    assert text.count("repetitions = 20") == 1 and text.count("repetitions = 10") == 1
    text = text.replace("repetitions = 20", "repetitions = 3").replace("repetitions = 10", "repetitions = 2")
    path = tmp_path / "study.toml"
    path.write_text(text, encoding="utf-8")
    _check_run(run_project(path, tmp_path / "run", verbose=False), (3, 2))


@pytest.mark.slow
def test_study_project_as_bundled(repo_root, tmp_path):
    t0 = time.perf_counter()
    out = run_project(repo_root / "fixtures/study/study.toml", tmp_path / "run", verbose=False)
    _check_run(out, (20, 10))
    assert time.perf_counter() - t0 < 120
