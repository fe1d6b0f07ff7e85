"""pycolmap cross-check: baarda's bundle against an independent implementation (pycolmap/Ceres).

The reference is pycolmap's own bundle adjustment on the same data: its camera models, its
rotation parametrisation, its solver.  When the problems are equivalent the two optima must
agree to rounding (required here: 1e-6 of the object size on points, 1e-4 px on residuals); the
brown ↔ OPENCV parameter mapping is checked against the formulas of docs/crosscheck.md, and
pycolmap's covariance (σ = 1 px) scaled by σ̂0² must equal baarda's.
"""

from __future__ import annotations

import copy

import numpy as np
import pycolmap
import pytest
from scipy.spatial.transform import Rotation

from baarda.pipeline.recording import read_recording
from baarda.pipeline.testing import check_stage, log_stage, run_stage
from baarda.plugins.bal.bal import bal_reprojection, block_from_bal, read_bal
from baarda.pipeline.adjustment import BundleSettings, adjust
from baarda.pipeline.colmap.writer import reconstruction_from_block
from baarda.pipeline.synthetic.aerial import perturb_start, simulate_convergent
from baarda.plugins.crosscheck import CrossCheckError, SolverSettings, Tolerances, crosscheck, exceeded
from baarda.plugins.crosscheck.stage import PycolmapCrossCheck

PIXEL = 0.004   # mm, the simulated camera's pixel


def _block(model, free, seed=3, **kw):
    rng = np.random.default_rng(seed)
    noisy, exact = simulate_convergent(rng, n_photos=10, n_points=150, model=model, free_intrinsics=free,
                                       noise_px=0.5, n_control=8, **kw)
    start = perturb_start(noisy, rng, position=0.15, angle=0.01, point=0.1, c=0.05 if "c" in free else 0.0,
                          zero_distortion=True)
    return start, exact


@pytest.fixture(scope="module")
def pinhole():
    start, exact = _block("none", ("c", "xp", "yp"))
    return start, exact, adjust(start, BundleSettings())


@pytest.fixture(scope="module")
def brown():
    start, exact = _block("brown", ("K1", "K2", "P1", "P2"), seed=4)
    return start, exact, adjust(start, BundleSettings())


def test_stage_protocol():
    check_stage(PycolmapCrossCheck)


def test_simulated_block_is_what_it_claims(pinhole):
    start, exact, res = pinhole
    assert len(start.photos) == 10 and len(start.points) >= 100
    assert (start.points.role == "full").sum() == 8
    # the noise: baarda's σ̂0 with σ = noise is 1 within its sampling error (dof ≈ 2 500)
    assert abs(res.sigma0_hat - 1.0) < 0.05
    # and the solution is near the truth (a few cm on a 12 m object)
    assert np.max(np.abs(res.state.XYZ - exact.points.XYZ)) < 0.02


@pytest.mark.parametrize("case", ["pinhole", "brown"])
@pytest.mark.parametrize("start", ["initial", "perturbed"])
def test_equivalent_models_agree(case, start, request, tmp_path):
    block, _, res = request.getfixturevalue(case)
    out = run_stage(PycolmapCrossCheck, {"block": block, "bundle": res}, {"start": start}, tmp_path=tmp_path)
    s = out.summary
    q = s["quantities"]
    assert s["equivalent"] and s["covariance_comparable"] and s["passed"]
    size = s["object_size"]
    assert 10 < size < 15
    assert q["points"]["n"] == 142 and q["points"]["max"] < 1e-6 * size
    assert q["centres"]["n"] == 10 and q["centres"]["max"] < 1e-6 * size
    assert q["angles"]["max"] < 1e-7
    assert q["residuals"]["n"] == len(block.observations) and q["residuals"]["max"] < 1e-4
    assert q["cost"]["max"] < 1e-10
    # cost: pycolmap's ½Σ r² in its pixels (= σ) is baarda's ½ vᵀPv (σ0 = 1)
    assert q["cost"]["pycolmap"] == pytest.approx(res.vtpv / 2, rel=1e-10)
    assert q["intrinsics"]["n"] == (3 if case == "pinhole" else 4) and q["intrinsics"]["max"] < 1e-4
    # pycolmap's covariance × σ̂0² = baarda's a-posteriori covariance (poses and camera)
    assert q["covariance_poses"]["n"] == 60 and q["covariance_poses"]["max"] < 1e-4
    assert q["covariance_intrinsics"]["max"] < 1e-4
    assert s["pycolmap"]["termination"] == "CONVERGENCE"
    if start == "initial":   # pycolmap started where baarda started
        assert q["cost"]["pycolmap_initial"] == pytest.approx(res.history[0].vtpv / 2, rel=1e-9)


