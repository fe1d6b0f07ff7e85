"""Issue 27, round three: what ``baarda validate`` must know before a run (a block that exists only
during the run, every output name a stage writes), one validation hook, the refusal messages, batch
sweep tables over one project."""

from __future__ import annotations

import contextlib
import io
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.cli import main
from baarda.pipeline.options import option
from baarda.pipeline.project import load_project, validate_inputs
from baarda.pipeline.stage import Stage, StageResult, ValidationContext
from baarda.pipeline.testing import make_plugin_manager

ROOT = Path(__file__).resolve().parents[2]
RENDERED = ROOT / "fixtures" / "rendered" / "rendered.toml"
DATA1 = (ROOT / "fixtures" / "paper000" / "data1.cmp").read_text(encoding="utf-8")


def cli(*argv) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, err.getvalue()


# -- 1. RRR's rho for a block that exists only during the run -------------------------------------

def _rendered_with_rrr(tmp_path: Path, rho: int) -> Path:
    text = RENDERED.read_text(encoding="utf-8").replace('method = "ids"', f'method = "rrr"\nrho = {rho}')
    p = tmp_path / "rendered.toml"
    p.write_text(text, encoding="utf-8")
    return p


def test_validate_bounds_rrr_rho_for_the_rendered_test_field(tmp_path):
    """The rendered field's block is made by detecting targets in the rendered images: validate
    builds it dry (every target whose disk reaches into each image) and refuses a rho beyond n − u."""
    p = _rendered_with_rrr(tmp_path, 200)
    line = next(i for i, ln in enumerate(p.read_text().splitlines(), 1) if ln.startswith("rho ="))
    code, err = cli("validate", p)
    assert code == 2, err
    assert f"rendered.toml:{line}, field 'rho'" in err and "n = " in err, err
    code, err = cli("validate", _rendered_with_rrr(tmp_path, 20))     # within the bound: valid
    assert code == 0, err


def test_the_dry_block_holds_every_target_a_detection_can_find():
    """The dry construction's (photo, target) pairs include every target whose true centre lies in
    the rendered image (what a perfect detector finds), so its rows bound the run's."""
    from baarda.pipeline.options import parse_options
    from baarda.plugins.testfield.photos import OBJECT_UNIT_MM, image_size, true_targets, truth_from_meta
    from baarda.plugins.testfield.render import RenderOptions, dry_detection_block
    from baarda.plugins.testfield.source import simulate_field

    opts = parse_options(RenderOptions, {"pixel_mm": 0.025, "testfield": {"case": 5}})
    sim = opts.simulation(7)
    block, _ = simulate_field(sim, np.random.default_rng(sim.seed))
    dry = dry_detection_block(block, opts)
    truth = truth_from_meta(block.meta)
    size = image_size(block.cameras.format_mm[0], opts.pixel_mm)
    pairs = {(str(dry.photos.ids[a]), str(dry.points.ids[b]))
             for a, b in zip(dry.observations.photo, dry.observations.point)}
    found = {(p, q) for p, t in true_targets(truth, opts.pixel_mm, size).items() for q in t}
    assert found and found <= pairs
    assert len(pairs) == len(dry.observations)                      # at most once per photo and target
    assert OBJECT_UNIT_MM[block.object_unit] > 0


# -- 6. one validation hook ------------------------------------------------------------------------

@dataclass(frozen=True)
class PointOptions:
    point: str = option("1", "a point id of the block")


class NewHook(Stage):
    summary = "checks a point id with validate_with"
    reads = ("block",)
    Options = PointOptions
    seen: list = []

    def validate_with(self, v: ValidationContext) -> None:
        NewHook.seen.append(v)
        if v.block is not None and v.options.point not in v.block.points.ids:
            raise v.ctx.option_error(f"unknown point {v.options.point!r}", "point")

    def run(self, inputs, options, ctx):
        return StageResult()


class OldHook(Stage):
    summary = "checks a point id with the deprecated validate_block"
    reads = ("block",)
    Options = PointOptions

    def validate_block(self, options, block, ctx):
        if options.point not in block.points.ids:
            raise ctx.option_error(f"unknown point {options.point!r}", "point")

    def run(self, inputs, options, ctx):
        return StageResult()


def _project(tmp_path, use, point):
    (tmp_path / "data.cmp").write_text(DATA1, encoding="utf-8")
    p = tmp_path / "p.toml"
    p.write_text(f'[[stage]]\nuse = "comparator"\nid = "source"\n[stage.options]\npath = "data.cmp"\n\n'
                 f'[[stage]]\nuse = "{use}"\nid = "check"\n[stage.options]\npoint = "{point}"\n', encoding="utf-8")
    return p


