"""The stereo chessboard as a two-camera rig (docs/rigs.md): the baseline with its σ, and
cv2.stereoCalibrate on the same detections (same interior parameters free) within a few σ."""

from pathlib import Path

import numpy as np

from baarda.pipeline.adjustment import adjust, rig_result
from baarda.pipeline.rigs import attach_rigs
from baarda.plugins.targets.blocks import consistent_rig_ids
from baarda.plugins.targets.calib import opencv_stereo

RIG = Path(__file__).resolve().parents[2] / "fixtures" / "calibration" / "stereo-rig.csv"
FREE = ["c", "xp", "yp", "K1", "K2", "K3", "P1", "P2"]


def test_stereo_chessboard_rig_against_stereo_calibrate(chessboard):
    res, _ = chessboard
    block = attach_rigs(res.artefacts["block"], RIG, frames_from_name=r"(\d+)$")
    warnings = []
    block = consistent_rig_ids(block, warnings.append)
    assert len(warnings) == 1 and "right05" in warnings[0]          # OpenCV numbered that view from the other end
    st = opencv_stereo(block, FREE, res.summary["opencv_calibration"])
    assert st["rms_px"] < 0.3 and len(st["frames"]) == 13
    rr = rig_result(adjust(block))
    right = rr.sensors[1]
    assert not right.reference_sensor
    assert 80 < right.baseline < 86 and 0 < right.sigma_baseline < 0.2            # mm
    d = right.value - np.r_[st["centre"], st["opk"]]
    d[3:] = (d[3:] + np.pi) % (2 * np.pi) - np.pi
    assert np.all(np.abs(d / right.sigma) < 3), d / right.sigma
    assert abs(right.baseline - st["baseline"]) < 3 * right.sigma_baseline
