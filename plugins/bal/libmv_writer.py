"""Writer of libmv / Blender camera-tracking problem files and the stage ``libmv-export``.

The inverse of :func:`.libmv.read_libmv` / :func:`.libmv.block_from_libmv` (layout in
:mod:`.libmv`): little-endian ``v``, markers in pixels ``P``, the shared intrinsics
``f, cx, cy, k1, k2, k3, p1, p2`` (float32), one libmv camera per oriented photo (image number,
column-major ``R``, ``t`` of the y-down/z-forward ``cam_from_world``), one track per point with
coordinates, one marker per active observation (pixels from the top-left corner).  The
conversions are the reader's, run backwards: :func:`~baarda.pipeline.camera.convert.opencv_from_brown`
(of ``brown_from_opencv``), :func:`~baarda.pipeline.geometry.pose.cv_from_pose` (of ``pose_from_cv``),
:func:`~baarda.pipeline.geometry.image.pixels_from_mm` (of ``mm_from_pixels``, corner convention).

libmv holds one camera for every image, OpenCV's model with ``fx = fy``, float32 values and
whole-number image and track ids.  A block that does not fit (several cameras, another AP model,
brown B1 or B2 ≠ 0, ids that are not whole numbers, no pixel pitch or image size) is refused with
an :class:`InputError` naming what.  float32 keeps about 7 digits: coordinates far from the origin
lose precision (the report says how much; ``docs/bal-libmv.md``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baarda.pipeline.camera.convert import opencv_from_brown
from baarda.pipeline.api import Context, InputError, StageResult, option
from baarda.pipeline.geometry.image import pixels_from_mm
from baarda.pipeline.geometry.pose import cv_from_pose

from .libmv import LibmvProblem


def _whole_ids(ids, what: str) -> np.ndarray:
    out = []
    for i in np.asarray(ids).tolist():
        try:
            v = int(str(i))
        except ValueError:
            raise InputError(f"{what} id {str(i)!r}: libmv numbers its {what}s with whole numbers",
                             field=what) from None
        if not -2**31 <= v < 2**31:
            raise InputError(f"{what} id {str(i)!r} does not fit libmv's int32", field=what)
        out.append(v)
    return np.array(out, int)


def libmv_from_block(block) -> tuple[LibmvProblem, dict]:
    """The libmv problem of ``block``: photos with an orientation become cameras, points with
    coordinates and an active observation by such a photo become tracks, their active
    observations markers (block order).  Returns the problem and ``info`` (counts, left out)."""
    cams, ph, pts, obs = block.cameras, block.photos, block.points, block.observations
    if len(cams) != 1:
        raise InputError(f"a libmv problem holds one camera for every image; the block has {len(cams)}",
                         field="camera")
    cid, model = str(cams.ids[0]), str(cams.ap_model[0])
    if model not in ("brown", "none"):
        raise InputError(f"camera {cid!r} uses the {model!r} model; libmv's is OpenCV's (baarda's 'brown')",
                         field="ap_model")
    pitch = float(cams.pixel_mm[0])
    size = tuple(int(v) for v in np.asarray(cams.resolution[0]).tolist())
    if not (np.isfinite(pitch) and pitch > 0 and min(size) > 0):
        raise InputError(f"camera {cid!r} has no pixel pitch or image size; libmv's markers are pixels",
                         field="camera")
    ap = np.zeros(7) if model == "none" else np.asarray(cams.ap[0], float)
    if ap.size > 5 and ap[5] != 0.0:
        raise InputError(f"camera {cid!r}: B1 = {ap[5]:g} (fx ≠ fy) cannot be written, libmv has one focal length",
                         field="B1")
    try:
        cv = opencv_from_brown(float(cams.c[0]), ap, pitch)
    except ValueError as e:
        raise InputError(f"camera {cid!r}: {e}", field="B2") from None
    cx, cy = pixels_from_mm([float(cams.xp[0]), float(cams.yp[0])], size, pitch, "colmap")
    oriented = np.isfinite(ph.X0).all(axis=1) & np.isfinite(ph.opk).all(axis=1)
    act = np.asarray(obs.active, bool) & oriented[obs.photo]
    known = np.isfinite(pts.XYZ).all(axis=1)
    act &= known[obs.point]
    used_pt = np.zeros(len(pts), bool)
    used_pt[obs.point[act]] = True
    image = _whole_ids(ph.ids[oriented], "photo")
    track = _whole_ids(pts.ids[used_pt], "point")
    R, t = cv_from_pose(ph.X0[oriented], ph.opk[oriented])
    uv = pixels_from_mm(obs.xy[act], size, pitch, "colmap")
    img_of = np.full(len(ph), -1)
    img_of[oriented] = image
    trk_of = np.full(len(pts), -1)
    trk_of[used_pt] = track
    problem = LibmvProblem(
        intrinsics=np.array([cv["fy"], cx, cy, cv["k1"], cv["k2"], cv["k3"], cv["p1"], cv["p2"]], float),
        image=image, R=R, t=t, track=track, X=np.asarray(pts.XYZ, float)[used_pt],
        marker_image=img_of[obs.photo[act]], marker_track=trk_of[obs.point[act]], marker_xy=uv)
    info = {"cameras": int(oriented.sum()), "points": int(used_pt.sum()), "markers": int(act.sum()),
            "skipped_photos": [str(i) for i in ph.ids[~oriented].tolist()],
            "skipped_points": int(len(pts) - used_pt.sum()), "skipped_observations": int(len(obs) - act.sum()),
            "resolution": list(size)}
    return problem, info


def libmv_bytes(problem: LibmvProblem) -> bytes:
    """The file's bytes (little endian, pixel markers)."""
    f4, i4 = "<f4", "<i4"
    cams = np.zeros(len(problem.image), [("image", i4), ("R", f4, (9,)), ("t", f4, (3,))])
    cams["image"] = problem.image
    cams["R"] = np.transpose(problem.R, (0, 2, 1)).reshape(-1, 9)          # column-major in the file
    cams["t"] = problem.t
    pts = np.zeros(len(problem.track), [("track", i4), ("X", f4, (3,))])
    pts["track"], pts["X"] = problem.track, problem.X
    mk = np.zeros(len(problem.marker_image), [("image", i4), ("track", i4), ("xy", f4, (2,))])
    mk["image"], mk["track"], mk["xy"] = problem.marker_image, problem.marker_track, problem.marker_xy
    parts = [b"vP", np.asarray(problem.intrinsics, f4).tobytes()]
    for rec in (cams, pts, mk):
        parts += [np.array([len(rec)], i4).tobytes(), rec.tobytes()]
    return b"".join(parts)


