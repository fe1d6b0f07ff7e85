"""PhotoModeler's marks against baarda's own detections (fixtures/dbat/camcal-detect.toml): the pairing
by position against a closed form, and the real photos — OpenCV's blob centres against PhotoModeler's
marks, and the calibration from the detections against the one from the marks."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.model import Observations
from baarda.plugins.dbat import dbat_block, read_dbat
from baarda.plugins.dbat.quality import compare_marks

ROOT = Path(__file__).resolve().parents[2]


def test_compare_marks_closed_form(shared_data):
    marks = dbat_block(read_dbat(shared_data / "dbat-camcal" / "camcaldemo.xml"))
    p = marks.cameras.pixel_mm[0]
    o = marks.observations
    rng = np.random.default_rng(3)
    shift = np.array([0.3, -0.2])                         # pixels, x right, y down
    noise = rng.normal(0, 0.05, (len(o), 2))
    xy = o.xy + (shift + noise) * [p, -p]
    keep = np.ones(len(o), bool)
    keep[::50] = False                                   # some marks not detected
    other = marks.replace(observations=Observations.make(o.photo[keep], o.point[keep], xy[keep], sigma=0.1 * p))
    c = compare_marks(marks, other, 3.0)
    a = c["all"]
    assert (a["marks"], a["points"], a["matched"], a["same_id"]) == (len(o), keep.sum(), keep.sum(), keep.sum())
    d = (shift + noise)[keep]
    assert np.allclose(a["bias_px"], d.mean(axis=0), atol=1e-9)
    assert np.allclose(a["rms_px"], np.sqrt((d ** 2).mean(axis=0)), atol=1e-9)
    # beyond the radius nothing pairs
    far = marks.replace(observations=Observations.make(o.photo, o.point, o.xy + 5 * p, sigma=0.1 * p))
    assert compare_marks(marks, far, 3.0)["all"]["matched"] == 0


def _run(tmp_path_factory, *overrides):
    from baarda.pipeline.cli import main

    out = tmp_path_factory.mktemp("camcal-detect") / "run"
    sets = [a for o in overrides for a in ("--set", o)]
    assert main(["run", str(ROOT / "fixtures" / "dbat" / "camcal-detect.toml"), "--out", str(out), "--quiet",
                 *sets]) == 0
    return out


@pytest.fixture(scope="module")
def detect_dir(shared_beside, tmp_path_factory):
    return _run(tmp_path_factory)


@pytest.fixture(scope="module")
def detect_run(detect_dir):
    return json.loads((detect_dir / "results.json").read_text())


def _summary(results, stage_id):
    return next(s for s in results["stages"] if s["id"] == stage_id)["summary"]


def test_detections_agree_with_photomodeler_marks(detect_run):
    m = _summary(detect_run, "marks_vs_detections")
    assert m["marks"] == 2074
    assert m["matched"] >= 2060 and m["same_id"] == m["matched"]
    # after each side's own pixel convention the centres agree to a few hundredths of a pixel on average
    assert np.all(np.abs(m["bias_px"]) < 0.05)
    assert np.all(np.array(m["rms_px"]) < 0.16)


CAMERA = ("cc", "px", "py", "K1", "K2", "K3", "P1", "P2", "as")


def _in_sigma(a, b, k):
    return (b["camera"][k]["value"] - a["camera"][k]["value"]) / np.hypot(a["camera"][k]["sigma"],
                                                                            b["camera"][k]["sigma"])


def _largest(a, b):
    return max(abs(_in_sigma(a, b, k)) for k in CAMERA)


def test_calibration_from_detections(detect_run):
    """The detections' calibration (eccentricity corrected) against the marks': σ like the marks', c the
    largest difference (≈ 3 σ; docs/dbat.md)."""
    a, b = _summary(detect_run, "report_marks"), _summary(detect_run, "report_detected")
    assert a["sigma0_hat"] == pytest.approx(1.5553, abs=0.002)
    assert b["sigma0_hat"] < a["sigma0_hat"]              # the detections fit at least as well
    for k in CAMERA:
        assert abs(_in_sigma(a, b, k)) < 3.4, k
        assert b["camera"][k]["sigma"] == pytest.approx(a["camera"][k]["sigma"], rel=0.05), k
    assert 2.7 < _largest(a, b) == abs(_in_sigma(a, b, "cc")) < 3.4


def test_eccentricity_correction_of_the_detections(detect_run):
    """The dots' eccentricity (31.6 mm in the sheet's frame, normals from the neighbours) is a few
    hundredths of a pixel and settles in two rounds."""
    e = _summary(detect_run, "bundle_detected")["eccentricity"]
    assert e["observations"] == 2067 and e["targets"] == 100 and e["normals_estimated"] == 100
    assert 0.03 < e["rms_px"] < 0.1 and 0.1 < e["max_px"] < 0.25
    assert e["settled"] and e["rounds"] <= 3 and e["remaining_sigma"] < e["tol_sigma"]
    assert "eccentricity" not in _summary(detect_run, "bundle_marks")


@pytest.mark.slow
def test_eccentricity_before_and_after(detect_run, tmp_path_factory):
    """The same project without the correction (``--set bundle_detected.eccentricity.enabled=false``):
    within 3 σ of the marks' calibration; the correction moves c by ≈ +0.4 σ — away from the marks'
    (PhotoModeler's marks are ellipse centres too) — and leaves the residuals (the swirl): σ̂0 changes
    in the fourth digit (docs/dbat.md)."""
    off = json.loads((_run(tmp_path_factory, "bundle_detected.eccentricity.enabled=false")
                      / "results.json").read_text())
    assert "eccentricity" not in _summary(off, "bundle_detected")
    marks = _summary(detect_run, "report_marks")
    before, after = _summary(off, "report_detected"), _summary(detect_run, "report_detected")
    assert abs(after["sigma0_hat"] - before["sigma0_hat"]) < 0.002
    assert 0.2 < _in_sigma(before, after, "cc") < 0.6
    for k in CAMERA:
        assert abs(_in_sigma(marks, before, k)) < 3, k
        assert abs(_in_sigma(before, after, k)) < 0.6, k
    assert 2.4 < _largest(marks, before) < _largest(marks, after)


@pytest.mark.slow
def test_the_dot_diameter_of_the_fixture_is_the_one_in_the_images(detect_dir, shared_data):
    """``circle_diameter = 31.6`` mm (0.0316 in the sheet's frame) measured again: each dot's ellipse
    (the detector's subpixel outline) has the area π r² |det J|, J the local image scale of the sheet
    from the detected neighbours and their adjusted coordinates (8 nearest; the coded targets' dots,
    inside rings, are left out).  Median over the dots of all photos."""
    import csv

    import cv2

    from baarda.plugins.targets.detect import _subpixel_outline

    rows = list(csv.DictReader(open(detect_dir / "targets_detections.csv", encoding="utf-8")))
    pts = {r["point"]: (float(r["X_m"]), float(r["Y_m"]))
           for r in csv.DictReader(open(detect_dir / "bundle_marks_points.csv", encoding="utf-8"))}
    est = []
    for photo in sorted({r["photo"] for r in rows})[::3]:             # every third photo: 7 of 21
        sel = [r for r in rows if r["photo"] == photo]
        ids = [r["point"] for r in sel]
        XY = np.array([pts[i] for i in ids])
        UV = np.array([[float(r["x_px"]), float(r["y_px"])] for r in sel])
        gray = cv2.imread(str(shared_data / "dbat-camcal" / "images" / f"{photo}.JPG"), cv2.IMREAD_GRAYSCALE)
        for i, pid in enumerate(ids):
            if pid.startswith("100"):
                continue
            x0, y0 = (np.round(UV[i]) - 40).astype(int)
            roi = gray[y0:y0 + 81, x0:x0 + 81]
            if roi.shape != (81, 81):
                continue
            _, bw = cv2.threshold(roi, 0, 255, cv2.THRESH_BINARY_INV + cv2.THRESH_OTSU)    # the dark dot
            contours, _ = cv2.findContours(bw, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            inside = [c for c in contours if len(c) >= 6 and cv2.pointPolygonTest(c, (40.0, 40.0), False) >= 0]
            if not inside:
                continue
            _, axes, _ = cv2.fitEllipse(inside[0])
            mid = 0.5 * (np.median(roi[bw > 0]) + np.median(roi[bw == 0]))
            edge = _subpixel_outline(roi, UV[i] - [x0, y0], axes, mid, 180)
            if len(edge) < 150:
                continue
            _, (A, B), _ = cv2.fitEllipse(edge)
            nb = np.argsort(np.linalg.norm(XY - XY[i], axis=1))[1:9]
            J = np.linalg.lstsq(XY[nb] - XY[i], UV[nb] - UV[i], rcond=None)[0].T
            est.append(2 * np.sqrt(A * B / 4 / abs(np.linalg.det(J))))
    assert len(est) > 200
    assert np.median(est) == pytest.approx(0.0316, abs=0.0003)


@pytest.mark.slow
def test_correcting_the_marks_too_shifts_their_calibration_alike(shared_data):
    """PhotoModeler's marks with the same circle table (0.0316, normals from the neighbours): c moves by
    ≈ +0.5 σ as the detections' does, the rest by < 0.05 σ (docs/dbat.md)."""
    from baarda.pipeline.api import BundleConfig, CircleTargets, adjust

    marks = dbat_block(read_dbat(shared_data / "dbat-camcal" / "camcaldemo.xml"))
    off = adjust(marks, BundleConfig(datum="control"))
    on = adjust(marks.replace(circles=CircleTargets.make(marks.points.ids, 0.0316)), BundleConfig(datum="control"))
    assert on.eccentricity.settled and off.eccentricity is None
    s = np.sqrt(np.diag(off.result.cov_cameras[0]))
    z = (on.result.state.cam_params[0] - off.result.state.cam_params[0]) / np.where(s > 0, s, np.inf)
    names = off.result.cam_param_names[0]
    assert 0.3 < z[names.index("c")] < 0.7
    assert np.all(np.abs(np.delete(z, names.index("c"))) < 0.05)


@pytest.mark.slow
def test_the_swirl_is_an_interior_orientation_that_changes_with_the_roll(shared_data):
    """benchmarks/camcal_swirl.py (docs/dbat.md "What the swirl is"): one camera per photo (c, xp, yp
    free, the distortion common) takes ≈ 58 % of the marks' vᵀPv with 63 parameters (σ̂0 1.555 → 1.015);
    the per-photo xp sort by the camera's roll against gravity (≈ 0 upright, −29 … −44 px on the side);
    a sheet bent differently in each photo (a cubic ΔZ, 10 parameters per photo) takes less than the
    3 interior-orientation parameters, one field common to all photos ≈ 20 %."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("camcal_swirl", ROOT / "benchmarks" / "camcal_swirl.py")
    S = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(S)
    from baarda.pipeline.api import BundleConfig, adjust

    marks = dbat_block(read_dbat(shared_data / "dbat-camcal" / "camcaldemo.xml"))
    base = adjust(marks, BundleConfig(datum="control"))
    adj = base.result.block
    pp = adjust(S.per_photo_cameras(adj), BundleConfig(datum="control"))
    assert 0.52 < 1 - pp.result.vtpv / base.result.vtpv < 0.64
    assert 0.95 < pp.result.sigma0_hat < 1.1
    pix = adj.cameras.pixel_mm[0]
    xp = pp.result.state.cam_params[:, 1] / pix
    g = S.gravity_in_image(adj)
    side = g[:, 0] < -0.4                                  # gravity along −x: the camera on its side
    assert side.sum() == 8
    assert np.all(xp[side] < -25) and np.all(np.abs(xp[~side]) < 8)
    lin = S.Linearised(adj)
    io = 1 - lin.with_columns(lin.per_photo(lin.camera_columns(["c", "xp", "yp"]))) / lin.vtpv
    sheet = 1 - lin.with_columns(lin.per_photo(lin.sheet_polynomial(3, axes=(2,)))) / lin.vtpv
    common = 1 - lin.with_columns(lin.common_field()) / lin.vtpv
    assert io > sheet + 0.05 and 0.55 < io < 0.67
    assert 0.1 < common < 0.3
