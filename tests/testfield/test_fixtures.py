"""The bundled projects of the test field and the AICON network load, and the cheap ones run."""

from __future__ import annotations

import pytest

from baarda.pipeline.plugins import PluginManager
from baarda.pipeline.project import load_project
from baarda.pipeline.runner import run_project


@pytest.mark.parametrize("name", ["testfield/study.toml", "testfield/block.toml", "aicon/aicon.toml"])
def test_fixture_projects_validate(repo_root, name):
    project = load_project(repo_root / "fixtures" / name, PluginManager())
    assert project.stages


def test_testfield_project_runs(repo_root, tmp_path):
    out = run_project(repo_root / "fixtures/testfield/block.toml", tmp_path / "run", verbose=False)
    assert out.ok, out.message
    block = out.artefacts["block"]
    assert len(block.photos) == 10 and block.cameras.ap_model[0] == "ebner12"


def test_aicon_project_reads_shared_data(repo_root, shared_data, tmp_path):
    """fixtures/aicon/aicon.toml names ../../../shared/data/...: from <repo>/fixtures/aicon that is
    <repo's parent>/shared/data, where CI (and this checkout) keep the shared data."""
    if (repo_root.parent / "shared" / "data").resolve() != shared_data.resolve():
        pytest.skip(f"shared data is not beside the repository ({shared_data})")
    out = run_project(repo_root / "fixtures/aicon/aicon.toml", tmp_path / "run", verbose=False)
    assert out.ok, out.message
    source = next(s for s in out.stages if s.id == "source")
    assert source.summary["photos"] == 115 and source.summary["perturbed"]
    bundle = next(s for s in out.stages if s.id == "bundle")
    # from positions ±5 cm, angles ±1°, c ±0.2 mm and zero distortion back to the exported solution;
    # the file's sx, sy scaled by their variance component 3.707 give σ̂0 = 1 before the rejections
    first = bundle.summary["before_rejection"]
    assert first["iterations"] <= 10
    assert first["sigma0_hat"] == pytest.approx(1.0, abs=0.005)
    # iterated data snooping until no |w| > 3.29 (docs/bundle.md, fixtures/aicon/aicon.toml)
    assert 40 <= len(bundle.summary["ids"]["removed"]) <= 80
    assert bundle.summary["data_snooping"]["n_flagged"] == 0