def test_parameter_mapping(brown):
    """OPENCV k1 = K1 c², k2 = K2 c⁴, p1 = −P2 c, p2 = P1 c (normalized), f = c / pixel."""
    block, _, res = brown
    cc = crosscheck(res)
    plan = cc.plan
    assert plan.cameras[0].colmap_model == "OPENCV" and plan.cameras[0].mode == "refine"
    assert plan.refine == {"focal": False, "principal_point": False, "extra": True}
    c = res.state.cam_params[0, 0]
    K1, K2, K3, P1, P2, B1, B2 = res.block.cameras.ap[0]
    fx, fy, cx, cy, k1, k2, p1, p2 = cc.solution.cam[0]["params"]
    sigma = plan.sigma_mm[0]
    assert sigma == pytest.approx(0.5 * PIXEL)                # pycolmap's pixel = a-priori σ
    assert fx == pytest.approx(c / sigma, rel=1e-12) and fy == pytest.approx(c / sigma, rel=1e-12)
    assert k1 == pytest.approx(K1 * c**2, rel=1e-7)
    assert k2 == pytest.approx(K2 * c**4, rel=1e-7)
    assert p1 == pytest.approx(-P2 * c, rel=1e-7)
    assert p2 == pytest.approx(P1 * c, rel=1e-7)
    # principal point: xp = (cx − W/2) σ, yp = −(cy − H/2) σ (COLMAP's pixel convention, y down)
    W, H = cc.solution.extra["size"][0]
    assert (cx - W / 2) * sigma == pytest.approx(res.state.cam_params[0, 1], abs=1e-12)
    assert -(cy - H / 2) * sigma == pytest.approx(res.state.cam_params[0, 2], abs=1e-12)


def test_exceeded_tolerance_fails_the_stage(pinhole, tmp_path):
    """A wrong bundle solution (one point moved by 5 mm) is caught, with the numbers."""
    block, _, res = pinhole
    bad = copy.copy(res)
    bad.state = res.state.copy()
    j = int(np.flatnonzero(res.problem.point_used & (res.block_in.points.role == "tie"))[0])
    bad.state.XYZ[j] += [0.005, 0.0, 0.0]
    with pytest.raises(CrossCheckError) as e:
        run_stage(PycolmapCrossCheck, {"block": block, "bundle": bad}, {}, tmp_path=tmp_path)
    msg = str(e.value)
    assert "object points: max 0.005" in msg and "of the object size" in msg and "tolerance 1e-06" in msg
    assert any(f.startswith("object points") for f in e.value.failures)
    # a user tolerance above the difference lets it pass; 'warn' turns the failure into warnings
    ok = run_stage(PycolmapCrossCheck, {"block": block, "bundle": bad},
                   {"tol_points": 1e-3, "tol_residuals_px": 10.0, "tol_cost": 1.0, "tol_intrinsics": 10.0,
                    "tol_angles": 1e-3, "tol_covariance": 1.0}, tmp_path=tmp_path)
    assert ok.summary["passed"]
    assert ok.summary["headline"].startswith("baarda and pycolmap agree within the tolerances: object points max 0.005 m")
    warn = run_stage(PycolmapCrossCheck, {"block": block, "bundle": bad}, {"on_exceed": "warn"}, tmp_path=tmp_path)
    assert not warn.summary["passed"] and any("object points" in w for w in warn.warnings)
    assert warn.summary["headline"].startswith("baarda and pycolmap differ beyond the tolerances")


