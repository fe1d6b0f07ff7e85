"""``baarda validate`` checks what a project's options name: input paths and the stages' own hooks.

The broken comparator inputs are the audit's b1–b4 (a bad number, a missing file, a duplicate
point, an absent pair photo), made from the paper-000 Data 1 fixture; each must give exit
status 2 and one line naming the file, the line and the field — before anything runs.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from baarda.pipeline.cli import main
from baarda.pipeline.errors import InputError
from baarda.pipeline.options import option
from baarda.pipeline.project import load_project, path_roles, validate_inputs
from baarda.pipeline.runner import viewer_command
from baarda.pipeline.stage import Stage, StageResult

from conftest import needs_shared_beside
from baarda.pipeline.testing import make_plugin_manager, run_project_text

ROOT = Path(__file__).resolve().parents[2]
DATA1 = (ROOT / "fixtures" / "paper000" / "data1.cmp").read_text(encoding="utf-8")

PROJECT = """[project]
name = "validate"

[[stage]]
use = "comparator"
id = "source"
[stage.options]
path = "data1.cmp"

[[stage]]
use = "helmert-screening"
"""
PATH_LINE = 8  # the line of `path = "data1.cmp"` above


def _line_of(text: str, start: str) -> int:
    return next(i for i, ln in enumerate(text.splitlines(), 1) if ln.startswith(start))


def _break(old: str, new: str) -> tuple[str, int]:
    """Data 1 with one line changed, and that line's number."""
    assert DATA1.count(old) == 1, old
    return DATA1.replace(old, new), _line_of(DATA1, old)


def _validate(tmp_path, capsys, cmp_text: str | None):
    (tmp_path / "p.toml").write_text(PROJECT, encoding="utf-8")
    if cmp_text is not None:
        (tmp_path / "data1.cmp").write_text(cmp_text, encoding="utf-8")
    rc = main(["validate", str(tmp_path / "p.toml")])
    return rc, capsys.readouterr()


def test_the_intact_project_is_valid(tmp_path, capsys):
    rc, out = _validate(tmp_path, capsys, DATA1)
    assert rc == 0, out.err
    assert "valid — 2 stage(s)" in out.out and out.err == ""


@pytest.mark.parametrize("old, new, message", [
    # b1: a bad number
    ("pt  4    70.903    60.735", "pt  4    70.9O3    60.735", "field 'x': expected a number for x, got '70.9O3'"),
    # b3: a duplicate point (the first 6 of photo R is on the line before)
    ("pt  7    70.361    42.833", "pt  6    70.361    42.833",
     "field 'pt': point '6' measured twice in photo 'R' (first at line {before})"),
    # b4: a pair naming an absent photo
    ("pair L R", "pair L Q", "field 'pair': pair L Q: right photo 'Q' is not in this file (photos: L, R)"),
], ids=["b1-bad-number", "b3-duplicate-point", "b4-pair-photo-absent"])
def test_mistakes_inside_the_comparator_file(tmp_path, capsys, old, new, message):
    text, line = _break(old, new)
    rc, out = _validate(tmp_path, capsys, text)
    assert rc == 2 and "valid" not in out.out
    assert out.err == f"baarda: error: {tmp_path / 'data1.cmp'}:{line}, {message.format(before=line - 1)}\n"


def test_b2_missing_file_names_the_project_line(tmp_path, capsys):
    rc, out = _validate(tmp_path, capsys, None)
    assert rc == 2
    assert out.err == (f"baarda: error: {tmp_path / 'p.toml'}:{PATH_LINE}, field 'path': "
                       f"file or folder not found: {tmp_path / 'data1.cmp'}\n")


def test_io_tolerance_warning_is_shown_by_validate(tmp_path, capsys):
    fid = (ROOT / "fixtures" / "paper000" / "fiducial.cmp").read_text(encoding="utf-8")
    (tmp_path / "data1.cmp").write_text(fid, encoding="utf-8")
    (tmp_path / "p.toml").write_text(PROJECT.replace('path = "data1.cmp"',
                                                     'path = "data1.cmp"\ntol_io_um = 0.1\n'
                                                     'on_tolerance = "warn"'), encoding="utf-8")
    assert main(["validate", str(tmp_path / "p.toml")]) == 0
    err = capsys.readouterr().err
    assert err.startswith("warning [source] ") and "more than the tolerance of 0.1 µm" in err
    (tmp_path / "p.toml").write_text(PROJECT.replace('path = "data1.cmp"',
                                                     'path = "data1.cmp"\ntol_io_um = 0.1'))
    assert main(["validate", str(tmp_path / "p.toml")]) == 2
    assert "misses the affine interior orientation" in capsys.readouterr().err


def test_missing_comparator_file_at_run_names_the_project_line(tmp_path):
    out = run_project_text(PROJECT, tmp_path)
    assert not out.ok
    assert (f"{tmp_path / 'project.toml'}:{PATH_LINE}, field 'path': comparator file not found: "
            f"{tmp_path / 'data1.cmp'}") in out.message


# -- the generic path check and the hook, on toy stages ---------------------------------------------

