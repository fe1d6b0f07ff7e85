"""One schema per parameter, as the engine sees it: options moved into nested tables (MOVED),
``--set`` and sweep rows applied to the parsed project in memory (the file parsed once, errors
naming the user's file or ``--set``), one range mechanism (declared bounds, by default the name's)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

import pytest

from baarda.pipeline import project as project_module
from baarda.pipeline.cli import main
from baarda.pipeline.errors import InputError
from baarda.pipeline.options import (Where, check_bounds, describe, field_range, option, option_value,
                                     options_problems, parse_options, range_text)
from baarda.pipeline.project import Overrides, load_project, with_overrides
from baarda.pipeline.stage import Stage, StageResult
from baarda.pipeline.testing import make_plugin_manager


@dataclass(frozen=True)
class Solver:
    max_iter: int = option(30, "iterations")
    tol_rel: float = option(1e-10, "relative tolerance")


@dataclass(frozen=True)
class Grouped:
    MOVED: ClassVar[dict[str, str]] = {"max_iter": "solver.max_iter", "tol_rel": "solver.tol_rel"}
    solver: Solver = option(Solver(), "the solver's options")
    sigma_px: float = option(1.0, "image sigma")
    path: str = option("", "a file")


class GroupedStage(Stage):
    summary = "A stage whose options form a nested table."
    writes = ("x",)
    Options = Grouped

    def run(self, inputs, options, ctx):
        return StageResult(artefacts={"x": options.solver.max_iter})


def _text(extra: str = "", tol_rel: str = "1e-8") -> str:
    """A project of one 'grouped' stage (id 'adj'): sigma_px and ``extra`` at lines 9 and 10, a
    [stage.options.solver] table at line 11 with tol_rel at line 12."""
    return "\n".join(['[project]', 'name = "grouped"', '', '[[stage]]', 'use = "grouped"', 'id = "adj"', '',
                      '[stage.options]', 'sigma_px = 2.0', extra, '[stage.options.solver]', f'tol_rel = {tol_rel}',
                      ''])


@pytest.fixture
def pm():
    return make_plugin_manager({"grouped": GroupedStage})


def _write(tmp_path, extra=""):
    p = tmp_path / "p.toml"
    p.write_text(_text(extra), encoding="utf-8")
    return p


def test_moved_option_is_rejected_with_its_new_place_in_the_file(tmp_path, pm):
    p = _write(tmp_path, "max_iter = 5")
    with pytest.raises(InputError) as e:
        load_project(p, pm)
    assert str(e.value) == (f"{p}:10, field 'max_iter': max_iter is now written as solver.max_iter "
                            "(in a [stage.options.solver] table)")


def test_moved_option_through_set_names_set(tmp_path, pm):
    p = _write(tmp_path)
    with pytest.raises(InputError) as e:
        load_project(p, pm, overrides={"adj.max_iter": 5})
    assert str(e.value) == "--set, field 'adj.max_iter': adj.max_iter is now written as adj.solver.max_iter"


def test_moved_with_parse_options_alone():
    with pytest.raises(InputError, match="tol_rel is now written as solver.tol_rel"):
        parse_options(Grouped, {"tol_rel": 1e-3})
    assert parse_options(Grouped, {"solver": {"max_iter": 4}}).solver == Solver(4, 1e-10)


@dataclass(frozen=True)
class Robust:
    method: str = option("none", "none or huber")
    c: float = option(1.5, "tuning constant")


@dataclass(frozen=True)
class SameName:
    """An old flat option ``robust`` became the group ``robust`` (its value robust.method)."""

    MOVED: ClassVar[dict[str, str]] = {"robust": "robust.method", "robust_c": "robust.c"}
    robust: Robust = option(Robust(), "robust estimation")


def test_an_old_flat_name_that_is_now_a_group():
    assert options_problems(SameName) == []          # a MOVED name may be a group's
    assert parse_options(SameName, {"robust": {"method": "huber"}}).robust == Robust("huber", 1.5)
    for value in ("huber", True, 1.5, ["huber"]):  # not a table: the old option, with its new spelling
        with pytest.raises(InputError) as e:
            parse_options(SameName, {"robust": value}, path="p.toml", line=9)
        assert str(e.value) == ("p.toml:9, field 'robust': robust is now written as robust.method "
                                "(in a [stage.options.robust] table)")
    with pytest.raises(InputError, match=r"^--set, field 'adj.robust': adj.robust is now written as "
                                         r"adj.robust.method$"):
        parse_options(SameName, {"robust": "huber"}, locate=lambda key: Where("--set", None, "adj."))


@pytest.mark.parametrize("flat, value, new", [
    ("solver", '"sparse"', "solver.solver"),
    ("robust", '"huber"', "robust.method"),
    ("variance_components", '"estimate"', "variance_components.mode"),
    ("ap_selection", "true", "ap_selection.enabled"),
])
def test_the_bundles_old_names_of_its_groups(tmp_path, flat, value, new, capsys):
    """An old bundle project's ``solver = "sparse"`` is not a type error on the group ``solver``:
    the file's line and the new dotted name; the same through ``--set bundle.solver=…``."""
    p = tmp_path / "old.toml"
    p.write_text('[project]\nname = "old"\n\n[[stage]]\nuse = "testfield"\nid = "source"\n\n'
                 f'[[stage]]\nuse = "bundle"\n[stage.options]\n{flat} = {value}\n', encoding="utf-8")
    with pytest.raises(InputError) as e:
        load_project(p)
    table = new.rpartition(".")[0]
    assert str(e.value) == (f"{p}:11, field '{flat}': {flat} is now written as {new} "
                            f"(in a [stage.options.{table}] table)")
    p.write_text('[project]\nname = "new"\n\n[[stage]]\nuse = "testfield"\nid = "source"\n\n'
                 f'[[stage]]\nuse = "bundle"\n[stage.options]\n{new} = {value}\n', encoding="utf-8")
    assert load_project(p).stages[1].options is not None              # the new spelling is fine
    assert main(["validate", str(p), "--set", f"bundle.{flat}={value}"]) == 2
    err = capsys.readouterr().err
    assert f"--set, field 'bundle.{flat}': bundle.{flat} is now written as bundle.{new}" in err
    # --set into the group of a file that still writes the old flat option: the file's mistake
    p.write_text('[project]\nname = "old"\n\n[[stage]]\nuse = "testfield"\nid = "source"\n\n'
                 f'[[stage]]\nuse = "bundle"\n[stage.options]\n{flat} = {value}\n', encoding="utf-8")
    with pytest.raises(InputError) as e:
        load_project(p, overrides={f"bundle.{new}": value.strip('"') if value != "true" else True})
    assert str(e.value).startswith(f"{p}:11, field '{flat}': {flat} is now written as {new}")


