"""Source stage ``dbat``: a DBAT script project (XML + control, check, image list, marks) as a block.

Parsing and the mapping to baarda live in :mod:`.reader` (``docs/dbat.md``); this stage resolves the
path, reports what was read (camera in DBAT's and baarda's conventions, which parameters are
estimated, control and check points, marks per file) and logs the points.  No orientation is
given: the bundle resects every photo from the control points and intersects the rest
(``baarda.pipeline.adjustment.initial_values``).  The report text and tables of the stages are in
:mod:`.report`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baarda.pipeline.api import Context, InputError, SourceStage, Stage, StageResult, TableData, option
from baarda.pipeline.report import markdown_table

from .reader import DbatInfo, dbat_block, read_dbat
from .report import (camera_comparison, quality_headline, quality_report, quality_tables, source_report,
                     source_tables)


@dataclass(frozen=True)
class DbatOptions:
    path: Path | None = option(None, "the DBAT script project (XML), relative to the project file (required)")
    dbat_dir: Path | None = option(None, "DBAT's installation folder, for paths that use $DBAT (the photos of "
                                         "an image list are otherwise looked up beside the list)")
    datum: str = option("script", "'script': the datum as the script sets it (control points, or set_datum depend: "
                                  "DBAT's dependent relative orientation); 'free': set_datum not carried out, for "
                                  "the bundle's free network (bundle datum = \"free\")")
    crs: str | None = option(None, "the CRS of the control, check and prior-EO coordinates (a DBAT script has no "
                                   "place for one; e.g. 'EPSG:32632'): the block is adjusted in a local "
                                   "east-north-up frame and reported and exported in this CRS (docs/crs.md)")


class DbatSource(SourceStage):
    summary = "Read a DBAT script project (XML, control/check points, marks, PhotoModeler-style camera)"
    reads = ()
    writes = ("block", "dbat_marks")
    Options = DbatOptions

    def run(self, inputs, options: DbatOptions, ctx: Context) -> StageResult:
        if options.path is None or not str(options.path) or str(options.path) == ".":
            raise InputError("the dbat stage needs the option 'path' (the script's XML file)",
                             path=ctx.project_file, field="path")
        dbat_dir = ctx.resolve(options.dbat_dir) if options.dbat_dir is not None else None
        script = read_dbat(ctx.resolve(options.path), dbat_dir=dbat_dir)
        if options.datum not in ("script", "free"):
            raise ctx.option_error(f"datum is 'script' or 'free', got {options.datum!r}", "datum")
        block = dbat_block(script, datum=options.datum)
        if options.crs is not None:
            block = _in_crs(block, options.crs, ctx)
        d: DbatInfo = block.meta["dbat"]
        if d_out := block.meta["dbat"].marks_outside:
            ctx.warn(f"{d_out[0]} mark(s) outside the {script.camera.image[0]} × {script.camera.image[1]} px image "
                     f"(u < 0 or u > W, v < 0 or v > H; first: {d_out[1]})")
        pts = block.points
        summary = {**block.summary(), "script": d.script, "name": d.name,
                   "control": int((pts.role == "full").sum()), "check": int((pts.role == "check").sum()),
                   "tie": int((pts.role == "tie").sum()), "marks": [m.count for m in d.marks],
                   "dropped_points": len(d.dropped_points), "dropped_marks": d.dropped_marks,
                   "photos_found": d.images_found,
                   "estimated": [k for k, v in d.estimate_io.items() if v]}
        report = source_report(block)
        if block.crs is not None:
            summary["crs"] = options.crs
            o = summary["origin_lon_lat_h"] = list(block.crs.origin)
            report += (f"\n\nCoordinates in {options.crs}: adjusted in a local frame (east, north, up; m) with its origin "
                       f"at lon {o[0]:.8f}°, lat {o[1]:.8f}°, h {o[2]:.3f} m (ellipsoidal); `docs/crs.md`.")
        return StageResult(artefacts={"block": block, "dbat_marks": block}, summary=summary, report=report,
                           tables=source_tables(block), data={"block": block})

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


def _in_crs(block, crs: str, ctx: Context):
    """``block`` with its coordinates, given in ``crs``, moved to the local east-north-up frame
    (``pipeline/crs.py``; origin at the control and check points): points and prior projection
    centres converted, prior attitudes turned by the rotation of the CRS's axes against the local
    ones at each centre (meridian convergence, curvature); σ kept as metres east/north/up."""
    from baarda.pipeline.crs import local_frame
    from baarda.pipeline.geometry import opk_from_rotation_many, rotation_from_opk_many

    if str(crs).strip().lower() in ("", "local", "none"):
        return block
    if block.object_unit != "m":
        raise InputError(f"crs needs a project in metres (project_unit is {block.object_unit!r})",
                         path=ctx.project_file, field="crs")
    pts, ph = block.points, block.photos
    known = np.isfinite(pts.XYZ).all(axis=1)
    if not known.any():
        raise InputError("crs: the script has no control or check points to place the local frame",
                         path=ctx.project_file, field="crs")
    frame = local_frame(crs, pts.XYZ[known], path=ctx.project_file, field="crs")
    XYZ = np.array(pts.XYZ, float)
    XYZ[known] = frame.to_local(XYZ[known])
    X0, opk = np.array(ph.X0, float), np.array(ph.opk, float)
    has = np.isfinite(X0).all(axis=1)
    if has.any():
        X0[has] = frame.to_local(X0[has])
        ok = np.isfinite(opk[has]).all(axis=1)
        R = rotation_from_opk_many(np.where(ok[:, None], opk[has], 0.0)) @ frame.rotation_from_local(X0[has])
        opk[has] = np.where(ok[:, None], opk_from_rotation_many(R), opk[has])
    return block.replace(points=pts.replace(XYZ=XYZ), photos=ph.replace(X0=X0, opk=opk), crs=frame.info())


# ---------------------------------------------------------------------------------------------
# dbat-report: DBAT's quality figures of the bundle's result


@dataclass(frozen=True)
class DbatReportOptions:
    rho_high: float = option(0.95, "camera-parameter correlations above this (absolute) are listed, as DBAT does",
                             gt=0.0, le=1.0)
    smallest_angles: int = option(10, "list the tie points with the smallest intersection angles (how many)", ge=0)


class DbatReport(Stage):
    summary = ("DBAT-style quality report of a bundle: camera in DBAT's conventions with σ and high correlations, "
               "control prior/adjusted/difference/σ, check-point errors, ray counts, intersection angles")
    reads = ("bundle", "dbat_report?")
    writes = ("dbat_report",)
    Options = DbatReportOptions
    retired = {"dbat-residuals": "DBAT's residual definition is the bundle's option residual = \"corrected\" "
                                 "(one bundle, exact; docs/dbat.md, \"Residual definition\")"}

    def run(self, inputs, options: DbatReportOptions, ctx: Context) -> StageResult:
        res = inputs["bundle"]
        if res is None:
            raise InputError("dbat-report needs the result of a bundle stage before it", path=ctx.project_file,
                             field="use")
        q = _quality(res)
        summary = {"sigma0_hat": q["sigma0"], "sigma0_hat_corrected": q["sigma0_corrected"], "dof": q["dof"],
                   "rms_px": q["rms_px"], "rms_px_corrected": q["rms_px_corrected"],
                   "camera": {k: {"value": v[0], "sigma": v[1]} for k, v in q["camera"].items()},
                   "control": {i: {"diff": d.tolist(), "sigma": s.tolist()} for i, d, s in
                               zip(q["control"]["ids"], q["control"]["diff"], q["control"]["sigma"])},
                   "check": {i: {"error": d.tolist(), "sigma": s.tolist()} for i, d, s in
                             zip(q["check"]["ids"], q["check"]["diff"], q["check"]["sigma"])},
                   "angles_deg": q["angle_stats"], "rays": q["ray_stats"]}
        if q["residual"] == "corrected":
            summary["residual"] = "corrected"
        report = quality_report(q, options)
        earlier = inputs.get("dbat_report")
        if earlier is not None:
            report += "\n\n" + camera_comparison(earlier, q)
            summary["camera_vs_earlier"] = {k: (q["camera"][k][0] - earlier["camera"][k][0]) for k in q["camera"]
                                            if k in earlier["camera"]}
        summary["headline"] = quality_headline(q, earlier)
        dbat: DbatInfo | None = res.block_in.meta.get("dbat")
        return StageResult(artefacts={"dbat_report": q}, summary=summary, report=report,
                           tables=quality_tables(q),
                           data={"quality": q, "earlier": earlier, "rho_high": options.rho_high,
                                 "script": dbat.script if dbat else None,
                                 "marks": (sum(m.count for m in dbat.marks) if dbat else 0) or None})

    def plots(self, result: StageResult, ctx: Context) -> dict:
        """Figures for report.html: the camera against DBAT's published report and an earlier
        dbat-report, its correlations, control and check differences, rays and angles."""
        from .figures import report_figures

        d = result.data
        return report_figures(d["quality"], d["script"], d["marks"], d["earlier"], d["rho_high"])


def _quality(res) -> dict:
    """DBAT's quality figures of a bundle result (in either residual definition of the bundle)."""
    from .quality import corrected_space_residuals, intersection_angles, point_comparison
    from .reader import dbat_from_baarda

    block = res.block_in
    st = res.state
    obs, pts = block.observations, block.points
    act = np.asarray(res.obs_active, bool)
    pix = float(block.cameras.pixel_mm[0]) if np.isfinite(block.cameras.pixel_mm[0]) else float("nan")
    rc = corrected_space_residuals(block, st, act)
    ok = act & np.isfinite(rc).all(axis=1)
    # vᵀPv with the image residuals replaced by the corrected-space ones (weighted constraints kept), these
    # weighted with the marks' σ as DBAT does (after a bundle with residual = "corrected": its own vᵀPv)
    P = np.linalg.inv(obs.cov[ok])
    qf = lambda r: float(np.einsum("ki,kij,kj->", r, P, r))
    s0c = (float(np.sqrt(max(res.vtpv - qf(res.residuals[ok]) + qf(rc[ok]), 0.0) / res.dof))
           if ok.any() and res.dof > 0 else float("nan"))
    v = res.residuals[act]
    rays = np.bincount(obs.point[act], minlength=len(pts))
    ang = np.rad2deg(intersection_angles(st.XYZ, st.X0, obs.photo[act], obs.point[act], len(pts)))
    dbat: DbatInfo | None = block.meta.get("dbat")
    camera = {}
    names = res.cam_param_names[0]
    table = res.camera_table(0)
    if dbat is not None:
        cam = dbat.camera
        cp = np.asarray(st.cam_params, float)
        vals = dbat_from_baarda(cp[0, 0], cp[0, 1], cp[0, 2], cp[0, 3:], cam)
        for key, bn in zip(("cc", "px", "py", "K1", "K2", "K3", "P1", "P2", "as", "sk"), names):
            row = next(r for r in table if r["parameter"] == bn)
            camera[key] = (vals[key], row["sigma"], row["status"], bn)
    else:
        for row in table:
            camera[row["parameter"]] = (row["value"], row["sigma"], row["status"], row["parameter"])
    ctrl = np.flatnonzero((pts.role != "tie") & (pts.role != "check") & res.point_used)
    chk = np.flatnonzero((pts.role == "check") & res.point_used & np.isfinite(pts.XYZ).all(axis=1))
    tie = np.flatnonzero((pts.role == "tie") & res.point_used)

    def stats(idx):
        a = ang[idx]
        if not len(idx):
            return None
        r = rays[idx]
        return {"min": float(np.nanmin(a)), "max": float(np.nanmax(a)), "mean": float(np.nanmean(a)),
                "min_id": str(pts.ids[idx][np.nanargmin(a)]), "max_id": str(pts.ids[idx][np.nanargmax(a)]),
                "rays_min": int(r.min()), "rays_max": int(r.max()), "rays_mean": float(r.mean()),
                "rays_hist": {int(k): int((r == k).sum()) for k in np.unique(r)}}

    return {
        "sigma0": res.sigma0_hat, "residual": getattr(res.settings, "residual", "measured"), "sigma0_corrected": s0c, "dof": int(res.dof), "pixel_mm": pix,
        "rms_px": float(np.sqrt(np.mean(np.sum(v ** 2, axis=1)))) / pix,
        "rms_mm": float(np.sqrt(np.mean(np.sum(v ** 2, axis=1)))),
        "rms_px_corrected": float(np.sqrt(np.mean(np.sum(rc[ok] ** 2, axis=1)))) / pix if ok.any() else float("nan"),
        "camera": {k: (float(a), float(b)) for k, (a, b, _, _) in camera.items()}, "dbat_camera": dbat is not None,
        "camera_rows": camera, "correlation": res.correlation_camera(0), "names": names,
        "control": point_comparison(pts, ctrl, st.XYZ, res.cov_points),
        "check": point_comparison(pts, chk, st.XYZ, res.cov_points),
        "rays": rays, "angles_deg": ang, "ids": pts.ids, "role": pts.role, "tie": tie,
        "labels": dict(dbat.labels) if dbat else {}, "object_unit": block.object_unit,
        "angle_stats": {"control": stats(ctrl), "check": stats(chk), "tie": stats(tie)},
        "ray_stats": {k: (v_["rays_hist"] if v_ else {}) for k, v_ in
                      (("control", stats(ctrl)), ("check", stats(chk)), ("tie", stats(tie)))},
    }


