"""Pre-analysis (network design): the a-priori switch, the prediction against Monte Carlo, the
closed-form link to an ordinary adjustment, determinability, the stages and their input errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats as sps

from baarda.pipeline.adjustment import BundleSettings, adjust, parameter_covariance
from baarda.pipeline.errors import AdjustmentError, InputError
from baarda.pipeline.runner import run_project
from baarda.plugins.design.network import (PlannedCamera, joint_test, plan_block, ratio_test, realisation_errors,
                                           realise)
from baarda.plugins.design.stage import read_stations, read_targets

ROOT = Path(__file__).resolve().parents[2]
FIX = ROOT / "fixtures" / "design"
CAM = PlannedCamera(c=24.0, pixel_mm=0.006, resolution=(4000, 3000), ap_model="brown",
                    free=("c", "xp", "yp", "K1", "K2", "P1", "P2"))


@pytest.fixture(scope="module")
def planned():
    tid, XYZ, role, _ = read_targets(FIX / "targets.csv")
    sid, X0, opk, _ = read_stations(FIX / "stations.csv", dict(zip(tid, XYZ)))
    block = plan_block(CAM, sid, X0, opk, tid, XYZ, role, sigma_image_mm=0.6e-3, sigma_control=0.2e-3)
    pred = adjust(block, BundleSettings(variance="a-priori"))
    return block, pred


def test_planned_observations_are_exact(planned):
    block, pred = planned
    assert pred.iterations == 1
    assert np.abs(pred.residuals).max() < 1e-12                       # mm: the bundle's own projection
    assert len(block.observations) == 240                              # every target in every station


def test_apriori_switch_scales_cofactors_by_sigma0(planned):
    block, _ = planned
    noisy = realise(block, np.random.default_rng(5))
    post = adjust(noisy, BundleSettings())
    prior = adjust(noisy, BundleSettings(variance="a-priori", sigma0=2.0))
    f = post.sigma0_hat ** 2
    assert 0.7 < f < 1.3
    # the weights are σ0² Σ⁻¹, so σ0² Q = Σ_x whatever σ0: a-priori gives Σ_x, a-posteriori σ̂0² Σ_x
    np.testing.assert_allclose(prior.cov_points * f, post.cov_points, rtol=1e-8, atol=0)
    np.testing.assert_allclose(prior.cov_cameras[0] * f, post.cov_cameras[0], rtol=1e-8, atol=1e-30)
    assert prior.variance_factor == 4.0 and post.variance_factor == pytest.approx(f)


def test_prediction_equals_ordinary_adjustment_rescaled(planned):
    """The closed-form link: the covariance of an ordinary adjustment of measured (noisy) observations
    × (σ0/σ̂0)² is the design's σ0² Q, up to the change of the linearisation point."""
    block, pred = planned
    res = adjust(realise(block, np.random.default_rng(11)), BundleSettings())
    k = (res.sigma0 / res.sigma0_hat) ** 2
    used = pred.point_used

    def close(A, B, tol):     # |ΔC_ij| ≤ tol √(C_ii C_jj)
        d = np.sqrt(np.einsum("...ii->...i", B))
        scale = d[..., :, None] * d[..., None, :]
        ok = scale > 0
        assert np.all(np.abs(A - B)[ok] <= tol * scale[ok]), np.max(np.abs(A - B)[ok] / scale[ok])
        assert np.all(A[~ok] == 0)

    # exact at one linearisation point: the design of the estimated network (error-free observations
    # f(x̂) = l − v) predicts exactly the measured network's covariance × (σ0/σ̂0)²
    at_est = res.block
    at_est = at_est.replace(observations=at_est.observations.replace(xy=at_est.observations.xy - res.residuals))
    exact = adjust(at_est, BundleSettings(variance="a-priori"))
    assert exact.vtpv < 1e-20
    np.testing.assert_allclose(res.cov_points[used] * k, exact.cov_points[used], rtol=1e-6,
                               atol=1e-9 * np.abs(exact.cov_points[used]).max())
    np.testing.assert_allclose(res.cov_cameras[0] * k, exact.cov_cameras[0], rtol=1e-6,
                               atol=1e-9 * np.abs(exact.cov_cameras[0]).max())
    # and at the plan up to the noise's move of the linearisation point (≈ 1σ of every parameter)
    close(res.cov_points[used] * k, pred.cov_points[used], 2e-3)
    close(res.cov_eo * k, pred.cov_eo, 2e-3)
    close(res.cov_cameras[0] * k, pred.cov_cameras[0], 1e-2)
    np.testing.assert_allclose(res.redundancy, exact.redundancy, atol=1e-8)
    np.testing.assert_allclose(res.redundancy, pred.redundancy, atol=2e-3)


