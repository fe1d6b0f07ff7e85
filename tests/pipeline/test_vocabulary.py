"""One vocabulary: renamed options, values and stages are rejected with their new spelling; unknown
names get the closest known ones; nested option tables are typed.  Checked through real project
files and the installed stages, as a user meets them."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.options import describe, option, parse_options
from baarda.pipeline.plugins import PluginManager
from baarda.pipeline.project import load_project


@pytest.fixture(scope="module")
def installed():
    return PluginManager()


def _load(tmp_path, installed, stage: str, options: str) -> str:
    p = tmp_path / "p.toml"
    p.write_text(f'[project]\nname = "t"\n\n[[stage]]\nuse = "{stage}"\n[stage.options]\n{options}\n',
                 encoding="utf-8")
    with pytest.raises(InputError) as e:
        load_project(p, installed)
    msg = str(e.value)
    assert "\n" not in msg and "p.toml:" in msg, msg
    return msg


@pytest.mark.parametrize("stage, old, new, value", [
    ("bundle", "image_sigma_scale", "sigma_image_scale", "2.0"),
    ("pycolmap-crosscheck", "max_iterations", "max_iter", "50"),
    ("independent-models", "critical", "critical_w", "3.29"),
    ("independent-models", "pc_sigma_factor", "sigma_pc_scale", "1.0"),
    ("helmert-screening", "deactivate", "action", "true"),
    ("blunder-rejection", "max_iter", "max_rejections", "10"),
    ("testfield-render", "noise_sigma", "sigma_noise", "1.0"),
])
def test_a_renamed_option_names_its_new_spelling(tmp_path, installed, stage, old, new, value):
    msg = _load(tmp_path, installed, stage, f"{old} = {value}")
    assert f"option '{old}' is now '{new}'" in msg and "p.toml:7" in msg and f"field '{old}'" in msg


def test_renamed_options_inside_a_nested_table(tmp_path, installed):
    p = tmp_path / "p.toml"
    p.write_text('[project]\nname = "t"\n\n[[stage]]\nuse = "aicon"\n[stage.options]\npath = "x"\n'
                 'perturb = { position_sigma = 50.0 }\n', encoding="utf-8")
    with pytest.raises(InputError, match="option 'perturb.position_sigma' is now 'perturb.sigma_position'"):
        load_project(p, installed)


@pytest.mark.parametrize("stage, option_, old, new", [
    ("helmert-screening", "on_too_few", "fail", "error"),
])
def test_a_renamed_value_names_its_new_spelling(tmp_path, installed, stage, option_, old, new):
    msg = _load(tmp_path, installed, stage, f'{option_} = "{old}"')
    assert f"the value '{old}' is now '{new}'" in msg and "p.toml:7" in msg


def test_unknown_option_gets_the_closest_names(tmp_path, installed):
    msg = _load(tmp_path, installed, "bundle", "solver.max_itre = 5")
    assert "unknown option 'solver.max_itre'; did you mean 'solver.max_iter'?" in msg


def test_a_renamed_stage_names_its_new_name(tmp_path, installed):
    p = tmp_path / "p.toml"
    p.write_text('[project]\nname = "t"\n\n[[stage]]\nuse = "control-study"\n', encoding="utf-8")
    with pytest.raises(InputError) as e:
        load_project(p, installed)
    assert "stage 'control-study' is now 'testfield-control-study'" in str(e.value)
    assert "p.toml:5" in str(e.value)


def test_unknown_stage_gets_the_closest_names(tmp_path, installed):
    p = tmp_path / "p.toml"
    p.write_text('[project]\nname = "t"\n\n[[stage]]\nuse = "bundel"\n', encoding="utf-8")
    with pytest.raises(InputError, match="no stage named 'bundel'; did you mean 'bundle'"):
        load_project(p, installed)


def test_typed_nested_tables(tmp_path, installed):
    msg = _load(tmp_path, installed, "bundle", 'ap_model = "brown"\nsigma = { K1 = "small" }')
    assert "sigma.K1" in msg and "expected a number" in msg
    msg = _load(tmp_path, installed, "bundle", 'ap_model = "brown"\nsigma = { K9 = 0.1 }')
    assert "sigma.K9: not a parameter" in msg and "did you mean 'K" in msg
    msg = _load(tmp_path, installed, "bundle", "ap_models = { cam = 3 }")
    assert "ap_models.cam" in msg and "expected a string" in msg
    msg = _load(tmp_path, installed, "bundle", 'distances = [{ from = "A", to = "B", distance = 1.0 }]')
    assert "distances.sigma" in msg and "missing" in msg
    msg = _load(tmp_path, installed, "bundle", 'distances = [{ from = "A", to = "B", distance = -1.0, sigma = 0.1 }]')
    assert "distances.distance" in msg and "must be greater than 0" in msg


def test_a_typed_table_with_a_keyword_key(tmp_path, installed):
    """The scale bar's ``from`` (a Python keyword) is the field ``from_``; the project says ``from``."""
    p = tmp_path / "p.toml"
    p.write_text('[project]\nname = "t"\n\n[[stage]]\nuse = "testfield"\n\n[[stage]]\nuse = "bundle"\n'
                 '[stage.options]\ndistances = [{ from = "1", to = "2", distance = 1.5, sigma = 0.001 }]\n',
                 encoding="utf-8")
    project = load_project(p, installed)
    bar = project.stages[1].options.distances[0]
    assert (bar.from_, bar.to, bar.distance, bar.sigma) == ("1", "2", 1.5, 0.001)
    types = {d["name"]: d["type"] for d in describe(type(project.stages[1].options))}
    assert types["distances"] == "list[table (from, to, distance, sigma)]"


def test_the_mechanism_on_a_class_of_ones_own():
    @dataclasses.dataclass(frozen=True)
    class Opts:
        RENAMED: ClassVar[dict[str, str]] = {"old": "new"}
        RENAMED_VALUES: ClassVar[dict[str, dict[str, str]]] = {"mode": {"fail": "error"}}
        new: float = option(1.0, "the new name")
        mode: str = option("error", "error or warn")
        weights: dict[str, float] = option({}, "a typed table")

    assert parse_options(Opts, {"new": 2, "weights": {"a": 1}}) == Opts(2.0, "error", {"a": 1.0})
    with pytest.raises(InputError, match="option 'old' is now 'new'"):
        parse_options(Opts, {"old": 2})
    with pytest.raises(InputError, match="the value 'fail' is now 'error'"):
        parse_options(Opts, {"mode": "fail"})
    with pytest.raises(InputError, match="weights.a"):
        parse_options(Opts, {"weights": {"a": "x"}})
    types = {d["name"]: d["type"] for d in describe(Opts)}
    assert types["weights"] == "table[str → float]" and "RENAMED" not in types
