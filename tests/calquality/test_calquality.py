"""Calibration quality (pipeline/adjustment/calquality.py, plugins/calquality): the projection
uncertainty against Monte Carlo, the cross-validation's consistency on simulated calibrations,
the stage and the real chessboard / ChArUco projects."""

from __future__ import annotations

import json

import numpy as np
import pytest

from baarda.pipeline.adjustment import adjust, project_observations
from baarda.pipeline.adjustment import calquality as cq
from baarda.pipeline.geometry.rotations import rotation_from_opk_many
from baarda.pipeline.synthetic.closerange import make_block
from baarda.pipeline.testing import check_recording, check_stage, log_stage, run_stage
from baarda.plugins.calquality.stage import CalibrationQuality

NOISE = 0.001      # mm, the block's a-priori σ


def _block(seed_noise: int, n_photos=12, n_points=60):
    """The simulated convergent calibration (brown, K3 held at its true value: with 60 points the
    r⁶ term is not determinable and its extrapolation folds the corners of the format)."""
    block, truth = make_block(n_photos=n_photos, n_points=n_points, noise_mm=NOISE,
                              rng=np.random.default_rng(seed_noise))
    sa = block.cameras.sigma_ap.copy()
    sa[0, 2] = 0.0
    return block.replace(cameras=block.cameras.replace(sigma_ap=sa)), truth


@pytest.fixture(scope="module")
def calibration():
    block, truth = _block(5)
    return adjust(block), truth


def test_unproject_inverts_the_projection_and_jacobian_matches_the_bundle(calibration):
    res, _ = calibration
    cp = res.state.cam_params[0]
    _, _, xy = cq.format_grid((36.0, 24.0), 10)
    d = cq.unproject(xy, cp, "brown")
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0) and (d[:, 2] < 0).all()
    assert np.abs(cq.project_camera(3.0 * d, cp, "brown") - xy).max() < 1e-11
    # the finite-difference camera Jacobian against the bundle's analytic one (a photo at the
    # origin with ω = φ = κ = 0: camera frame = object frame)
    sig = np.sqrt(np.diag(res.cov_cameras[0]))
    J, _ = cq.projection_jacobians(xy, 3.0, cp, "brown", sigmas=sig)
    n = len(xy)
    pr = project_observations(np.zeros(n, int), np.arange(n), 3.0 * d, np.zeros((1, 3)), np.zeros((1, 3)),
                              np.zeros(1, int), cp[None], ["brown"], [{}], jacobians=True)
    free = sig > 0
    assert np.allclose(pr.xy, xy, atol=1e-11)
    assert np.allclose(J[:, :, free], pr.J_cam[:, :, free], rtol=1e-6, atol=1e-9 * np.abs(pr.J_cam).max())


def test_projection_sigma_against_sampling_the_covariance(calibration):
    """The brief's Monte Carlo: camera parameters and orientations drawn from their joint
    covariance, the fixed point re-projected through the perturbed frames, empirical σ."""
    res, _ = calibration
    rng = np.random.default_rng(11)
    dist = 3.0
    m = cq.projection_uncertainty(res, 0, dist, nx=8)
    photos = cq.camera_photos(res, 0)
    S = cq.joint_covariance(res, 0, photos)
    P = len(res.cam_param_names[0])
    cp = res.state.cam_params[0, :P]
    X0, opk = res.state.X0[photos], res.state.opk[photos]
    R = rotation_from_opk_many(opk)
    p = dist * cq.unproject(m.xy, cp, "brown")
    w, V = np.linalg.eigh(S)
    L = V * np.sqrt(np.clip(w, 0, None))
    qs = []
    for _ in range(3000):
        dx = L @ rng.standard_normal(len(w))
        cpk = cp + dx[:P]
        eo = np.column_stack([X0, opk]) + dx[P:].reshape(-1, 6)
        pk = cq._mean_pcam(p, X0, R, eo[:, :3], rotation_from_opk_many(eo[:, 3:]))
        qs.append(cq.project_camera(pk, cpk, "brown"))
    qs = np.array(qs)
    C = np.einsum("kni,knj->nij", qs - qs.mean(0), qs - qs.mean(0)) / (len(qs) - 1)
    ratio = cq.worst_sigma(C) / m.sigma.ravel()
    print(f"\nsampled / predicted σ: {ratio.min():.3f} … {ratio.max():.3f} (centre σ {m.at(0, 0) * 1e3:.3f} µm)")
    assert np.all(np.abs(ratio - 1) < 0.08)


