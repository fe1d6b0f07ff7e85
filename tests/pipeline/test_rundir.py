"""Run directories that never lose data: staging, replacement, failed re-runs, interrupted runs,
foreign files, exit codes."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass

import pytest

from baarda.pipeline.cli import main
from baarda.pipeline.errors import AdjustmentError, InputError
from baarda.pipeline.options import option
from baarda.pipeline.rundir import INCOMPLETE_MARKER, stale_partials
from baarda.pipeline.runner import RunInterrupted, run_project
from baarda.pipeline.stage import Stage, StageResult, TableData
from baarda.pipeline.testing import make_plugin_manager


class Source(Stage):
    summary = "Numbers, and optionally a folder of files (as COLMAP export writes one)."
    writes = ("numbers",)

    @dataclass(frozen=True)
    class Options:
        n: int = option(3, "how many numbers")
        folder: bool = option(False, "also write a sub-folder")

    def run(self, inputs, options, ctx):
        if options.folder:
            (ctx.run_dir / "model").mkdir()
            (ctx.run_dir / "model" / "points.txt").write_text("1 2 3\n")
        x = [float(i) for i in range(options.n)]
        return StageResult(artefacts={"numbers": x}, summary={"n": options.n},
                           tables={"numbers": TableData({"x": x})})


class Second(Stage):
    summary = "Fails on request, as a user's input, an adjustment or a bug would."
    reads = ("numbers",)
    writes = ("sum",)

    @dataclass(frozen=True)
    class Options:
        fail: str = option("", "'', 'input', 'adjustment', 'bug' or 'interrupt'")

    def run(self, inputs, options, ctx):
        if options.fail == "input":
            raise InputError("bad value", path="data.txt", line=3, field="x")
        if options.fail == "adjustment":
            raise AdjustmentError(f"singular: fix the datum (state in {ctx.run_dir})")
        if options.fail == "bug":
            return {}["missing"]
        if options.fail == "interrupt":
            raise KeyboardInterrupt
        return StageResult(artefacts={"sum": sum(inputs["numbers"])}, summary={"sum": sum(inputs["numbers"])})


def project(tmp_path, fail="", folder=False, n=3):
    p = tmp_path / "p.toml"
    p.write_text(f'[[stage]]\nuse = "source"\n[stage.options]\nn = {n}\nfolder = {str(folder).lower()}\n'
                 f'[[stage]]\nuse = "second"\n[stage.options]\nfail = "{fail}"\n')
    return p


@pytest.fixture
def pm():
    return make_plugin_manager({"source": Source, "second": Second})


def snapshot(d):
    return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def test_results_json_lists_every_file_and_is_written_last(tmp_path, pm):
    out = run_project(project(tmp_path, folder=True), tmp_path / "run", plugins=pm, verbose=False)
    assert out.ok and out.run_dir == (tmp_path / "run").absolute()
    res = json.loads((out.run_dir / "results.json").read_text())
    on_disk = sorted(str(p.relative_to(out.run_dir).as_posix()) for p in out.run_dir.rglob("*") if p.is_file())
    assert res["files"] == on_disk and "model/points.txt" in on_disk and INCOMPLETE_MARKER not in on_disk
    last = (out.run_dir / "results.json").stat().st_mtime_ns
    assert all((out.run_dir / f).stat().st_mtime_ns <= last for f in on_disk)
    assert not list(tmp_path.glob(".run.partial-*"))          # no staging left behind


def test_failed_rerun_leaves_the_complete_run_untouched(tmp_path, pm):
    first = run_project(project(tmp_path, folder=True), tmp_path / "run", plugins=pm, verbose=False)
    before = snapshot(first.run_dir)
    again = run_project(project(tmp_path, fail="adjustment", n=5), tmp_path / "run", plugins=pm, verbose=False)
    assert not again.ok and again.failure == "adjustment"
    assert snapshot(first.run_dir) == before
    assert again.run_dir == (tmp_path / "run.failed").absolute() and again.kept == first.run_dir
    res = json.loads((again.run_dir / "results.json").read_text())
    assert [s["status"] for s in res["stages"]] == ["ok", "failed"]
    assert (again.run_dir / "source_numbers.csv").read_text().count("\n") == 6      # the new run's 5 numbers
    assert str(again.run_dir) in res["stages"][1]["error"] and ".partial-" not in json.dumps(res)


def test_complete_rerun_replaces_the_run_without_stale_files(tmp_path, pm):
    run_project(project(tmp_path, folder=True), tmp_path / "run", plugins=pm, verbose=False)
    out = run_project(project(tmp_path, folder=False), tmp_path / "run", plugins=pm, verbose=False)
    assert out.ok and not (out.run_dir / "model").exists()
    assert json.loads((out.run_dir / "results.json").read_text())["files"] == sorted(
        p.name for p in out.run_dir.iterdir())


def test_a_failed_first_run_is_kept_in_place_and_replaced_later(tmp_path, pm):
    out = run_project(project(tmp_path, fail="input"), tmp_path / "run", plugins=pm, verbose=False)
    assert out.failure == "input" and out.run_dir == (tmp_path / "run").absolute()
    assert (out.run_dir / "source_numbers.csv").exists()                # the earlier stage's results
    again = run_project(project(tmp_path), tmp_path / "run", plugins=pm, verbose=False)
    assert again.ok and again.run_dir == out.run_dir


def test_foreign_files_are_never_deleted(tmp_path, pm):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "p.toml").write_text("mine")
    (tmp_path / "run" / "results.json").write_text('{"something": "else"}')
    with pytest.raises(InputError, match="not a baarda run"):
        run_project(project(tmp_path), tmp_path / "run", plugins=pm, verbose=False)
    # a real run with a file added by the user afterwards
    out = run_project(project(tmp_path), tmp_path / "run2", plugins=pm, verbose=False)
    (out.run_dir / "notes.txt").write_text("my notes")
    with pytest.raises(InputError, match="'notes.txt', which baarda did not write"):
        run_project(project(tmp_path), tmp_path / "run2", plugins=pm, verbose=False)
    assert (out.run_dir / "notes.txt").read_text() == "my notes"
    assert (tmp_path / "run" / "p.toml").read_text() == "mine"
    assert not list(tmp_path.glob(".run*.partial-*"))


def test_interrupted_run_is_marked_and_replaceable(tmp_path, pm):
    with pytest.raises(RunInterrupted) as ei:
        run_project(project(tmp_path, fail="interrupt"), tmp_path / "run", plugins=pm, verbose=False)
    run = ei.value.outcome.run_dir
    res = json.loads((run / "results.json").read_text())
    assert [s["status"] for s in res["stages"]] == ["ok", "interrupted"] and res["ok"] is False
    # a run killed without a chance to clean up leaves a marked staging directory; the next run removes it
    dead = tmp_path / ".run.partial-dead"
    dead.mkdir()
    (dead / INCOMPLETE_MARKER).write_text(json.dumps({"pid": 2 ** 22 + 12345}))
    alive = tmp_path / ".run.partial-alive"
    alive.mkdir()
    (alive / INCOMPLETE_MARKER).write_text(json.dumps({"pid": os.getpid()}))
    assert stale_partials((tmp_path / "run").absolute()) == [dead.absolute()]
    out = run_project(project(tmp_path), tmp_path / "run", plugins=pm, verbose=False)
    assert out.ok and not dead.exists() and alive.exists()


@pytest.mark.parametrize("fail, code", [("", 0), ("input", 2), ("adjustment", 1), ("bug", 3), ("interrupt", 130)])
def test_exit_status_by_kind_of_failure(tmp_path, pm, monkeypatch, capsys, fail, code):
    import baarda.pipeline.runner as runner_mod

    monkeypatch.setattr(runner_mod, "PluginManager", lambda: pm)
    p = project(tmp_path, fail=fail)
    assert main(["run", str(p), "--out", str(tmp_path / "run"), "--quiet"]) == code
    err = capsys.readouterr().err
    assert "Traceback" not in err
    if code == 3:
        assert "KeyError" in err and "second.error.txt" in err


def test_unwritable_out_is_one_line(tmp_path, pm, monkeypatch, capsys):
    import baarda.pipeline.runner as runner_mod

    monkeypatch.setattr(runner_mod, "PluginManager", lambda: pm)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["run", str(project(tmp_path)), "--out", str(blocker / "run"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot write the run directory" in err
    assert blocker.read_text() == "x"
