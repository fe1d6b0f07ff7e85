"""DBAT's residual definition (corrected marks): :mod:`baarda.plugins.dbat.corrected` and the
``dbat-residuals`` stage against DBAT's published camcal report (numbers: ``test_projects.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from baarda.pipeline.adjustment import BundleSettings, adjust
from baarda.pipeline.camera import get_ap_model
from baarda.plugins.dbat import dbat_block, read_dbat
from baarda.plugins.dbat.corrected import (adjust_corrected, camera_at_dbat_minimum, corrected_cov,
                                          correction_jacobian)
from baarda.plugins.dbat.stage import _quality

from .test_projects import CAMCAL, CAMCAL_REDUNDANCY, CAMCAL_SIGMA0


def test_jacobian_against_the_closed_form():
    """∂g/∂m of the backward model by central differences against the model's own G."""
    model = get_ap_model("brown-backward")
    rng = np.random.default_rng(3)
    lb = rng.uniform(-4, 4, (50, 2))
    prm = np.array([4.6e-3, -4.6e-5, -2e-6, -6e-5, -4.4e-5, 3.9e-4, 1e-4])
    J = correction_jacobian(model, lb, prm, 7.45)
    _, _, G, _ = model._correction(lb[:, 0], lb[:, 1], model._params(np.tile(prm, (50, 1)), 50), True)
    np.testing.assert_allclose(J, G, rtol=1e-7, atol=1e-10)


def test_reweighting_makes_the_residuals_dbats(shared_data):
    """At a fixed solution, baarda's residuals weighted with J⁻¹ΣJ⁻ᵀ give DBAT's vᵀPv to first order."""
    block = dbat_block(read_dbat(shared_data / "dbat-camcal" / "camcaldemo.xml"))
    res = adjust(block, BundleSettings(datum="control"))
    cov = corrected_cov(block, res.state.cam_params, block.observations.cov)
    r = res.residuals
    ours = float(np.einsum("ki,kij,kj->", r, np.linalg.inv(cov), r))
    q = _quality(res)
    dbat = q["sigma0_corrected"] ** 2 * res.dof - (res.vtpv - float(np.einsum(
        "ki,kij,kj->", r, np.linalg.inv(block.observations.cov), r)))
    assert ours == pytest.approx(dbat, rel=1e-4)
    assert not np.shares_memory(cov, block.observations.cov)


def test_camcal_in_dbats_definition(shared_data):
    block = dbat_block(read_dbat(shared_data / "dbat-camcal" / "camcaldemo.xml"))

    def run(b):
        r = adjust(b, BundleSettings(datum="control"))
        return r, r.block

    res, used, rounds, move = adjust_corrected(block, run)
    assert rounds <= 4 and move < 0.01
    assert res.dof == CAMCAL_REDUNDANCY
    assert f"{res.sigma0_hat:.5g}" == f"{CAMCAL_SIGMA0:.5g}"             # 1.6148, DBAT's own σ0
    used = used.replace(meta={**dict(used.meta), "dbat_residuals": {"marks_cov": block.observations.cov}})
    res = adjust(used, BundleSettings(datum="control"))
    q = _quality(res)
    assert f"{q['sigma0_corrected']:.5g}" == f"{CAMCAL_SIGMA0:.5g}"
    for k, (v, s) in CAMCAL.items():
        assert abs(q["camera"][k][0] - v) / s < 0.3, k
        assert q["camera"][k][1] == pytest.approx(s, rel=0.02), k            # σ as DBAT's to 2 %


def test_camera_at_dbats_minimum(shared_data):
    """The Newton step of DBAT's own objective from the reweighted solution lands on DBAT's camera:
    every parameter within 0.05 σ of DBAT's report (the reweighted camera alone: within 0.3 σ), σ̂0
    DBAT's to 5 digits."""
    block = dbat_block(read_dbat(shared_data / "dbat-camcal" / "camcaldemo.xml"))

    def run(b):
        r = adjust(b, BundleSettings(datum="control"))
        return r, r.block

    res, used, _, _ = adjust_corrected(block, run)
    mini = camera_at_dbat_minimum(used, res, block.observations.cov)
    assert mini["F_after"] < mini["F_before"]
    s0 = np.sqrt((res.vtpv - mini["F_before"] + mini["F_after"]) / res.dof)
    assert f"{s0:.5g}" == f"{CAMCAL_SIGMA0:.5g}"
    q = _quality(res, {**mini, "sigma0": s0})
    for k, (v, s) in CAMCAL.items():
        tol = 0.06 if k == "cc" else 0.05           # DBAT prints c to 4 decimals (0.05 σ)
        assert abs(q["camera"][k][0] - v) / s < tol, (k, (q["camera"][k][0] - v) / s)
    assert np.abs(mini["step"]).max() > 0 and not np.shares_memory(mini["cam_params"], res.state.cam_params)


def test_fixture_bundle_residuals_bundle(repo_root, tmp_path):
    """fixtures/dbat/camcal-corrected.toml through the runner: bundle, dbat-residuals, bundle,
    dbat-report — σ̂0 DBAT's, the reported camera within 0.06 σ of DBAT's report."""
    import json

    from baarda.pipeline.runner import run_project

    out = tmp_path / "run"
    run_project(repo_root / "fixtures" / "dbat" / "camcal-corrected.toml", out)
    stages = {s["id"]: s for s in json.loads((out / "results.json").read_text())["stages"]}
    assert f"{stages['bundle']['summary']['sigma0_hat']:.5g}" == f"{CAMCAL_SIGMA0:.5g}"
    assert stages["dbat-residuals"]["summary"]["sigma_ratio_min"] < 0.95
    cam = stages["dbat"]["summary"]["camera"]
    for k, (v, s) in CAMCAL.items():
        assert abs(cam[k]["value"] - v) / s < 0.06, k
    assert f"{stages['dbat']['summary']['dbat_minimum']['sigma0_hat']:.5g}" == f"{CAMCAL_SIGMA0:.5g}"
