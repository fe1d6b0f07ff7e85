"""Every writer resolves its output with one rule (issue 27): inside the run directory, never empty
or ".", never a file the run writes itself or one already written; a clash is an InputError naming
the option — in ``validate`` too where it can be known before the run."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import pytest

from baarda.pipeline.cli import main
from baarda.pipeline.options import output_problem

ROOT = Path(__file__).resolve().parents[2]
WRITERS = ["export", "aicon-export", "bal-export", "colmap-export", "comparator-export", "gcp-export",
           "libmv-export", "dbat-export"]


def project(tmp_path, use, path, extra=""):
    (tmp_path / "data.cmp").write_text((ROOT / "fixtures/paper000/data1.cmp").read_text())
    p = tmp_path / "p.toml"
    p.write_text('[[stage]]\nuse = "comparator"\nid = "source"\n[stage.options]\npath = "data.cmp"\n'
                 f'[[stage]]\nuse = "{use}"\n[stage.options]\npath = "{path}"\n{extra}')
    return p


def cli(*argv):
    o, e = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(o), contextlib.redirect_stderr(e):
        code = main(list(argv))
    return code, e.getvalue()


def outside(tmp_path):
    return sorted(p.name for p in tmp_path.iterdir() if p.name not in ("data.cmp", "p.toml", "out", "out.failed"))


@pytest.mark.parametrize("use", ["export", "aicon-export", "bal-export", "colmap-export"])
@pytest.mark.parametrize("path", ["", ".", "./", "sub/..", "report.md", "results.json", "project.resolved.toml",
                                  "source.rrd", "report.html"])
def test_a_bad_output_path_is_refused_by_validate_and_run(tmp_path, use, path):
    if use in ("export", "aicon-export") and path.endswith((".md", ".json", ".toml", ".rrd", ".html")):
        path = "x/y/../.."      # a prefix writer makes report.md.ply: its own file, not the run's
    p = project(tmp_path, use, path)
    code, err = cli("validate", str(p))
    assert code == 2 and "field 'path'" in err and "p.toml:9" in err, err
    code, err = cli("run", str(p), "--out", str(tmp_path / "out"), "-q")
    assert code == 2 and "field 'path'" in err and "Traceback" not in err, err
    assert outside(tmp_path) == []                      # nothing beside the run directory


@pytest.mark.parametrize("use,path", [("export", "source_observations"), ("bal-export", "source_observations.csv"),
                                      ("colmap-export", "source_observations.csv")])
def test_an_output_that_collides_with_an_earlier_stage_file_is_an_input_error(tmp_path, use, path):
    """The stage's tables are known before the run (its ``outputs``, or every ``<id>_*``): validate
    and the run refuse the name before anything is written."""
    p = project(tmp_path, use, path)
    for argv in (["validate", str(p)], ["run", str(p), "--out", str(tmp_path / "out"), "-q"]):
        code, err = cli(*argv)
        assert code == 2, err
        assert "stage 'source'" in err and "field 'path'" in err and "FileExistsError" not in err, err
    assert not (tmp_path / "out").exists()
    assert outside(tmp_path) == []


def test_two_writers_of_one_name_are_refused_before_the_run(tmp_path):
    p = project(tmp_path, "export", "pts")
    p.write_text(p.read_text() + '[[stage]]\nuse = "export"\nid = "e2"\n[stage.options]\npath = "./pts"\n')
    code, err = cli("validate", str(p))
    assert code == 2 and "'pts.ply' is written by stage 'export' already" in err, err


def test_the_rule():
    assert output_problem("points") is None and output_problem("a/b/c.txt") is None
    for bad in ("", " ", ".", "a/..", "/tmp/x", "~/x", "../x", "a/../../x", "report.md", "x.rrd", "./results.json"):
        assert output_problem(bad), bad
    assert output_problem("report", adds=(".md",))
    assert output_problem("s.error", stage_ids=("s",), adds=(".txt",))
