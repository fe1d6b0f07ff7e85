"""The worked example of docs/bring-your-own.md runs and gives what the page says."""

from __future__ import annotations

import json
import runpy
import shutil
from pathlib import Path

import pytest

from baarda.pipeline.cli import main

EXAMPLE = Path(__file__).resolve().parents[2] / "docs" / "examples" / "bring-your-own"


@pytest.mark.slow
def test_bring_your_own_bal_example(tmp_path, monkeypatch, capsys):
    for f in ("make_bal.py", "mine.toml"):
        shutil.copy(EXAMPLE / f, tmp_path / f)
    monkeypatch.chdir(tmp_path)
    runpy.run_path(str(tmp_path / "make_bal.py"))
    assert (tmp_path / "mine.txt").read_text().splitlines()[0] == "6 40 240"
    assert main(["validate", "mine.toml"]) == 0
    assert main(["-q", "run", "mine.toml", "--out", str(tmp_path / "runs" / "mine")]) == 0
    results = json.loads((tmp_path / "runs" / "mine" / "results.json").read_text())
    bundle = next(s for s in results["stages"] if s["id"] == "bundle")
    assert bundle["summary"]["dof"] == 331
    assert bundle["summary"]["sigma0_hat"] == pytest.approx(0.9419, abs=5e-4)     # the page quotes 0.9419
    page = (EXAMPLE.parents[1] / "bring-your-own.md").read_text()
    assert "σ̂0 = 0.9419" in page and "dof = 331" in page
