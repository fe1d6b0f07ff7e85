"""The rendered pipeline from pixels to a report (fixtures/rendered/rendered.toml): detection finds
the rendered targets, and the self-calibrating bundle recovers the true camera, points and
orientations within the precision it reports.

Independent reference: the simulator's truth (true target positions in the images, true camera,
true points and orientations), never the pipeline's own numbers.
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.runner import run_project
from baarda.pipeline.testing import run_project_text
from baarda.plugins.testfield.truth import detection_errors, truth_errors

ROOT = Path(__file__).resolve().parents[2]
FIXTURE = ROOT / "fixtures" / "rendered" / "rendered.toml"
Z_MAX = 5.0


def fast_variant(text: str, seed: int | None = None) -> str:
    """The fixture at 50 µm pixels (2340 × 1660): 4 × fewer pixels; the detector's RMS error there
    (0.0118 px in u, 0.0104 px in v against the truth) as a-priori σ."""
    out, n1 = re.subn(r"pixel_mm = 0\.025\b", "pixel_mm = 0.05", text)
    out, n2 = re.subn(r"sigma_px = 0\.008\b", "sigma_px = 0.011", out)
    assert n1 == n2 == 1, "the fixture's pixel_mm / sigma_px lines changed; update fast_variant"
    if seed is not None:
        out, n3 = re.subn(r"^seed = \d+", f"seed = {seed}", out, count=1, flags=re.M)
        assert n3 == 1
    return out


def check_outcome(outcome, *, max_px: float, max_missing: int = 0):
    """The assertions shared by the fast and the full run; returns (detection, truth) checks."""
    assert outcome.ok, outcome.message
    statuses = {r.id: r.status for r in outcome.stages}
    assert statuses == {k: "ok" for k in ("render", "targets", "screening", "blunders", "bundle", "crosscheck",
                                          "comparison")}
    res = outcome.artefacts["bundle"]
    # detection: every complete target found (a target near the border may be predicted outside the
    # image from the approximate orientation and not be matched), no false identity, subpixel
    det = detection_errors(res.block_in)
    assert det.extra == [] and len(det.missing) <= max_missing, det.summary()
    assert len(det.duv) >= 76
    assert np.abs(det.duv).max() < max_px and (det.rms_px < max_px / 2).all(), det.summary()
    # nothing rejected: the images hold no blunders
    assert int(res.obs_active.sum()) == len(det.duv)
    assert 0.7 < res.sigma0_hat < 1.4            # (the B-method global test has α′ ≈ 0.28 here: not a criterion)
    # the truth within the reported precision.  In one realisation the errors of the 21 points are
    # far from independent: the points' precision (≈ 0.03 mm) is the control survey's (σ 0.05 mm)
    # and image precision is 0.2 µm, so the control draw moves the whole block — the fixture's seed
    # shifts it by ≈ −0.08 mm in X (2.5σ) even with error-free image coordinates.  So no share of
    # |z| < 3 is asserted; every z = (estimate − true)/σ stays below Z_MAX instead.  Z_MAX follows
    # from the calibration the Monte Carlo test (slow marker) measures — RMS z ≈ 1.2 over seeds —:
    # P(max |z| > 5) ≈ 0.7 % for the 63 point coordinates, against ≈ 13 % for a bound of 4.
    tc = truth_errors(res)
    assert len(tc.points["ids"]) == 21 and len(tc.photos["z"]) == 10
    assert np.abs(tc.points["z"]).max() < Z_MAX, tc.points["z"]
    assert np.abs(tc.photos["z"]).max() < Z_MAX, tc.photos["z"]
    z_cam = {r["parameter"]: r["z"] for r in tc.camera}
    assert set(z_cam) == {"c", "xp", "yp", "K1", "K2", "K3", "P1", "P2", "B1", "B2"}
    assert max(abs(z) for z in z_cam.values()) < Z_MAX, tc.camera
    # the report has every stage's section and the cross-check compared both solutions
    report = (outcome.run_dir / "report.md").read_text()
    for sid in ("render", "targets", "screening", "blunders", "bundle", "crosscheck", "comparison"):
        assert f"## {sid} (" in report
    cc = outcome.artefacts["crosscheck"]
    assert cc.quantities["points"]["max"] < 1e-6 * cc.object_size
    return det, tc


@pytest.mark.slow  # 12-25 s: renders and detects 13 photos
def test_fast_variant(tmp_path):
    """2340 × 1660 pixel photos, about 5 s."""
    outcome = run_project_text(fast_variant(FIXTURE.read_text()), tmp_path)
    det, tc = check_outcome(outcome, max_px=0.06, max_missing=1)
    print("\nfast:", det.summary(), tc.summary())


@pytest.mark.slow  # 35-75 s: the full-size rendered project (make test-slow)
def test_fixture(tmp_path):
    """The bundled project as `baarda run` runs it (4680 × 3320 pixels)."""
    t0 = time.perf_counter()
    outcome = run_project(FIXTURE, tmp_path / "run", verbose=False)
    seconds = time.perf_counter() - t0
    det, tc = check_outcome(outcome, max_px=0.04)
    assert (tmp_path / "run" / "images" / "13.png").is_file()
    assert not (FIXTURE.parent / "images").exists()
    print(f"\nfixture ({seconds:.1f} s):", det.summary(), tc.summary())


@pytest.mark.slow
def test_monte_carlo_precision(tmp_path):
    """Ten noise realisations (image noise and control survey): the errors against the truth,
    divided by the reported σ, have an RMS close to 1 for points and camera parameters, and σ̂0
    averages about 1 — the reported precision is neither optimistic nor pessimistic."""
    z_pts, z_cam, s0 = [], [], []
    for seed in range(10):
        outcome = run_project_text(fast_variant(FIXTURE.read_text(), seed), _mkdir(tmp_path / str(seed)))
        assert outcome.ok, outcome.message
        res = outcome.artefacts["bundle"]
        tc = truth_errors(res)
        z_pts.append(tc.points["z"])
        z_cam.append([r["z"] for r in tc.camera])
        s0.append(res.sigma0_hat)
    z_pts, z_cam = np.concatenate(z_pts), np.array(z_cam)
    rms_pts = np.sqrt(np.mean(z_pts ** 2, axis=0))
    rms_cam = np.sqrt(np.mean(z_cam ** 2))
    print(f"\nσ̂0 mean {np.mean(s0):.3f}; RMS z of points (X, Y, Z) {rms_pts}; of the camera {rms_cam:.3f}")
    assert 0.8 < np.mean(s0) < 1.2
    assert (0.6 < rms_pts).all() and (rms_pts < 1.5).all()
    assert 0.6 < rms_cam < 1.5


def _mkdir(path: Path) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    return path
