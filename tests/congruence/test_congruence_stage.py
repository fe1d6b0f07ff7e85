"""The monitoring fixture end to end: two simulated epochs, congruence test, localisation.

fixtures/monitoring/testfield-epochs.toml moves target 11 by 1.96 mm and 7 by 0.9 mm (several MDDs)
and 15 by 0.05 mm (below its MDD); the run must name 11 and 7 as moved, estimate their displacements
within their σ, and a second project comparing with the first run's epoch file must agree."""

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.runner import run_project

ROOT = Path(__file__).resolve().parents[2]
FIXTURE = ROOT / "fixtures" / "monitoring" / "testfield-epochs.toml"
TRUE = {"11": (0.0012, -0.0010, 0.0012), "7": (0.0, 0.0, 0.0009), "15": (0.00005, 0.0, 0.0)}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = run_project(FIXTURE, tmp_path_factory.mktemp("mon") / "run", verbose=False)
    assert out.ok, out.message
    return out.run_dir


def _rows(run):
    with open(run / "congruence_points.csv", encoding="utf-8") as fh:
        return {r["point"]: r for r in csv.DictReader(fh)}


def test_moved_targets_are_found(run):
    res = json.loads((run / "results.json").read_text())
    summ = next(s for s in res["stages"] if s["id"] == "congruence")["summary"]["comparisons"][0]
    assert not summ["global_test"]["accepted"]
    assert set(summ["moved"]) == {"11", "7"}
    rows = _rows(run)
    for pid in ("11", "7"):
        r = rows[pid]
        d = np.array([float(r["dX_m"]), float(r["dY_m"]), float(r["dZ_m"])])
        s = np.array([float(r["sigma_dX_m"]), float(r["sigma_dY_m"]), float(r["sigma_dZ_m"])])
        # the similarity datum of the stable points absorbs a little: within 4 σ per component
        assert np.all(np.abs(d - TRUE[pid]) < 4 * s + 1e-5), (pid, d, s)
        assert float(r["mdd_m"]) < np.linalg.norm(TRUE[pid])
    assert rows["15"]["status"] == "stable" and float(rows["15"]["mdd_m"]) > 0.00005
    assert summ["after_localisation"]["p"] > 0.05
    report = (run / "report.md").read_text()
    assert "Global congruence test" in report and (run / "congruence_displacements_E2.png").exists()


def test_an_earlier_runs_epoch_file_is_the_reference(run, tmp_path):
    text = FIXTURE.read_text()
    # epoch 2 only, compared with epoch 1 of the first run through its file
    head, rest = text.split('[[stage]]\nuse = "testfield"\nid = "source-2"')
    project = tmp_path / "epoch2.toml"
    shutil.copy(run / "epoch-1_epoch.npz", tmp_path / "e1.npz")
    body = head.split("[[stage]]")[0] + '[[stage]]\nuse = "testfield"\nid = "source-2"' + rest
    body = body.replace('alpha = 0.05', 'alpha = 0.05\nreference = "e1.npz"')
    project.write_text(body.replace("../../", str(ROOT) + "/"))
    out = run_project(project, tmp_path / "run2", verbose=False)
    assert out.ok, out.message
    a, b = _rows(run), _rows(out.run_dir)
    for pid in a:
        assert float(a[pid]["T"]) == pytest.approx(float(b[pid]["T"]), rel=1e-9)


def test_unknown_datum_point_is_an_input_error(run, tmp_path):
    project = tmp_path / "bad.toml"
    project.write_text(FIXTURE.read_text().replace('alpha = 0.05', 'alpha = 0.05\ndatum_points = ["1", "99"]'))
    out = run_project(project, tmp_path / "run3", verbose=False)
    assert not out.ok and out.failure == "input"
    assert "99" in out.message and "datum_points" in out.message and "bad.toml" in out.message
