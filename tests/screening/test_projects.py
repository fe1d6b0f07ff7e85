"""The fixture projects run end to end through the runner (what `make demo` does)."""

import csv
import json
from pathlib import Path

import pytest

from baarda.pipeline.plugins import PluginManager
from baarda.pipeline.runner import run_project
from baarda.plugins.blunder_rejection.stage import BlunderRejection
from baarda.plugins.comparator.stage import ComparatorSource
from baarda.plugins.screening.stage import HelmertScreening

FIX = Path(__file__).resolve().parents[2] / "fixtures" / "paper000"


def plugins():
    pm = PluginManager(discover=False)
    pm.register("comparator", ComparatorSource)
    pm.register("helmert-screening", HelmertScreening)
    pm.register("blunder-rejection", BlunderRejection)
    return pm


@pytest.mark.parametrize("name,rrr", [("data1", ["X9", "Y5", "X5"]), ("printed", ["X9"])])
def test_fixture_project_runs(tmp_path, name, rrr):
    out = run_project(FIX / f"{name}.toml", tmp_path / "run", plugins=plugins(), verbose=False)
    assert out.ok, out.message
    results = json.loads((tmp_path / "run" / "results.json").read_text())
    text = json.dumps(results)
    assert "helmert-screening" in text
    with open(tmp_path / "run" / "screening_observations.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 18
    assert {"v_mm", "r", "w", "tau", "nabla_hat_mm", "mdb_mm", "data_snooping", "pope", "threshold", "format",
            "swap_with", "flagged"} <= set(rows[0])
    with open(tmp_path / "run" / "blunders_observations.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["label"] for r in rows if r["rrr"] == "reject"] == sorted(rrr, key=lambda s: (s[1:], s[0]))
    assert all((tmp_path / "run" / f"{s}.rrd").exists() for s in ("source", "screening", "blunders"))
