"""docs/library.md runs as written: each ```python block is extracted and run from the repository's
root (the COLMAP and DBAT examples read ../shared/data beside it, and are skipped without it)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "library.md"


def _blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)


def _block(marker: str) -> str:
    found = [b for b in _blocks() if marker in b]
    assert len(found) == 1, marker
    return found[0]


def _run(code: str, name: str, monkeypatch) -> dict:
    monkeypatch.chdir(ROOT)
    ns: dict = {"__name__": f"library_doc_{name}"}
    exec(compile(code, f"{DOC}:{name}", "exec"), ns)
    return ns


def test_the_page_has_the_three_examples():
    assert len(_blocks()) == 3


def test_every_example_uses_the_public_face():
    """adjust and its config come from baarda.pipeline.api, never from the core's modules."""
    for code in _blocks():
        mods = re.findall(r"^from (baarda\.pipeline\S*) import", code, re.M)
        assert "baarda.pipeline.api" in mods and not any(m.startswith("baarda.pipeline.adjustment") for m in mods)


def test_simulated_block(monkeypatch):
    ns = _run(_block("baarda.pipeline.synthetic"), "simulated", monkeypatch)
    report = ns["report"]
    assert report.ids.removed == [14]                       # image point 7, x
    assert not report.global_test.rejected
    with pytest.raises(Exception):                          # frozen
        report.result = None


def test_colmap_model(shared_beside, monkeypatch):
    ns = _run(_block("read_colmap"), "colmap", monkeypatch)
    assert len(ns["block"].photos) == 23 and ns["report"].snooping is not None


def test_dbat_project(shared_beside, monkeypatch, tmp_path):
    """The library's numbers are the bundle stage's (the stage runs the same function)."""
    import numpy as np

    from baarda.pipeline.testing import run_stage
    from baarda.plugins.bundle.stage import BundleAdjustment

    ns = _run(_block("read_dbat"), "dbat", monkeypatch)
    res = ns["res"]
    stage = run_stage(BundleAdjustment, {"block": ns["block"]}, {"datum": "control"}, tmp_path=tmp_path)
    assert stage.artefacts["bundle"].sigma0_hat == pytest.approx(res.sigma0_hat, rel=1e-12)
    np.testing.assert_allclose(stage.artefacts["bundle"].state.XYZ, res.state.XYZ, rtol=1e-12)
    assert stage.summary["data_snooping"]["n_flagged"] == int(ns["report"].snooping.flagged.sum())


def test_the_readmes_example(shared_beside, monkeypatch):
    """README.md's 'From Python' example runs as written and gives the COLMAP example's numbers."""
    code = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(encoding="utf-8"), re.S)
    assert len(code) == 1
    monkeypatch.chdir(ROOT)
    ns: dict = {"__name__": "readme_example"}
    exec(compile(code[0], "README.md", "exec"), ns)
    doc = _run(_block("read_colmap"), "colmap", monkeypatch)
    assert ns["report"].result.sigma0_hat == doc["report"].result.sigma0_hat