def test_redundancy_numbers_sum_to_the_redundancy(planned):
    _, pred = planned
    # trace(Qvv P) over the image rows + the weighted control's own redundancy = dof
    assert 0 < pred.redundancy.min() and pred.redundancy.max() < 1
    assert pred.redundancy.sum() <= pred.dof + 1e-9
    assert pred.redundancy.sum() > pred.dof - 18          # 18 weighted control coordinates


def test_predicted_sigma_agrees_with_monte_carlo(planned):
    block, pred = planned
    N = 60
    errs = [realisation_errors(block, BundleSettings(), np.random.default_rng(s))
            for s in np.random.SeedSequence(7).spawn(N)]
    free = np.flatnonzero(pred.point_used & ~(block.points.sigma == 0).all(axis=1))
    E = np.stack([e["XYZ"][free] for e in errs]).reshape(N, -1)
    sig = np.sqrt(np.einsum("nii->ni", pred.cov_points[free])).reshape(-1)
    t = ratio_test(E, sig, alpha=0.01)
    # per component N s²/σ² ~ χ²(N): at α = 1 % about 1 % outside; 8 of 90 would be p < 1e-4 (binomial)
    assert t.rejected.sum() <= 7, t.ratio
    assert 0.9 < t.pooled_ratio < 1.1
    names, C = parameter_covariance(pred, [f"point {i}" for i in block.points.ids[free]])
    jt = joint_test(E, C)
    assert jt["p"] > 1e-3, jt
    assert abs(jt["normalised"] - 1) < 5 * np.sqrt(2 / jt["dof"])
    # the same test has the power to reject a prediction 20 % too optimistic
    assert joint_test(E, C * 0.8 ** 2)["p"] < 1e-6
    s0 = np.array([e["sigma0_hat"] for e in errs])
    assert abs(np.mean(s0 ** 2) - 1) < 4 * np.sqrt(2 / pred.dof / N)


def test_ratio_test_against_chi2_bounds():
    lo = sps.chi2.ppf(0.025, 20) / 20
    t = ratio_test(np.ones((20, 2)) * np.array([np.sqrt(lo) * 0.99, 1.0]), np.ones(2))
    assert t.rejected.tolist() == [True, False]


def test_undeterminable_parameter_is_named():
    xs, ys = np.meshgrid(np.linspace(-1, 1, 5), np.linspace(-0.8, 0.8, 5))
    XYZ = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(25)])      # a flat field ...
    role = np.array(["tie"] * 25, dtype="<U5")
    role[[0, 4, 20, 24]] = "full"
    X0 = np.array([[x, 0, 3.0] for x in (-0.6, -0.2, 0.2, 0.6)])      # ... from one height, parallel axes
    cam = PlannedCamera(24.0, 0.006, (4000, 3000), "none", free=("c",))
    b = plan_block(cam, list("ABCD"), X0, np.zeros((4, 3)), [f"t{i}" for i in range(25)], XYZ, role,
                   sigma_image_mm=6e-4)
    with pytest.raises(AdjustmentError, match="parameter c of camera 'cam' cannot be determined"):
        adjust(b, BundleSettings(variance="a-priori"))


def test_bundled_project_runs(tmp_path):
    out = run_project(FIX / "design.toml", tmp_path / "run", verbose=False)
    assert out.ok, out.message
    res = {s["id"]: s for s in json.loads((tmp_path / "run" / "results.json").read_text())["stages"]}
    mc = res["design-montecarlo"]["summary"]
    assert mc["n_sim"] == 20 and mc["points_components"] == 90
    assert mc["joint"]["p"] > 1e-3
    assert mc["headline"].startswith("predicted median σ X, Y, Z ") and "20 realisations" in mc["headline"]
    assert float(mc["headline"].rsplit("joint test p = ", 1)[1]) == pytest.approx(mc["joint"]["p"], abs=1e-3)
    assert res["bundle"]["summary"]["sigma0_hat"] == 0.0
    report = (tmp_path / "run" / "report.md").read_text()
    assert "Poorly separable" in report and "Joint test" in report
    rows = (tmp_path / "run" / "design-montecarlo_points.csv").read_text().splitlines()
    assert len(rows) == 31
    # the bundle stage's option reached the adjustment: its point σ are σ0² Q, not σ̂0² Q = 0
    import csv
    pts = {r["point"]: r for r in csv.DictReader((tmp_path / "run" / "bundle_points.csv").open())}
    mc_rows = {r["point"]: r for r in csv.DictReader((tmp_path / "run" / "design-montecarlo_points.csv").open())}
    for pid in ("T01", "T17"):
        assert float(pts[pid]["sX_m"]) == pytest.approx(float(mc_rows[pid]["sigma_X_pred_m"]), rel=1e-9)
        assert 5e-5 < float(pts[pid]["sZ_m"]) < 5e-4