def test_set_into_an_option_that_is_no_table(tmp_path, pm):
    with pytest.raises(InputError) as e:
        load_project(_write(tmp_path), pm, overrides={"adj.sigma_px.x": 1.0})
    assert str(e.value) == ("--set, field 'adj.sigma_px.x': 'sigma_px' is not a table here, so "
                            "'sigma_px.x' cannot be set")


def test_nested_table_values_and_dotted_set(tmp_path, pm):
    p = _write(tmp_path)
    proj = load_project(p, pm, overrides={"adj.solver.max_iter": 5})
    assert proj.stages[0].options.solver == Solver(5, 1e-8)       # the file's tol_rel kept
    assert proj.stages[0].options.sigma_px == 2.0
    assert load_project(p, pm).stages[0].options.solver == Solver(30, 1e-8)
    # a mistake inside the nested table: the file's line under [stage.options.solver]
    p.write_text(_text(tol_rel="-1.0"), encoding="utf-8")
    with pytest.raises(InputError) as e:
        load_project(p, pm)
    assert str(e.value).startswith(f"{p}:12, field 'solver.tol_rel': must be greater than 0")
    # ... and an override's own mistake names --set with the full dotted name
    with pytest.raises(InputError) as e:
        load_project(_write(tmp_path), pm, overrides={"adj.solver.max_iterr": 5})
    assert str(e.value).startswith("--set, field 'adj.solver.max_iterr': unknown option "
                                   "'adj.solver.max_iterr'; did you mean 'adj.solver.max_iter'?")
    with pytest.raises(InputError, match=r"^--set, field 'adj.solver.max_iter': must be at least 1, got 0"):
        load_project(_write(tmp_path), pm, overrides={"adj.solver.max_iter": 0})


