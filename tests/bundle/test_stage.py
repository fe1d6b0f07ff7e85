"""The ``bundle`` stage: options, artefacts, tables, report, recording, blunder handling."""

import numpy as np
import pytest

from baarda.pipeline.testing import check_stage, log_stage, run_stage
from baarda.plugins.bundle.stage import BundleAdjustment

from baarda.pipeline.synthetic.closerange import make_block, perturb, with_correlated_noise


def test_stage_protocol():
    check_stage(BundleAdjustment, "bundle")


def test_stage_runs_and_logs(tmp_path):
    blk, truth = make_block(model="brown", n_photos=8, n_points=40, noise_mm=0.001,
                            rng=np.random.default_rng(5))
    res = run_stage(BundleAdjustment, {"block": perturb(blk, np.random.default_rng(1))},
                    {"tests": {"blunders": "data-snooping"}}, tmp_path=tmp_path)
    b = res.artefacts["bundle"]
    assert res.artefacts["adjustment"].snapshot.n == 2 * len(blk.observations)
    assert abs(b.sigma0_hat - 1) < 0.15
    t = res.tables["observations"]
    assert len(t) == len(blk.observations)
    assert {"vx_um", "wy", "mdb_x_um", "decision"} <= set(t.columns)
    assert "Camera parameters" in res.report
    path = log_stage(BundleAdjustment, res, tmp_path / "bundle.rrd")
    from baarda.pipeline.recording import read_recording

    rec = read_recording(path)
    ents = {e.path: e for e in rec.entities}
    for p in ("/bundle/world/points", "/bundle/world/photos/P1", "/bundle/images/P1/residuals",
              "/bundle/cameras/cam/distortion", "/bundle/convergence/cost/vtpv", "/bundle/summary"):
        assert p in ents, p
    assert "iteration" in ents["/bundle/convergence/cost/vtpv"].timelines
    from baarda.pipeline.recording import read_series

    assert len(read_series(path)["/bundle/convergence/cost/vtpv"]) == b.iterations + 1
    assert {"Transform3D", "Pinhole"} <= {c.split(":")[0] for c in ents["/bundle/world/photos/P1"].columns}


def test_ids_rejects_a_planted_blunder(tmp_path):
    blk, truth = make_block(model="none", n_photos=8, n_points=40, noise_mm=0.001, rng=np.random.default_rng(7))
    obs = blk.observations
    xy = obs.xy.copy()
    k = 37
    xy[k, 1] += 0.02                  # 20 σ in y
    bad = blk.replace(observations=obs.replace(xy=xy))
    res = run_stage(BundleAdjustment, {"block": bad}, {"tests": {"blunders": "ids"}}, tmp_path=tmp_path)
    dec = np.array(res.tables["observations"].columns["decision"])
    assert dec[k] == "rejected"
    assert (dec == "rejected").sum() == 1
    assert not res.artefacts["block"].observations.active[k]
    assert abs(res.artefacts["bundle"].sigma0_hat - 1) < 0.15
    # the recording: T with its F critical value (which fell with the dof) in one view, max |w| per
    # rejection; K, the same for the whole run, a static value
    from baarda.pipeline.recording import read_recording, read_series

    path = log_stage(BundleAdjustment, res, tmp_path / "bundle.rrd")
    series = read_series(path)
    ids = res.data["report"].ids
    np.testing.assert_allclose(series["/bundle/ids/global_test/T"], [h.T for h in ids.history])
    np.testing.assert_allclose(series["/bundle/ids/global_test/F_critical"], [h.critical for h in ids.history])
    assert len(series["/bundle/ids/w/w_max"]) == 2 and "/bundle/ids/w/K" not in series
    rec = read_recording(path)
    assert "K" in {e.path: e for e in rec.entities}["/bundle/ids/w/constants"].columns
    assert {"/bundle/ids/global_test", "/bundle/ids/w"} <= {v.origin for v in rec.views if v.kind == "TimeSeries"}


