"""Stage ``opencv-targets``: detect targets in images and emit a block of image observations.

Per image: read (grayscale), detect, convert pixels to mm with the camera's pitch and format
(``docs/conventions.md``: ``x = (u − (W−1)/2) p``, ``y = −(v − (H−1)/2) p``), attach the a-priori
sigma of the target type.  A known board gives full control points (Z = 0) and approximate photo
orientations (``cv2.solvePnP``).  A problem with one image (unreadable, nothing found, too few
points, other size) is a warning and the image is skipped; only "no usable image at all" fails.
The block of the detections is built in :mod:`.blocks`, the report text in :mod:`.report`.
"""

from __future__ import annotations

import dataclasses
import glob
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from baarda.pipeline.api import (CircleTargets, Context, InputError, RigConfig, Stage, StageResult, TableData,
                                 attach_rigs, entity_part,
                                 log_block, option)
from baarda.pipeline.geometry import rotation_from_opk
from baarda.pipeline.imagefiles import read_gray

from baarda.pipeline.geometry.image import pixels_from_mm
from baarda.pipeline.api import project_block
from baarda.pipeline.camera.convert import BROWN

from .blocks import IOP, consistent_rig_ids, detection_block
from .boards import BoardGeometry, aruco_dictionary
from .calib import opencv_calibration, opencv_stereo
from .detect import (DEFAULT_SIGMA_PX, Detection, detect_aruco, detect_blobs, detect_charuco, detect_chessboard,
                     detect_circles_grid, detector_parameters, match_to_predicted)
from .report import detection_report, headline


