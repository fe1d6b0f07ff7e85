"""Target detection: real OpenCV sample photos (counts, cv2.calibrateCamera reference), rendered
ArUco / circle targets (accuracy against the drawn truth), board geometry, broken input, logging."""

from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.model import Block, Cameras, Observations, Photos, Points
from baarda.pipeline.options import parse_options
from baarda.pipeline.stage import Context
from baarda.pipeline.geometry.image import pixels_from_mm
from baarda.pipeline.adjustment import project_block
from baarda.plugins.targets.boards import F_BOARD, BoardGeometry, object_points, opencv_board
from baarda.plugins.targets.calib import opencv_calibration
from baarda.plugins.targets.detect import (detect_aruco, detect_blobs, detect_circles_grid, match_to_predicted,
                                    refine_ellipse_centres)
from baarda.plugins.targets.stage import TargetDetection, TargetOptions

from .conftest import run_targets

S = 8   # supersampling of rendered images


def _run(folder: Path, **opts):
    return run_targets(folder, **opts)


# ---------------------------------------------------------------------------------------------
# real photos
# ---------------------------------------------------------------------------------------------

def test_chessboard_counts_and_opencv_reference(chessboard):
    res, ctx = chessboard
    det = res.summary["detections"]
    assert len(det) == 26 and all(n == 54 for n in det.values()), det
    assert res.summary["headline"].startswith("chessboard: 26 of 26 image(s) used; 1404 image points of 54 object "
                                              "points (54 per image); cv2.calibrateCamera RMS left 0.")
    assert ctx.warnings == []
    b = res.artefacts["block"]
    assert b.cameras.ids.tolist() == ["left", "right"] and b.object_unit == "mm"
    assert (b.points.role == "full").all() and np.allclose(b.points.XYZ[:, 2], 0.0)
    assert b.photos.has_orientation.all()                    # approximations by solvePnP
    assert (b.photos.X0[:, 2] > 100).all()                    # cameras on the +Z side of the board
    for cam in ("left", "right"):
        ref = res.summary["opencv_calibration"][cam]
        d = ", ".join(f"{v:+.5f}" for v in ref["dist"])
        print(f"\ncv2.calibrateCamera {cam} (13 views, 702 corners): fx {ref['fx']:.3f} fy {ref['fy']:.3f} "
              f"cx {ref['cx']:.3f} cy {ref['cy']:.3f} px, (k1 k2 p1 p2 k3) = ({d}), RMS {ref['rms_px']:.4f} px")
        assert len(ref["views"]) == 13 and ref["n_points"] == 702
        assert 500 < ref["fx"] < 570 and abs(ref["fx"] / ref["fy"] - 1) < 0.005
        assert 300 < ref["cx"] < 360 and 210 < ref["cy"] < 270
        assert -0.4 < ref["dist"][0] < -0.2                  # barrel distortion of the webcam
        assert ref["rms_px"] < 0.3


def test_charuco_counts_occlusion_and_reference(charuco, shared_data):
    res, ctx = charuco
    det = res.summary["detections"]
    print(f"\nChArUco corners per image (OpenCV defaults + subpixel refinement): {det}")
    assert det == {"img_00": 24, "img_01": 24, "img_02": 24, "img_03": 24, "chocclusion_original": 16}
    assert any("chocclusion_original.jpg: partial board: 16 of 24" in w for w in ctx.warnings)
    ref = res.summary["opencv_calibration"]["cam"]
    print(f"cv2.calibrateCamera ChArUco (5 views, {ref['n_points']} corners): fx {ref['fx']:.2f} fy {ref['fy']:.2f} "
          f"cx {ref['cx']:.2f} cy {ref['cy']:.2f} px, dist {np.round(ref['dist'], 4).tolist()}, RMS {ref['rms_px']:.4f} px")
    assert ref["n_points"] == 112 and ref["rms_px"] < 0.3
    b = res.artefacts["block"]
    assert b.object_unit == "m" and len(b.points) == 24
    # the tutorial's detector settings (no corner refinement) find fewer corners; still handled
    res2, ctx2 = _run(shared_data / "opencv-charuco", images=["img_0*.jpg", "chocclusion_original.jpg"],
                      target="charuco", squares=[5, 7], square_size=0.04, marker_size=0.02, unit="m",
                      detector_params="detector_params.yml")
    print(f"with detector_params.yml: {res2.summary['detections']}")
    assert res2.summary["detections"] == {"img_00": 22, "img_01": 24, "img_02": 21, "img_03": 24,
                                          "chocclusion_original": 14}


