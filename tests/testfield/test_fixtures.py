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


@pytest.mark.slow  # 30-70 s: the 115-photo AICON project
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
    # the factor on the file's sx, sy is estimated by the variance components (no hand-copied number):
    # one image group, ≈ 3.7 ± 0.02, the scale bar not estimable (docs/aicon-format.md)
    vc = {g["name"]: g for g in bundle.summary["variance_components"]["groups"]}
    img = vc["image camera 1"]
    assert bundle.summary["variance_components"]["converged"] and img["rejected"]
    assert 3.6 < img["factor"] < 3.8 and img["sigma_factor"] < 0.03
    assert not vc["scale bars"]["estimable"]
    # iterated data snooping until no |w| > 3.29 (docs/bundle.md, fixtures/aicon/aicon.toml)
    assert 40 <= bundle.summary["ids"]["n_removed"] <= 80
    assert bundle.summary["data_snooping"]["n_flagged"] == 0