@dataclass
class Mutable:
    n: int = option(1, "n")


@dataclass(frozen=True)
class Holder:
    group: Mutable = option(Mutable(), "a group whose dataclass is not frozen")


def test_a_group_default_may_be_a_mutable_dataclass():
    a, b = Holder(), Holder()
    assert a.group == Mutable(1) and a.group is not b.group
    assert parse_options(Holder, {"group": {"n": 3}}).group == Mutable(3)
    assert [(d["name"], d["field"], d["default"], d["group"]) for d in describe(Holder)] == [("group.n", "group.n", 1, "group")]


@dataclass(frozen=True)
class Keyed:
    from_: int = option(0, "a key that is a Python keyword", key="from")


@dataclass(frozen=True)
class Deep:
    solver: Solver = option(Solver(max_iter=50), "the solver's options, with a default of their own")
    keyed: Keyed | None = option(None, "an optional group")
    sigma_px: float = option(1.0, "image sigma")


def test_describe_lists_the_options_of_groups_by_their_dotted_names():
    got = {d["name"]: d for d in describe(Deep)}
    assert list(got) == ["solver.max_iter", "solver.tol_rel", "keyed.from", "sigma_px"]
    assert got["solver.max_iter"]["default"] == 50                   # the group's default instance
    assert got["solver.max_iter"]["bounds"] == "≥ 1" and got["solver.tol_rel"]["bounds"] == "> 0"
    assert (got["solver.max_iter"]["group"], got["solver.max_iter"]["group_doc"]) == (
        "solver", "the solver's options, with a default of their own")
    assert (got["keyed.from"]["field"], got["keyed.from"]["default"]) == ("keyed.from_", 0)
    assert (got["sigma_px"]["group"], got["sigma_px"]["type"]) == ("", "float")
    opts = parse_options(Deep, {"solver": {"tol_rel": 1e-3}, "keyed": {"from": 4}})
    assert [option_value(opts, d["field"]) for d in describe(Deep)] == [50, 1e-3, 4, 1.0]
    assert option_value(Deep(), "keyed.from_") is None


def test_moved_declarations_are_checked():
    @dataclass(frozen=True)
    class Bad:
        MOVED: ClassVar[dict[str, str]] = {"a": "solver.nothing", "sigma_px": "solver.max_iter"}
        solver: Solver = option(Solver(), "s")
        sigma_px: float = option(1.0, "x")

    problems = options_problems(Bad)
    assert any("'a' → 'solver.nothing' names no option" in p for p in problems)
    assert any("'sigma_px' is still an option" in p for p in problems)
    assert options_problems(Grouped) == []


def test_overrides_are_applied_to_the_parsed_file_once(tmp_path, pm, monkeypatch):
    p = _write(tmp_path)
    calls = []
    real = project_module.tomllib.loads
    monkeypatch.setattr(project_module.tomllib, "loads", lambda text: calls.append(1) or real(text))
    proj = load_project(p, pm, overrides=Overrides({"adj.sigma_px": 3.0}))
    assert len(calls) == 1 and proj.stages[0].options.sigma_px == 3.0
    assert proj.path == p.resolve() and "(run with --set adj.sigma_px=3.0)" in proj.description
    variant = with_overrides(proj, {"adj.sigma_px": 4.0}, pm)      # a sweep row: no parse again
    assert len(calls) == 1 and variant.stages[0].options.sigma_px == 4.0
    assert proj.stages[0].options.sigma_px == 3.0 and proj.data["stage"][0]["options"]["sigma_px"] == 2.0
    assert "max_iter = 5" not in p.read_text()


