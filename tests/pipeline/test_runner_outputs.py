"""A stage's outputs: the tables written in a worker thread while the figures are drawn and the
recording is written (``runner.TABLES_IN_THREAD``) give the same run directory, the same order of
files, readable progress lines, and the same errors as writing them first."""

from __future__ import annotations

import io
import json
import threading
from dataclasses import dataclass

import numpy as np
import pytest

import baarda.pipeline.runner as runner
from baarda.pipeline.stage import Progress, Stage, StageResult, TableData
from baarda.pipeline.testing import make_plugin_manager


@dataclass(frozen=True)
class _Options:
    broken_table: bool = False


class _Writer(Stage):
    """Writes two tables, draws two figures, logs a recording."""

    summary = "test stage with tables and figures"
    reads = ()
    writes = ()
    Options = _Options

    def run(self, inputs, options, ctx):
        rows = np.arange(2000, dtype=float)
        table = {"v_px": rows, "w": rows / 7}
        if options.broken_table:
            table["bad"] = np.zeros((len(rows), 2))        # two dimensions: an error writing the table
        return StageResult(artefacts={}, summary={"n": 2000}, report="two tables",
                           tables={"big": TableData(table, detail=True), "small": TableData({"n": [1]})})

    def plots(self, result, ctx):
        import matplotlib.pyplot as plt

        figs = {}
        for name in ("one", "two"):
            fig, ax = plt.subplots(figsize=(2, 2))
            ax.plot([0, 1], [0, 1])
            figs[name] = fig
        return figs


class _InterruptingWriter(_Writer):
    def plots(self, result, ctx):
        raise KeyboardInterrupt


class _BrokenPlotWriter(_Writer):
    def plots(self, result, ctx):
        raise RuntimeError("the plot broke")


PROJECT = """
[project]
name = "outputs"

[[stage]]
use = "writer"
id = "w"
[stage.options]
broken_table = {broken}
"""


def _run(tmp_path, thread: bool, monkeypatch, cls=_Writer, broken="false", stream=None):
    monkeypatch.setattr(runner, "TABLES_IN_THREAD", thread)
    project = tmp_path / "p.toml"
    project.write_text(PROJECT.format(broken=broken))
    return runner.run_project(project, tmp_path / "run", plugins=make_plugin_manager({"writer": cls}),
                              verbose=stream is not None, stream=stream)


def _stage_entry(run_dir):
    return json.loads((run_dir / "results.json").read_text())["stages"][0]


def test_the_same_run_directory_either_way(tmp_path, monkeypatch):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    seq = _run(tmp_path / "a", False, monkeypatch)
    par = _run(tmp_path / "b", True, monkeypatch)
    assert seq.ok and par.ok
    a, b = _stage_entry(seq.run_dir), _stage_entry(par.run_dir)
    assert a["files"] == b["files"] == ["w_big.csv", "w_big.parquet", "w_small.csv", "w_small.parquet",
                                        "w_one.png", "w_two.png", "w.rrd"]
    assert a["tables"] == b["tables"]
    for f in ("w_big.csv", "w_small.csv"):
        assert (seq.run_dir / f).read_bytes() == (par.run_dir / f).read_bytes()
    assert "w_big.csv" in (par.run_dir / "report.md").read_text()


def test_progress_lines_stay_whole(tmp_path, monkeypatch):
    out = io.StringIO()                          # progress on, plain lines (no live bars), every step
    monkeypatch.setattr(runner, "Progress", lambda sid, stream, enabled: Progress(sid, stream=stream, enabled=True,
                                                                                  live=False, interval=0))
    assert _run(tmp_path, True, monkeypatch, stream=out).ok
    lines = out.getvalue().splitlines()
    assert all(ln.startswith(("[1/1]", "      done", "  [w] ")) for ln in lines), lines
    tables = [ln for ln in lines if ln.startswith("  [w] tables ")]
    figures = [ln for ln in lines if ln.startswith("  [w] figures ")]
    assert tables and figures
    assert tables[-1].startswith("  [w] tables 2001/2001 (100 %), last small")
    # the tables' lines come together, after the figures' and the recording's
    k = lines.index(tables[0])
    assert lines[k:k + len(tables)] == tables and lines.index(figures[-1]) < k


@pytest.mark.parametrize("thread", [False, True])
def test_an_error_writing_a_table_stops_the_run_as_before(tmp_path, monkeypatch, thread):
    before = threading.active_count()
    with pytest.raises(ValueError, match="column 'bad': expected one dimension"):
        _run(tmp_path, thread, monkeypatch, broken="true")
    assert threading.active_count() == before                  # no writer left behind


def test_the_same_error_either_way(tmp_path, monkeypatch):
    msgs = {}
    for t in (False, True):
        (tmp_path / str(t)).mkdir()
        with pytest.raises(Exception) as e:
            _run(tmp_path / str(t), t, monkeypatch, broken="true")
        msgs[t] = (type(e.value), str(e.value))
    assert msgs[False] == msgs[True]


def test_a_broken_plot_warns_and_the_tables_are_written(tmp_path, monkeypatch):
    out = _run(tmp_path, True, monkeypatch, cls=_BrokenPlotWriter)
    assert out.ok
    entry = _stage_entry(out.run_dir)
    assert any("figures incomplete: RuntimeError: the plot broke" in w for w in entry["warnings"])
    assert entry["files"][:4] == ["w_big.csv", "w_big.parquet", "w_small.csv", "w_small.parquet"]
    assert (out.run_dir / "w_big.parquet").is_file()


def test_ctrl_c_while_drawing_waits_for_the_tables(tmp_path, monkeypatch):
    before = threading.active_count()
    with pytest.raises(KeyboardInterrupt) as e:
        _run(tmp_path, True, monkeypatch, cls=_InterruptingWriter)
    assert threading.active_count() == before
    outcome = e.value.outcome
    assert outcome.failure == "interrupted"
    # the tables were complete before the run was closed, and are listed as written
    assert (outcome.run_dir / "w_big.csv").read_text().count("\n") == 2001
    assert outcome.stages[0].files[:2] == ["w_big.csv", "w_big.parquet"]
