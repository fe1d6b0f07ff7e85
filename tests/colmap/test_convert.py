"""Pixels ↔ mm, pose and camera-model conversions, checked against closed forms, OpenCV and pycolmap."""

import numpy as np
import pytest

from baarda.pipeline.geometry import rotation_from_opk
from baarda.pipeline.model import Block, Cameras, Observations, Photos, Points
from baarda.pipeline.geometry.image import mm_from_pixels, pixels_from_mm
from baarda.pipeline.geometry.pose import cv_from_pose, pose_from_cv
from baarda.pipeline.camera.convert import (BROWN, COLMAP_PARAMS, UnsupportedCamera, brown_from_colmap, brown_from_opencv, colmap_from_brown, opencv_brown_exact, opencv_from_brown)
from baarda.pipeline.adjustment import project_block


# ---------------------------------------------------------------------------------------------
# pixels ↔ mm (docs/conventions.md, "Pixels ↔ mm")
# ---------------------------------------------------------------------------------------------

def test_pixels_to_mm_closed_form_opencv():
    W, H, p = 640, 480, 0.0055
    uv = np.array([[0.0, 0.0], [319.5, 239.5], [639.0, 479.0], [100.0, 50.0]])
    xy = mm_from_pixels(uv, (W, H), p, "opencv")
    expected = np.array([[-319.5 * p, 239.5 * p], [0.0, 0.0], [319.5 * p, -239.5 * p],
                         [(100 - 319.5) * p, -(50 - 239.5) * p]])
    np.testing.assert_allclose(xy, expected, rtol=0, atol=1e-15)
    np.testing.assert_allclose(pixels_from_mm(xy, (W, H), p, "opencv"), uv, atol=1e-12)