def test_projection_sigma_against_repeated_calibrations():
    """The independent reference: 150 simulated calibrations with fresh image noise.  For each, the
    point on the true camera's ray at the distance is carried through the true and the estimated
    orientations (mean-pcam) and projected with the estimated camera; the empirical scatter
    against the predicted map, at the working distance and far away; camera-only likewise."""
    blocks = [_block(100 + k) for k in range(150)]
    truth = blocks[0][1]
    ref = adjust(blocks[0][0])
    cam_t = truth["cam"]
    R_t = rotation_from_opk_many(truth["opk"])
    states = [adjust(block).state for block, _ in blocks]
    for dist in (3.0, 30.0):
        _, _, xy = cq.format_grid((36.0, 24.0), 8)
        p = dist * cq.unproject(xy, cam_t, "brown")
        qs, qc = [], []
        for r in states:
            Rk = rotation_from_opk_many(r.opk)
            qs.append(cq.project_camera(cq._mean_pcam(p, truth["X0"], R_t, r.X0, Rk), r.cam_params[0], "brown"))
            qc.append(cq.project_camera(p, r.cam_params[0], "brown"))
        for name, q, frame in (("mean-pcam", np.array(qs), "mean-pcam"), ("camera", np.array(qc), "camera")):
            e = q - xy
            C = np.einsum("kni,knj->nij", e, e) / len(e)          # about the truth, not the mean
            m = cq.projection_uncertainty(ref, 0, dist, nx=8, frame=frame, format_mm=(36.0, 24.0))
            ratio = cq.worst_sigma(C) / m.sigma.ravel()
            print(f"\n{name} at {dist}: empirical / predicted σ median {np.median(ratio):.3f}, "
                  f"range {ratio.min():.3f} … {ratio.max():.3f}")
            # 150 realisations: the σ estimate's own spread is ≈ 6 %; σ̂0 of the reference ±9 %
            assert 0.8 < np.median(ratio) < 1.2
            assert np.all((ratio > 0.7) & (ratio < 1.35))
    # the pose term matters: at the working distance the mean-pcam σ at the centre is far below
    # the camera-only one (xp, yp trade off against the orientations)
    m3 = cq.projection_uncertainty(ref, 0, 3.0, nx=8)
    mc = cq.projection_uncertainty(ref, 0, 3.0, nx=8, frame="camera")
    assert m3.sigma.min() < 0.5 * mc.sigma.min()


def test_cross_validation_is_consistent_on_simulated_calibrations():
    """30 simulated calibrations, each split even/odd: the differences of the two halves' cameras
    follow the predicted covariance (mean Δqᵀ(Σ₁+Σ₂)⁻¹Δq ≈ 2, its χ²(2) expectation)."""
    m2, frac, ratio_rms, m2_fit, frac_fit = [], [], [], [], []
    for k in range(30):
        block, _ = _block(300 + k, n_photos=16, n_points=60)
        res = adjust(block)
        cv = cq.cross_validate(res, 0, split="even-odd", distance=3.0, nx=10)
        assert len(np.intersect1d(*cv.photos)) == 0 and len(cv.photos[0]) == len(cv.photos[1]) == 8
        m2.append(np.nanmean(cv.mahalanobis2))
        frac.append(cv.fraction_above_2sigma)
        ratio_rms.append(cv.rms / np.sqrt(np.nanmean(cv.sigma_pred ** 2)))
        m2_fit.append(np.nanmean(cv.mahalanobis2_fit))
        frac_fit.append(cv.fraction_above_2sigma_fit)
    print(f"\nmean Mahalanobis² {np.mean(m2):.2f} (2 expected), RMS |Δq| / RMS σ_pred {np.mean(ratio_rms):.2f}, "
          f"fraction beyond 2σ {np.mean(frac):.3f}; after the rotation fit: mean Mahalanobis² "
          f"{np.mean(m2_fit):.2f}, beyond 2σ {np.mean(frac_fit):.3f}")
    assert 1.5 < np.mean(m2_fit) < 2.6
    assert np.mean(frac_fit) < 0.2
    assert 1.5 < np.mean(m2) < 2.6
    assert 0.75 < np.mean(ratio_rms) < 1.25
    assert np.mean(frac) < 0.2


def test_cross_validation_detects_a_changed_camera():
    """A lens that changed between the halves (K1 + 5e-5 mm⁻², a quarter of its value, on the odd
    photos) is flagged: the differences exceed the prediction over most of the format.  (A change of
    c by 20 µm is not: c trades off against the orientations of a half, σ_pred ≈ 26 µm.)"""
    block, truth = _block(7, n_photos=16)
    obs = block.observations
    odd = obs.photo % 2 == 1
    cam2 = truth["cam"].copy()
    cam2[3] += 5e-5
    pr = project_observations(obs.photo[odd], obs.point[odd], truth["XYZ"], truth["X0"], truth["opk"], np.zeros(16, int), cam2[None],
            ["brown"], [{}], jacobians=False)
    xy = obs.xy.copy()
    xy[odd] = pr.xy + NOISE * np.random.default_rng(1).standard_normal(pr.xy.shape)
    block = block.replace(observations=obs.replace(xy=xy))
    cv = cq.cross_validate(adjust(block), 0, split="even-odd", distance=3.0, nx=10)
    assert cv.fraction_above_2sigma > 0.5
    assert cv.fraction_above_2sigma_fit > 0.5       # a change of K1 is no rotation
    assert np.nanmean(cv.mahalanobis2) > 6          # 9.0 here; 2 expected for an unchanged lens


