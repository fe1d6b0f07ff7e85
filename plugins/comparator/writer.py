"""Writer of comparator files in photo mode and the stage ``comparator-export``.

The inverse of :func:`.parser.parse_comparator` + :func:`.block.build_block` for image
coordinates already in mm (``mode photo``; format: ``docs/comparator-format.md``): ``unit mm``,
the cameras (``camera <id> c … format … xp … yp …``), one photo section per photo with every active
measurement and its own σ (``pt <id> <x> <y> <sx> <sy>``), the stereo pairs, the object points with
role, coordinates and — where they differ from the role's default — a-priori σ.

What the format cannot hold is refused with an :class:`InputError` naming the camera, point or
photo: additional parameters (the format has c, xp, yp only), correlated image coordinates (only
``sx sy``: ``on_correlated = "drop"`` writes them without the correlation, with a warning), ids with
blanks, an object unit other than m or mm, a free coordinate of a control point.  Machine
coordinates and fiducials are not written: the block holds image coordinates after the interior
orientation.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from baarda.pipeline.api import Context, InputError, StageResult, option
from baarda.pipeline.model import Points

from .block import IMPLICIT_CAMERA


def _g(v: float) -> str:
    """Shortest text that reads back as the same float."""
    return repr(float(v))


def _check_id(i, what: str) -> str:
    s = str(i)
    if not s or any(ch.isspace() for ch in s) or s.startswith("#"):
        raise InputError(f"{what} id {s!r} cannot be written to a comparator file (empty, blanks or '#')", field=what)
    return s


def comparator_text(block, *, on_correlated: str = "error") -> tuple[str, dict]:
    """The comparator file (photo mode) of ``block`` and ``info``."""
    if block.object_unit not in ("m", "mm"):
        raise InputError(f"object unit {block.object_unit!r}: comparator files hold m or mm", field="object_unit")
    cams, ph, pts, obs = block.cameras, block.photos, block.points, block.observations
    lines = ["# comparator file written by baarda (comparator-export): image coordinates in mm",
             "unit mm", "mode photo", f"object_unit {block.object_unit}", ""]
    implicit = len(cams) == 1 and not np.isfinite(cams.c[0])
    for j in range(len(cams)):
        cid = _check_id(cams.ids[j], "camera")
        ap = np.asarray(cams.ap[j], float)
        if np.any(ap != 0.0):
            k = int(np.flatnonzero(ap != 0.0)[0])
            raise InputError(f"camera {cid!r} ({cams.ap_model[j]} model) has additional parameter {k + 1} = "
                             f"{ap[k]:g}; comparator files hold c, xp, yp only", field="ap")
        if implicit:
            if cid != IMPLICIT_CAMERA or cams.xp[j] != 0.0 or cams.yp[j] != 0.0:
                raise InputError(f"camera {cid!r} has no principal distance; a comparator file needs c", field="c")
            continue
        if not (np.isfinite(cams.c[j]) and cams.c[j] > 0):
            raise InputError(f"camera {cid!r} has no principal distance; a comparator file needs c", field="c")
        text = f"camera {cid} c {_g(cams.c[j])}"
        fmt = np.asarray(cams.format_mm[j], float)
        if np.isfinite(fmt).all() and (fmt > 0).all():
            text += f" format {_g(fmt[0])} {_g(fmt[1])}"
        text += f" xp {_g(cams.xp[j])} yp {_g(cams.yp[j])}"
        lines.append(text)
    if not implicit:
        lines.append("")
    sxy = np.sqrt(np.stack([obs.cov[:, 0, 0], obs.cov[:, 1, 1]], axis=1))
    act = np.asarray(obs.active, bool)
    corr = act & (obs.cov[:, 0, 1] != 0.0)
    if corr.any() and on_correlated == "error":
        r = int(np.flatnonzero(corr)[0])
        raise InputError(f"the measurement of point {str(pts.ids[obs.point[r]])!r} in photo "
                         f"{str(ph.ids[obs.photo[r]])!r} has correlated x, y; a comparator file holds sx sy only "
                         "(on_correlated = 'drop' writes them without the correlation)", field="on_correlated")
    for i in range(len(ph)):
        pid = _check_id(ph.ids[i], "photo")
        lines.append(f"photo {pid}" + ("" if implicit else f" camera {cams.ids[ph.camera[i]]}"))
        for r in np.flatnonzero(act & (obs.photo == i)):
            q = _check_id(pts.ids[obs.point[r]], "point")
            lines.append(f"pt {q} {_g(obs.xy[r, 0])} {_g(obs.xy[r, 1])} {_g(sxy[r, 0])} {_g(sxy[r, 1])}")
        lines.append("")
    for a, b in zip(block.pairs.left, block.pairs.right):
        lines.append(f"pair {ph.ids[a]} {ph.ids[b]}")
    default = Points.make(pts.ids, pts.XYZ, pts.role).sigma
    declared = 0
    for k in range(len(pts)):
        q = _check_id(pts.ids[k], "point")
        role = str(pts.role[k])
        xyz = np.asarray(pts.XYZ[k], float)
        if not np.isfinite(xyz).all():
            if role != "tie":
                raise InputError(f"{role} point {q!r} has no coordinates", field="point")
            continue                          # a measured tie point needs no line
        text = f"point {q} {role} {_g(xyz[0])} {_g(xyz[1])} {_g(xyz[2])}"
        s = np.asarray(pts.sigma[k], float)
        if not np.array_equal(s, default[k]):
            if not np.isfinite(s).all():
                raise InputError(f"point {q!r} ({role}) has the a-priori σ {s.tolist()}; a comparator file holds "
                                 "finite σ for all three coordinates or the role's default", field="sigma")
            text += f" {_g(s[0])} {_g(s[1])} {_g(s[2])}"
        lines.append(text)
        declared += 1
    info = {"cameras": 0 if implicit else len(cams), "photos": len(ph), "measurements": int(act.sum()),
            "inactive_left_out": int((~act).sum()), "correlation_dropped": int(corr.sum()),
            "points_declared": declared, "pairs": len(block.pairs)}
    return "\n".join(lines).rstrip() + "\n", info


def write_comparator(block, path: str | Path, **kw) -> dict:
    text, info = comparator_text(block, **kw)
    Path(path).write_text(text, encoding="utf-8")
    return info


# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ComparatorExportOptions:
    path: Path = option(Path("comparator.cmp"), "output file inside the run directory")
    source: bool = option(False, "write the block as read (the bundle's input block) instead of the adjusted one")
    on_correlated: Literal["error", "drop"] = option(
        "error", "image coordinates with correlated x, y (a fiducial-mode source): 'error', or 'drop' the "
                 "correlation with a warning (the format holds sx sy only)")


class ComparatorExport:
    summary = "block → comparator file in photo mode (image coordinates in mm, cameras c xp yp, points, pairs)"
    reads = ("block", "bundle?")
    writes = ()
    paths = {"path": "output"}
    outputs = ()                          # no table or figure: every other name is free for path
    Options = ComparatorExportOptions

    def run(self, inputs, options: ComparatorExportOptions, ctx: Context) -> StageResult:
        bundle = inputs.get("bundle")
        block = inputs["block"] if bundle is None else bundle.block
        if options.source and bundle is not None:
            block = bundle.block_in
        out = ctx.output_path(options.path, "path")
        out.parent.mkdir(parents=True, exist_ok=True)
        try:
            info = write_comparator(block, out, on_correlated=options.on_correlated)
        except InputError as e:
            key = "on_correlated" if e.field == "on_correlated" else "path"
            raise ctx.option_error(f"cannot write a comparator file: {e.message}", key) from None
        if info["correlation_dropped"]:
            ctx.warn(f"{info['correlation_dropped']} measurement(s) written without their x–y correlation "
                     "(on_correlated = 'drop')")
        report = (f"Wrote the comparator file `{options.path}` (photo mode, mm): {info['photos']} photos, "
                  f"{info['measurements']} measurements, {info['points_declared']} object points, {info['pairs']} "
                  "pair(s).")
        if info["inactive_left_out"]:
            report += f"  {info['inactive_left_out']} inactive measurement(s) left out."
        headline = (f"comparator file {options.path} (photo mode, mm): {info['photos']} photos, {info['measurements']} "
                    f"measurements, {info['points_declared']} object points, {info['pairs']} pair(s)"
                    + (f"; {info['inactive_left_out']} inactive left out" if info["inactive_left_out"] else ""))
        return StageResult(summary={**info, "path": str(options.path), "headline": headline}, report=report)
