"""Camera calibration from real photos of planar boards: baarda's bundle against cv2.calibrateCamera.

With ``CALIB_FIX_ASPECT_RATIO`` (fx = fy) OpenCV's camera is exactly baarda's brown model with
B1 = B2 = 0 (``docs/targets.md``), both fix the board (control points, Z = 0) and free every photo's
orientation and c, xp, yp, K1, K2, K3, P1, P2; both minimise the same sum of squares, so the
solutions must agree to the convergence tolerance of the two solvers.
"""

from pathlib import Path

import numpy as np
import pytest

from pipeline.options import parse_options
from pipeline.stage import Context
from plugins.targets.calib import opencv_calibration
from plugins.targets.stage import TargetDetection, TargetOptions

adjust_mod = pytest.importorskip("plugins.bundle.adjust", reason="the bundle (plugins/bundle) is not installed")

CASES = {
    "chessboard-left": ("opencv-chessboard", {"images": ["left*.jpg"], "target": "chessboard", "squares": [10, 7],
                                              "square_size": 25.0}),
    "chessboard-right": ("opencv-chessboard", {"images": ["right*.jpg"], "target": "chessboard",
                                               "squares": [10, 7], "square_size": 25.0}),
    # 5 views only: K3 is held at 0 on both sides (OpenCV: CALIB_FIX_K3)
    "charuco": ("opencv-charuco", {"images": ["*.jpg"], "target": "charuco", "squares": [5, 7],
                                   "square_size": 0.04, "marker_size": 0.02, "unit": "m",
                                   "unknowns": ["c", "xp", "yp", "K1", "K2", "P1", "P2"]}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_bundle_self_calibration_agrees_with_opencv(shared_data, case):
    folder, opts = CASES[case]
    ctx = Context("targets", project_dir=Path(shared_data / folder))
    res = TargetDetection().run({}, parse_options(TargetOptions, {**opts, "opencv_reference": False}), ctx)
    block = res.artefacts["block"]
    from plugins.bundle.solver import BundleSettings

    # the 5-view ChArUco case creeps (LM damping stays at 1e-5 for ~25 iterations): 36 iterations
    result = adjust_mod.adjust(block, BundleSettings(max_iter=100))
    import cv2

    fixed_k3 = "K3" not in opts.get("unknowns", ["K3"])
    ref = opencv_calibration(block, 0, flags=cv2.CALIB_FIX_K3 if fixed_k3 else 0, fix_aspect=True)
    p = float(block.cameras.pixel_mm[0])
    tab = {row["parameter"]: row for row in result.camera_table(0)}
    v = result.residuals[result.obs_active] / p
    rms = float(np.sqrt((v**2).sum(axis=1).mean()))         # OpenCV's definition: per point, 2-D
    print(f"\n{case}: {len(block.photos)} views, {int(result.obs_active.sum())} points; σ̂0 = "
          f"{result.sigma0_hat:.3f} (a priori {np.sqrt(block.observations.cov[0, 0, 0]) / p:g} px)")
    print(f"  {'':4} {'baarda':>16} {'± σ':>12} {'OpenCV':>16} {'Δ/σ':>10}")
    rows = [("c", tab["c"]["value"], tab["c"]["sigma"], ref["c_mm"]),
            ("xp", tab["xp"]["value"], tab["xp"]["sigma"], ref["xp_mm"]),
            ("yp", tab["yp"]["value"], tab["yp"]["sigma"], ref["yp_mm"])]
    rows += [(n, tab[n]["value"], tab[n]["sigma"], ref["brown"][k]) for k, n in enumerate(("K1", "K2", "K3", "P1", "P2"))
             if not (n == "K3" and fixed_k3)]
    for name, val, sig, cv in rows:
        print(f"  {name:4} {val:16.9g} {sig:12.3g} {cv:16.9g} {(val - cv) / sig:10.2e}")
        assert abs(val - cv) < 0.01 * sig, name                 # far inside the precision
    print(f"  RMS {rms:.9f} px (baarda), {ref['rms_px']:.9f} px (OpenCV); "
          f"c = {tab['c']['value'] / p:.4f} px, OpenCV fx = fy = {ref['fy']:.4f} px")
    assert rms == pytest.approx(ref["rms_px"], rel=1e-6)
    if case.startswith("chessboard"):                         # well determined: agreement to ~1e-6 px
        assert abs(tab["c"]["value"] - ref["c_mm"]) / p < 1e-4
        assert abs(tab["xp"]["value"] - ref["xp_mm"]) / p < 1e-4
        assert abs(tab["yp"]["value"] - ref["yp_mm"]) / p < 1e-4
        assert rms == pytest.approx(ref["rms_px"], rel=1e-9)
