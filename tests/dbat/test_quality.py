"""The dbat-report stage's figures against closed forms and DBAT's published reports (ray counts,
intersection angles, the corrected-space σ̂0).  References as in test_projects.py."""

from __future__ import annotations

import numpy as np
import pytest

from baarda.pipeline.adjustment import BundleSettings, adjust
from baarda.plugins.dbat import dbat_block, read_dbat
from baarda.plugins.dbat.quality import intersection_angles
from baarda.plugins.dbat.stage import DbatReport, DbatReportOptions


def test_intersection_angle_closed_form():
    X0 = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, -5.0, 0.0]])
    XYZ = np.array([[1.0, 1.0, 0.0], [0.0, 0.0, 7.0], [5.0, 5.0, 5.0]])
    ph = np.array([0, 1, 2, 0, 1])
    pt = np.array([0, 0, 0, 2, 1])
    a = np.rad2deg(intersection_angles(XYZ, X0, ph, pt, 3))
    # point 0: rays from (0,0,0) and (2,0,0) meet at 90°, the third (from below) at 45° to both
    assert a[0] == pytest.approx(90.0, abs=1e-12)
    assert a[1] == 0.0 and a[2] == 0.0                     # one ray each
    # rays 120° apart intersect at 60° (lines, as DBAT counts)
    X0b = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    top = np.array([[1.0, np.tan(np.deg2rad(30.0)), 0.0]])
    assert np.rad2deg(intersection_angles(top, X0b, np.array([0, 1]), np.array([0, 0]), 1))[0] == pytest.approx(60.0)


def _report(shared_data, name, xml):
    block = dbat_block(read_dbat(shared_data / name / xml))
    res = adjust(block, BundleSettings(datum="control"))
    out = DbatReport().run({"bundle": res}, DbatReportOptions(), None)
    return out.artefacts["dbat_report"], out


def test_camcal_quality_as_dbat(shared_data):
    q, out = _report(shared_data, "dbat-camcal", "camcaldemo.xml")
    assert q["sigma0_corrected"] == pytest.approx(1.6148, rel=5e-4)    # DBAT: Sigma0 1.6148
    assert q["rms_px_corrected"] == pytest.approx(0.216, abs=5e-4)      # DBAT: overall point RMS 0.216 px
    a = q["angle_stats"]
    # DBAT: CP 83.4 (1003) – 85.8 (1002), mean 84.7; OP 79.6 (90) – 90.0 (59), mean 86.5
    assert (round(a["control"]["min"], 1), a["control"]["min_id"]) == (83.4, "1003")
    assert (round(a["control"]["max"], 1), a["control"]["max_id"]) == (85.8, "1002")
    assert round(a["control"]["mean"], 1) == 84.7
    assert (round(a["tie"]["min"], 1), a["tie"]["min_id"]) == (79.6, "90")
    assert (round(a["tie"]["max"], 1), a["tie"]["max_id"]) == (90.0, "59")
    assert round(a["tie"]["mean"], 1) == 86.5
    # DBAT: OP ray count 16-21: 1×16, 1×17, 2×18, 3×19, 5×20, 84×21; CP 4×21
    assert q["ray_stats"]["tie"] == {16: 1, 17: 1, 18: 2, 19: 3, 20: 5, 21: 84}
    assert q["ray_stats"]["control"] == {21: 4}
    assert "K2–K3 -97.8%" in out.report                                 # DBAT: K2/K3 −97.9 %
    # fixed control has no differences: the review line names the calibrated camera instead
    cc, s = q["camera"]["cc"]
    assert out.summary["headline"] == (f"σ̂0 = {q['sigma0']:.4f} (RMS {q['rms_px']:.3f} px); control fixed (4); "
                                       f"9 camera parameter(s) free, cc {cc:.6g} ± {s:.3g} mm")


def test_sxb_quality_as_dbat(shared_data):
    q, out = _report(shared_data, "dbat-sxb", "sxb.xml")
    # no distortion: both residual spaces agree and give DBAT's σ̂0
    assert q["sigma0"] == pytest.approx(1.1786, abs=5e-4)
    assert q["sigma0_corrected"] == pytest.approx(q["sigma0"], rel=1e-12)
    assert q["rms_px"] == pytest.approx(1.101, abs=5e-4)                # DBAT: overall point RMS 1.101 px
    a = q["angle_stats"]
    # DBAT: CP 0.0 (403) – 25.7 (422) mean 13.9; CCP 15.2 (351) – 25.8 (410) mean 20.5; OP 12.8 (65696) – 26.2 (66544) mean 15.5
    for kind, lo, lo_id, hi, hi_id, mean in (("control", 0.0, "403", 25.7, "422", 13.9),
                                             ("check", 15.2, "351", 25.8, "410", 20.5),
                                             ("tie", 12.8, "65696", 26.2, "66544", 15.5)):
        s = a[kind]
        assert (round(s["min"], 1), s["min_id"], round(s["max"], 1), s["max_id"], round(s["mean"], 1)) == \
            (lo, lo_id, hi, hi_id, mean), kind
    # DBAT: CP 1×1, 3×2, 7×3, 3×4; CCP 1×3, 1×4; OP (tie and check) 312×3, 55×4
    assert q["ray_stats"]["control"] == {1: 1, 2: 3, 3: 7, 4: 3}
    assert q["ray_stats"]["check"] == {3: 1, 4: 1}
    assert q["ray_stats"]["tie"] == {3: 311, 4: 54}
    # DBAT's smallest angles: 65696 12.84, 67415 13.00, 65297 13.12, 65265 13.15, 67395 13.17
    t = q["tie"][np.argsort(q["angles_deg"][q["tie"]])[:5]]
    assert q["ids"][t].tolist() == ["65696", "67415", "65297", "65265", "67395"]
    assert np.round(q["angles_deg"][t], 2).tolist() == [12.84, 13.00, 13.12, 13.15, 13.17]
    # control: DBAT's ctrl point delta RMS 0.035, max 0.073 at 492; check RMS 0.421, max 0.488 at 351
    assert "RMS of the control differences: 0.035 m (3-D), largest 0.073 m at 492" in out.report
    assert "RMS of the check differences: 0.421 m (3-D), largest 0.488 m at 351" in out.report
    # the line of `baarda review`: the same numbers
    assert out.summary["headline"] == ("σ̂0 = 1.1786 (RMS 1.101 px); control RMS 0.035 m (3-D), largest 0.073 m "
                                       "at 492; check RMS 0.421 m (3-D), largest 0.488 m at 351")


def test_report_of_a_block_not_from_dbat():
    """dbat-report on any bundle: baarda's parameter names, no corrected-space σ̂0 (no backward camera),
    noise-free data give σ̂0 = 0 and the true camera."""
    from baarda.pipeline.synthetic.closerange import make_block

    block, truth = make_block(model="brown", n_photos=4, n_points=12)
    res = adjust(block, BundleSettings())
    out = DbatReport().run({"bundle": res}, DbatReportOptions(), None)
    q = out.artefacts["dbat_report"]
    assert not q["dbat_camera"] and np.isnan(q["sigma0_corrected"])
    assert q["sigma0"] < 1e-6
    assert np.allclose([q["camera"][k][0] for k in ("c", "xp", "yp")], truth["cam"][:3], atol=1e-8)
    assert "not from a DBAT script" in out.report