def test_set_mistakes_in_the_file_name_the_users_file(tmp_path, pm):
    """An override that is fine itself while the file has a mistake: the user's file and line."""
    p = _write(tmp_path, "sigma_pxx = 1.0")
    with pytest.raises(InputError) as e:
        load_project(p, pm, overrides={"adj.sigma_px": 3.0})
    assert str(e.value).startswith(f"{p}:10, field 'sigma_pxx'")
    with pytest.raises(InputError, match=r"^--set, field 'adx.sigma_px': no stage 'adx' in p.toml; "
                                         r"did you mean 'adj'\?"):
        load_project(_write(tmp_path), pm, overrides={"adx.sigma_px": 3.0})


def test_sweep_row_errors_name_table_value_line_and_header_line(tmp_path, pm):
    proj = load_project(_write(tmp_path), pm)
    with pytest.raises(InputError, match=r"^sweep.csv:1, field 'adj.sigma_pz'"):
        with_overrides(proj, Overrides({"adj.sigma_pz": 1.0}, source="sweep.csv", line=4, name_line=1), pm)
    with pytest.raises(InputError, match=r"^sweep.csv:4, field 'adj.sigma_px': must be greater than 0"):
        with_overrides(proj, Overrides({"adj.sigma_px": -1.0}, source="sweep.csv", line=4, name_line=1), pm)


def test_cli_validate_and_run_use_the_users_file(tmp_path, pm, monkeypatch, capsys):
    import baarda.pipeline.plugins as plugins

    monkeypatch.setattr(plugins, "PluginManager", lambda: pm)          # what `baarda validate` creates
    p = _write(tmp_path)
    assert main(["validate", str(p), "--set", "adj.solver.max_iter=7", "-v"]) == 0
    out = capsys.readouterr().out
    assert "    solver.max_iter = 7  (≥ 1)\n    solver.tol_rel = 1e-08  (> 0)\n" in out
    assert "sigma_px = 2.0  (> 0)" in out and "{" not in out
    assert main(["validate", str(p), "--set", "adj.max_iter=7"]) == 2
    assert "adj.max_iter is now written as adj.solver.max_iter" in capsys.readouterr().err


def test_one_range_mechanism():
    @dataclass(frozen=True)
    class Cfg:
        sigma_px: float = option(1.0, "name-implied: > 0")
        alpha: float = option(0.05, "name-implied: (0, 1)")
        rho_max: float = option(0.5, "declared: replaces the name's", gt=0, lt=0.9)
        n: int = option(3, "declared on a name without a range", ge=2)

        def __post_init__(self):
            check_bounds(self)

    ranges = {f.name: field_range(f) for f in dataclasses.fields(Cfg)}
    assert ranges == {"sigma_px": {"gt": 0}, "alpha": {"gt": 0, "lt": 1}, "rho_max": {"gt": 0, "lt": 0.9},
                      "n": {"ge": 2}}
    assert [d["bounds"] for d in describe(Cfg)] == ["> 0", "in (0, 1)", "in (0, 0.9)", "≥ 2"]
    assert range_text({"ge": 0, "le": 1}) == "in [0, 1]" and range_text(None) == ""
    # the same bounds, whether the values come from a project or from Python
    for bad, message in [({"rho_max": 0.95}, "less than 0.9"), ({"n": 1}, "at least 2"),
                         ({"sigma_px": float("nan")}, "finite")]:
        with pytest.raises(InputError, match=message):
            parse_options(Cfg, bad)
        with pytest.raises(ValueError, match=message):
            Cfg(**bad)
    assert Cfg(rho_max=0.8).rho_max == 0.8
