"""GNSS antenna positions (``gnss-centres``) on a simulated aerial block (pipeline.synthetic.simulate_aerial),
against truth.

The block is placed in UTM 22S (a local frame at 49.4° W, 25.6° S); GNSS antenna positions are the
true centres plus a lever arm rotated by the true attitude plus 5 cm noise, written as a CSV in
EPSG:32722.  Only the four corner control points are kept.  The stage puts the antennas into the
block as observations; one bundle adjusts them with the lever arm.  The adjusted centres and points
must agree with truth within their predicted σ (normalised errors ``dᵀ C⁻¹ d`` ~ χ²(3)).
"""

from __future__ import annotations

import numpy as np
import pytest

from baarda.pipeline.adjustment import BundleSettings, adjust
from baarda.pipeline.crs import LocalFrame, local_frame
from baarda.pipeline.geometry import rotation_from_opk_many
from baarda.pipeline.synthetic.aerial import simulate_aerial
from baarda.pipeline.testing import run_stage
from baarda.plugins.gcp.stage import GnssCentres

ARM = np.array([0.12, -0.05, 0.25])      # antenna in the camera frame (m)


def _scene(seed=3):
    rng = np.random.default_rng(seed)
    noisy, exact = simulate_aerial(rng, n_strips=3, photos_per_strip=8, height=100.0, points_per_photo=60,
                                   control_spacing=100, noise_px=0.5)
    frame = local_frame("EPSG:32722", [[658550.0, 7166980.0, 890.0]])
    pts = noisy.points
    # keep the block-corner control points only (4), everything else a tie point
    role = np.where(pts.role == "full", "full", "tie")
    sigma = np.where((role == "full")[:, None], np.full((len(role), 3), 0.01), np.inf)
    # the control is surveyed with σ 1 cm: its given coordinates carry that error
    XYZ = np.where((role == "full")[:, None], pts.XYZ + rng.normal(0, 0.01, pts.XYZ.shape), pts.XYZ)
    noisy = noisy.replace(points=pts.replace(role=role, sigma=sigma, XYZ=XYZ), crs=frame.info())
    # start from nothing: no orientation, tie points unknown
    noisy = noisy.replace(photos=noisy.photos.replace(X0=np.full_like(noisy.photos.X0, np.nan),
                                                      opk=np.full_like(noisy.photos.opk, np.nan)),
                          points=noisy.points.replace(XYZ=np.where((role == "full")[:, None], noisy.points.XYZ, np.nan)))
    return noisy, exact, frame, rng


def _gnss_csv(tmp_path, exact, frame, rng, sigma=0.05):
    R = rotation_from_opk_many(exact.photos.opk)
    antenna = exact.photos.X0 + np.einsum("kji,j->ki", R, ARM)
    antenna_noisy = antenna + rng.normal(0, sigma, antenna.shape)
    utm = frame.from_local(antenna_noisy)
    lines = ["# crs: EPSG:32722", "photo,E,N,h,sigma"]
    lines += [f"{p},{e:.4f},{n:.4f},{h:.4f},{sigma}" for p, (e, n, h) in zip(exact.photos.ids, utm)]
    path = tmp_path / "gnss.csv"
    path.write_text("\n".join(lines) + "\n")
    return path


def _normalised(est, truth, cov):
    d = est - truth
    return np.array([d[k] @ np.linalg.solve(cov[k], d[k]) for k in range(len(d))])


def test_gnss_centres_with_lever_arm_against_truth(tmp_path):
    noisy, exact, frame, rng = _scene()
    csv = _gnss_csv(tmp_path, exact, frame, rng)
    opts = {"path": str(csv), "lever_arm": {"cam": ARM.tolist()}, "opk_deg": [0.0, 0.0, 0.0]}
    # one pass: the antennas are observations of the bundle (no reduction with a fixed attitude)
    out = run_stage(GnssCentres, {"block": noisy}, opts, tmp_path=tmp_path)
    blk = out.artefacts["block"]
    gn = blk.gnss
    assert len(gn) == len(blk.photos) and np.allclose(gn.lever_arm, ARM) and np.allclose(gn.sigma, 0.05)
    # the antennas in the local frame: truth + Rᵀ·arm + noise (UTM → local round trip)
    R = rotation_from_opk_many(exact.photos.opk)
    assert np.abs(gn.XYZ - exact.photos.X0 - np.einsum("kji,j->ki", R, ARM)).max() < 0.25
    # initial values only: the photos start at the antennas reduced with the nadir attitude
    assert np.allclose(blk.photos.opk, 0.0) and np.isinf(blk.photos.sigma_eo).all()
    assert out.summary["initial_centres"] == len(blk.photos) and not out.warnings
    assert out.summary["headline"] == (f"{len(blk.photos)} photo(s) with GNSS antennas from {csv.name} (EPSG:32722): "
                                       "σ E/N/h median 50/50/50 mm, range 50–50 mm; lever arm camera cam "
                                       f"({', '.join(f'{x:g}' for x in ARM)}) m")
    assert "antennas" in out.tables
    res = adjust(blk, BundleSettings())
    ok_pts = exact.points.role == "tie"
    q_pts = _normalised(res.block.points.XYZ[ok_pts], exact.points.XYZ[ok_pts], res.cov_points[ok_pts])
    q_ph = _normalised(res.block.photos.X0, exact.photos.X0, res.cov_eo[:, :3, :3])
    # χ²(3) per point: mean 3, 99.99 % quantile 21.1.  The errors of one block are correlated (one
    # datum), so one realisation's mean scatters (the Monte Carlo test below averages 20 blocks)
    assert 1.2 < q_pts.mean() < 5.0, q_pts.mean()
    assert q_pts.max() < 30.0
    assert 1.0 < q_ph.mean() < 5.0, q_ph.mean()
    assert q_ph.max() < 30.0
    # without the lever arm the centres are off by |ARM| ≈ 29 cm: far outside their σ
    blk_bad = run_stage(GnssCentres, {"block": noisy}, {"path": str(csv), "opk_deg": [0, 0, 0]},
                        tmp_path=tmp_path).artefacts["block"]
    bad = adjust(blk_bad, BundleSettings())
    q_bad = _normalised(bad.block.photos.X0, exact.photos.X0, bad.cov_eo[:, :3, :3])
    assert q_bad.mean() > 10 * q_ph.mean()
    # the GNSS antennas carry the datum: adjusted centres within a few cm of truth
    err = np.linalg.norm(res.block.photos.X0 - exact.photos.X0, axis=1)
    print(f"GNSS test: centres RMS error {np.sqrt(np.mean(err ** 2)) * 1000:.1f} mm, "
          f"mean q points {q_pts.mean():.2f} (χ²(3): 3), mean q centres {q_ph.mean():.2f}, "
          f"without lever arm {q_bad.mean():.1f}")
    assert np.sqrt(np.mean(err ** 2)) < 0.05
    # a second gnss-centres stage replaces the antennas of the photos it names and keeps the others
    two = run_stage(GnssCentres, {"block": res.block}, opts, tmp_path=tmp_path).artefacts["block"]
    assert len(two.gnss) == len(gn) and two.summary()["gnss_antennas"] == len(gn)
    assert np.array_equal(two.photos.X0, res.block.photos.X0)     # adjusted centres are not replaced