def test_joint_2d_test_per_image_point_against_closed_form(tmp_path):
    """T2d of every image point equals v_gᵀ (Qvv)_gg⁻¹ v_g / σ0² from a dense reference (normal
    matrix of finite-difference Jacobians; with P block-diagonal per point this is Förstner's
    (Pv)ᵀ(PQvvP)⁻¹(Pv)); the critical value is χ²(1 − α; 2) = −2 ln α; a point displaced in x and y
    is flagged and the report counts it."""
    from adjustment.test_precision import _dense_reference

    blk, _ = make_block(model="none", n_photos=5, n_points=14, noise_mm=0.0, n_control=5)
    blk = with_correlated_noise(blk, np.random.default_rng(11), sigma=(0.8e-3, 1.5e-3), rho=0.6)
    obs = blk.observations
    xy = obs.xy.copy()
    k_bad = 23
    xy[k_bad] += [0.008, -0.008]                           # ≈ 6 σ in both coordinates
    blk = blk.replace(observations=obs.replace(xy=xy))
    out = run_stage(BundleAdjustment, {"block": blk}, {"tests": {"blunders": "data-snooping", "alpha0": 0.001}},
                    tmp_path=tmp_path)
    res = out.artefacts["bundle"]
    unknowns, A, P, N = _dense_reference(res)
    Qvv = np.linalg.inv(P) - A @ np.linalg.inv(N) @ A.T
    oi = np.flatnonzero(res.obs_active)
    T_ref = np.empty(len(oi))
    for r, k in enumerate(oi):
        v = res.residuals[k]
        T_ref[r] = v @ np.linalg.solve(Qvv[2 * r:2 * r + 2, 2 * r:2 * r + 2], v) / res.sigma0 ** 2
    t = out.tables["observations"].columns
    T = np.asarray(t["T2d"], float)[oi]
    assert np.allclose(T, T_ref, rtol=1e-4)
    crit = -2 * np.log(0.001)
    assert np.allclose(np.asarray(t["T2d_critical"], float)[oi], crit, rtol=1e-12)
    flagged = np.asarray(t["T2d_flagged"], bool)
    assert np.array_equal(flagged[oi], T_ref > crit)
    assert flagged[k_bad] and T_ref[list(oi).index(k_bad)] > 3 * crit
    n = int((T_ref > crit).sum())
    assert f"T > {crit:.3f} (α = 0.001) at {n} of {len(oi)} image points" in out.report
    assert out.summary["joint_test"]["n_flagged"] == n


def test_joint_2d_test_false_alarm_rate_monte_carlo():
    """Under H0 the 2-D statistic is χ²(2): over 40 noisy realisations of a small block the share of
    image points with T > χ²(0.9; 2) = 4.605 is 10 % ± 4 binomial σ, and the mean of T is 2."""
    from baarda.pipeline import stats
    from baarda.pipeline.adjustment import adjust

    blk, _ = make_block(model="none", n_photos=5, n_points=20, noise_mm=0.0, n_control=5)
    obs = blk.observations
    rng = np.random.default_rng(21)
    Ts = []
    start = None
    for _ in range(40):
        noisy = blk.replace(observations=obs.replace(xy=obs.xy + 0.001 * rng.standard_normal(obs.xy.shape)))
        res = adjust(noisy, start=start)
        start = start or res.state
        Ts.append(stats.joint_test_2d(res.snapshot, alpha=0.1).T)
    T = np.concatenate(Ts)
    share = np.mean(T > -2 * np.log(0.1))
    assert abs(share - 0.1) < 4 * np.sqrt(0.1 * 0.9 / T.size)
    assert abs(T.mean() - 2.0) < 4 * 2.0 / np.sqrt(T.size)


def test_non_convergence_saves_the_last_state(tmp_path):
    """max_iter = 1 on the simulated test field: the run fails with a message naming the saved files,
    which hold the last iterate (10 photos, 21 points, 3 + 12 camera parameters)."""
    import csv

    from baarda.pipeline.testing import make_plugin_manager, run_project_text
    from baarda.plugins.testfield.source import TestFieldSource

    text = """
[project]
name = "no convergence"
seed = 1990
object_unit = "m"

[[stage]]
use = "testfield"
id = "source"
[stage.options]
case = 5
sigma_image_um = 40.0
ap_model = "ebner12"

[[stage]]
use = "bundle"
[stage.options]
solver.max_iter = 1
"""
    pm = make_plugin_manager({"testfield": TestFieldSource, "bundle": BundleAdjustment})
    outcome = run_project_text(text, tmp_path, plugins=pm)
    assert not outcome.ok
    assert "no convergence after 1 iterations" in outcome.message
    run = tmp_path / "run"
    assert f"the last state is saved in {run}: bundle_last_eo.csv, bundle_last_points.csv, " \
           "bundle_last_cameras.csv" in outcome.message
    rows = {}
    for name in ("eo", "points", "cameras"):
        with open(run / f"bundle_last_{name}.csv", newline="") as fh:
            rows[name] = list(csv.DictReader(fh))
    assert len(rows["eo"]) == 10 and len(rows["points"]) == 21 and len(rows["cameras"]) == 15
    assert [r["parameter"] for r in rows["cameras"]][:4] == ["c", "xp", "yp", "b1"]
    # the last iterate, not the start: one Gauss–Newton step moved the approximate orientations
    block = outcome.artefacts["block"]
    X0 = np.array([[float(r[k]) for k in ("X0_m", "Y0_m", "Z0_m")] for r in rows["eo"]])
    moved = np.abs(X0 - block.photos.X0).max()
    assert 1e-4 < moved < 0.1
    assert np.isfinite([float(r["X_m"]) for r in rows["points"]]).all()


