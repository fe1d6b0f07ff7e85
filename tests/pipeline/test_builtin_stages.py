"""Every built-in stage registers through the `baarda.stages` entry points and follows the protocol."""

from __future__ import annotations

import tomllib
from importlib.metadata import entry_points

import pytest

from baarda.pipeline.plugins import GROUP, PluginManager
from baarda.pipeline.testing import check_stage

PYPROJECT = tomllib.loads((__import__("pathlib").Path(__file__).resolve().parents[2] / "pyproject.toml").read_text())
DECLARED = PYPROJECT["project"]["entry-points"][GROUP]


def test_installed_entry_points_match_pyproject():
    installed = {ep.name: ep.value for ep in entry_points(group=GROUP) if ep.value.startswith("baarda.plugins.")}
    assert installed == DECLARED, "reinstall (pip install -e .) after changing entry points"


@pytest.mark.parametrize("name", sorted(DECLARED))
def test_builtin_stage_loads_and_follows_protocol(name):
    pm = PluginManager()
    assert name not in pm.load_errors, pm.load_errors.get(name)
    info = pm.get(name)
    assert info.package == "baarda"
    check_stage(info.cls, name)
    # every artefact a stage reads is written by some built-in stage
    writers = {w.rstrip("?") for i in pm for w in i.cls.writes}
    for r in info.cls.reads:
        assert r.rstrip("?") in writers or r.endswith("?"), f"{name} reads '{r}' that no stage writes"


def test_stages_command_lists_every_builtin(capsys):
    from baarda.pipeline.cli import main

    assert main(["stages"]) == 0
    out = capsys.readouterr().out
    for name in DECLARED:
        assert any(line.split()[0] == name for line in out.splitlines()), name
