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


@pytest.fixture(scope="module")
def detect_run(shared_beside, tmp_path_factory):
    from baarda.pipeline.cli import main

    out = tmp_path_factory.mktemp("camcal-detect") / "run"
    assert main(["run", str(ROOT / "fixtures" / "dbat" / "camcal-detect.toml"), "--out", str(out), "--quiet"]) == 0
    return json.loads((out / "results.json").read_text())


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


def test_calibration_from_detections(detect_run):
    """The detections without the eccentricity correction (report_uncorrected) against the marks."""
    a, b = _summary(detect_run, "report_marks"), _summary(detect_run, "report_uncorrected")
    assert a["sigma0_hat"] == pytest.approx(1.5553, abs=0.002)
    assert b["sigma0_hat"] < a["sigma0_hat"]              # the detections fit at least as well
    for k in CAMERA:
        assert abs(_in_sigma(a, b, k)) < 3, k
        assert b["camera"][k]["sigma"] == pytest.approx(a["camera"][k]["sigma"], rel=0.05), k


def test_eccentricity_correction_of_the_detections(detect_run):
    """The dots' eccentricity (31.7 mm in the sheet's frame, normals from the neighbours) is a few
    hundredths of a pixel, settles in two rounds and moves c by ≈ +0.4 σ — away from the marks'
    calibration (PhotoModeler's marks are ellipse centres too); the residuals (the swirl) stay: σ̂0
    changes in the fourth digit (docs/dbat.md)."""
    e = _summary(detect_run, "bundle_detected")["eccentricity"]
    assert e["observations"] == 2067 and e["targets"] == 100 and e["normals_estimated"] == 100
    assert 0.03 < e["rms_px"] < 0.1 and 0.1 < e["max_px"] < 0.25
    assert e["settled"] and e["rounds"] <= 3 and e["remaining_sigma"] < e["tol_sigma"]
    assert "eccentricity" not in _summary(detect_run, "bundle_uncorrected")
    marks = _summary(detect_run, "report_marks")
    on, off = _summary(detect_run, "report_detected"), _summary(detect_run, "report_uncorrected")
    assert abs(on["sigma0_hat"] - off["sigma0_hat"]) < 0.002
    assert 0.2 < _in_sigma(off, on, "cc") < 0.6
    for k in CAMERA:
        assert abs(_in_sigma(off, on, k)) < 0.6, k
    worst = lambda s: max(abs(_in_sigma(marks, s, k)) for k in CAMERA)
    assert 2.4 < worst(off) < worst(on) < 3.4