def test_split_photos():
    a, b = cq.split_photos(np.arange(5), "even-odd")
    assert a.tolist() == [0, 2, 4] and b.tolist() == [1, 3]
    a, b = cq.split_photos(np.arange(5), "halves")
    assert a.tolist() == [0, 1, 2] and b.tolist() == [3, 4]
    with pytest.raises(ValueError, match="split"):
        cq.split_photos(np.arange(5), "thirds")


def test_stage(calibration, tmp_path):
    res, _ = calibration
    check_stage(CalibrationQuality)
    r = run_stage(CalibrationQuality, {"bundle": res}, {"grid": 12, "distance": 3.0}, tmp_path=tmp_path)
    s = r.summary["cameras"]["cam"]
    m = cq.projection_uncertainty(res, 0, 3.0, nx=12)
    assert s["unit"] == "µm"            # the simulated camera is film-like (no pixel pitch)
    assert s["sigma_centre"] == pytest.approx(1000 * m.at(0, 0))
    assert s["sigma_worst"] == pytest.approx(1000 * np.nanmax(m.sigma))
    assert "cross_validation" in s and 0 <= s["cross_validation"]["fraction_above_2sigma"] <= 1
    t = r.tables["map_cam"]
    assert len(t.columns["x_mm"]) == m.sigma.size
    json.dumps(r.summary)
    figs = CalibrationQuality().plots(r, None)
    assert list(figs) == ["uncertainty_cam"] and len(figs["uncertainty_cam"][0].axes) == 6 + 6   # maps + colour bars
    rec = check_recording(log_stage(CalibrationQuality, r, tmp_path / "quality.rrd"))
    assert rec is not None
    with pytest.raises(Exception, match="camera 'nope'"):
        run_stage(CalibrationQuality, {"bundle": res}, {"cameras": ["nope"]}, tmp_path=tmp_path)


# -- the real calibrations (fixtures/calibration) ------------------------------------------------
def _quality_of(project: str, tmp_path):
    from pathlib import Path

    from baarda.pipeline.runner import run_project

    from conftest import needs_shared_beside

    path = Path(__file__).resolve().parents[2] / "fixtures" / "calibration" / project
    if needs_shared_beside(path):
        pytest.skip("the OpenCV sample photos (../shared/data beside the repository) are absent")
    out = run_project(path, tmp_path / "run", verbose=False)
    assert out.ok, out.message
    res = json.loads((tmp_path / "run" / "results.json").read_text())
    st = {s["id"]: s for s in res["stages"]}["quality"]
    assert st["status"] == "ok"
    assert (tmp_path / "run" / "quality.rrd").exists()
    return st


def _check_camera(s, n_photos):
    assert s["unit"] == "px" and s["photos"] == n_photos
    assert 0 < s["sigma_centre"] < min(s["sigma_corners"]) <= s["sigma_worst"]
    assert s["sigma_centre"] < s["sigma_camera_only_centre"]      # the orientations' frame shift helps
    cv = s["cross_validation"]
    assert sum(cv["photos"]) == n_photos and cv["rms"] > 0 and 0 <= cv["fraction_above_2sigma"] <= 1


def test_charuco_project(tmp_path):
    st = _quality_of("charuco.toml", tmp_path)
    s = st["summary"]["cameras"]["cam"]
    _check_camera(s, 5)
    print(f"\nChArUco: σ centre {s['sigma_centre']:.3f} px, worst {s['sigma_worst']:.1f} px; "
          f"cross-validation {s['cross_validation']}")
    assert s["cross_validation"]["photos"] == [3, 2]


@pytest.mark.slow
def test_chessboard_project(tmp_path):
    st = _quality_of("chessboard.toml", tmp_path)
    for cam in ("left", "right"):
        s = st["summary"]["cameras"][cam]
        _check_camera(s, 13)
        print(f"\nchessboard {cam}: σ centre {s['sigma_centre']:.3f} px, corners {s['sigma_corners']}, "
              f"cross-validation RMS {s['cross_validation']['rms']:.2f} px vs predicted "
              f"{s['cross_validation']['sigma_pred_rms']:.2f} px, beyond 2σ "
              f"{s['cross_validation']['fraction_above_2sigma']:.2f}")