def test_pixels_to_mm_closed_form_colmap_corner_convention():
    # COLMAP: the centre of the top-left pixel is (0.5, 0.5); the image centre is (W/2, H/2)
    W, H, p = 3031, 2006, 0.004
    uv = np.array([[0.5, 0.5], [1515.5, 1003.0], [0.0, 0.0]])
    xy = mm_from_pixels(uv, (W, H), p, "colmap")
    np.testing.assert_allclose(xy[1], [0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(xy[2], [-W / 2 * p, H / 2 * p], atol=1e-15)
    # the same physical pixel centre in both conventions is the same mm position
    np.testing.assert_allclose(xy[0], mm_from_pixels([0.0, 0.0], (W, H), p, "opencv"), atol=1e-15)
    np.testing.assert_allclose(pixels_from_mm(xy, (W, H), p, "colmap"), uv, atol=1e-12)


def test_pixels_per_point_size_and_pitch():
    uv = np.array([[10.0, 20.0], [10.0, 20.0]])
    xy = mm_from_pixels(uv, np.array([[100, 50], [200, 80]]), np.array([0.01, 0.002]), "opencv")
    np.testing.assert_allclose(xy, [[(10 - 49.5) * 0.01, -(20 - 24.5) * 0.01],
                                    [(10 - 99.5) * 0.002, -(20 - 39.5) * 0.002]], atol=1e-15)
    with pytest.raises(ValueError, match="pixel convention"):
        mm_from_pixels(uv, (10, 10), 1.0, "matlab")


# ---------------------------------------------------------------------------------------------
# poses
# ---------------------------------------------------------------------------------------------

def test_pose_round_trip_and_axes():
    rng = np.random.default_rng(1)
    opk = rng.uniform(-1, 1, (5, 3))
    X0 = rng.normal(size=(5, 3)) * 10
    R, t = cv_from_pose(X0, opk)
    for k in range(5):
        X0b, opkb = pose_from_cv(R[k], t[k])
        np.testing.assert_allclose(X0b, X0[k], atol=1e-12)
        np.testing.assert_allclose(opkb, opk[k], atol=1e-12)
        # the y-down/z-forward frame is baarda's image-space frame with y and z flipped
        np.testing.assert_allclose(R[k], np.diag([1, -1, -1]) @ rotation_from_opk(*opk[k]), atol=1e-15)
    # a camera at the origin with ω φ κ = 0 looks down −Z: a point at Z = −5 is in front (z_cv > 0)
    R0, t0 = cv_from_pose(np.zeros((1, 3)), np.zeros((1, 3)))
    p = R0[0] @ np.array([0.3, 0.2, -5.0]) + t0[0]
    assert p[2] > 0 and p[1] < 0          # in front; y up in baarda = y negative (up) in OpenCV


# ---------------------------------------------------------------------------------------------
# distortion: brown (baarda, mm) ↔ OpenCV / COLMAP (normalized)
# ---------------------------------------------------------------------------------------------

def _single_photo_block(c, xp, yp, ap, X, X0, opk, pitch, size):
    cams = Cameras.make(["k"], c, xp, yp, ap_model="brown", ap=np.atleast_2d(ap), pixel_mm=pitch, resolution=size)
    pts = Points.make([str(i) for i in range(len(X))], XYZ=X)
    ph = Photos.make(["p"], 0, X0=X0, opk=opk)
    obs = Observations.make(np.zeros(len(X), int), np.arange(len(X)), np.zeros((len(X), 2)))
    return Block(cams, ph, pts, obs)


def _scene(rng, n=200):
    X = np.column_stack([rng.uniform(-4, 4, n), rng.uniform(-3, 3, n), rng.uniform(-2, 2, n)])
    return X, np.array([0.3, -0.2, 12.0]), np.array([0.05, -0.08, 0.6])


@pytest.mark.parametrize("fx_over_fy", [1.0, 1.002])
def test_brown_equals_opencv_projectpoints(fx_over_fy):
    """Independent reference: cv2.projectPoints with (k1, k2, p1, p2, k3)."""
    import cv2

    rng = np.random.default_rng(7)
    W, H, pitch = 4000, 3000, 0.0039
    fy = 3200.0
    fx = fy * fx_over_fy
    cx, cy = 2011.3, 1490.8
    k1, k2, p1, p2, k3 = -0.12, 0.05, 0.0012, -0.0007, -0.01
    X, X0, opk = _scene(rng)
    c, ap = brown_from_opencv(fx, fy, pitch, k1=k1, k2=k2, p1=p1, p2=p2, k3=k3)
    xp, yp = mm_from_pixels([cx, cy], (W, H), pitch, "opencv")
    b = _single_photo_block(c, xp, yp, ap, X, X0, opk, pitch, (W, H))
    uv_baarda = pixels_from_mm(project_block(b, np.zeros(len(X), int), np.arange(len(X))), (W, H), pitch, "opencv")
    R, t = cv_from_pose(X0[None], opk[None])
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    uv_cv, _ = cv2.projectPoints(X, cv2.Rodrigues(R[0])[0], t[0], K, np.array([k1, k2, p1, p2, k3]))
    err = np.abs(uv_baarda - uv_cv.reshape(-1, 2)).max()
    if fx_over_fy == 1.0:
        assert opencv_brown_exact(fx, fy, k1, k2, p1, p2, k3)
        assert err < 1e-9, err
    else:
        # not exact: brown's radial/decentring terms are not scaled by fx/fy; the error is
        # (fx/fy − 1) × distortion, i.e. 0.2 % of up to ~700 px here
        assert not opencv_brown_exact(fx, fy, k1, k2, p1, p2, k3)
        assert 1e-3 < err < 0.002 * 800, err


def test_brown_opencv_round_trip_and_units():
    pitch = 0.0045
    c, ap = brown_from_opencv(1000.0, 1000.0, pitch, k1=-0.2, k2=0.03, p1=0.001, p2=-0.002, k3=0.004)
    assert c == pytest.approx(4.5)
    K1, K2, K3, P1, P2, B1, B2 = ap
    assert K1 == pytest.approx(-0.2 / 4.5**2) and K2 == pytest.approx(0.03 / 4.5**4)
    assert K3 == pytest.approx(0.004 / 4.5**6)
    assert P1 == pytest.approx(-0.002 / 4.5) and P2 == pytest.approx(-0.001 / 4.5)   # P1 = p2/c, P2 = −p1/c
    assert B1 == 0 and B2 == 0
    back = opencv_from_brown(c, ap, pitch)
    for key, v in {"fx": 1000, "fy": 1000, "k1": -0.2, "k2": 0.03, "p1": 0.001, "p2": -0.002, "k3": 0.004}.items():
        assert back[key] == pytest.approx(v, rel=1e-12, abs=1e-15)
    with pytest.raises(ValueError, match="B2"):
        opencv_from_brown(c, np.r_[ap[:6], 1e-4], pitch)


def _colmap_examples():
    return {
        "SIMPLE_PINHOLE": [2400.0, 1500.3, 999.1],
        "PINHOLE": [2400.0, 2403.5, 1500.3, 999.1],
        "SIMPLE_RADIAL": [2400.0, 1500.3, 999.1, -0.09],
        "RADIAL": [2400.0, 1500.3, 999.1, -0.09, 0.02],
        "OPENCV": [2400.0, 2400.0, 1500.3, 999.1, -0.09, 0.02, 0.001, -0.0005],
        "FULL_OPENCV": [2400.0, 2400.0, 1500.3, 999.1, -0.09, 0.02, 0.001, -0.0005, 0.003, 0, 0, 0],
    }


@pytest.mark.parametrize("model", list(COLMAP_PARAMS))
def test_colmap_models_equal_pycolmap_projection(model):
    """Each supported COLMAP model: baarda's projection equals pycolmap's img_from_cam (< 1e-9 px)
    and the inverse mapping gives the same COLMAP parameters back."""
    import pycolmap

    params = np.array(_colmap_examples()[model])
    W, H, pitch = 3000, 2000, 0.0059
    cam = pycolmap.Camera.create_from_model_name(1, model, 1.0, W, H)
    cam.params = params
    b = brown_from_colmap(model, params, (W, H), pitch)
    assert b["exact"]
    rng = np.random.default_rng(3)
    X, X0, opk = _scene(rng)
    blk = _single_photo_block(b["c"], b["xp"], b["yp"], b["ap"], X, X0, opk, pitch, (W, H))
    uv = pixels_from_mm(project_block(blk, np.zeros(len(X), int), np.arange(len(X))), (W, H), pitch, "colmap")
    R, t = cv_from_pose(X0[None], opk[None])
    ref = cam.img_from_cam(X @ R[0].T + t[0])
    assert np.abs(uv - ref).max() < 1e-9
    name, back = colmap_from_brown(b["c"], b["xp"], b["yp"], b["ap"], (W, H), pitch, model)
    assert name == model
    np.testing.assert_allclose(back, params, rtol=1e-12, atol=1e-15)


def test_colmap_auto_model_choice_and_limits():
    W, H, p = 1000, 800, 0.01
    none = np.zeros(7)
    assert colmap_from_brown(5.0, 0, 0, none, (W, H), p)[0] == "SIMPLE_PINHOLE"
    assert colmap_from_brown(5.0, 0, 0, np.r_[0.001, 0, 0, 0, 0, 0, 0], (W, H), p)[0] == "SIMPLE_RADIAL"
    assert colmap_from_brown(5.0, 0, 0, np.r_[0.001, 1e-5, 0, 0, 0, 0, 0], (W, H), p)[0] == "RADIAL"
    assert colmap_from_brown(5.0, 0, 0, np.r_[0, 0, 0, 0, 0, 1e-3, 0], (W, H), p)[0] == "PINHOLE"
    assert colmap_from_brown(5.0, 0, 0, np.r_[0.001, 0, 0, 1e-4, 0, 0, 0], (W, H), p)[0] == "OPENCV"
    assert colmap_from_brown(5.0, 0, 0, np.r_[0.001, 0, 1e-7, 0, 0, 0, 0], (W, H), p)[0] == "FULL_OPENCV"
    with pytest.raises(UnsupportedCamera, match="B1"):
        colmap_from_brown(5.0, 0, 0, np.r_[0.001, 0, 0, 0, 0, 1e-3, 0], (W, H), p)
    with pytest.raises(ValueError, match="B2"):
        colmap_from_brown(5.0, 0, 0, np.r_[0, 0, 0, 0, 0, 0, 1e-3], (W, H), p)
    with pytest.raises(UnsupportedCamera, match="SIMPLE_RADIAL cannot hold brown K2"):
        colmap_from_brown(5.0, 0, 0, np.r_[0.001, 1e-5, 0, 0, 0, 0, 0], (W, H), p, "SIMPLE_RADIAL")
    assert BROWN == ("K1", "K2", "K3", "P1", "P2", "B1", "B2")


@pytest.mark.parametrize("model,params", [("OPENCV_FISHEYE", [500, 500, 320, 240, 0.1, 0, 0, 0]),
                                          ("FOV", [500, 500, 320, 240, 0.9]),
                                          ("FULL_OPENCV", [500, 500, 320, 240, 0, 0, 0, 0, 0, 0.1, 0, 0])])
def test_unsupported_colmap_models(model, params):
    with pytest.raises(UnsupportedCamera):
        brown_from_colmap(model, params, (640, 480), 0.01)


def test_opencv_with_aspect_and_distortion_is_flagged_inexact():
    b = brown_from_colmap("OPENCV", [2400.0, 2410.0, 1500, 1000, -0.1, 0, 0, 0], (3000, 2000), 0.005)
    assert not b["exact"]
    b = brown_from_colmap("OPENCV", [2400.0, 2410.0, 1500, 1000, 0, 0, 0, 0], (3000, 2000), 0.005)
    assert b["exact"]