@dataclass(frozen=True)
class TargetOptions:
    target: Literal["chessboard", "charuco", "aruco", "circles-grid", "circles"] = field(
        metadata={"doc": "target type (required); 'circles' takes ids from the layout of an input block (matching)"})
    images: list[str] = option([], "image files or glob patterns, relative to the project file; empty: the "
                                   "'images' artefact of an earlier stage (e.g. testfield-render), whose pixel "
                                   "pitch then replaces pixel_mm")
    squares: list[int] = option([], "chessboard / ChArUco: squares along x and y (OpenCV's 9×6 inner-corner "
                                    "sample board is [10, 7])")
    square_size: float = option(0.0, "side of a square (circle grid: centre spacing), in 'unit'")
    marker_size: float = option(0.0, "side of an ArUco marker (ChArUco, ArUco grid), in 'unit'")
    marker_separation: float = option(0.0, "ArUco grid board: gap between markers, in 'unit'")
    markers: list[int] = option([], "ArUco grid board: markers along x and y; empty: single markers (tie points)")
    circles: list[int] = option([], "circle grid: circles per row and rows [cols, rows]")
    asymmetric: bool = option(False, "circle grid with every other row offset (OpenCV's asymmetric grid)")
    dictionary: str = option("DICT_6X6_250", "ArUco dictionary (ChArUco, ArUco)")
    legacy_pattern: bool = option(False, "ChArUco board printed with OpenCV < 4.6 (even number of rows)")
    detector_params: str = option("", "YAML file of ArUco detector parameters (default: OpenCV's defaults "
                                      "with subpixel corner refinement)")
    chessboard_method: Literal["auto", "sb", "classic"] = option(
        "auto", "chessboard detector: findChessboardCornersSB, findChessboardCorners + cornerSubPix, or sb then classic")
    unit: Literal["mm", "m", "cm"] = option("mm", "unit of the board lengths = the block's object unit")
    pixel_mm: float = option(0.001, "camera pixel pitch, mm (default 1 µm: µm in reports read as pixels)")
    principal_distance_mm: float = option(0.0, "principal distance guess, mm; 0: estimated from the board "
                                               "(cv2.initCameraMatrix2D) or, without one, the image width")
    camera_from_name: str = option("", "regular expression on the file name whose first group (or match) "
                                       "names the camera, e.g. '^(left|right)'; empty: one camera 'cam'")
    ap_model: Literal["brown", "none"] = option("brown", "additional-parameter model of the cameras")
    unknowns: list[str] = option(["c", "xp", "yp", "K1", "K2", "K3", "P1", "P2"],
                                 "interior parameters that are unknowns (self-calibration); the others are fixed")
    sigma_px: float = option(0.0, "a-priori sigma of an image coordinate, pixels; 0: per target type "
                                  "(ChArUco/chessboard 0.05, ArUco corners 0.2, circles 0.07)")
    min_points: int = option(4, "images with fewer detected points are skipped (warning)")
    match_radius_px: float = option(10.0, "'circles': largest distance of a blob from its predicted position")
    polarity: Literal["auto", "dark", "light"] = option("auto", "'circles': dark dots, light dots or both")
    eccentricity: bool = option(True, "'circles': the bundle corrects the detected (ellipse) centres for the "
                                      "perspective eccentricity of circular targets (needs circle_diameter or an "
                                      "input block with a circle table; docs/targets.md)")
    circle_diameter: float = option(0.0, "'circles': diameter of the circular targets, in 'unit' (converted to the "
                                         "block's object unit); 0: the input block's circle table, if any", ge=0.0)
    circle_normal: list[float] = option([], "'circles': normal of the targets' plane [X, Y, Z] in the object system "
                                            "(a planar test field); empty: per target, the best-fitting plane of "
                                            "its 8 nearest targets at the adjusted coordinates")
    circle_normals: dict[str, list[float]] = option({}, "'circles': normals of single targets, point id -> [X, Y, Z] "
                                                        "(override circle_normal for those points)")
    circle_diameters: dict[str, float] = option({}, "'circles': diameters of single targets, point id -> diameter in "
                                                    "'unit' (override circle_diameter for those points)", gt=0.0)
    opencv_reference: bool = option(True, "with a known board: also run cv2.calibrateCamera per camera and report it")
    log_max_size: int = option(800, "longest side of the images logged to rerun, pixels")
    rig: RigConfig = option(RigConfig(), "the cameras as a rig (rig table and frames, docs/rigs.md); a rig of two "
                                         "cameras is also calibrated by cv2.stereoCalibrate for comparison")

    def __post_init__(self):       # pixel_mm > 0: the range its name implies (pipeline/options.py)
        bad = sorted(set(self.unknowns) - set(IOP) - set(BROWN))
        if bad:
            raise ValueError(f"unknown interior parameter(s) {bad} in 'unknowns'; known: {', '.join(IOP + BROWN)}")
        if self.camera_from_name:
            try:
                re.compile(self.camera_from_name)
            except re.error as e:
                raise ValueError(f"camera_from_name is not a regular expression: {e}") from None
        for name, n in [("circle_normal", self.circle_normal)] * bool(self.circle_normal) + [
                (f"circle_normals.{k}", v) for k, v in self.circle_normals.items()]:
            if len(n) != 3 or not np.all(np.isfinite(n)) or not np.any(np.asarray(n, float)):
                raise ValueError(f"{name}: expected 3 finite numbers, not all zero [X, Y, Z], got {n!r}")
        self.geometry()   # validates the board options
        if self.target in ("aruco", "charuco"):
            aruco_dictionary(self.dictionary)

    def geometry(self) -> BoardGeometry:
        two = lambda v: tuple(int(x) for x in v) if len(v) == 2 else (0, 0)
        if any(len(v) not in (0, 2) for v in (self.squares, self.markers, self.circles)):
            raise ValueError("squares, markers and circles take two numbers [x, y]")
        return BoardGeometry(self.target, squares=two(self.squares), square_size=self.square_size,
                             marker_size=self.marker_size, marker_separation=self.marker_separation,
                             markers=two(self.markers), circles=two(self.circles), asymmetric=self.asymmetric,
                             dictionary=self.dictionary, legacy_pattern=self.legacy_pattern)


def find_images(patterns: list[str], base: Path) -> list[Path]:
    """Files matching the patterns (sorted per pattern, first occurrence kept)."""
    out, seen = [], set()
    for pat in patterns:
        p = Path(pat).expanduser()
        full = p if p.is_absolute() else base / p
        hits = sorted(Path(h) for h in glob.glob(str(full))) if glob.has_magic(str(full)) else [full]
        for h in hits:
            if h not in seen:
                seen.add(h)
                out.append(h)
    return out


def camera_name(file: Path, pattern: str) -> str | None:
    """Camera id of an image from ``pattern`` (first group or whole match); None if it does not match."""
    if not pattern:
        return "cam"
    m = re.search(pattern, file.name)
    if not m:
        return None
    return m.group(1) if m.groups() else m.group(0)