def test_held_parameters_keep_the_optimum():
    """Weighted control and a free network cannot be expressed in pycolmap; holding them at baarda's
    adjusted values leaves the optimum of everything else unchanged."""
    start, _ = _block("none", ("c", "xp", "yp"), seed=5)
    pts = start.points
    sig = pts.sigma.copy()
    sig[pts.role == "full"] = 0.005                       # weighted control, 5 mm
    res = adjust(start.replace(points=pts.replace(sigma=sig)), BundleSettings())
    cc = crosscheck(res)
    assert cc.plan.exact and cc.plan.point_held.sum() == 8 and not cc.plan.covariance_comparable
    assert exceeded(cc, Tolerances()) == []
    assert cc.quantities["points"]["relative"] < 1e-8
    # free network: tie points only, inner constraints; two photos hold the gauge in pycolmap
    ties = start.replace(points=pts.replace(role=np.array(["tie"] * len(pts)), sigma=np.full((len(pts), 3), np.inf)))
    res = adjust(ties, BundleSettings(datum="free"))
    cc = crosscheck(res)
    assert cc.plan.exact and cc.plan.photo_held.sum() == 2
    assert exceeded(cc, Tolerances()) == []
    assert cc.quantities["residuals"]["max"] < 1e-4
    # free network *with* fixed control is over-constrained in baarda: reported, not compared
    res = adjust(start, BundleSettings(datum="free"))
    cc = crosscheck(res)
    assert not cc.plan.exact and any("inner constraints" in n for n in cc.notes)
    assert cc.quantities["cost"]["pycolmap"] < cc.quantities["cost"]["baarda"]


def test_not_equivalent_model_is_reported(tmp_path):
    """Ebner's set has no COLMAP model: the observations are corrected by baarda's distortion and
    the comparison is first-order (reported, not enforced); require_equivalent fails."""
    start, _ = _block("brown", ("c", "xp", "yp"), seed=6)
    cams = start.cameras.replace(ap_model=np.array(["ebner12"]), ap=np.zeros((1, 12)),
                                 sigma_ap=np.full((1, 12), np.inf))
    blk = start.replace(cameras=cams, ap_meta={"cam": {"b": 8.0}})
    res = adjust(blk, BundleSettings())
    out = run_stage(PycolmapCrossCheck, {"block": blk, "bundle": res}, {}, tmp_path=tmp_path)
    s = out.summary
    assert not s["equivalent"] and s["passed"]
    assert s["headline"].startswith("not an equivalent problem for pycolmap")
    assert s["cameras"][0]["mode"] == "corrected"
    assert any("ebner12" in n and "no COLMAP counterpart" in n for n in s["notes"])
    # first order: the distortion's slope times the residuals — far below the noise, not rounding
    assert s["quantities"]["residuals"]["max"] < 0.05
    assert s["quantities"]["points"]["relative"] < 1e-4
    with pytest.raises(CrossCheckError, match="cannot reproduce this adjustment exactly"):
        run_stage(PycolmapCrossCheck, {"block": blk, "bundle": res}, {"require_equivalent": True}, tmp_path=tmp_path)


def test_free_focal_with_distortion_holds_intrinsics(tmp_path):
    """c free together with K1…P2: OPENCV would free fx and fy separately (not brown) — the
    camera is held at baarda's values, poses and points must still agree exactly."""
    start, _ = _block("brown", ("c", "xp", "yp", "K1", "K2", "P1", "P2"), seed=7)
    res = adjust(start, BundleSettings())
    cc = crosscheck(res)
    assert cc.plan.cameras[0].mode == "constant" and cc.plan.cameras[0].colmap_model == "OPENCV"
    assert cc.plan.exact and not cc.plan.covariance_comparable
    assert exceeded(cc, Tolerances()) == []
    assert cc.quantities["intrinsics"]["n"] == 0