def test_one_validation_hook_gets_the_whole_context(tmp_path):
    from baarda.pipeline.errors import InputError

    pm = make_plugin_manager({"new": NewHook, "old": OldHook}, builtins=True)
    NewHook.seen.clear()
    validate_inputs(load_project(_project(tmp_path, "new", "1"), pm))
    v = NewHook.seen[-1]
    assert v.block is not None and v.rows is v.block and v.adjuster is None
    assert v.spec.id == "check" and [s.id for s in v.project.stages] == ["source", "check"]
    with pytest.raises(InputError) as e:
        validate_inputs(load_project(_project(tmp_path, "new", "NOPE"), pm))
    assert e.value.field == "point" and e.value.line == 11
    # the old hook still runs, with a DeprecationWarning naming the new one
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        with pytest.raises(InputError) as e:
            validate_inputs(load_project(_project(tmp_path, "old", "NOPE"), pm))
    assert e.value.field == "point"
    assert any(issubclass(x.category, DeprecationWarning) and "validate_with" in str(x.message) for x in w)


def test_no_builtin_stage_uses_the_old_hooks():
    from baarda.pipeline.plugins import PluginManager

    pm = PluginManager()
    old = [n for n in pm.names() if any(hasattr(pm.get(n).cls, h) for h in ("validate_block", "validate_rows"))]
    assert old == []
    assert {"bundle", "gnss-centres", "blunder-rejection", "testfield-render"} <= {
        n for n in pm.names() if hasattr(pm.get(n).cls, "validate_with")}


# -- 2. validate knows every output name each stage writes ----------------------------------------

def _writer_before_tables(tmp_path: Path, path: str, writer: str = "export") -> Path:
    (tmp_path / "data.cmp").write_text(DATA1, encoding="utf-8")
    p = tmp_path / "p.toml"
    p.write_text('[[stage]]\nuse = "comparator"\nid = "source"\n[stage.options]\npath = "data.cmp"\n\n'
                 f'[[stage]]\nuse = "{writer}"\nid = "export"\n[stage.options]\npath = "{path}"\n\n'
                 '[[stage]]\nuse = "helmert-screening"\nid = "screening"\n', encoding="utf-8")
    return p


@pytest.mark.parametrize("path,writer", [("screening_observations", "export"),     # + .csv: a later table
                                         ("screening_observations.csv", "comparator-export"),
                                         ("screening_anything.csv", "comparator-export")])
def test_validate_refuses_a_writer_name_of_a_later_stages_table(tmp_path, path, writer):
    p = _writer_before_tables(tmp_path, path, writer)
    code, err = cli("validate", p)
    assert code == 2, err
    assert "p.toml:11, field 'path'" in err and "stage 'screening'" in err, err
    code, err = cli("run", p, "--out", tmp_path / "run", "--quiet")         # the run: the same rule, first
    assert code == 2 and "p.toml:11, field 'path'" in err, err
    assert not (tmp_path / "run" / "results.json").exists()


def test_declared_outputs_leave_other_names_free(tmp_path):
    """A stage that declares its tables owns only those: a writer may use its own id's prefix, and
    gnss-centres' id as a prefix of a name that is not its table (fixtures/gnss: gnss_points)."""
    from baarda.pipeline.options import output_problem

    assert output_problem("export_points", {"export": ()}) is None
    assert output_problem("gnss_points", {"gnss": ("antennas",)}, adds=(".ply", ".csv")) is None
    assert "gnss_antennas.csv" in output_problem("gnss_antennas", {"gnss": ("antennas",)}, adds=(".ply", ".csv"))
    assert "stage 'bundle'" in output_problem("bundle_mine.csv", {"bundle": None})
    assert output_problem("bundle/mine.csv", {"bundle": None}) is None          # a folder named as the id
    code, err = cli("validate", _writer_before_tables(tmp_path, "export_points"))
    assert code == 0, err


@dataclass(frozen=True)
class NoOpts:
    pass


class Undeclared(Stage):
    summary = "writes a table its declaration does not name"
    outputs = ("declared",)
    Options = NoOpts

    def run(self, inputs, options, ctx):
        from baarda.pipeline.stage import TableData

        return StageResult(tables={"other": TableData({"a": [1.0]})})