def _photo_ids(files: list[Path]) -> list[str]:
    stems = [f.stem for f in files]
    if len(set(stems)) == len(stems):
        return stems
    return [str(f) for f in files]


def _downscale(gray: np.ndarray, max_size: int) -> tuple[np.ndarray, float]:
    import cv2

    s = min(1.0, max_size / max(gray.shape[:2])) if max_size > 0 else 1.0
    if s >= 1.0:
        return gray, 1.0
    return cv2.resize(gray, (int(round(gray.shape[1] * s)), int(round(gray.shape[0] * s))),
                      interpolation=cv2.INTER_AREA), s


MIN_IMAGE_PX = 16
"""Images smaller than this (either side, pixels) hold no target a detector can find: skipped."""


def _quiet_opencv() -> None:
    """OpenCV's own log lines (``[ERROR:0@3.7] … readHeader …``) off: the stage reports unreadable
    images itself, as one warning naming the file."""
    import cv2

    try:
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    except AttributeError:        # a build without the logging utilities
        pass


class TargetDetection(Stage):
    """Detect ArUco markers, ChArUco boards, chessboards or circular targets in images → block."""

    summary = "OpenCV target detection in images → block (image observations in mm, board as control)"
    reads = ("block?", "images?")
    writes = ("block",)
    paths = {"images": "glob", "detector_params": "input"}
    Options = TargetOptions

    @staticmethod
    def keeps_rows(options: TargetOptions) -> bool:
        """'circles' measures the points of its input block in that block's photos: at most one
        observation per photo and point of the layout (``baarda validate`` keeps the layout's bound)."""
        return options.target == "circles"

    def validate(self, options: TargetOptions, ctx: Context) -> None:
        """``baarda validate``: the images exist and have a readable image header, the detector
        parameters parse; no detection (that is the run's work)."""
        import cv2

        if options.target in ("charuco", "aruco"):
            self._params(options, ctx)
        if not options.images:
            return None
        files = find_images(options.images, ctx.project_dir)
        if not files:
            raise InputError(f"no image matches {options.images}", field="images", path=ctx.project_file)
        _quiet_opencv()
        usable = 0
        for f in files:
            gray = read_gray(f) if f.is_file() else None
            if gray is None or min(gray.shape) < MIN_IMAGE_PX:
                ctx.warn(f"{f}: {'not a readable image' if gray is None else 'too small'}; a run skips it")
            else:
                usable += 1
        if not usable:
            raise InputError(f"none of the {len(files)} image(s) is a readable image of at least {MIN_IMAGE_PX} "
                             "pixels", field="images", path=ctx.project_file)
        if options.rig.table:
            _with_rig(_skeleton_block(files, options), options, ctx)
        return None

    def _params(self, options: TargetOptions, ctx: Context):
        try:
            return detector_parameters(ctx.resolve(options.detector_params) if options.detector_params else None)
        except ValueError as e:
            raise InputError(str(e), field="detector_params", path=ctx.project_file) from None

    def run(self, inputs, options: TargetOptions, ctx: Context) -> StageResult:
        import cv2

        _quiet_opencv()
        geom = options.geometry()
        art_ids = None
        if options.images:
            for pat in options.images:      # an explicit list is not a glob: a file it names must exist
                if not glob.has_magic(str(pat)) and not ctx.resolve(pat).is_file():
                    raise ctx.option_error(f"image file not found: {ctx.resolve(pat)}", "images")
            files = find_images(options.images, ctx.project_dir)
            if not files:
                raise InputError(f"no image matches {options.images}", field="images", path=ctx.project_file)
        else:
            art = inputs.get("images")
            if art is None:
                raise InputError("option 'images' is empty and no earlier stage wrote an 'images' artefact: give "
                                 "image files or glob patterns", field="images", path=ctx.project_file)
            files = [Path(f) for f in art.paths]
            if not files:
                raise InputError("the 'images' artefact of the earlier stage holds no image", field="images",
                                 path=ctx.project_file)
            options = dataclasses.replace(options, pixel_mm=float(art.pixel_mm))
            art_ids = [str(i) for i in art.photo_ids]
        layout = inputs.get("block") if options.target == "circles" else None
        if options.target == "circles" and layout is None:
            raise InputError("target 'circles' takes its ids from an input block (layout points and approximate "
                             "orientations); add a source stage before this one, or use 'circles-grid'",
                             field="target", path=ctx.project_file)
        params = self._params(options, ctx) if options.target in ("charuco", "aruco") else None
        sigma_px = options.sigma_px or DEFAULT_SIGMA_PX[options.target]
        photo_ids = art_ids or _photo_ids(files)

        rows, dets, logged = [], [], []
        for file, pid in ctx.progress.track(list(zip(files, photo_ids)), what="images"):
            row = {"file": str(file), "photo": pid, "camera": "", "points": 0, "status": "ok", "message": ""}
            rows.append(row)
            cam = camera_name(file, options.camera_from_name)
            if cam is None:
                row["status"], row["message"] = "skipped", "file name does not match camera_from_name"
                ctx.warn(f"{file.name}: {row['message']} '{options.camera_from_name}'")
                continue
            row["camera"] = cam
            gray = read_gray(file) if file.is_file() else None
            if gray is None:
                row["status"] = "skipped"
                row["message"] = "file not found" if not file.exists() else "not a readable image"
                ctx.warn(f"{file}: {row['message']}; skipped")
                continue
            if min(gray.shape) < MIN_IMAGE_PX:
                row["status"], row["message"] = "skipped", f"{gray.shape[1]} × {gray.shape[0]} pixels: too small"
                ctx.warn(f"{file}: {row['message']}; skipped")
                continue
            try:
                det = self._detect(gray, geom, options, params, layout, pid)
            except cv2.error as e:          # OpenCV refuses this image: skip it as an unreadable one
                row["status"], row["message"] = "skipped", f"OpenCV: {str(e).strip().splitlines()[-1][:120]}"
                ctx.warn(f"{file}: {row['message']}; skipped")
                continue
            det.extra["file"] = str(file)
            row["points"], row["message"] = len(det), det.message
            small, s = _downscale(gray, options.log_max_size)
            logged.append((pid, small, det.uv * s + (s - 1) / 2, det.ids))
            if len(det) < options.min_points:
                row["status"] = "skipped"
                ctx.warn(f"{file.name}: {det.message or 'too few points'} ({len(det)} < min_points "
                         f"{options.min_points}); skipped")
                continue
            if det.message:
                ctx.warn(f"{file.name}: {det.message}")
            dets.append((pid, cam, (gray.shape[1], gray.shape[0]), det))
        if not dets:
            raise InputError(f"no usable detection in {len(files)} image(s) (see the warnings)", field="images",
                             path=ctx.project_file)
        block, info = detection_block(dets, geom, options, sigma_px, layout, ctx.warn)
        if options.target == "circles":
            block = block.replace(circles=circle_table(options, layout, block))
        for r in rows:
            if r["photo"] in info["size_mismatch"]:
                r["status"], r["message"] = "skipped", "image size differs from the camera's first image"
        summary = {**block.summary(), "target": options.target, "sigma_px": sigma_px,
                   **({"circles": _circles_summary(block)} if block.circles is not None else {}),
                   "images": len(files), "used_images": len(block.photos),
                   "detections": {r["photo"]: r["points"] for r in rows}, "cameras_px": info["cameras_px"]}
        ref = {}
        if options.opencv_reference and geom.has_geometry:
            for k, cid in enumerate(block.cameras.ids):
                try:
                    # like for like: OpenCV frees the parameters this stage frees (opencv_flags)
                    cal = opencv_calibration(block, k, free=options.unknowns)
                except ValueError as e:
                    ctx.warn(str(e))
                    continue
                ref[str(cid)] = {key: v for key, v in cal.items() if key not in ("rvecs", "tvecs")}
            summary["opencv_calibration"] = ref
        if options.rig.table:
            block = _with_rig(block, options, ctx)
            if options.target == "chessboard":
                block = consistent_rig_ids(block, ctx.warn)
            summary["rig"] = {"sensors": len(block.rigs.sensors), "frames": len(set(block.rigs.frames.frame.tolist()))}
        if options.rig.table and options.opencv_reference and len(ref) == 2 and len(block.rigs.sensors) == 2:
            try:
                stereo = opencv_stereo(block, options.unknowns, ref)
            except ValueError as e:
                ctx.warn(str(e))
            else:
                rs = block.rigs.sensors
                right = ~rs.reference
                rc, ro = np.array(rs.ref_centre), np.array(rs.ref_opk)
                rc[right], ro[right] = stereo["centre"], stereo["opk"]
                block = block.replace(rigs=block.rigs.replace(sensors=rs.replace(ref_centre=rc, ref_opk=ro),
                                                              reference_name="cv2.stereoCalibrate"))
                summary["opencv_stereo"] = stereo
        folder = _common_folder(files)
        per_image = TableData({"file": [_relative(r["file"], folder) for r in rows],
                               **{k: [r[k] for r in rows] for k in ("photo", "camera", "points", "status", "message")}},
                              f"detections per image (file: relative to the image folder {folder.name or folder}/)")
        table = TableData({"photo": [pid for pid, _, _, d in dets for _ in d.ids],
                           "camera": [cam for _, cam, _, d in dets for _ in d.ids],
                           "point": [str(i) for _, _, _, d in dets for i in d.ids],
                           "x_px": np.concatenate([d.uv[:, 0] for *_, d in dets]),
                           "y_px": np.concatenate([d.uv[:, 1] for *_, d in dets])},
                          "every detection: its image point in pixels (OpenCV convention: origin at the centre of the "
                          "top-left pixel, x right, y down), as detected (before any image is dropped)",
                          detail=True)
        report = detection_report(options, files, rows, block, ref, sigma_px)
        if "opencv_stereo" in summary:
            st = summary["opencv_stereo"]
            report += (f"\n\ncv2.stereoCalibrate reference, rig {st['left']} + {st['right']} ({len(st['frames'])} frames, "
                       f"the same interior parameters free, started from cv2.calibrateCamera): baseline |T| = "
                       f"{st['baseline']:.4f} {block.object_unit}, T = ({', '.join(f'{t:.4f}' for t in st['T'])}) "
                       f"{block.object_unit}, RMS {st['rms_px']:.4f} px; flags {', '.join(st['flags']) or 'none'}. "
                       "The bundle compares its rig with it (bundle section, differences in σ).")
        summary["headline"] = headline(options.target, rows, block, ref)
        return StageResult(artefacts={"block": block}, summary=summary, report=report, tables={"detections": table, "images": per_image},
                           data={"images": logged, "block": block})

    # -- per image ------------------------------------------------------------------------------
    def _detect(self, gray, geom, options, params, layout, pid) -> Detection:
        t = options.target
        if t == "chessboard":
            return detect_chessboard(gray, geom, options.chessboard_method)
        if t == "charuco":
            return detect_charuco(gray, geom, params)
        if t == "aruco":
            return detect_aruco(gray, geom, params)
        if t == "circles-grid":
            return detect_circles_grid(gray, geom)
        # circles: ids from the layout block
        uv = detect_blobs(gray, options.polarity)
        try:
            k = int(layout.photos.index_of([pid])[0])
        except KeyError:
            return Detection([], np.zeros((0, 2)), f"photo '{pid}' not in the input block (layout)")
        if not layout.photos.has_orientation[k]:
            return Detection([], np.zeros((0, 2)), f"photo '{pid}' has no approximate orientation in the input block")
        cams = layout.cameras
        ci = int(layout.photos.camera[k])
        pts = layout.points
        ph = layout.photos
        depth = (pts.XYZ - ph.X0[k]) @ rotation_from_opk(*ph.opk[k])[2]     # W < 0: in front of the camera
        known = np.flatnonzero(np.isfinite(pts.XYZ).all(axis=1) & (depth < 0))
        xy = project_block(layout, np.full(known.size, k), known)
        size = (gray.shape[1], gray.shape[0])
        pred = pixels_from_mm(xy, size, cams.pixel_mm[ci] if np.isfinite(cams.pixel_mm[ci]) else options.pixel_mm,
                              "opencv")
        inside = (pred[:, 0] >= 0) & (pred[:, 1] >= 0) & (pred[:, 0] <= size[0] - 1) & (pred[:, 1] <= size[1] - 1)
        return match_to_predicted(uv, pred[inside], [str(i) for i in pts.ids[known[inside]]], options.match_radius_px)

    def log(self, result, rec, ctx) -> None:
        import rerun as rr

        for pid, small, uv, ids in result.data["images"]:
            path = f"{ctx.stage_id}/images/{entity_part(pid)}"
            rec.log(path, rr.Image(small), static=True)
            if len(ids):
                rec.log(f"{path}/points", rr.Points2D(uv, labels=list(ids), colors=[[255, 60, 40]],
                                                      radii=rr.Radius.ui_points(3.0)), static=True)
        log_block(rec, result.data["block"], root=f"{ctx.stage_id}/block")