def test_sigma_eo_and_image_sigma_scale_options():
    from baarda.pipeline.options import parse_options
    from baarda.pipeline.adjustment import BundleConfig, configure_block

    blk, _ = make_block(model="none", n_photos=4, n_points=20)
    ph = blk.photos
    blk = blk.replace(photos=ph.replace(X0=np.where(np.arange(4)[:, None] == 2, np.nan, ph.X0)))
    o = parse_options(BundleConfig, {"sigma_eo": [0.01, 0.01, 0.02, 0.5, 0.5, 1.0], "sigma_image_scale": 2.0},
                      path="<test>")
    out = configure_block(blk, o)
    se = out.photos.sigma_eo
    assert np.allclose(se[[0, 1, 3]], [0.01, 0.01, 0.02, np.pi / 360, np.pi / 360, np.pi / 180])
    assert np.isinf(se[2]).all()                       # no orientation given: stays free
    assert np.allclose(out.observations.cov, 4 * blk.observations.cov)
    for bad in ({"sigma_eo": [0.01, 0.01]}, {"sigma_eo": [0.01] * 5 + [-1]}, {"sigma_image_scale": 0.0}):
        with pytest.raises(Exception, match="sigma_eo|sigma_image_scale"):
            parse_options(BundleConfig, bad, path="<test>")


def test_ids_until_no_w_exceeds_the_critical_value(tmp_path):
    """Three planted blunders: Kok's IDS stops once the global test accepts; ids_stop = 'w-test'
    goes on until no |w| > 3.29 and rejects all three (and the report lists them)."""
    blk, _ = make_block(model="none", n_photos=8, n_points=40, noise_mm=0.001, rng=np.random.default_rng(7))
    obs = blk.observations
    xy = obs.xy.copy()
    bad = {37: (1, 0.02), 90: (0, 0.007), 150: (1, -0.0065)}   # 20 σ, 7 σ, 6.5 σ
    for k, (c, e) in bad.items():
        xy[k, c] += e
    blk = blk.replace(observations=obs.replace(xy=xy))
    kok = run_stage(BundleAdjustment, {"block": blk}, {"tests": {"blunders": "ids"}}, tmp_path=tmp_path)
    full = run_stage(BundleAdjustment, {"block": blk}, {"tests": {"blunders": "ids", "ids_stop": "w-test"}},
                     tmp_path=tmp_path)
    rej = lambda r: set(np.flatnonzero(np.array(r.tables["observations"].columns["decision"]) == "rejected"))
    assert rej(full) == set(bad)
    assert rej(kok) < set(bad)
    ids = full.data["report"].ids
    assert [i // 2 for i in ids.removed] == [37, 90, 150]
    assert "no |w| above K" in ids.stop_reason
    assert "3 coordinate(s) rejected" in full.report and "| 3 | photo" in full.report
    assert full.summary["data_snooping"]["n_flagged"] == 0


def test_testfield_fixture_selects_aps_by_the_papers_rule(repo_root, tmp_path):
    """fixtures/testfield/block.toml runs the bundle with the AP selection: 12 + 0 parameters in,
    every kept AP significant by a Student t-test on the final adjustment's dof (scipy), no pair of
    kept camera parameters correlated above 0.75, and the removed ones fixed at 0."""
    from scipy import stats as sps

    from baarda.pipeline.runner import run_project

    out = run_project(repo_root / "fixtures/testfield/block.toml", tmp_path / "run", verbose=False)
    assert out.ok, out.message
    b = out.artefacts["bundle"]
    sel = next(s for s in out.stages if s.use == "bundle").summary["ap_selection"]
    kept = [k.split(":")[1] for k in sel["kept"]]
    removed = [k.split(":")[1] for k in sel["removed"]]
    assert sorted(kept + removed, key=lambda n: int(n[1:])) == [f"b{i}" for i in range(1, 13)]
    assert kept
    table = {r["parameter"]: r for r in b.camera_table(0)}
    t_crit = sps.t.isf(0.025, b.dof)
    for name in kept:
        assert abs(table[name]["value"] / table[name]["sigma"]) > t_crit, name
    for name in removed:
        assert table[name]["value"] == 0.0 and table[name]["status"] == "fixed"
    names = b.cam_param_names[0]
    idx = [names.index(n) for n in kept]
    cov = b.cov_cameras[0][np.ix_(idx, idx)]
    rho = cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    assert np.abs(rho[~np.eye(len(idx), dtype=bool)]).max(initial=0) <= 0.75
    assert (tmp_path / "run" / "bundle_observations.csv").exists()


def test_no_distortion_view_for_a_camera_without_distortion(tmp_path):
    """APs held at zero (sxb's historical camera): the recording has no empty distortion view."""
    blk, _ = make_block(model="brown", n_photos=8, n_points=40, noise_mm=0.001, rng=np.random.default_rng(5))
    cams = blk.cameras.replace(ap=np.zeros_like(blk.cameras.ap))
    blk = blk.replace(cameras=cams)
    res = run_stage(BundleAdjustment, {"block": perturb(blk, np.random.default_rng(1))}, {"aps": "fixed"},
                    tmp_path=tmp_path)
    from baarda.pipeline.recording import read_recording

    rec = read_recording(log_stage(BundleAdjustment, res, tmp_path / "bundle.rrd"))
    paths = {e.path for e in rec.entities}
    assert "/bundle/images/P1/residuals" in paths
    assert not any(p.startswith("/bundle/cameras/") for p in paths)
    assert not any(v.origin.startswith("/bundle/cameras/") for v in rec.views)
