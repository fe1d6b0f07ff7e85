"""VDI/VDE 2634-1 length test (stage ``length-test``) on the simulated fixture."""

import csv
from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.runner import run_project
from baarda.pipeline.stage import Context
from baarda.plugins.acceptance.stage import LengthTest, LengthTestOptions

ROOT = Path(__file__).resolve().parents[2]
FIXTURE = ROOT / "fixtures" / "monitoring" / "vdi2634.toml"


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = run_project(FIXTURE, tmp_path_factory.mktemp("vdi") / "run", verbose=False)
    assert out.ok, out.message
    return out


def _csv(path):
    with open(path, encoding="utf-8") as fh:
        return list(csv.DictReader(l for l in fh if not l.startswith("#")))


def test_length_errors_from_the_adjusted_points(run):
    pts = {r["point"]: r for r in _csv(run.run_dir / "bundle_points.csv")}
    xyz = lambda p: np.array([float(pts[p][k]) for k in ("X", "Y", "Z")] if "X" in pts[p] else  # noqa: E731
                             [float(pts[p][k]) for k in ("X_m", "Y_m", "Z_m")])
    bars = _csv(ROOT / "fixtures" / "monitoring" / "vdi-bars.csv")
    rows = {(r["from"], r["to"]): r for r in _csv(run.run_dir / "length-test_bars.csv")}
    assert len(rows) == len(bars) == 21
    for b in bars:
        r = rows[(b["from"], b["to"])]
        L = np.linalg.norm(xyz(b["to"]) - xyz(b["from"]))
        assert float(r["error_um"]) == pytest.approx((L - float(b["length_m"])) * 1e6, abs=1e-6)
        assert float(r["mpe_um"]) == pytest.approx(40.0 + 20.0 * float(b["length_m"]))
        assert 5.0 < float(r["sigma_um"]) < 40.0          # σ 0.02 px at ~3 m: some 10–20 µm
    s = run.stages[-1].summary
    assert s["passed"] and s["exceedances"] == 0 and len(s["lines"]) == 7


def _ctx(tmp_path):
    return Context(stage_id="length-test", project_dir=ROOT / "fixtures" / "monitoring", object_unit="m",
                   project_file=FIXTURE)


def test_a_tight_mpe_fails_and_counts(run, tmp_path):
    res = LengthTest().run({"bundle": run.artefacts["bundle"]},
                           LengthTestOptions(bars_file="vdi-bars.csv", mpe_a_um=1.0), _ctx(tmp_path))
    errs = np.abs(res.tables["bars"].columns["error_um"])
    assert res.summary["exceedances"] == int(np.sum(errs > 1.0)) > 0 and not res.summary["passed"]
    res2 = LengthTest().run({"bundle": run.artefacts["bundle"]},
                            LengthTestOptions(bars_file="vdi-bars.csv", mpe_a_um=1.0, max_exceedances=21),
                            _ctx(tmp_path))
    assert res2.summary["passed"]


def test_bad_bars_file_names_its_line(run, tmp_path):
    bad = tmp_path / "bars.csv"
    bad.write_text("from,to,length_m,line\nD1-1a,D1-1b,0.6,D1\nD1-2a,NOPE,1.2,D1\n")
    with pytest.raises(InputError) as e:
        LengthTest().run({"bundle": run.artefacts["bundle"]},
                         LengthTestOptions(bars_file=str(bad), mpe_a_um=10.0), _ctx(tmp_path))
    assert e.value.line == 3 and "NOPE" in str(e.value)
    bad.write_text("from,to,length_m\nD1-1a,D1-1b,-0.6\n")
    with pytest.raises(InputError) as e:
        LengthTest().run({"bundle": run.artefacts["bundle"]},
                         LengthTestOptions(bars_file=str(bad), mpe_a_um=10.0), _ctx(tmp_path))
    assert e.value.line == 2 and e.value.field == "length_m"