def test_the_run_refuses_a_table_the_declaration_does_not_name(tmp_path):
    from baarda.pipeline.testing import run_project_text

    pm = make_plugin_manager({"undeclared": Undeclared})
    out = run_project_text('[[stage]]\nuse = "undeclared"\nid = "u"\n', tmp_path, plugins=pm)
    assert not out.ok and "'other'" in out.message and "outputs" in out.message, out.message
    assert not (out.run_dir / "u_other.csv").exists()


# -- 5. the XML refusal in words ------------------------------------------------------------------

BOMB = b'<?xml version="1.0"?>\n<!DOCTYPE d [\n <!ENTITY a "x">\n <!ENTITY b "&a;&a;">\n]>\n<document>&b;</document>\n'


def test_each_defusedxml_refusal_is_said_in_words():
    from defusedxml import common

    from baarda.pipeline.xmlsafe import refusal_text

    cases = {common.EntitiesForbidden("lol", "x", None, None, None, None): ("entity declarations", "<!ENTITY lol"),
             common.DTDForbidden("d", None, None): ("document type declaration", "remove the DTD"),
             common.ExternalReferenceForbidden(None, None, "file:///etc/passwd", None): ("external references",
                                                                                          "file:///etc/passwd"),
             common.NotSupportedError("x"): ("not support", "remove"),
             common.DefusedXmlException(): ("refuses", "remove")}
    for e, words in cases.items():
        text = refusal_text(e, "cams.xml")
        assert type(e).__name__ not in text and "cams.xml" in text, text
        assert all(w in text for w in words), text


def test_metashape_entity_refusal_names_the_line_in_words(tmp_path):
    from baarda.pipeline.errors import InputError
    from baarda.pipeline.metashape import read_metashape

    f = tmp_path / "cams.xml"
    f.write_bytes(BOMB)
    with pytest.raises(InputError) as e:
        read_metashape(f)
    msg = str(e.value)
    assert "EntitiesForbidden" not in msg and "XML refused" not in msg
    assert "entity declarations (<!ENTITY a …>) are not allowed in cams.xml" in msg and "remove the DTD" in msg
    assert e.value.line == 3 and e.value.field == "xml"


# -- 4. a sweep table naming several projects ------------------------------------------------------

BASE = ('[project]\nname = "{name}"\n\n[[stage]]\nuse = "comparator"\nid = "source"\n[stage.options]\n'
        'path = "data.cmp"\n\n[[stage]]\nuse = "helmert-screening"\nid = "screening"\n[stage.options]\n'
        'threshold_mm = {threshold}\n')


def _two_projects(tmp_path: Path) -> None:
    (tmp_path / "data.cmp").write_text(DATA1, encoding="utf-8")
    (tmp_path / "p.toml").write_text(BASE.format(name="first", threshold=3.0), encoding="utf-8")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "data.cmp").write_text(DATA1, encoding="utf-8")
    (tmp_path / "other" / "q.toml").write_text(BASE.format(name="second", threshold=7.0), encoding="utf-8")


@pytest.mark.parametrize("table,text", [
    ("sweep.csv", "name,project,screening.alpha0\na,p.toml,0.01\nb,other/q.toml,0.02\nc,,0.03\n"),
    pytest.param("sweep.toml", '[[run]]\nname = "a"\nproject = "p.toml"\n"screening.alpha0" = 0.01\n\n'
                               '[[run]]\nname = "b"\nproject = "other/q.toml"\n"screening.alpha0" = 0.02\n\n'
                               '[[run]]\nname = "c"\n"screening.alpha0" = 0.03\n', marks=pytest.mark.slow)])
def test_each_sweep_row_runs_its_own_project(tmp_path, table, text):
    """A table naming two projects: every row runs the project it names (its own options and inputs),
    never the first one; a row without one runs the project given on the command line."""
    import tomllib

    _two_projects(tmp_path)
    (tmp_path / table).write_text(text, encoding="utf-8")
    code, err = cli("batch", tmp_path / "p.toml", "--sweep", tmp_path / table, "--out", tmp_path / "b",
                    "--scheduler", "sync", "--quiet")
    assert code == 0, err
    resolved = {n: tomllib.loads((tmp_path / "b" / "runs" / n / "project.resolved.toml").read_text())
                for n in "abc"}
    screening = {n: next(s for s in r["stage"] if s["id"] == "screening")["options"] for n, r in resolved.items()}
    assert [resolved[n]["project"]["name"] for n in "abc"] == ["first [a]", "second [b]", "first [c]"]
    assert [screening[n]["threshold_mm"] for n in "abc"] == [3.0, 7.0, 3.0]
    assert [screening[n]["alpha0"] for n in "abc"] == [0.01, 0.02, 0.03]
    src = next(s for s in resolved["b"]["stage"] if s["id"] == "source")["options"]["path"]
    assert Path(src) == (tmp_path / "other" / "data.cmp").resolve()     # q's own input, relative to q