class Reader(Stage):
    summary = "Reads files named by its options."
    writes = ("x",)
    calls: list = []

    @dataclass(frozen=True)
    class Options:
        table: Path | None = option(None, "an input file")
        more: list[Path] = option([], "more input files")
        out: Path = option(Path("out"), "an output folder")
        images: list[str] = option([], "files or glob patterns")
        prefix: str = option("", "prefix of a set of files")

    paths = {"out": "output", "images": "glob", "prefix": "prefix"}

    def validate(self, options, ctx):
        Reader.calls.append((options, ctx.stage_id, ctx.run_dir))
        if options.table is not None and ctx.resolve(options.table).read_text() == "bad":
            raise InputError("bad content", ctx.resolve(options.table), 1, "value")
        ctx.warn("looked at the table")

    def run(self, inputs, options, ctx):  # pragma: no cover - never run here
        return StageResult(artefacts={"x": 1})


class NoHook:
    summary = "A stage class that does not subclass Stage and has no validate."
    reads = ()
    writes = ("y",)

    @dataclass(frozen=True)
    class Options:
        file: Path = option(Path("f.txt"), "an input file")

    def run(self, inputs, options, ctx):  # pragma: no cover
        return StageResult(artefacts={"y": 1})


PM = make_plugin_manager({"reader": Reader, "nohook": NoHook})


def _check(tmp_path, options: str, stage: str = "reader"):
    p = tmp_path / "p.toml"
    p.write_text(f'[[stage]]\nuse = "{stage}"\n[stage.options]\n{options}\n', encoding="utf-8")
    return validate_inputs(load_project(p, PM))


def test_path_roles():
    assert path_roles(Reader) == {"table": "input", "more": "input", "out": "output", "images": "glob",
                                  "prefix": "prefix"}
    assert path_roles(NoHook) == {"file": "input"}


@pytest.mark.parametrize("options, line, field, message", [
    ('table = "t.csv"', 4, "table", "file or folder not found: {d}/t.csv"),
    ('more = ["a.csv", "nope.csv"]', 4, "more", "file or folder not found: {d}/nope.csv"),
    ('images = ["img/*.png"]', 4, "images", "no file matches {d}/img/*.png"),
    ('images = ["a.csv", "img/x.png"]', 4, "images", "file not found: {d}/img/x.png"),
    ('prefix = "sub/exp"', 4, "prefix", "no file or folder starts with {d}/sub/exp"),
    ('more = []\n\ntable = "t.csv"', 6, "table", "file or folder not found: {d}/t.csv"),
])
def test_missing_inputs_name_project_line_and_option(tmp_path, options, line, field, message):
    (tmp_path / "a.csv").write_text("ok")
    with pytest.raises(InputError) as ei:
        _check(tmp_path, options)
    e = ei.value
    assert (e.path, e.line, e.field) == (str(tmp_path / "p.toml"), line, field)
    assert e.message == message.format(d=tmp_path)


def test_existing_inputs_pass_and_the_hook_runs(tmp_path):
    (tmp_path / "t.csv").write_text("ok")
    (tmp_path / "img").mkdir()
    (tmp_path / "img" / "1.png").write_bytes(b"")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "exp.ior").write_text("")
    Reader.calls.clear()
    warnings = _check(tmp_path, 'table = "t.csv"\nmore = ["t.csv", "img"]\nimages = ["img/*.png", "img/*.jpg"]\n'
                                'prefix = "sub/exp"\nout = "does/not/exist/yet"')
    assert warnings == ["[reader] looked at the table"]
    assert len(Reader.calls) == 1 and Reader.calls[0][1:] == ("reader", None)


def test_the_hooks_error_comes_through(tmp_path):
    (tmp_path / "t.csv").write_text("bad")
    with pytest.raises(InputError, match="t.csv:1, field 'value': bad content"):
        _check(tmp_path, 'table = "t.csv"')


def test_a_default_path_is_checked_too_and_a_class_without_hook_is_fine(tmp_path):
    with pytest.raises(InputError) as ei:
        _check(tmp_path, "", stage="nohook")
    assert (ei.value.line, ei.value.field) == (1, "file")  # not set in the project: the [[stage]] line
    (tmp_path / "f.txt").write_text("")
    assert _check(tmp_path, "", stage="nohook") == []


def test_every_bundled_project_validates(shared_data):
    """Fixtures whose inputs live in ../shared/data included (hence the shared_data fixture)."""
    from baarda.pipeline.plugins import PluginManager

    pm = PluginManager()
    projects = sorted((ROOT / "fixtures").rglob("*.toml"))
    runnable = [p for p in projects if not needs_shared_beside(p)]
    for path in runnable:
        validate_inputs(load_project(path, pm))
    if len(runnable) < len(projects):
        pytest.skip(f"{len(projects) - len(runnable)} project(s) read ../shared/data beside the repository, "
                    "absent here; the others validate")


def test_viewer_command_is_the_one_beside_python(tmp_path, monkeypatch):
    import sys

    bindir = tmp_path / "venv" / "bin"
    bindir.mkdir(parents=True)
    monkeypatch.setattr(sys, "executable", str(bindir / "python"))
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    assert viewer_command() == "rerun"
    (bindir / "rerun").write_text("#!/bin/sh\n")
    assert viewer_command() == str(bindir / "rerun")


def test_report_names_the_viewer_to_open_the_recordings(tmp_path):
    out = run_project_text(PROJECT, tmp_path, files={"data1.cmp": DATA1})
    assert out.ok, out.message
    # named as the user types it in the run directory; no absolute path of the machine in the report
    from baarda.pipeline.runner import _shown_viewer

    text = (out.run_dir / "report.md").read_text()
    assert f"`{_shown_viewer()} *.rrd`" in text and Path(viewer_command()).name in text
    assert str(out.run_dir) not in text
