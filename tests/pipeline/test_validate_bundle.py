"""`baarda validate` checks the bundle's fix/free/sigma names against the block's camera models, as
`run` does (issue 23, item 11)."""

from __future__ import annotations

from pathlib import Path

import pytest

from baarda.pipeline.cli import EXIT_STATUS, main

ROOT = Path(__file__).resolve().parents[2]
SXB = ROOT / "fixtures" / "dbat" / "sxb.toml"
DATA = ROOT.parent / "shared" / "data" / "dbat-sxb"


@pytest.mark.skipif(not DATA.exists(), reason="DBAT data absent")
@pytest.mark.parametrize("option", ['bundle.fix=["K4"]', 'bundle.free=["K9"]', 'bundle.sigma={K4 = 0.1}'])
def test_validate_rejects_a_parameter_the_camera_model_lacks(capsys, option):
    assert main(["validate", str(SXB), "--set", option]) == EXIT_STATUS["input"]
    err = capsys.readouterr().err
    assert "K4" in err or "K9" in err
    assert "belongs to none of the cameras' models" in err and "sxb.toml" in err


@pytest.mark.skipif(not DATA.exists(), reason="DBAT data absent")
def test_validate_accepts_a_parameter_of_the_model(capsys):
    assert main(["validate", str(SXB), "--set", 'bundle.fix=["K3"]']) == 0
    assert "valid" in capsys.readouterr().out