def test_unequal_weights_are_not_equivalent():
    start, _ = _block("none", ("c", "xp", "yp"), seed=8)
    obs = start.observations
    sig = np.full(len(obs), 0.5 * PIXEL)
    sig[::3] *= 2.0
    blk = start.replace(observations=obs.replace(cov=np.einsum("k,ij->kij", sig**2, np.eye(2))))
    cc = crosscheck(adjust(blk, BundleSettings()))
    assert not cc.plan.weights_equivalent and not cc.plan.exact
    assert any("not weighted σ² I" in n for n in cc.notes)


def test_recording(pinhole, tmp_path):
    block, _, res = pinhole
    out = run_stage(PycolmapCrossCheck, {"block": block, "bundle": res}, {}, tmp_path=tmp_path)
    summary = read_recording(log_stage(PycolmapCrossCheck, out, tmp_path / "crosscheck.rrd"))
    paths = {e.path: e for e in summary.entities}
    for p in ("/crosscheck/baarda/points", "/crosscheck/pycolmap/points", "/crosscheck/baarda/centres",
              "/crosscheck/pycolmap/centres"):
        assert any(c.startswith("Points3D:positions") for c in paths[p].columns)
    for p in ("/crosscheck/differences/points", "/crosscheck/differences/centres"):
        assert any(c.startswith("Arrows3D:vectors") for c in paths[p].columns)
    assert "/crosscheck/report" in paths


def test_bal_real_data(shared_data):
    """Real data (BAL ladybug, 1 800-point subset): RADIAL (f, k1, k2 per camera), free network.

    The file has 31 observations of points behind their camera: COLMAP gives them a zero
    residual (its initial cost is BAL's minus exactly their share), so the problems differ until
    they are switched off — then the optima agree."""
    path = shared_data / "bal" / "bal-ladybug-problem-49-7776-pre-shrink-1800.txt"
    if not path.exists():
        pytest.skip(f"{path} not found")
    problem = read_bal(path)
    blk = block_from_bal(problem)
    settings = BundleSettings(datum="free", max_iter=200, covariance=False)
    solver = SolverSettings(covariance=False)
    cc = crosscheck(adjust(blk, settings), solver=solver)
    assert not cc.plan.exact and cc.plan.behind.sum() == 31
    assert any("behind their camera" in n for n in cc.notes)
    # pycolmap's initial cost = ½Σ of BAL's own residuals (px) without the 31 — COLMAP's rule
    P = problem.cameras[problem.cam]
    R = Rotation.from_rotvec(P[:, :3]).as_matrix()
    depth = np.einsum("kij,kj->ki", R, problem.points[problem.pt])[:, 2] + P[:, 5]
    v = bal_reprojection(problem)
    front = depth < 0
    assert (~front).sum() == 31
    rec, _ = reconstruction_from_block(blk.replace(cameras=blk.cameras.replace(resolution=np.full((49, 2), 2000))),
                                       camera_model="RADIAL")
    opts = pycolmap.BundleAdjustmentOptions()
    opts.print_summary = False
    opts.ceres.solver_options.max_num_iterations = 1
    config = pycolmap.BundleAdjustmentConfig()
    for i in rec.images:
        config.add_image(i)
    initial = pycolmap.create_default_ceres_bundle_adjuster(opts, config, rec).solve().ceres_summary.initial_cost
    assert initial == pytest.approx(0.5 * np.sum(v[front] ** 2), rel=1e-9)

    blk = blk.replace(observations=blk.observations.replace(active=front))
    res = adjust(blk, settings)
    cc = crosscheck(res, solver=solver)
    assert cc.plan.exact
    assert all(p.colmap_model == "RADIAL" and p.mode == "refine" for p in cc.plan.cameras)
    assert cc.plan.refine == {"focal": True, "principal_point": False, "extra": True}
    q = cc.quantities
    assert q["cost"]["max"] < 1e-8
    assert q["residuals"]["max"] < 1e-4
    assert q["points"]["relative"] < 1e-6 and q["centres"]["relative"] < 1e-6