def test_charuco_control_points_fit_the_photos(charuco):
    """The board coordinates (ids → object points) are consistent with the image points:
    a resection per photo with OpenCV's calibration reprojects to < 0.5 px."""
    import cv2

    res, _ = charuco
    b = res.artefacts["block"]
    ref = opencv_calibration(b, 0)
    K = np.array([[ref["fx"], 0, ref["cx"]], [0, ref["fy"], ref["cy"]], [0, 0, 1]])
    obs = b.observations
    for k in range(len(b.photos)):
        rows = obs.photo == k
        X = b.points.XYZ[obs.point[rows]] @ F_BOARD
        uv = pixels_from_mm(obs.xy[rows], (640, 480), b.cameras.pixel_mm[0], "opencv")
        ok, rv, tv = cv2.solvePnP(X, uv, K, np.array(ref["dist"]))
        proj, _ = cv2.projectPoints(X, rv, tv, K, np.array(ref["dist"]))
        assert np.sqrt(((proj.reshape(-1, 2) - uv) ** 2).sum(1).mean()) < 0.5


def test_board_geometry_matches_opencv_boards():
    import cv2

    g = BoardGeometry("charuco", squares=(5, 7), square_size=0.04, marker_size=0.02)
    ids, X = object_points(g)
    ref = opencv_board(g).getChessboardCorners()
    np.testing.assert_allclose(X @ F_BOARD, ref, atol=1e-7)
    assert ids[:3] == ["0", "1", "2"] and len(ids) == 24
    g = BoardGeometry("aruco", markers=(3, 2), marker_size=0.04, marker_separation=0.01)
    ids, X = object_points(g)
    ref = np.concatenate([np.asarray(c).reshape(4, 3) for c in opencv_board(g).getObjPoints()])
    np.testing.assert_allclose(X @ F_BOARD, ref, atol=1e-7)
    assert ids[4:8] == ["4", "5", "6", "7"]
    g = BoardGeometry("chessboard", squares=(10, 7), square_size=25.0)
    ids, X = object_points(g)
    assert len(ids) == 54
    np.testing.assert_allclose(X[10], [25.0, -25.0, 0.0])       # row 1, col 1: Y = −row · s (y up)
    with pytest.raises(ValueError, match="square_size"):
        BoardGeometry("chessboard", squares=(10, 7))
    with pytest.raises(ValueError, match="marker_size must be smaller"):
        BoardGeometry("charuco", squares=(5, 7), square_size=0.02, marker_size=0.03)


# ---------------------------------------------------------------------------------------------
# rendered targets: accuracy against the drawn truth (OpenCV pixel-centre convention)
# ---------------------------------------------------------------------------------------------

def _downsample(big: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.resize(big, (big.shape[1] // S, big.shape[0] // S), interpolation=cv2.INTER_AREA)


def _small(uv_big):
    """Supersampled → final pixel coordinates (pixel-centre convention)."""
    return (np.asarray(uv_big, float) + 0.5) / S - 0.5


def _render_aruco_grid(angle_deg=12.0, shift=(137.3, 81.7)):
    """An ArUco grid board (3 × 2 markers, DICT_6X6_250) rotated and shifted; truth corners in pixels."""
    import cv2

    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
    side, gap, margin = 64 * S, 16 * S, 24 * S          # supersampled pixels: 8 px per bit cell when final
    board = np.full((2 * margin + 2 * side + gap, 2 * margin + 3 * side + 2 * gap), 255, np.uint8)
    truth = {}
    for m in range(6):
        r, c = divmod(m, 3)
        x0, y0 = margin + c * (side + gap), margin + r * (side + gap)
        board[y0:y0 + side, x0:x0 + side] = cv2.aruco.generateImageMarker(d, m, side)
        corners = np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]], float) - 0.5
        for k in range(4):
            truth[str(4 * m + k)] = corners[k]
    a = np.deg2rad(angle_deg)
    A = np.array([[np.cos(a), -np.sin(a), shift[0] * S], [np.sin(a), np.cos(a), shift[1] * S]])
    big = cv2.warpAffine(board, A, (640 * S, 480 * S), flags=cv2.INTER_LINEAR, borderValue=255)
    truth = {k: _small(A[:, :2] @ v + A[:, 2]) for k, v in truth.items()}
    return _downsample(big), truth


