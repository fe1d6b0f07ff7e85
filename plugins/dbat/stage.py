"""Source stage ``dbat``: a DBAT script project (XML + control, check, image list, marks) as a block.

Parsing and the mapping to baarda live in :mod:`.reader` (``docs/dbat.md``); this stage resolves the
path, reports what was read (camera in DBAT's and baarda's conventions, which parameters are
estimated, control and check points, marks per file) and logs the points.  No orientation is
given: the bundle resects every photo from the control points and intersects the rest
(``baarda.pipeline.adjustment.initial_values``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baarda.pipeline.errors import InputError
from baarda.pipeline.options import option
from baarda.pipeline.report import markdown_table
from baarda.pipeline.stage import Context, SourceStage, StageResult, TableData

from .reader import AP_NAMES, DBAT_SIGN, dbat_block, read_dbat


@dataclass(frozen=True)
class DbatOptions:
    path: Path | None = option(None, "the DBAT script project (XML), relative to the project file (required)")
    dbat_dir: Path | None = option(None, "DBAT's installation folder, for paths that use $DBAT (the photos of "
                                         "an image list are otherwise looked up beside the list)")


class DbatSource(SourceStage):
    summary = "Read a DBAT script project (XML, control/check points, marks, PhotoModeler-style camera)"
    reads = ()
    writes = ("block",)
    Options = DbatOptions

    def run(self, inputs, options: DbatOptions, ctx: Context) -> StageResult:
        if options.path is None or not str(options.path) or str(options.path) == ".":
            raise InputError("the dbat stage needs the option 'path' (the script's XML file)",
                             path=ctx.project_file, field="path")
        dbat_dir = ctx.resolve(options.dbat_dir) if options.dbat_dir is not None else None
        script = read_dbat(ctx.resolve(options.path), dbat_dir=dbat_dir)
        block = dbat_block(script)
        d = block.meta["dbat"]
        pts = block.points
        summary = {**block.summary(), "script": d["script"], "name": d["name"],
                   "control": int((pts.role == "full").sum()), "check": int((pts.role == "check").sum()),
                   "tie": int((pts.role == "tie").sum()), "marks": [m["count"] for m in d["marks"]],
                   "dropped_points": len(d["dropped_points"]), "dropped_marks": d["dropped_marks"],
                   "photos_found": sum(v is not None for v in d["images"].values()),
                   "estimated": [k for k, v in d["estimate_io"].items() if v]}
        return StageResult(artefacts={"block": block}, summary=summary, report=_report(block),
                           tables=_tables(block), data={"block": block})

    def log(self, result: StageResult, rec, ctx: Context) -> None:
        import rerun as rr

        block = result.data["block"]
        pts = block.points
        ok = np.isfinite(pts.XYZ).all(axis=1)
        colors = {"full": [230, 60, 60], "check": [60, 120, 230]}
        for role in ("full", "check"):
            sel = ok & (pts.role == role)
            if sel.any():
                rec.log(f"world/{'control' if role == 'full' else 'check'}_points",
                        rr.Points3D(pts.XYZ[sel], labels=pts.ids[sel].tolist(), colors=colors[role],
                                    radii=rr.Radius.ui_points(5.0)), static=True)


def _fmt_sigma(s):
    s = np.asarray(s, float)
    if np.all(s == 0):
        return "fixed"
    return "/".join(f"{v:g}" for v in s)


def _report(block) -> str:
    d = block.meta["dbat"]
    cam = d["camera"]
    pts, obs = block.points, block.observations
    c = block.cameras
    W, H = cam["image"]
    p = float(c.pixel_mm[0])
    lines = [f"Read the DBAT script `{d['script']}` ({d['name'] or 'no name'}): {len(block.photos)} photos "
             f"({sum(v is not None for v in d['images'].values())} image files found), "
             f"{int((pts.role == 'full').sum())} control, {int((pts.role == 'check').sum())} check and "
             f"{int((pts.role == 'tie').sum())} tie points, {len(obs)} marks. Object unit "
             f"{block.object_unit}. No orientations: the bundle resects every photo from the control points "
             "and intersects the rest.", ""]
    rows = [[m["file"].rsplit("/", 1)[-1], m["count"], ", ".join(f"{s:g}" for s in m["sigma_px"]),
             m["sigma_source"]] for m in d["marks"]]
    lines += [markdown_table(["marks file", "marks", "σ (px)", "σ from"], rows), ""]
    if d["dropped_points"]:
        lines += [f"Left out (DBAT's check_ray_count, min_rays = {d['min_rays']}): {len(d['dropped_points'])} "
                  f"tie/check point(s) with fewer rays and their {d['dropped_marks']} mark(s).", ""]
    if d["unmeasured_control"]:
        lines += [f"Control points without any mark (they do not enter the adjustment): "
                  f"{', '.join(d['unmeasured_control'])}.", ""]
    sw = cam["sensor"][0]
    lines += [f"Camera *{cam['name']}*: DBAT lens model {cam['model']} → baarda `{c.ap_model[0]}`; "
              f"{W} × {H} px, sensor {'auto' if sw is None else f'{sw:g}'} × {cam['sensor'][1]:g} mm, pixel "
              f"{p * 1000:.5f} µm (DBAT's pixel: sensor width / W, or height / H when the width is auto). "
              f"Initial values: `{d['io_initial']}`.", ""]
    est = d["estimate_io"]
    names = ["c", "xp", "yp", *AP_NAMES]
    dbat_names = ["cc", "px", "py", "K1", "K2", "K3", "P1", "P2", "aspect", "skew"]
    vals = [c.c[0], c.xp[0], c.yp[0], *c.ap[0]]
    rows = []
    for k, (bn, dn, v) in enumerate(zip(names, dbat_names, vals)):
        sign = "" if k < 3 else ("" if DBAT_SIGN[k - 3] > 0 else " (sign flipped: DBAT's y points down)")
        rows.append([bn, dn + sign, f"{v + 0.0:.6g}", "estimated" if est[dn] else "fixed"])
    lines += [markdown_table(["baarda", "DBAT", "initial (baarda frame)", "in the bundle"], rows), ""]
    ctrl = np.flatnonzero(pts.role == "full")
    rays = np.bincount(obs.point, minlength=len(pts))
    rows = [[pts.ids[i], d["labels"].get(str(pts.ids[i]), ""), *[f"{v:.4f}" for v in pts.XYZ[i]],
             _fmt_sigma(pts.sigma[i]), int(rays[i])] for i in ctrl]
    lines += ["Control points (prior):", "",
              markdown_table(["point", "label", "X", "Y", "Z", "σ X/Y/Z", "rays"], rows), ""]
    chk = np.flatnonzero(pts.role == "check")
    if chk.size:
        rows = [[pts.ids[i], d["labels"].get(str(pts.ids[i]), ""), *[f"{v:.4f}" for v in pts.XYZ[i]], int(rays[i])]
                for i in chk]
        lines += ["Check points (adjusted as tie points, compared afterwards):", "",
                  markdown_table(["point", "label", "X", "Y", "Z", "rays"], rows), ""]
    if d["unknown_operations"]:
        lines += [f"Operations baarda does not carry out: {', '.join(d['unknown_operations'])}.", ""]
    lines.append(f"Operations in the script: {', '.join(d['operations']) or 'none'}.")
    return "\n".join(lines)


def _tables(block) -> dict:
    pts, obs = block.points, block.observations
    d = block.meta["dbat"]
    rays = np.bincount(obs.point, minlength=len(pts))
    points = TableData({
        "point": pts.ids.tolist(), "label": [d["labels"].get(str(i), "") for i in pts.ids],
        "role": pts.role.tolist(), "X": pts.XYZ[:, 0], "Y": pts.XYZ[:, 1], "Z": pts.XYZ[:, 2],
        "sX": pts.sigma[:, 0], "sY": pts.sigma[:, 1], "sZ": pts.sigma[:, 2], "rays": rays,
    }, "object points as read (prior coordinates and σ; tie points have none)")
    ph = block.photos
    photos = TableData({
        "photo": ph.ids.tolist(), "file": [d["images"].get(str(i)) or "" for i in ph.ids],
        "marks": np.bincount(obs.photo, minlength=len(ph)),
    }, "photos: image file (empty when not found) and number of marks")
    return {"points": points, "photos": photos}