def float32_loss(problem: LibmvProblem) -> dict:
    """Largest change of coordinates and markers by float32 rounding (object units, pixels)."""
    def d(a):
        a = np.asarray(a, float)
        return float(np.abs(a.astype(np.float32).astype(float) - a).max(initial=0.0))

    return {"points": max(d(problem.X), d(problem.t)), "markers_px": d(problem.marker_xy)}


@dataclass(frozen=True)
class LibmvExportOptions:
    path: Path = option(Path("problem.libmv"), "output file inside the run directory")
    source: bool = option(False, "write the block as the source stage read it (initial values) instead of the "
                                 "bundle's adjusted block")


class LibmvExport:
    summary = "block (adjusted when a bundle ran) → libmv/Blender tracking problem (one camera, OpenCV model)"
    reads = ("block", "bundle?")
    writes = ()
    paths = {"path": "output"}
    outputs = ()                          # no table or figure: every other name is free for path
    Options = LibmvExportOptions

    def run(self, inputs, options: LibmvExportOptions, ctx: Context) -> StageResult:
        bundle = inputs.get("bundle")
        block = inputs["block"] if bundle is None else bundle.block
        if options.source and bundle is not None:
            block = bundle.block_in
        out = ctx.output_path(options.path, "path")
        out.parent.mkdir(parents=True, exist_ok=True)
        try:
            problem, info = libmv_from_block(block)
        except InputError as e:
            raise ctx.option_error(f"cannot write a libmv problem: {e.message}", "path") from None
        out.write_bytes(libmv_bytes(problem))
        loss = float32_loss(problem)
        what = "source" if options.source or bundle is None else "adjusted"
        report = (f"Wrote the {what} block as the libmv problem `{options.path}`: {info['cameras']} cameras, "
                  f"{info['points']} tracks, {info['markers']} markers; float32 rounding moves coordinates by up to "
                  f"{loss['points']:.3g} {block.object_unit} and markers by up to {loss['markers_px']:.3g} px.")
        if info["skipped_photos"] or info["skipped_points"] or info["skipped_observations"]:
            report += (f"  Left out: {len(info['skipped_photos'])} photo(s) without orientation, "
                       f"{info['skipped_points']} point(s) without coordinates or active rays, "
                       f"{info['skipped_observations']} inactive or unusable observation(s).")
        left = len(info["skipped_photos"]) + info["skipped_points"] + info["skipped_observations"]
        headline = (f"libmv problem {options.path} ({what} block): {info['cameras']} cameras, {info['points']} tracks, "
                    f"{info['markers']} markers; float32 rounding ≤ {loss['markers_px']:.3g} px"
                    + (f"; left out {len(info['skipped_photos'])} photo(s), {info['skipped_points']} point(s), "
                       f"{info['skipped_observations']} observation(s)" if left else ""))
        return StageResult(summary={**info, **{f"float32_{k}": v for k, v in loss.items()},
                                    "path": str(options.path), "block": what, "headline": headline}, report=report)