# ---------------------------------------------------------------------------------------------
# dbat-marks: the marks of the script against another block's image points (e.g. detections)


@dataclass(frozen=True)
class DbatMarksOptions:
    match_radius_px: float = option(3.0, "largest distance (pixels) of a detection from a mark it is paired with")


class DbatMarks(Stage):
    summary = ("Compare the script's marks (PhotoModeler's) with the image points of the current block (e.g. "
               "opencv-targets detections), paired by position: count, bias, RMS per photo and overall")
    reads = ("dbat_marks", "block")
    writes = ("dbat_marks_comparison",)
    Options = DbatMarksOptions

    def run(self, inputs, options: DbatMarksOptions, ctx: Context) -> StageResult:
        from .quality import compare_marks

        marks, block = inputs.get("dbat_marks"), inputs.get("block")
        if marks is None or block is None:
            raise InputError("dbat-marks needs a dbat source stage and a later stage that writes a block",
                             path=ctx.project_file, field="use")
        cmp = compare_marks(marks, block, options.match_radius_px)
        a = cmp["all"]
        summary = {k: a[k] for k in ("marks", "points", "matched", "same_id", "bias_px", "rms_px", "sd_px")}
        summary["headline"] = (f"{a['matched']} of {a['marks']} marks paired with the block's {a['points']} image "
                               f"points ({a['same_id']} same id); bias ({a['bias_px'][0]:+.3f}, "
                               f"{a['bias_px'][1]:+.3f}) px, RMS ({a['rms_px'][0]:.3f}, {a['rms_px'][1]:.3f}) px")
        rows = [[r["photo"], r["marks"], r["points"], r["matched"], r["same_id"], f"{r['bias_px'][0]:+.3f}",
                 f"{r['bias_px'][1]:+.3f}", f"{r['rms_px'][0]:.3f}", f"{r['rms_px'][1]:.3f}"] for r in cmp["photos"]]
        rows.append(["all", a["marks"], a["points"], a["matched"], a["same_id"], f"{a['bias_px'][0]:+.3f}",
                     f"{a['bias_px'][1]:+.3f}", f"{a['rms_px'][0]:.3f}", f"{a['rms_px'][1]:.3f}"])
        report = (f"The script's {a['marks']} marks against the block's {a['points']} image points, paired by "
                  f"position (nearest, one-to-one, within {options.match_radius_px:g} px): {a['matched']} pairs, "
                  f"{a['same_id']} of them with the same point id. Differences (block − marks, pixels, x right, "
                  f"y down): bias ({a['bias_px'][0]:+.3f}, {a['bias_px'][1]:+.3f}), RMS ({a['rms_px'][0]:.3f}, "
                  f"{a['rms_px'][1]:.3f}), standard deviation about the bias ({a['sd_px'][0]:.3f}, "
                  f"{a['sd_px'][1]:.3f}). Both in image mm first, each with its own pixel convention (DBAT's "
                  "marks: the image corner at 0; OpenCV's detections: the first pixel's centre at 0), so a bias "
                  "here is a real offset of the centres.\n\n"
                  + markdown_table(["photo", "marks", "points", "pairs", "same id", "bias x", "bias y", "RMS x",
                                    "RMS y"], rows))
        d = cmp["pairs"]
        table = TableData({"photo": d["photo"], "mark_point": d["mark_point"], "point": d["point"],
                           "u_mark_px": d["uv_mark"][:, 0], "v_mark_px": d["uv_mark"][:, 1],
                           "du_px": d["duv"][:, 0], "dv_px": d["duv"][:, 1]},
                          "paired marks and image points: differences in pixels (block − marks)", detail=True)
        return StageResult(artefacts={"dbat_marks_comparison": cmp}, summary=summary, report=report,
                           tables={"pairs": table}, data={"radius_px": options.match_radius_px})

    def plots(self, result: StageResult, ctx: Context) -> dict:
        """Figure for report.html: the pairs' differences as vectors, histograms and scatter."""
        from .figures import marks_figure

        return {"differences": (marks_figure(result.artefacts["dbat_marks_comparison"], result.data["radius_px"]),
                                "Image points of the block − the script's marks (pixels, x right, y down): vectors "
                                "over the image (all photos), histograms with the bias, du against dv")}