def test_rendered_aruco_corners():
    img, truth = _render_aruco_grid()
    g = BoardGeometry("aruco", markers=(3, 2), marker_size=1.0)
    det = detect_aruco(img, g)
    assert sorted(det.ids, key=int) == sorted(truth, key=int)
    err = np.array([det.uv[i] - truth[k] for i, k in enumerate(det.ids)])
    rms = np.sqrt((err**2).mean())
    print(f"\nrendered ArUco grid: {len(det)} corners, RMS error {rms:.3f} px per coordinate, max {np.abs(err).max():.3f} px")
    assert rms < 0.2 and np.abs(err).max() < 0.5


def _render_dots(centres, radius, size=(640, 480), dark=True):
    import cv2

    big = np.full((size[1] * S, size[0] * S), 255 if dark else 20, np.uint8)
    for u, v in centres:
        cb = ((u + 0.5) * S - 0.5, (v + 0.5) * S - 0.5)      # final → supersampled coordinates
        cv2.circle(big, (int(round(cb[0] * 16)), int(round(cb[1] * 16))), int(round(radius * S * 16)),
                   30 if dark else 240, -1, cv2.LINE_AA, shift=4)
    return _downsample(big)


def test_rendered_circle_grid_subpixel():
    rng = np.random.default_rng(5)
    cols, rows, step = 7, 5, 52.0
    origin = np.array([140.37, 110.81])
    grid = np.array([[c * step, r * step] for r in range(rows) for c in range(cols)], float)
    a = np.deg2rad(4.0)
    Rm = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    truth = grid @ Rm.T + origin + rng.uniform(-0.3, 0.3, grid.shape) * 0   # exact grid
    img = _render_dots(truth, radius=12.3)
    det = detect_circles_grid(img, BoardGeometry("circles-grid", circles=(cols, rows), square_size=10.0))
    assert len(det) == cols * rows, det.message
    # OpenCV orders the grid row by row; match the order to the truth by nearest neighbour
    d = np.linalg.norm(det.uv[:, None] - truth[None], axis=2)
    err = det.uv - truth[d.argmin(axis=1)]
    rms = np.sqrt((err**2).mean())
    print(f"\nrendered circle grid: {len(det)} centres, RMS {rms:.4f} px per coordinate, max {np.abs(err).max():.4f} px")
    assert rms < 0.05
    # the ids follow the grid order: neighbours in a row are one step apart
    uv = det.uv.reshape(rows, cols, 2)
    assert np.allclose(np.linalg.norm(np.diff(uv, axis=1), axis=2), step, atol=0.2)


def test_refine_ellipse_centres_light_and_dark():
    truth = np.array([[100.3, 120.7], [300.55, 200.15], [500.9, 400.4]])
    for dark in (True, False):
        img = _render_dots(truth, radius=9.0, dark=dark)
        found = detect_blobs(img, "dark" if dark else "light")
        assert len(found) == 3
        d = np.linalg.norm(found[:, None] - truth[None], axis=2)
        assert d.min(axis=1).max() < 0.05, d.min(axis=1)
    refined, ok = refine_ellipse_centres(img, truth + 1.5, radius_px=14.0)
    assert ok.all() and np.abs(refined - truth).max() < 0.05
    _, ok = refine_ellipse_centres(img, np.array([[2.0, 2.0]]), 14.0)    # window outside the image
    assert not ok.any()


def test_match_to_predicted_is_one_to_one():
    uv = np.array([[10.0, 10.0], [50.0, 50.0], [52.0, 50.0], [90, 90]])
    pred = np.array([[11.0, 9.0], [51.0, 50.0], [200.0, 200.0], [89, 91]])
    det = match_to_predicted(uv, pred, ["a", "b", "c", "d"], 5.0)
    assert det.ids == ["a", "d"] and "1 layout point(s) ambiguous" in det.message
    np.testing.assert_allclose(det.uv, [[10, 10], [90, 90]])


def _layout_block(pitch=0.005):
    """A planar target field (5 × 4 dots) seen by one photo; the layout for target 'circles'."""
    XY = np.array([[x, y] for y in np.linspace(-0.3, 0.3, 4) for x in np.linspace(-0.5, 0.5, 5)])
    pts = Points.make([f"T{i}" for i in range(len(XY))], XYZ=np.column_stack([XY, np.zeros(len(XY))]), role="full")
    cams = Cameras.make(["cam"], 3.2, 0.01, -0.02, ap_model="brown", ap=[[-2e-3, 0, 0, 0, 0, 0, 0]], pixel_mm=pitch,
                        resolution=(640, 480))
    ph = Photos.make(["shot1"], 0, X0=[0.05, -0.02, 2.0], opk=[0.05, -0.03, 0.2])
    return Block(cams, ph, pts, Observations.make([], [], np.zeros((0, 2))), object_unit="m")


