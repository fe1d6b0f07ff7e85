"""Two epochs from real data: the AICON network and a simulated second epoch with known
displacements and its own real residuals (fixtures/monitoring/aicon-epochs.toml)."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.runner import run_project

ROOT = Path(__file__).resolve().parents[2]
TRUE = {"1010": (0.12, -0.10, 0.12), "1045": (0.0, 0.0, 0.05), "40": (0.03, 0.0, 0.0), "1060": (0.0, 0.003, 0.0)}


@pytest.mark.slow
def test_aicon_two_epochs_find_the_displaced_targets(tmp_path, shared_beside):
    out = run_project(ROOT / "fixtures" / "monitoring" / "aicon-epochs.toml", tmp_path / "run", verbose=False)
    assert out.ok, out.message
    res = json.loads((out.run_dir / "results.json").read_text())
    summ = next(s for s in res["stages"] if s["id"] == "congruence")["summary"]["comparisons"][0]
    assert {"1010", "1045", "40"} <= set(summ["moved"]) and "1060" not in summ["moved"]
    assert len(summ["moved"]) <= 5          # at most two false alarms among 146 stable targets
    with open(out.run_dir / "congruence_points.csv", encoding="utf-8") as fh:
        rows = {r["point"]: r for r in csv.DictReader(fh)}
    for pid in ("1010", "1045", "40"):
        d = np.array([float(rows[pid][k]) for k in ("dX_mm", "dY_mm", "dZ_mm")])
        s = np.array([float(rows[pid][k]) for k in ("sigma_dX_mm", "sigma_dY_mm", "sigma_dZ_mm")])
        assert np.all(np.abs(d - TRUE[pid]) < 5 * s + 2e-3), (pid, d)
    assert float(rows["1060"]["mdd_mm"]) > 0.003          # below its MDD: not expected to be found
