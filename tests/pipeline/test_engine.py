"""The engine: project files, options, runner, run directory, recordings, CLI."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.cli import main
from baarda.pipeline.errors import InputError
from baarda.pipeline.options import option
from baarda.pipeline.project import load_project
from baarda.pipeline.recording import read_recording
from baarda.pipeline.stage import Stage, StageResult, TableData
from baarda.pipeline.testing import check_stage, make_plugin_manager, run_project_text, run_stage


class NumbersSource(Stage):
    summary = "Emit n numbers drawn from the stage rng."
    writes = ("numbers",)

    @dataclass(frozen=True)
    class Options:
        n: int = option(5, "how many numbers")
        scale: float = option(1.0, "their standard deviation")

    def run(self, inputs, options, ctx):
        x = ctx.rng.normal(0, options.scale, options.n)
        return StageResult(artefacts={"numbers": x}, summary={"n": options.n},
                           report=f"{options.n} numbers", tables={"numbers": TableData({"x": x})})

    def log(self, result, rec, ctx):
        import rerun as rr

        for i, v in enumerate(result.artefacts["numbers"]):
            rec.set_time("iteration", sequence=i)
            rec.log("numbers/value", rr.Scalars([float(v)]))


class Mean(Stage):
    summary = "Mean of the numbers."
    reads = ("numbers",)
    writes = ("mean",)

    @dataclass(frozen=True)
    class Options:
        fail: bool = option(False, "raise an error (for tests)")

    def run(self, inputs, options, ctx):
        if options.fail:
            raise InputError("told to fail", path="somefile.txt", line=3, field="value")
        x = inputs["numbers"]
        return StageResult(artefacts={"mean": float(np.mean(x))}, summary={"mean": float(np.mean(x))},
                           report="mean computed")


class Buggy(Stage):
    summary = "A stage with a bug."
    reads = ("numbers",)
    writes = ("nothing",)

    @dataclass(frozen=True)
    class Options:
        pass

    def run(self, inputs, options, ctx):
        return 1 / 0


PROJECT = """
[project]
name = "toy"
seed = 7

[[stage]]
use = "numbers"
[stage.options]
n = 4

