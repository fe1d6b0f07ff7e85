"""GNSS projection centres on a simulated aerial block (pipeline.synthetic.simulate_aerial), against truth.

The block is placed in UTM 22S (a local frame at 49.4° W, 25.6° S); GNSS antenna positions are the
true centres plus a lever arm rotated by the true attitude plus 5 cm noise, written as a CSV in
EPSG:32722.  Only the four corner control points are kept.  The adjusted centres and points must
agree with truth within their predicted σ (normalised errors: mean square near 1, none beyond 4.5).
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
    noisy = noisy.replace(points=pts.replace(role=role, sigma=sigma, XYZ=XYZ), meta={**noisy.meta, "crs": frame.to_meta()})
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
    # pass 1: attitude from opk_deg (nadir) for the lever arm; pass 2: from the adjusted attitude
    blk = run_stage(GnssCentres, {"block": noisy}, opts, tmp_path=tmp_path).artefacts["block"]
    res = adjust(blk, BundleSettings())
    second = run_stage(GnssCentres, {"block": res.block, "bundle": res}, opts, tmp_path=tmp_path)
    blk2 = second.artefacts["block"]
    # the neglected term |a|·σ_angle is reported: sub-millimetre here, no warning
    assert 0 < second.summary["neglected_max"] < 1e-3 and not second.warnings
    res2 = adjust(blk2, BundleSettings())
    # the prior is the antenna position reduced with the adjusted attitude: its error is |ARM|·Δangle
    ok_pts = exact.points.role == "tie"
    q_pts = _normalised(res2.block.points.XYZ[ok_pts], exact.points.XYZ[ok_pts], res2.cov_points[ok_pts])
    q_ph = _normalised(res2.block.photos.X0, exact.photos.X0, res2.cov_eo[:, :3, :3])
    # χ²(3) per point: mean 3, 99.99 % quantile 21.1.  The errors of one block are correlated (one
    # datum), so one realisation's mean scatters (1.3-5.5 over seeds 0-25; the Monte Carlo test below
    # averages 20 blocks)
    assert 1.2 < q_pts.mean() < 5.0, q_pts.mean()
    assert q_pts.max() < 30.0
    assert 1.0 < q_ph.mean() < 5.0, q_ph.mean()
    assert q_ph.max() < 30.0
    # without the lever arm correction the centres are off by |ARM| ≈ 29 cm: far outside their σ
    blk_bad = run_stage(GnssCentres, {"block": noisy}, {"path": str(csv), "opk_deg": [0, 0, 0]},
                        tmp_path=tmp_path).artefacts["block"]
    bad = adjust(blk_bad, BundleSettings())
    q_bad = _normalised(bad.block.photos.X0, exact.photos.X0, bad.cov_eo[:, :3, :3])
    assert q_bad.mean() > 10 * q_ph.mean()
    # the GNSS centres carry the datum: adjusted centres within a few cm of truth
    err = np.linalg.norm(res2.block.photos.X0 - exact.photos.X0, axis=1)
    print(f"GNSS test: centres RMS error {np.sqrt(np.mean(err ** 2)) * 1000:.1f} mm, "
          f"mean q points {q_pts.mean():.2f} (χ²(3): 3), mean q centres {q_ph.mean():.2f}, "
          f"without lever arm {q_bad.mean():.1f}")
    assert np.sqrt(np.mean(err ** 2)) < 0.05


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
        blk = run_stage(GnssCentres, {"block": adjust(blk, BundleSettings()).block}, opts,
                        tmp_path=tmp_path).artefacts["block"]
        res = adjust(blk, BundleSettings())
        tie = exact.points.role == "tie"
        qp.append(_normalised(res.block.points.XYZ[tie], exact.points.XYZ[tie], res.cov_points[tie]).mean())
        qc.append(_normalised(res.block.photos.X0, exact.photos.X0, res.cov_eo[:, :3, :3]).mean())
    print(f"Monte Carlo (20 blocks): mean q points {np.mean(qp):.2f}, centres {np.mean(qc):.2f} (χ²(3): 3)")
    assert 2.4 < np.mean(qp) < 3.6
    assert 2.3 < np.mean(qc) < 3.7