def test_circles_matched_to_layout_block(tmp_path):
    import cv2

    layout = _layout_block()
    n = len(layout.points)
    truth = pixels_from_mm(project_block(layout, np.zeros(n, int), np.arange(n)), (640, 480), 0.005, "opencv")
    img = _render_dots(truth, radius=6.0)
    cv2.imwrite(str(tmp_path / "shot1.png"), img)
    cv2.imwrite(str(tmp_path / "other.png"), img)
    # approximate orientation: shifted by a few pixels
    approx = layout.replace(photos=layout.photos.replace(X0=layout.photos.X0 + [0.004, 0.0, 0.01]))
    ctx = Context("det", project_dir=tmp_path)
    res = TargetDetection().run({"block": approx}, parse_options(TargetOptions, {"images": ["*.png"],
                                                                                 "target": "circles"}), ctx)
    b = res.artefacts["block"]
    assert b.photos.ids.tolist() == ["shot1"] and len(b.observations) == n
    assert any("other.png" in w and "not in the input block" in w for w in ctx.warnings)
    # the photo's file travels with the block (the bundle's residual figure draws it behind the arrows)
    assert b.photos.images() == {"shot1": str(tmp_path / "shot1.png")}
    uv = pixels_from_mm(b.observations.xy, (640, 480), 0.005, "opencv")
    idx = layout.points.index_of(b.points.ids[b.observations.point])
    err = uv - truth[idx]
    print(f"\n'circles' matched to a layout: {len(err)} of {n}, RMS {np.sqrt((err**2).mean()):.4f} px")
    assert np.abs(err).max() < 0.05
    np.testing.assert_allclose(b.observations.cov[:, 0, 0], (0.07 * 0.005) ** 2)
    with pytest.raises(InputError, match="input block"):
        TargetDetection().run({}, parse_options(TargetOptions, {"images": ["*.png"], "target": "circles"}), ctx)


# ---------------------------------------------------------------------------------------------
# stage: pixel ↔ mm, sigmas, broken input, logging
# ---------------------------------------------------------------------------------------------

def test_stage_pixels_to_mm_and_sigma(tmp_path):
    import cv2

    img, truth = _render_aruco_grid()
    cv2.imwrite(str(tmp_path / "grid.png"), img)
    res, _ = _run(tmp_path, images=["grid.png"], target="aruco", markers=[3, 2], marker_size=12.0,
                  marker_separation=3.0, pixel_mm=0.0045)
    b = res.artefacts["block"]
    ids = b.points.ids[b.observations.point]
    uv = np.array([truth[i] for i in ids])
    # closed form: x = (u − (W − 1)/2) p, y = −(v − (H − 1)/2) p
    expected = np.column_stack([(uv[:, 0] - 319.5) * 0.0045, -(uv[:, 1] - 239.5) * 0.0045])
    assert np.abs(b.observations.xy - expected).max() < 0.5 * 0.0045
    np.testing.assert_allclose(b.observations.cov[:, 0, 0], (0.2 * 0.0045) ** 2)        # ArUco corners 0.2 px
    np.testing.assert_allclose(b.cameras.format_mm, [[640 * 0.0045, 480 * 0.0045]])
    assert b.cameras.resolution.tolist() == [[640, 480]]
    res, _ = _run(tmp_path, images=["grid.png"], target="aruco", sigma_px=0.3)
    b = res.artefacts["block"]
    assert (b.points.role == "tie").all() and np.isnan(b.points.XYZ).all()     # single markers: no geometry
    np.testing.assert_allclose(b.observations.cov[:, 1, 1], (0.3 * 0.001) ** 2)


