"""One run at a time per ``--out`` (issue 27): a second run is refused by name while one runs, a
lock left by a killed run is taken over, a failed run never replaces a complete one — with real
concurrent processes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.rundir import close_run, lock_path, open_run

ROOT = Path(__file__).resolve().parents[2]

SLOW_RUN = textwrap.dedent('''
    import sys, time
    from dataclasses import dataclass
    from baarda.pipeline.options import option
    from baarda.pipeline.runner import run_project
    from baarda.pipeline.stage import Stage, StageResult, TableData
    from baarda.pipeline.testing import make_plugin_manager

    class Slow(Stage):
        summary = "Sleeps, then writes a table (or fails)."
        writes = ("numbers",)

        @dataclass(frozen=True)
        class Options:
            seconds: float = option(1.0, "how long")
            fail: bool = option(False, "fail at the end")

        def run(self, inputs, options, ctx):
            print("started", flush=True)
            time.sleep(options.seconds)
            if options.fail:
                from baarda.pipeline.errors import InputError
                raise InputError("bad value", path="data.txt", line=1, field="x")
            return StageResult(artefacts={"numbers": [1.0]}, summary={"n": 1},
                               tables={"numbers": TableData({"x": [1.0]})})

    project, out, seconds, fail = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4]
    open(project, "w").write(f'[[stage]]\\nuse = "slow"\\n[stage.options]\\nseconds = {seconds}\\nfail = {fail}\\n')
    try:
        o = run_project(project, out, plugins=make_plugin_manager({"slow": Slow}), verbose=False)
    except Exception as e:
        print("refused:", e, flush=True)
        sys.exit(2)
    print("ok" if o.ok else "failed", o.run_dir, flush=True)
    sys.exit(0 if o.ok else 1)
''')


def start(tmp_path, name, out, seconds, fail=False):
    script = tmp_path / "slow_run.py"
    script.write_text(SLOW_RUN)
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    return subprocess.Popen([sys.executable, str(script), str(tmp_path / f"{name}.toml"), str(out), str(seconds),
                             "true" if fail else "false"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env, cwd=tmp_path)


def wait_for_line(proc, timeout=60.0):
    line = proc.stdout.readline()
    assert line, proc.stderr.read()
    return line.strip()


def test_a_second_run_into_the_same_out_is_refused_by_name(tmp_path):
    out = tmp_path / "run"
    a = start(tmp_path, "a", out, 4.0)
    assert wait_for_line(a) == "started"          # A holds the lock and is inside its stage
    b = start(tmp_path, "b", out, 0.0)
    b_out, b_err = b.communicate(timeout=120)
    assert b.returncode == 2, (b_out, b_err)
    assert "another baarda run" in b_out and f"process {a.pid}" in b_out and str(out) in b_out
    a_out, a_err = a.communicate(timeout=120)
    assert a.returncode == 0, a_err
    res = json.loads((out / "results.json").read_text())
    assert res["ok"] is True
    assert not lock_path(out).exists()            # the lock goes with the run
    assert not (tmp_path / "run.failed").exists()


def test_a_failing_run_started_first_does_not_lose_a_later_complete_run(tmp_path):
    """The issue's case: B (failing) starts first; A, started while B runs, is refused — it used to
    finish complete and then be replaced by B's failure."""
    out = tmp_path / "run"
    b = start(tmp_path, "b", out, 3.0, fail=True)
    assert wait_for_line(b) == "started"
    a = start(tmp_path, "a", out, 0.0)
    a_out, _ = a.communicate(timeout=120)
    assert a.returncode == 2 and "another baarda run" in a_out
    b.communicate(timeout=120)
    assert b.returncode == 1
    assert json.loads((out / "results.json").read_text())["ok"] is False
    # now a complete run, then B's failure again: the complete run stays, B goes beside it
    a = start(tmp_path, "a", out, 0.0)
    assert a.communicate(timeout=120)[0].startswith("started\nok"), a.stderr
    b = start(tmp_path, "b", out, 0.0, fail=True)
    b.communicate(timeout=120)
    assert json.loads((out / "results.json").read_text())["ok"] is True
    assert json.loads((tmp_path / "run.failed" / "results.json").read_text())["ok"] is False


def test_a_lock_left_by_a_killed_run_is_taken_over(tmp_path):
    out = tmp_path / "run"
    a = start(tmp_path, "a", out, 60.0)
    assert wait_for_line(a) == "started"
    assert lock_path(out).is_file()
    os.kill(a.pid, signal.SIGKILL)
    a.wait(timeout=30)
    assert lock_path(out).is_file()               # the file is left, its flock died with the process
    b = start(tmp_path, "b", out, 0.0)
    b_out, b_err = b.communicate(timeout=120)
    assert b.returncode == 0, (b_out, b_err)
    assert json.loads((out / "results.json").read_text())["ok"] is True
    assert not lock_path(out).exists()
    assert not list(tmp_path.glob(".run.partial-*"))   # the killed run's staging directory is removed


def test_the_lock_is_held_between_open_and_close_and_released_on_error(tmp_path):
    target = tmp_path / "run"
    run = open_run(target)
    with pytest.raises(InputError, match=f"process {os.getpid()}"):
        open_run(target)
    close_run(run, ok=True)
    open_run(target).lock.release()
    (tmp_path / "blocker").write_text("a file")
    with pytest.raises(InputError):
        open_run(tmp_path / "blocker")
    assert not lock_path(tmp_path / "blocker").exists()
    run = open_run(tmp_path / "blocker2")        # a refused open left no lock behind
    close_run(run, ok=True)


def test_a_failed_run_never_replaces_a_complete_run_that_appeared_while_it_ran(tmp_path):
    target = tmp_path / "run"
    run = open_run(target)
    assert run.previous == "none"
    target.mkdir()                                # written by something that ignored the lock
    (target / "results.json").write_text(json.dumps({"baarda_version": "0", "stages": [], "ok": True,
                                                     "files": ["results.json"]}))
    (run.staging / "results.json").write_text(json.dumps({"baarda_version": "0", "stages": [], "ok": False,
                                                          "files": ["results.json"]}))
    final = close_run(run, ok=False)
    assert final == tmp_path / "run.failed"
    assert json.loads((target / "results.json").read_text())["ok"] is True
