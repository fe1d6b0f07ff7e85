"""The monitoring fixture end to end: two simulated epochs, congruence test, localisation.

fixtures/monitoring/panel-epochs.toml moves T08 by 0.98 mm and T17 by 0.4 mm (several MDDs) and T23
by 0.02 mm (below its MDD); the run must name T08 and T17 as moved, estimate their displacements
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
FIXTURE = ROOT / "fixtures" / "monitoring" / "panel-epochs.toml"
TRUE = {"T08": (0.0006, -0.0005, 0.0006), "T17": (0.0, 0.0, 0.0004), "T23": (0.00002, 0.0, 0.0)}


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
    assert set(summ["moved"]) == {"T08", "T17"}
    rows = _rows(run)
    for pid in ("T08", "T17"):
        r = rows[pid]
        d = np.array([float(r["dX_m"]), float(r["dY_m"]), float(r["dZ_m"])])
        s = np.array([float(r["sigma_dX_m"]), float(r["sigma_dY_m"]), float(r["sigma_dZ_m"])])
        # the similarity datum of the stable points absorbs a little: within 4 σ per component
        assert np.all(np.abs(d - TRUE[pid]) < 4 * s + 1e-5), (pid, d, s)
        assert float(r["mdd_m"]) < np.linalg.norm(TRUE[pid])
    assert rows["T23"]["status"] == "stable" and float(rows["T23"]["mdd_m"]) > 0.00002
    assert summ["after_localisation"]["p"] > 0.05
    report = (run / "report.md").read_text()
    assert "Global congruence test" in report and (run / "congruence_displacements_E2.png").exists()


def test_an_earlier_runs_epoch_file_is_the_reference(run, tmp_path):
    text = FIXTURE.read_text()
    # epoch 2 only, compared with epoch 1 of the first run through its file
    head, rest = text.split('[[stage]]\nuse = "design"\nid = "source-2"')
    project = tmp_path / "epoch2.toml"
    shutil.copy(run / "epoch-1_epoch.npz", tmp_path / "e1.npz")
    body = head.split("[[stage]]")[0] + '[[stage]]\nuse = "design"\nid = "source-2"' + rest
    body = body.replace('datum = "similarity"', 'datum = "similarity"\nreference = "e1.npz"')
    body = body.replace('"../design/', f'"{ROOT}/fixtures/design/').replace(
        '"panel-targets-2.csv"', f'"{ROOT}/fixtures/monitoring/panel-targets-2.csv"')
    project.write_text(body)
    out = run_project(project, tmp_path / "run2", verbose=False)
    assert out.ok, out.message
    a, b = _rows(run), _rows(out.run_dir)
    for pid in a:
        assert float(a[pid]["T"]) == pytest.approx(float(b[pid]["T"]), rel=1e-9)


@pytest.mark.slow
def test_unknown_datum_point_is_an_input_error(run, tmp_path):
    project = tmp_path / "bad.toml"
    project.write_text(FIXTURE.read_text().replace('datum = "similarity"', 'datum = "similarity"\ndatum_points = ["T01", "T99"]')
                       .replace('"../design/', f'"{ROOT}/fixtures/design/')
                       .replace('"panel-targets-', f'"{ROOT}/fixtures/monitoring/panel-targets-'))
    out = run_project(project, tmp_path / "run3", verbose=False)
    assert not out.ok and out.failure == "input"
    assert "T99" in out.message and "datum_points" in out.message and "bad.toml" in out.message


def test_batch_summary_row_carries_the_congruence(run):
    from baarda.pipeline.batch import quality

    res = json.loads((run / "results.json").read_text())
    q = quality(res["stages"])
    summ = next(s for s in res["stages"] if s["id"] == "congruence")["summary"]["comparisons"][0]
    assert q["congruence"] == "moved" and q["congruence.n_moved"] == len(summ["moved"])
    assert q["congruence.T"] == summ["global_test"]["T"] and q["congruence.moved"].split() == summ["moved"]
    assert q["congruence.reference"] == "E1" and q["congruence.epoch"] == "E2"


@pytest.mark.slow
def test_a_batch_of_epochs_is_one_congruence_summary(tmp_path):
    """A monitoring job through `baarda batch`: the panel project swept over epoch 2's targets (nothing
    moved / three targets moved); summary.csv holds each run's congruence verdict and moved points."""
    from baarda.pipeline.cli import main

    sweep = tmp_path / "epochs.csv"
    sweep.write_text("name,source-2.targets\n"
                     f"unchanged,\"{ROOT}/fixtures/monitoring/panel-targets-1.csv\"\n"
                     f"moved,\"{ROOT}/fixtures/monitoring/panel-targets-2.csv\"\n")
    out = tmp_path / "batch"
    assert main(["batch", str(FIXTURE), "--sweep", str(sweep), "--out", str(out), "--scheduler", "sync",
                 "--quiet"]) == 0
    with open(out / "summary.csv", encoding="utf-8") as fh:
        rows = {r["name"]: r for r in csv.DictReader(fh)}
    assert rows["unchanged"]["congruence"] == "congruent" and rows["unchanged"]["congruence.n_moved"] == "0"
    assert rows["moved"]["congruence"] == "moved" and set(rows["moved"]["congruence.moved"].split()) == {"T08", "T17"}
