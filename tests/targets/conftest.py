"""Detections on the real OpenCV sample photos, computed once per test session (the sector-based
chessboard detector takes several seconds for the 26 images)."""

import pytest

from baarda.pipeline.options import parse_options
from baarda.pipeline.stage import Context
from baarda.plugins.targets.stage import TargetDetection, TargetOptions


def run_targets(folder, **opts):
    ctx = Context("targets", project_dir=folder)
    return TargetDetection().run({}, parse_options(TargetOptions, opts), ctx), ctx


@pytest.fixture(scope="session")
def chessboard(shared_data):
    """Both cameras (left, right) of opencv-chessboard: 9 × 6 inner corners, 25 mm squares."""
    return run_targets(shared_data / "opencv-chessboard", images=["left*.jpg", "right*.jpg"], target="chessboard",
                       squares=[10, 7], square_size=25.0, camera_from_name="^(left|right)")


@pytest.fixture(scope="session")
def charuco(shared_data):
    """The four ChArUco photos and the occluded one: 5 × 7 squares, 0.04 m, markers 0.02 m."""
    return run_targets(shared_data / "opencv-charuco", images=["img_0*.jpg", "chocclusion_original.jpg"],
                       target="charuco", squares=[5, 7], square_size=0.04, marker_size=0.02,
                       dictionary="DICT_6X6_250", unit="m")