_UNIT_M = {"mm": 1e-3, "cm": 1e-2, "m": 1.0, "ft": 0.3048, "km": 1e3}


def circle_table(options: TargetOptions, layout, block) -> CircleTargets | None:
    """The circle table the output block carries for the bundle's eccentricity correction: every
    detected point a circle of ``circle_diameter`` (in ``unit``, converted to the block's object unit)
    with ``circle_normal`` (or NaN: estimated); without a diameter the input block's own table (its
    rows of the detected points); None with ``eccentricity = false`` or nothing known."""
    if not options.eccentricity:
        return None
    known = set(block.points.ids.tolist()) | set(getattr(layout, "points", block.points).ids.tolist())
    for name, table in (("circle_normals", options.circle_normals), ("circle_diameters", options.circle_diameters)):
        bad = sorted(set(table) - known)
        if bad:
            raise InputError(f"{name}: no point {bad[0]!r} in the input block", field=name)
    own = getattr(layout, "circles", None)
    if options.circle_diameter > 0 or options.circle_diameters:
        if block.object_unit not in _UNIT_M:
            raise InputError(f"circle_diameter: the input block's object unit {block.object_unit!r} is not a length "
                             f"({', '.join(_UNIT_M)}): the diameter cannot be converted", field="circle_diameter")
        f = _UNIT_M[options.unit] / _UNIT_M[block.object_unit]
        ids = block.points.ids.tolist()
        d = np.array([options.circle_diameters.get(i, options.circle_diameter) * f for i in ids])
        n = np.array([options.circle_normals.get(i, options.circle_normal or [np.nan] * 3) for i in ids], float)
        keep = d > 0                        # without circle_diameter only the points circle_diameters names
        return CircleTargets.make(np.asarray(ids)[keep], d[keep], n[keep]) if keep.any() else None
    if own is None:
        return None
    keep = np.isin(own.ids, block.points.ids)
    if not keep.any():
        return None
    own = own.take(keep)
    if options.circle_normal or options.circle_normals:
        n = np.array([options.circle_normals.get(i, options.circle_normal or list(v))
                      for i, v in zip(own.ids.tolist(), own.normal)], float)
        own = own.replace(normal=n)
    return own