def test_bundle_stage_reports_the_antennas(tmp_path):
    """The bundle stage's GNSS section and table: per photo the antenna residuals, r, w; a 1 m
    blunder on one antenna height is flagged."""
    from baarda.plugins.bundle.stage import BundleAdjustment

    noisy, exact, frame, rng = _scene(5)
    csv = _gnss_csv(tmp_path, exact, frame, rng)
    text = csv.read_text().splitlines()
    e, n, h, s = text[2 + 7].split(",")[1:]
    text[2 + 7] = ",".join([text[2 + 7].split(",")[0], e, n, f"{float(h) + 1.0:.4f}", s])
    csv.write_text("\n".join(text) + "\n")
    opts = {"path": str(csv), "lever_arm": {"cam": ARM.tolist()}, "opk_deg": [0.0, 0.0, 0.0]}
    blk = run_stage(GnssCentres, {"block": noisy}, opts, tmp_path=tmp_path).artefacts["block"]
    out = run_stage(BundleAdjustment, {"block": blk}, {}, tmp_path=tmp_path)
    tab = out.tables["gnss"].columns
    assert list(tab["photo"]) == blk.photos.ids.tolist()
    res = out.artefacts["bundle"]
    from baarda.pipeline.adjustment import group_parts, image_group_labels

    parts = {p.name: p for p in group_parts(res, image_group_labels(res.block_in, "all"))}
    assert set(parts) == {"image", "control", "GNSS"}
    assert sum(p.redundancy for p in parts.values()) == pytest.approx(res.dof, rel=1e-9)
    assert np.sum(tab["rE"]) + np.sum(tab["rN"]) + np.sum(tab["rU"]) == pytest.approx(parts["GNSS"].redundancy)
    flagged = [p for p, f in zip(tab["photo"], tab["flagged"]) if f]
    assert flagged == [blk.photos.ids[7]]
    assert abs(tab["wU"][7]) > 10
    assert "### GNSS antennas" in out.report and f"| {blk.photos.ids[7]} |" in out.report
    assert out.summary["gnss"]["antennas"] == len(blk.photos) and out.summary["gnss"]["flagged"] == 1
    # the recording: observed antennas and their residual arrows (computed → observed)
    import rerun as rr

    from baarda.pipeline.recording import read_recording

    rec = rr.RecordingStream("gnss-test")
    rec.save(str(tmp_path / "bundle.rrd"))
    BundleAdjustment().log(out, rec, None)
    rec.flush()
    del rec
    paths = {e.path for e in read_recording(tmp_path / "bundle.rrd").entities}
    assert {"/world/gnss/antennas", "/world/gnss/residuals"} <= paths


@pytest.mark.slow
def test_gnss_predicted_precision_monte_carlo(tmp_path):
    """Over 20 simulated blocks the normalised errors average to χ²(3)'s mean 3: the predicted
    covariances of points and centres are right (one block's mean scatters from 1.3 to 5.5)."""
    qp, qc = [], []
    for seed in range(6, 26):
        noisy, exact, frame, rng = _scene(seed)
        csv = _gnss_csv(tmp_path, exact, frame, rng)
        opts = {"path": str(csv), "lever_arm": {"cam": ARM.tolist()}, "opk_deg": [0.0, 0.0, 0.0]}
        blk = run_stage(GnssCentres, {"block": noisy}, opts, tmp_path=tmp_path).artefacts["block"]
        res = adjust(blk, BundleSettings())
        tie = exact.points.role == "tie"
        qp.append(_normalised(res.block.points.XYZ[tie], exact.points.XYZ[tie], res.cov_points[tie]).mean())
        qc.append(_normalised(res.block.photos.X0, exact.photos.X0, res.cov_eo[:, :3, :3]).mean())
    print(f"Monte Carlo (20 blocks): mean q points {np.mean(qp):.2f}, centres {np.mean(qc):.2f} (χ²(3): 3)")
    assert 2.4 < np.mean(qp) < 3.6
    assert 2.3 < np.mean(qc) < 3.7
