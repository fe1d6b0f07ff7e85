"""Every bundled project validates, and the quick ones run end to end through the runner."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from baarda.pipeline.plugins import PluginManager
from baarda.pipeline.project import load_project
from baarda.pipeline.runner import run_project

from conftest import SHARED_BESIDE, needs_shared_beside

ROOT = Path(__file__).resolve().parents[2]
PROJECTS = sorted((ROOT / "fixtures").rglob("*.toml"))
QUICK = ["paper000/data1.toml", "paper000/data2.toml", "paper000/data3.toml", "paper000/printed.toml",
         "paper000/fiducial.toml", "calibration/charuco.toml", "colmap/colmap.toml"]


def test_there_are_bundled_projects():
    names = {p.relative_to(ROOT / "fixtures").as_posix() for p in PROJECTS}
    assert set(QUICK) <= names


@pytest.mark.parametrize("path", PROJECTS, ids=lambda p: p.relative_to(ROOT / "fixtures").as_posix())
def test_bundled_project_validates(path):
    project = load_project(path, PluginManager())
    assert project.stages


@pytest.mark.parametrize("rel", QUICK)
def test_quick_project_runs(rel, tmp_path, shared_data):
    if needs_shared_beside(ROOT / "fixtures" / rel):
        pytest.skip(f"{rel} reads ../shared/data beside the repository ({SHARED_BESIDE}), absent here")
    out = run_project(ROOT / "fixtures" / rel, tmp_path / "run", verbose=False)
    assert out.ok, out.message
    res = json.loads((tmp_path / "run" / "results.json").read_text())
    assert all(s["status"] == "ok" for s in res["stages"])
    assert all((tmp_path / "run" / f"{s['id']}.rrd").exists() for s in res["stages"])