def test_broken_images_are_warnings(tmp_path, shared_data):
    import shutil

    (tmp_path / "broken.jpg").write_text("not an image")
    blank = np.full((480, 640), 200, np.uint8)
    import cv2

    cv2.imwrite(str(tmp_path / "blank.png"), blank)
    shutil.copy(shared_data / "opencv-chessboard" / "left01.jpg", tmp_path / "left01.jpg")
    res, ctx = _run(tmp_path, images=["broken.jpg", "blank.png", "left01.jpg"], target="chessboard",
                    squares=[10, 7], square_size=25.0, chessboard_method="classic")
    assert len(res.artefacts["block"].photos) == 1
    assert res.summary["detections"] == {"broken": 0, "blank": 0, "left01": 54}
    text = "\n".join(ctx.warnings)
    assert "broken.jpg: not a readable image" in text
    assert "blank.png: no 9×6 inner-corner chessboard found" in text
    table = res.tables["images"]
    assert table.columns["status"] == ["skipped", "skipped", "ok"]
    assert table.columns["file"] == ["broken.jpg", "blank.png", "left01.jpg"]     # no machine path
    det = res.tables["detections"]
    assert len(det) == 54 and set(det.columns["photo"]) == {"left01"} and det.units["x_px"] == "px"
    assert 0 < min(det.columns["x_px"]) and max(det.columns["x_px"]) < 640 and max(det.columns["y_px"]) < 480
    with pytest.raises(InputError, match="image file not found.*gone.jpg"):   # an explicit list is not a glob
        _run(tmp_path, images=["left01.jpg", "gone.jpg"], target="chessboard", squares=[10, 7], square_size=25.0)
    with pytest.raises(InputError, match="no usable detection"):
        _run(tmp_path, images=["broken.jpg", "blank.png"], target="chessboard", squares=[10, 7], square_size=25.0)
    with pytest.raises(InputError, match="no image matches"):
        _run(tmp_path, images=["*.tif"], target="chessboard", squares=[10, 7], square_size=25.0)
    with pytest.raises(InputError, match="squares"):
        parse_options(TargetOptions, {"images": ["x"], "target": "chessboard", "square_size": 25.0})
    with pytest.raises(InputError, match="unknown ArUco dictionary|dictionary"):
        _run(tmp_path, images=["left01.jpg"], target="aruco", dictionary="DICT_9X9_1")
    with pytest.raises(InputError, match="unknown interior parameter"):
        parse_options(TargetOptions, {"images": ["x"], "target": "aruco", "unknowns": ["f"]})


def test_log_images_to_rerun(charuco, tmp_path):
    from baarda.pipeline.recording import open_recording, read_recording

    res, _ = charuco
    rec = open_recording(tmp_path / "t.rrd", "test")
    TargetDetection().log(res, rec, Context("targets", project_dir=tmp_path))
    rec.disconnect()
    summary = read_recording(tmp_path / "t.rrd")
    paths = {e.path for e in summary.entities}
    assert "/t/targets/images/img_00" in paths and "/t/targets/images/chocclusion_original/points" in paths
    assert "Image" in " ".join(summary.archetypes) and "Points2D" in " ".join(summary.archetypes)


@pytest.mark.parametrize("printed_legacy", [True, False])
def test_charuco_legacy_pattern_even_rows(printed_legacy):
    """A 5 × 6 board (even rows) printed with the pre-4.6 layout is found only with
    legacy_pattern = true, and vice versa; corners land on the drawn square corners."""
    from baarda.plugins.targets.detect import detect_charuco

    geom = lambda legacy: BoardGeometry("charuco", squares=(5, 6), square_size=1.0, marker_size=0.7,
                                        legacy_pattern=legacy)
    sq, m = 60, 40
    img = opencv_board(geom(printed_legacy)).generateImage((5 * sq + 2 * m, 6 * sq + 2 * m), marginSize=m)
    right = detect_charuco(img, geom(printed_legacy))
    wrong = detect_charuco(img, geom(not printed_legacy))
    assert len(right) == 20 and len(wrong) == 0 and "no ChArUco corners" in wrong.message
    ids, X = object_points(geom(printed_legacy))
    truth = {i: np.array([m + X[k, 0] * sq - 0.5, m - X[k, 1] * sq - 0.5]) for k, i in enumerate(ids)}
    err = np.array([right.uv[k] - truth[i] for k, i in enumerate(right.ids)])
    assert np.abs(err).max() < 0.05


def test_stage_contract_and_project(shared_data, tmp_path):
    from baarda.pipeline.testing import check_stage, run_project_text

    check_stage(TargetDetection, "opencv-targets")
    with pytest.raises(InputError, match="required option 'target'"):
        parse_options(TargetOptions, {"images": ["a.png"]})
    folder = shared_data / "opencv-charuco"
    out = run_project_text(f"""
[[stage]]
use = "opencv-targets"
id = "charuco"
[stage.options]
images = ["{folder}/img_01.jpg", "{folder}/chocclusion_original.jpg"]
target = "charuco"
squares = [5, 7]
square_size = 40.0
marker_size = 20.0
pixel_mm = 0.0014
""", tmp_path)
    assert out.ok, out.message
    rec = out.stages[0]
    assert (out.run_dir / "charuco_detections.csv").is_file() and (out.run_dir / "charuco.rrd").is_file()
    b = out.artefacts["block"]
    assert len(b.photos) == 2 and b.object_unit == "mm"
    np.testing.assert_allclose(b.cameras.pixel_mm, 0.0014)