@pytest.mark.parametrize("text,line,field", [("project,screening.alpha0\np.toml,0.01\nnope.toml,0.02\n", 3, "project"),
                                             ("project,screening.alpha0\nother,0.01\n", 2, "project")])
def test_a_sweep_row_naming_a_missing_project_is_refused_with_its_line(tmp_path, text, line, field):
    _two_projects(tmp_path)
    (tmp_path / "sweep.csv").write_text(text, encoding="utf-8")
    code, err = cli("batch", tmp_path / "p.toml", "--sweep", tmp_path / "sweep.csv", "--out", tmp_path / "b",
                    "--scheduler", "sync", "--quiet")
    assert code == 2 and f"sweep.csv:{line}, field '{field}'" in err, err
    assert not (tmp_path / "b" / "runs").exists() or not any((tmp_path / "b" / "runs").iterdir())


def test_several_projects_with_one_sweep_are_refused_by_name(tmp_path):
    _two_projects(tmp_path)
    (tmp_path / "sweep.csv").write_text("screening.alpha0\n0.01\n", encoding="utf-8")
    code, err = cli("batch", tmp_path / "p.toml", tmp_path / "other" / "q.toml", "--sweep", tmp_path / "sweep.csv",
                    "--out", tmp_path / "b", "--scheduler", "sync", "--quiet")
    assert code == 2 and "sweep.csv" in err and "2 were given" in err and "column 'project'" in err, err


# -- 7. one mechanism where there were two ---------------------------------------------------------

def test_the_model_exports_share_one_mechanism():
    from baarda.pipeline.exporting import BlockExport, block_to_export
    from baarda.plugins.colmap import stage as colmap_stage
    from baarda.plugins.metashape.stage import MetashapeExport
    from baarda.plugins.opensfm.stage import OpensfmExport

    assert issubclass(MetashapeExport, BlockExport) and issubclass(OpensfmExport, BlockExport)
    assert "run" not in vars(MetashapeExport) and "run" not in vars(OpensfmExport)
    assert colmap_stage.block_to_export is block_to_export


def test_gnss_centres_reads_its_csv_once_and_checks_photos_in_one_place(monkeypatch):
    from baarda.pipeline.project import load_project, stage_context
    from baarda.plugins.gcp import stage as gcp_stage

    project = load_project(ROOT / "fixtures" / "gnss" / "gnss.toml")
    source, gnss = project.stages[0], project.stages[1]
    block = source.cls().validate(source.options, stage_context(project, source))
    calls = []
    real = gcp_stage.read_gnss_csv
    monkeypatch.setattr(gcp_stage, "read_gnss_csv", lambda *a, **k: calls.append(a) or real(*a, **k))
    matched = []
    real_matched = gcp_stage.GnssCentres._matched
    monkeypatch.setattr(gcp_stage.GnssCentres, "_matched",
                        staticmethod(lambda *a: matched.append(a) or real_matched(*a)))
    gnss.cls().run({"block": block}, gnss.options, stage_context(project, gnss))
    assert len(calls) == 1 and len(matched) == 1


# -- 3. the new readers' corpora: findings of the fuzzing -------------------------------------------

def test_a_metashape_marker_id_given_twice_is_an_input_error(tmp_path):
    """Found by fuzzing (a line doubled): two markers with one id ended in an IndexError."""
    from baarda.pipeline.errors import InputError
    from baarda.pipeline.metashape import read_metashape

    text = (Path(__file__).parent / "metashape" / "mini.xml").read_text(encoding="utf-8")
    marker = '      <marker id="0" label="p0">'
    assert marker in text
    f = tmp_path / "cams.xml"
    f.write_text(text.replace(marker, '      <marker id="0" label="q0"/>\n' + marker, 1), encoding="utf-8")
    with pytest.raises(InputError) as e:
        read_metashape(f)
    assert e.value.field == "marker[@id='0']/@id" and "given twice" in e.value.message


def test_a_long_element_path_keeps_its_end_in_the_message():
    """A field longer than 40 characters (an XML element path) showed as 'of 52 characters'."""
    from baarda.pipeline.errors import InputError

    e = InputError("must be a number", "cams.xml", None, "sensor[@id='0']/property[@name='pixel_width']/@value")
    assert "of 52 characters" not in str(e) and "/@value'" in str(e), str(e)
    assert "of 3 characters" in str(InputError("x", "f", None, "a\x00b"))      # never a file's raw bytes