[[stage]]
use = "mean"
"""


@pytest.fixture
def pm():
    return make_plugin_manager({"numbers": NumbersSource, "mean": Mean, "buggy": Buggy})


def test_stage_protocol_helpers():
    check_stage(NumbersSource)
    r = run_stage(NumbersSource, {}, {"n": 3}, seed=1)
    assert r.artefacts["numbers"].shape == (3,)


def test_run_writes_run_directory(tmp_path, pm):
    out = run_project_text(PROJECT, tmp_path, plugins=pm)
    assert out.ok, out.message
    run = out.run_dir
    for f in ["report.md", "results.json", "project.resolved.toml", "numbers.rrd", "mean.rrd", "numbers_numbers.csv"]:
        assert (run / f).exists(), f
    res = json.loads((run / "results.json").read_text())
    assert [s["status"] for s in res["stages"]] == ["ok", "ok"]
    x = np.loadtxt(run / "numbers_numbers.csv", skiprows=1, delimiter=",")
    assert res["stages"][1]["summary"]["mean"] == pytest.approx(x.mean())
    # reproducible: the same seed gives the same numbers
    (tmp_path / "again").mkdir()
    out2 = run_project_text(PROJECT, tmp_path / "again", plugins=pm)
    assert np.allclose(np.loadtxt(out2.run_dir / "numbers_numbers.csv", skiprows=1, delimiter=","), x)
    # recordings read back, one recording id for the run
    a, b = read_recording(run / "numbers.rrd"), read_recording(run / "mean.rrd")
    assert a.recording_id == b.recording_id == res["recording_id"]
    paths = {e.path for e in a.entities}
    assert "/numbers/value" in paths and "/numbers/summary" in paths
    val = next(e for e in a.entities if e.path == "/numbers/value")
    assert val.rows == 4 and "iteration" in val.timelines
    assert "4 numbers" in a.summary_text


def test_failed_stage_keeps_earlier_results(tmp_path, pm):
    text = PROJECT + "[stage.options]\nfail = true\n"
    out = run_project_text(text, tmp_path, plugins=pm)
    assert not out.ok
    assert "somefile.txt:3" in out.message and "told to fail" in out.message
    res = json.loads((out.run_dir / "results.json").read_text())
    assert [s["status"] for s in res["stages"]] == ["ok", "failed"]
    assert (out.run_dir / "numbers_numbers.csv").exists()
    assert "Failed" in (out.run_dir / "report.md").read_text()


def test_bug_in_stage_is_reported_with_traceback_file(tmp_path, pm):
    text = PROJECT.replace('use = "mean"', 'use = "buggy"')
    out = run_project_text(text, tmp_path, plugins=pm)
    assert not out.ok and "ZeroDivisionError" in out.message
    assert (out.run_dir / "buggy.error.txt").exists()


@pytest.mark.parametrize("snippet, expect_line, expect", [
    ('[[stage]]\nuse = "numbers"\n[stage.options]\nn = 4\nsigma = 2\n', 5, "unknown option 'sigma'"),
    ('[[stage]]\nuse = "numbers"\n[stage.options]\nn = "four"\n', 4, "expected an integer"),
    ('[[stage]]\nuse = "nosuch"\n', 2, "no stage named 'nosuch'"),
    ('[[stage]]\nuse = "mean"\n', 1, "reads 'numbers', which no earlier stage writes"),
    ('[[stage]]\nuse = "numbers"\n[[stage]]\nuse = "numbers"\n', 3, "used twice"),
    ('[[stage]]\nuse = "numbers"\ncolour = 1\n', 3, "unknown key 'colour'"),
    ('[[stage]\nuse = "numbers"\n', 1, "not valid TOML"),
])
def test_project_errors_name_file_line_field(tmp_path, pm, snippet, expect_line, expect):
    p = tmp_path / "p.toml"
    p.write_text(snippet)
    with pytest.raises(InputError) as ei:
        load_project(p, pm)
    msg = str(ei.value)
    assert expect in msg and f"p.toml:{expect_line}" in msg, msg
    assert "\n" not in msg


def test_missing_project_file(tmp_path, pm):
    with pytest.raises(InputError, match="project file not found"):
        load_project(tmp_path / "nope.toml", pm)


def test_run_dir_refuses_foreign_directory(tmp_path, pm):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "thesis.docx").write_text("precious")
    with pytest.raises(InputError, match="non-empty directory"):
        run_project_text(PROJECT, tmp_path, plugins=pm)
    assert (tmp_path / "run" / "thesis.docx").read_text() == "precious"


def test_cli_exit_codes(tmp_path, capsys):
    assert main(["validate", str(tmp_path / "missing.toml")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("baarda: error:") and "missing.toml" in err and err.count("\n") == 1
    assert main(["stages"]) == 0


def test_review_reads_recordings_back(tmp_path, pm, capsys):
    out = run_project_text(PROJECT, tmp_path, plugins=pm)
    assert main(["review", str(out.run_dir), "--entities"]) == 0
    text = capsys.readouterr().out
    assert "numbers.rrd: " in text and "entities under /numbers" in text and "mean.rrd: " in text
    assert "/numbers/value  rows=4 over iteration" in text
    assert "share recording id" in text and "baarda view" in text


def test_review_of_a_directory_without_recordings(tmp_path, capsys):
    assert main(["review", str(tmp_path)]) == 2
    assert "no .rrd recordings" in capsys.readouterr().err


class SlowLog(Stage):
    """A stage whose recording takes a known time."""
    summary = "Quick to run, slow to log."
    reads = ("numbers",)
    writes = ("slow",)

    @dataclass(frozen=True)
    class Options:
        pass

    def run(self, inputs, options, ctx):
        return StageResult(artefacts={"slow": 1}, summary={}, report="ok")

    def log(self, result, rec, ctx):
        import time

        time.sleep(0.3)


def test_stage_time_counts_all_of_its_work(tmp_path):
    """The time in report.md / results.json includes writing the stage's recording and figures."""
    import json

    pm = make_plugin_manager({"numbers": NumbersSource, "slow": SlowLog})
    out = run_project_text(PROJECT.replace('use = "mean"', 'use = "slow"'), tmp_path, plugins=pm)
    assert out.ok, out.message
    res = json.loads((out.run_dir / "results.json").read_text())
    slow = next(s for s in res["stages"] if s["use"] == "slow")
    assert slow["seconds"] >= 0.3
