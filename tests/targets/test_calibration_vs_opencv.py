"""Camera calibration from real photos of planar boards: baarda's bundle against cv2.calibrateCamera.

With ``CALIB_FIX_ASPECT_RATIO`` (fx = fy) OpenCV's camera is exactly baarda's brown model with
B1 = B2 = 0 (``docs/targets.md``); both fix the board (control points, Z = 0) and free every photo's
orientation and c, xp, yp, K1, K2, K3, P1, P2; both minimise the same sum of squares, so the
solutions must agree to the convergence tolerance of the two solvers.
"""

import numpy as np
import pytest

from baarda.plugins.targets.calib import opencv_calibration

adjust_mod = pytest.importorskip("baarda.pipeline.adjustment.adjust", reason="the bundle (plugins/bundle) is not installed")


def _compare(name, block, result, cam, fixed_k3=False, strict=True):
    import cv2

    ref = opencv_calibration(block, cam, flags=cv2.CALIB_FIX_K3 if fixed_k3 else 0, fix_aspect=True)
    p = float(block.cameras.pixel_mm[cam])
    tab = {row["parameter"]: row for row in result.camera_table(cam)}
    used = result.obs_active & (block.photos.camera[block.observations.photo] == cam)
    v = result.residuals[used] / p
    rms = float(np.sqrt((v**2).sum(axis=1).mean()))         # OpenCV's definition: per point, 2-D
    print(f"\n{name}: {len(ref['views'])} views, {int(used.sum())} points; σ̂0 = {result.sigma0_hat:.3f} "
          f"(a priori {np.sqrt(block.observations.cov[0, 0, 0]) / p:g} px)")
    print(f"  {'':4} {'baarda':>16} {'± σ':>12} {'OpenCV':>16} {'Δ/σ':>10}")
    rows = [("c", tab["c"]["value"], tab["c"]["sigma"], ref["c_mm"]),
            ("xp", tab["xp"]["value"], tab["xp"]["sigma"], ref["xp_mm"]),
            ("yp", tab["yp"]["value"], tab["yp"]["sigma"], ref["yp_mm"])]
    rows += [(n, tab[n]["value"], tab[n]["sigma"], ref["brown"][k]) for k, n in enumerate(("K1", "K2", "K3", "P1", "P2"))
             if not (n == "K3" and fixed_k3)]
    for pname, val, sig, cv in rows:
        print(f"  {pname:4} {val:16.9g} {sig:12.3g} {cv:16.9g} {(val - cv) / sig:10.2e}")
        assert abs(val - cv) < 0.01 * sig, pname               # far inside the precision
    print(f"  RMS {rms:.9f} px (baarda), {ref['rms_px']:.9f} px (OpenCV); "
          f"c = {tab['c']['value'] / p:.4f} px, OpenCV fx = fy = {ref['fy']:.4f} px")
    assert rms == pytest.approx(ref["rms_px"], rel=1e-6)
    if strict:                                                 # well determined: agreement to ~1e-6 px
        assert abs(tab["c"]["value"] - ref["c_mm"]) / p < 1e-4
        assert abs(tab["xp"]["value"] - ref["xp_mm"]) / p < 1e-4
        assert abs(tab["yp"]["value"] - ref["yp_mm"]) / p < 1e-4
        assert rms == pytest.approx(ref["rms_px"], rel=1e-9)


def test_chessboard_two_cameras_agree_with_opencv(chessboard):
    """left and right cameras in one adjustment (13 views each)."""
    res, _ = chessboard
    block = res.artefacts["block"]
    result = adjust_mod.adjust(block)
    for k, cam in enumerate(block.cameras.ids):
        _compare(f"chessboard {cam}", block, result, k)


def test_charuco_agrees_with_opencv(charuco):
    """5 views (one occluded): K3 is held at 0 on both sides (OpenCV: CALIB_FIX_K3)."""
    res, _ = charuco
    block = res.artefacts["block"]
    sig = block.cameras.sigma_ap.copy()
    sig[:, 2] = 0.0                                            # K3 fixed
    block = block.replace(cameras=block.cameras.replace(sigma_ap=sig))
    result = adjust_mod.adjust(block)                           # weak: ~25 iterations
    print(f"\nChArUco bundle: {result.iterations} iterations")
    _compare("ChArUco", block, result, 0, fixed_k3=True, strict=False)


def test_opencv_flags_free_what_baarda_frees():
    import cv2

    from baarda.plugins.targets.calib import opencv_flags

    flags, aspect, notes = opencv_flags(["c", "xp", "yp", "K1", "K2", "P1", "P2"])
    assert flags == cv2.CALIB_FIX_K3 and aspect and notes == []
    flags, aspect, _ = opencv_flags(["c", "K1"])
    assert flags == (cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST)
    flags, aspect, notes = opencv_flags(["c", "xp", "yp", "K1", "K2", "K3", "P1", "B1", "B2"])
    assert flags == 0 and not aspect and len(notes) == 2          # one tangential term, shear: said


def test_stage_reference_is_like_for_like(shared_data):
    """The targets stage's cv2 reference frees what the stage frees: with K3 fixed (as the bundled
    ChArUco project) OpenCV gets CALIB_FIX_K3 and the same c, principal point and RMS as baarda's
    bundle of that block; two runs give the same reference (cv2.setNumThreads(1))."""
    from tests.targets.conftest import run_targets

    kw = dict(images=["img_0*.jpg", "chocclusion_original.jpg"], target="charuco", squares=[5, 7],
              square_size=40.0, marker_size=20.0, dictionary="DICT_6X6_250", unit="mm",
              unknowns=["c", "xp", "yp", "K1", "K2", "P1", "P2"], sigma_px=0.15)
    res, _ = run_targets(shared_data / "opencv-charuco", **kw)
    ref = res.summary["opencv_calibration"]["cam"]
    assert ref["flags"] == ["CALIB_FIX_ASPECT_RATIO", "CALIB_FIX_K3"] and ref["dist"][4] == 0.0
    block = res.artefacts["block"]
    result = adjust_mod.adjust(block)
    p = float(block.cameras.pixel_mm[0])
    tab = {row["parameter"]: row for row in result.camera_table(0)}
    assert abs(tab["c"]["value"] - ref["c_mm"]) < 0.01 * tab["c"]["sigma"]
    v = result.residuals[result.obs_active] / p
    assert float(np.sqrt((v ** 2).sum(axis=1).mean())) == pytest.approx(ref["rms_px"], rel=1e-6)
    # the image σ 0.15 px is the corners' precision: the global test accepts at 5 %
    from baarda.pipeline.stats import global_test

    assert global_test(result.snapshot).verdict == "accepted"
    again, _ = run_targets(shared_data / "opencv-charuco", **kw)
    assert again.summary["opencv_calibration"]["cam"]["rms_px"] == ref["rms_px"]
