"""DBAT's residual definition (corrected marks) — the bundle option ``residual = "corrected"`` —
against DBAT's published camcal results (numbers: ``test_projects.py``; docs/dbat.md,
"Residual definition").

DBAT writes the adjusted camera with all its digits to ``data/script/camcaldemo/result/c4040z.xml``
(niclasborlin/dbat b8d1b15, DBAT 0.9.2.0); converted to baarda's conventions below."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.adjustment import BundleSettings, adjust
from baarda.plugins.dbat import dbat_block, read_dbat
from baarda.plugins.dbat.stage import _quality

from .test_projects import CAMCAL, CAMCAL_REDUNDANCY, CAMCAL_SIGMA0

# c4040z.xml (DBAT's result): cc, pp, K, P, aspect (sensor 7.25301132255482273 × 5.43764 mm, 2272 × 1704 px)
CAMCAL_FULL = {"cc": 7.45699532273933752, "px": 3.61546239970888994, "py": 2.61329279848268081,
               "K1": 0.00458860662755811253, "K2": -4.51350997187018702e-05, "K3": -2.05253370760761127e-06,
               "P1": -6.12803065099492536e-05, "P2": -4.41170561685059337e-05, "as": 1 - 0.999610402322309577}   # DBAT prints as = 1 − aspect


@pytest.fixture(scope="module")
def camcal_corrected(shared_data):
    block = dbat_block(read_dbat(shared_data / "dbat-camcal" / "camcaldemo.xml"))
    return block, adjust(block, BundleSettings(datum="control", residual="corrected"))


def test_camcal_in_dbats_definition(camcal_corrected):
    """σ̂0 DBAT's to its printed digits, the camera DBAT's to 10⁻³ σ (its full digits) and its σ
    as DBAT's printed ones."""
    block, res = camcal_corrected
    assert res.dof == CAMCAL_REDUNDANCY
    assert f"{res.sigma0_hat:.5g}" == f"{CAMCAL_SIGMA0:.5g}"              # 1.6148
    q = _quality(res)
    assert q["residual"] == "corrected"
    assert q["sigma0_corrected"] == pytest.approx(res.sigma0_hat, rel=1e-12)   # the bundle's own residuals are DBAT's
    for k, (v, s) in CAMCAL.items():
        value, sigma = q["camera"][k]
        assert abs(value - CAMCAL_FULL[k]) / s < 1e-3, (k, (value - CAMCAL_FULL[k]) / s)
        assert abs(value - v) / s < 0.06, k                                # the printed digits (c: 4 decimals)
        assert sigma == pytest.approx(s, rel=0.01), k                     # σ as DBAT's printed ones
    assert not np.shares_memory(res.state.cam_params, block.cameras.ap)


def test_fixture(repo_root, tmp_path):
    """fixtures/dbat/camcal-corrected.toml through the runner: dbat, bundle (residual = "corrected"),
    dbat-report."""
    from baarda.pipeline.runner import run_project

    out = tmp_path / "run"
    run_project(repo_root / "fixtures" / "dbat" / "camcal-corrected.toml", out)
    stages = {s["id"]: s for s in json.loads((out / "results.json").read_text())["stages"]}
    assert f"{stages['bundle']['summary']['sigma0_hat']:.5g}" == f"{CAMCAL_SIGMA0:.5g}"
    assert stages["dbat"]["summary"]["residual"] == "corrected"
    cam = stages["dbat"]["summary"]["camera"]
    for k, (v, s) in CAMCAL.items():
        assert abs(cam[k]["value"] - CAMCAL_FULL[k]) / s < 1e-3, k
    assert "DBAT's residual definition" in (out / "report.md").read_text()


ROMA_DIR = os.environ.get("DBAT_REPO")


@pytest.mark.slow
@pytest.mark.skipif(not ROMA_DIR or not (Path(ROMA_DIR or ".") / "data/script/romabundledemo").is_dir(),
                    reason="set DBAT_REPO to a checkout of niclasborlin/dbat (romabundledemo: 2.6 MB, not bundled)")
def test_roma_in_dbats_definition():
    """romabundledemo (60 photos, 181 122 coordinates, set_datum depend): σ̂0 0.582769 and the camera of
    DBAT's result/EOS5DMarkII.xml (b8d1b15) to 10⁻³ σ."""
    d = Path(ROMA_DIR) / "data/script/romabundledemo"
    block = dbat_block(read_dbat(d / "romabundledemo.xml"))
    res = adjust(block, BundleSettings(datum="control", residual="corrected"))
    assert res.dof == 101801
    assert f"{res.sigma0_hat:.6f}" == "0.582769"
    q = _quality(res)
    full = {"cc": (24.5425002994450807, 0.00254), "px": (18.0816295411089882, 0.00195),
            "py": (12.0164475994770967, 0.00189), "K1": (0.000221523347553201198, 2.54e-07),
            "K2": (-1.86984852928280264e-07, 5.85e-10)}
    for k, (v, s) in full.items():
        assert abs(q["camera"][k][0] - v) / s < 1e-3, k
        assert q["camera"][k][1] == pytest.approx(s, rel=0.01), k


def test_validate_refuses_corrected_for_a_forward_model(shared_data, tmp_path, capsys):
    """``baarda validate``: residual = "corrected" with a camera model that has no correction of the
    marks is one error naming the project file, the option's line and the field."""
    from baarda.pipeline.cli import main

    p = tmp_path / "p.toml"
    p.write_text(f'[project]\nname = "t"\n\n[[stage]]\nuse = "dbat"\n[stage.options]\n'
                 f'path = "{(shared_data / "dbat-camcal" / "camcaldemo.xml").as_posix()}"\n\n'
                 '[[stage]]\nuse = "bundle"\n[stage.options]\nap_model = "brown"\nresidual = "corrected"\n',
                 encoding="utf-8")
    assert main(["validate", str(p)]) != 0
    err = capsys.readouterr().err
    assert "p.toml:13, field 'residual'" in err and "brown-backward" in err and err.count("error") == 1


def test_the_retired_stage_names_the_option(tmp_path, capsys):
    from baarda.pipeline.cli import main

    p = tmp_path / "p.toml"
    p.write_text('[project]\nname = "t"\n\n[[stage]]\nuse = "dbat-residuals"\n', encoding="utf-8")
    assert main(["validate", str(p)]) != 0
    assert 'p.toml:5, field \'use\': stage \'dbat-residuals\' was retired' in capsys.readouterr().err