def _circles_summary(block) -> dict:
    c = block.circles
    d = np.unique(c.diameter)
    return {"targets": len(c), "diameter": float(d[0]) if d.size == 1 else [float(d.min()), float(d.max())],
            "unit": block.object_unit, "normals_given": int(np.isfinite(c.normal).all(axis=1).sum())}


def _skeleton_block(files, options: TargetOptions):
    """Cameras and photos the images name (no observations): what ``baarda validate`` checks a rig
    table and its frames against."""
    from baarda.pipeline.api import Block
    from baarda.pipeline.model import Cameras, Observations, Photos, Points

    ids = _photo_ids(files)
    cams = [camera_name(f, options.camera_from_name) for f in files]
    keep = [i for i, c in enumerate(cams) if c is not None]
    cam_ids = list(dict.fromkeys(cams[i] for i in keep))
    return Block(Cameras.make(cam_ids, 1.0), Photos.make([ids[i] for i in keep], [cam_ids.index(cams[i]) for i in keep]),
                 Points.make([]), Observations.make(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2))),
                 object_unit=options.unit)


def _with_rig(block, options: TargetOptions, ctx: Context):
    """The detections' block with the rig of the option table ``rig`` (docs/rigs.md)."""
    rc = options.rig
    try:
        return attach_rigs(block, ctx.resolve(rc.table), frames=ctx.resolve(rc.frames) if rc.frames else None,
                           frames_from_name=rc.frames_from_name)
    except InputError as e:
        if e.path is None:
            raise ctx.option_error(e.message, e.field or "rig") from None
        raise


def _common_folder(files) -> Path:
    """The deepest folder holding every image (for file names without the machine's path)."""
    parents = [str(Path(f).resolve().parent) for f in files]
    return Path(os.path.commonpath(parents)) if parents else Path(".")


def _relative(file, folder: Path) -> str:
    try:
        return Path(file).resolve().relative_to(folder).as_posix()
    except ValueError:
        return Path(file).name
