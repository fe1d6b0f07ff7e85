"""RRR inside `baarda run`: the blunder-rejection stage hands its Monte Carlo realisations to the
run's Dask engine, with the same decisions and critical value as in-process."""

from __future__ import annotations

import json
from pathlib import Path

from baarda.pipeline import montecarlo as mc
from baarda.pipeline.runner import run_project

ROOT = Path(__file__).resolve().parents[2]


def _rrr(run_dir: Path) -> dict:
    res = json.loads((run_dir / "results.json").read_text())
    stage = next(s for s in res["stages"] if s["use"] == "blunder-rejection")
    return json.dumps(stage["summary"], sort_keys=True)


def test_rrr_of_a_run_goes_through_the_engine(tmp_path):
    project = ROOT / "fixtures" / "paper000" / "data1.toml"
    here = run_project(project, tmp_path / "here", verbose=False)
    assert here.ok, here.message
    with mc.Engine(mc.Scheduler("processes", workers=2), min_seconds=0) as eng, mc.using(eng):
        there = run_project(project, tmp_path / "there", verbose=False)
        sent = eng.tasks_sent
    assert there.ok, there.message
    assert sent > 1                                   # the realisations went out as tasks
    assert _rrr(tmp_path / "there") == _rrr(tmp_path / "here")
