"""Two epochs of the simulated paper-001 test field (fixtures/monitoring/testfield-epochs.toml).

Epoch 2 moves target 8 by 2.5 mm in Z and 13 by (1, −1, 0) mm — both above their minimal detectable
displacement (MDD) — and 16 by 0.02 mm in Z, far below its MDD.  The congruence stage must name 8 and
13 (and nothing else), estimate their displacements within their σ, and leave 16 stable."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.cli import main
from baarda.pipeline.runner import run_project
from baarda.pipeline.synthetic.testfield import Displacement, TestFieldConfig, simulate_testfield

ROOT = Path(__file__).resolve().parents[2]
FIXTURE = ROOT / "fixtures" / "monitoring" / "testfield-epochs.toml"
TRUE_MM = {"8": (0.0, 0.0, 2.5), "13": (1.0, -1.0, 0.0), "16": (0.0, 0.0, 0.02)}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = run_project(FIXTURE, tmp_path_factory.mktemp("tf") / "run", verbose=False)
    assert out.ok, out.message
    return out.run_dir


def test_moved_targets_found_and_estimated(run):
    res = json.loads((run / "results.json").read_text())
    comp = next(s for s in res["stages"] if s["id"] == "congruence")["summary"]["comparisons"][0]
    assert not comp["global_test"]["accepted"]
    assert set(comp["moved"]) == {"8", "13"}
    with open(run / "congruence_points.csv", encoding="utf-8") as fh:
        rows = {r["point"]: r for r in csv.DictReader(fh)}
    for pid in ("8", "13"):
        r = rows[pid]
        d = np.array([float(r[f"d{a}_m"]) for a in "XYZ"])
        s = np.array([float(r[f"sigma_d{a}_m"]) for a in "XYZ"])
        true = np.array(TRUE_MM[pid]) * 1e-3
        assert np.all(np.abs(d - true) < 4 * s), (pid, d, s)
        assert float(r["mdd_m"]) < np.linalg.norm(true)             # above its MDD, as the README says
    r16 = rows["16"]
    assert r16["status"] == "stable" and float(r16["mdd_m"]) > 10 * np.linalg.norm(TRUE_MM["16"]) * 1e-3


def test_the_simulator_moves_the_true_targets_only():
    cfg = TestFieldConfig(case=5, sigma_image_um=4.0, displacements=(Displacement("13", 1.0, -1.0, 0.0),))
    _, t0 = simulate_testfield(TestFieldConfig(case=5, sigma_image_um=4.0), np.random.default_rng(1))
    blk, t1 = simulate_testfield(cfg, np.random.default_rng(1))
    d = t1.XYZ - t0.XYZ
    k = list(t1.point_ids).index("13")
    assert np.allclose(d[k], [1e-3, -1e-3, 0.0], atol=1e-15)
    assert np.abs(np.delete(d, k, axis=0)).max() == 0.0
    assert blk.meta["testfield"]["config"]["displacements"] == [{"point": "13", "dX": 1.0, "dY": -1.0, "dZ": 0.0}]


@pytest.mark.parametrize("moves, text", [
    ('{ point = "99", dZ = 1.0 }', "no target '99'"),
    ('{ point = "8", dZ = 1.0 }, { point = "8", dX = 1.0 }', "moved twice"),
])
def test_a_bad_displacement_names_the_field(tmp_path, capsys, moves, text):
    p = tmp_path / "p.toml"
    p.write_text('[project]\nname = "x"\nseed = 1\n[[stage]]\nuse = "testfield"\n[stage.options]\n'
                 f"displacements = [{moves}]\n")
    for cmd in (["validate", str(p)], ["run", str(p), "--out", str(tmp_path / "run")]):
        assert main(cmd) == 2
        out = capsys.readouterr()
        err = out.err + out.out
        assert text in err and "field 'displacements'" in err and "p.toml:7" in err, err
        assert "Traceback" not in err
