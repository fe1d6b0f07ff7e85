"""Sweep tables: every name and value checked before anything runs, one line naming file, line
and field; TOML [[run]] tables; projects by glob and folder."""

from pathlib import Path

import pytest

from baarda.pipeline.batch import expand_projects, plan_batch, read_sweep
from baarda.pipeline.errors import InputError
from baarda.pipeline.plugins import PluginManager
from baarda.pipeline.project import load_project

FIX = Path(__file__).resolve().parents[2] / "fixtures" / "paper000"


@pytest.fixture(scope="module")
def project():
    return load_project(FIX / "data1.toml", PluginManager())


def _sweep(tmp_path, text, name="sweep.csv"):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


@pytest.mark.parametrize("text,where,message", [
    ("screenin.threshold_mm\n2\n", ":1, field 'screenin.threshold_mm'", "no stage 'screenin' in data1.toml; did you mean 'screening'?"),
    ("screening.treshold_mm\n2\n", ":1, field 'screening.treshold_mm'", "did you mean 'screening.threshold_mm'?"),
    ("screenin.tab.threshold_mm\n2\n", ":1, field 'screenin.tab.threshold_mm'",
     "no stage 'screenin' in data1.toml; did you mean 'screening'?"),
    ("screening.tab.threshold_mm\n2\n", ":1, field 'screening.tab'", "unknown option 'screening.tab'"),
    ("threshold_mm\n2\n", ":1, field 'threshold_mm'", "must be <stage id>.<option>"),
    ("screening.threshold_mm\n2\nabc\n", ":3, field 'screening.threshold_mm'", "expected"),
    ("screening.threshold_mm\n-1\n", ":2, field 'screening.threshold_mm'", "must be greater than 0"),
    ("blunders.alpha_rrr\n0.01\n1.5\n", ":3, field 'blunders.alpha_rrr'", ""),
    ("blunders.max_iter\n3\n", ":1, field 'blunders.max_iter'", "is now 'blunders.max_rejections'"),
    ("screening.threshold_mm,blunders.rho\n2\n", ":2", "1 cells for 2 columns"),
    ("a.b,a.b\n1,2\n", ":1, field 'a.b'", "appears twice"),
    ("screening.threshold_mm\n", "sweep.csv", "has no runs"),
])
def test_sweep_mistakes_name_file_line_and_column(tmp_path, project, text, where, message):
    p = _sweep(tmp_path, text)
    with pytest.raises(InputError) as e:
        read_sweep(p, project)
    msg = str(e.value)
    assert msg.startswith(str(p)) and where in msg and message in msg and "\n" not in msg


def test_cells_are_toml_values(tmp_path, project):
    p = _sweep(tmp_path, 'name,screening.threshold_mm,blunders.method,screening.action,blunders.rho\n'
                         'a,2,rrr,"remove",5\n')
    (row,) = read_sweep(p, project)
    assert row["name"] == "a" and row["line"] == 2
    assert row["overrides"] == {"screening.threshold_mm": 2, "blunders.method": "rrr",
                                "screening.action": "remove", "blunders.rho": 5}


def test_toml_sweep(tmp_path, project):
    p = _sweep(tmp_path, '[[run]]\nname = "one"\n"screening.threshold_mm" = 2.5\n\n'
                         '[[run]]\n"blunders.alpha_rrr" = "x"\n', name="sweep.toml")
    with pytest.raises(InputError, match=r"sweep.toml:5, field 'blunders.alpha_rrr'"):
        read_sweep(p, project)
    p.write_text('[[run]]\nname = "one"\n"screening.threshold_mm" = 2.5\n', encoding="utf-8")
    rows = read_sweep(p, project)
    assert [r.pop("project") for r in rows] == [project]        # no project column: the one given
    assert rows == [{"name": "one", "line": 1, "overrides": {"screening.threshold_mm": 2.5}}]


def test_sweep_project_files_have_absolute_inputs(tmp_path):
    p = _sweep(tmp_path, "screening.threshold_mm\n2\n2\n")
    jobs = plan_batch([FIX / "data1.toml"], tmp_path / "out", sweep=p)
    assert [j.name for j in jobs] == ["data1-001", "data1-002"]
    text = jobs[0].project.read_text(encoding="utf-8")
    assert f'path = "{FIX / "data1.cmp"}"' in text
    load_project(jobs[0].project, PluginManager())          # a valid project on its own
    with pytest.raises(InputError, match="a sweep applies to one project; 2 were given"):
        plan_batch([FIX / "data1.toml", FIX / "data2.toml"], tmp_path / "out2", sweep=p)


def test_projects_by_glob_folder_and_path(tmp_path):
    got = expand_projects([str(FIX / "data[12].toml"), str(FIX / "data1.toml")])
    assert [p.name for p in got] == ["data1.toml", "data2.toml"]
    assert len(expand_projects([str(FIX)])) == len(list(FIX.glob("*.toml")))
    jobs = plan_batch([FIX / "data1.toml", FIX.parent / "paper000" / "data1.toml"], tmp_path / "o")
    assert [j.name for j in jobs] == ["data1"]                       # the same file once
    with pytest.raises(InputError, match="project file not found"):
        expand_projects([str(tmp_path / "none.toml")])


TINY = """[project]
name = "tiny"
seed = 3

[[stage]]
use = "testfield"
id = "source"

[[stage]]
use = "bundle"
id = "adj"
[stage.options]
datum = "control"
[stage.options.tests]
blunders = "data-snooping"
"""


def test_a_sweep_of_options_in_nested_tables(tmp_path):
    """Columns ``adj.solver.max_iter``: the stage id, then the option's dotted path into the bundle's
    nested tables, applied as ``--set`` applies it — the file's other options of the table kept."""
    from baarda.pipeline import montecarlo as mc
    from baarda.pipeline.batch import run_batch

    project = tmp_path / "tiny.toml"
    project.write_text(TINY, encoding="utf-8")
    sweep = _sweep(tmp_path, "name,adj.solver.max_iter,adj.tests.alpha0\nfew,2,\nmany,30,0.01\n")
    jobs = plan_batch([project], tmp_path / "out", sweep=sweep)
    assert [j.overrides for j in jobs] == [{"adj.solver.max_iter": 2},
                                           {"adj.solver.max_iter": 30, "adj.tests.alpha0": 0.01}]
    written = load_project(jobs[1].project, PluginManager()).stages[1].options
    assert (written.solver.max_iter, written.tests.alpha0, written.tests.blunders) == (30, 0.01, "data-snooping")
    rows = run_batch(jobs, tmp_path / "out", mc.Engine(mc.Scheduler("sync")))
    few, many = rows
    assert few["status"] == "failed" and "no convergence after 2 iterations" in few["message"]
    assert many["status"] == "ok", many["message"]
    import tomllib

    resolved = tomllib.loads((Path(many["run_dir"]) / "project.resolved.toml").read_text(encoding="utf-8"))
    adj = next(s["options"] for s in resolved["stage"] if s["id"] == "adj")
    assert adj["solver"]["max_iter"] == 30 and adj["tests"] == {**adj["tests"], "alpha0": 0.01,
                                                                  "blunders": "data-snooping"}
    header = (tmp_path / "out" / "summary.csv").read_text(encoding="utf-8").splitlines()[0].split(",")
    assert "adj.solver.max_iter" in header and "adj.tests.alpha0" in header