def _project(tmp_path, stations=None, targets=None, camera_extra=""):
    (tmp_path / "stations.csv").write_text(stations or (FIX / "stations.csv").read_text())
    (tmp_path / "targets.csv").write_text(targets or (FIX / "targets.csv").read_text())
    p = tmp_path / "p.toml"
    p.write_text('[project]\nname = "t"\nobject_unit = "m"\n\n[[stage]]\nuse = "design"\n[stage.options]\n'
                 'stations = "stations.csv"\ntargets = "targets.csv"\n[stage.options.camera]\nc_mm = 24.0\n'
                 f'pixel_mm = 0.006\nresolution = [4000, 3000]\nap_model = "brown"\n{camera_extra}\n')
    return p


def _error(tmp_path, **kw) -> str:
    from baarda.pipeline.plugins import PluginManager
    from baarda.pipeline.project import load_project
    from baarda.pipeline.stage import Context

    p = _project(tmp_path, **kw)
    project = load_project(p, PluginManager())
    spec = project.stages[0]
    from baarda.plugins.design.stage import DesignSource
    ctx = Context(stage_id="design", project_dir=tmp_path, project_file=p, object_unit="m",
                  option_lines=dict(spec.option_lines), stage_line=spec.line)
    with pytest.raises(InputError) as e:
        DesignSource().run({}, spec.options, ctx)
    return str(e.value)


def test_input_errors_name_file_line_field(tmp_path):
    st = (FIX / "stations.csv").read_text().splitlines()
    bad = "\n".join(st[:4] + [st[4].replace("1.600", "1.6x0", 1)] + st[5:])   # S2's row is line 5
    msg = _error(tmp_path, stations=bad.replace("1.131,3.200", "1.1x1,3.200", 1))
    assert "stations.csv:5" in msg and "field 'Y'" in msg and "expected a number" in msg
    tg = (FIX / "targets.csv").read_text().replace("T02,-0.5701,-0.7504,0.0365,tie", "T02,-0.5701,-0.7504,0.0365,pillar")
    msg = _error(tmp_path, targets=tg)
    assert "targets.csv:4" in msg and "field 'role'" in msg and "pillar" in msg
    far = (FIX / "targets.csv").read_text().replace("T02,-0.5701,-0.7504,0.0365", "T02,-0.5701,-9.7504,0.0365")
    msg = _error(tmp_path, targets=far)
    assert "targets.csv:4" in msg and "'T02' is seen from" in msg
    msg = _error(tmp_path, camera_extra='free = ["c", "K9"]')
    assert "p.toml:" in msg and "camera.free" in msg and "'K9'" in msg
    no_col = (FIX / "targets.csv").read_text().replace("id,X,Y,Z,role", "id,X,Y,role")
    assert "field 'Z'" in _error(tmp_path, targets=no_col)


def test_free_network_prediction_agrees_with_monte_carlo(planned):
    """Inner constraints: the predicted covariance is singular (rank q − 7 over the points); the
    joint test works in its range space."""
    block, _ = planned
    settings = BundleSettings(datum="free")
    pred = adjust(block, BundleSettings(datum="free", variance="a-priori"))
    free = np.flatnonzero(pred.point_used)
    N = 30
    errs = [realisation_errors(block, settings, np.random.default_rng(s)) for s in np.random.SeedSequence(3).spawn(N)]
    E = np.stack([e["XYZ"][free] for e in errs]).reshape(N, -1)
    _, C = parameter_covariance(pred, [f"point {i}" for i in block.points.ids[free]])
    jt = joint_test(E, C)
    assert jt["rank"] == E.shape[1] - 7
    assert jt["p"] > 1e-3, jt
    assert joint_test(E, C * 0.8 ** 2)["p"] < 1e-6


def test_montecarlo_needs_a_planned_network(tmp_path):
    from baarda.pipeline.testing import run_project_text

    text = (FIX / "design.toml").read_text().replace('use = "design"\n[stage.options]\n',
                                                      'use = "testfield"\n[stage.options]\n#')
    text = "\n".join(ln for ln in text.splitlines()
                     if not ln.startswith(("targets", "sigma_px", "sigma_control", "margin", "c_mm", "pixel_mm",
                                           "resolution", "ap_model", "free", "[stage.options.camera]")))
    out = run_project_text(text, tmp_path)
    assert not out.ok
    assert "design-montecarlo needs the bundle of a planned network" in out.message
