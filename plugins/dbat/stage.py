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
from baarda.pipeline.stage import Context, SourceStage, Stage, StageResult, TableData

from .reader import AP_NAMES, DBAT_SIGN, dbat_block, read_dbat


@dataclass(frozen=True)
class DbatOptions:
    path: Path | None = option(None, "the DBAT script project (XML), relative to the project file (required)")
    dbat_dir: Path | None = option(None, "DBAT's installation folder, for paths that use $DBAT (the photos of "
                                         "an image list are otherwise looked up beside the list)")
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
        block = dbat_block(script)
        if options.crs is not None:
            block = _in_crs(block, options.crs, ctx)
        d = block.meta["dbat"]
        pts = block.points
        summary = {**block.summary(), "script": d["script"], "name": d["name"],
                   "control": int((pts.role == "full").sum()), "check": int((pts.role == "check").sum()),
                   "tie": int((pts.role == "tie").sum()), "marks": [m["count"] for m in d["marks"]],
                   "dropped_points": len(d["dropped_points"]), "dropped_marks": d["dropped_marks"],
                   "photos_found": sum(v is not None for v in d["images"].values()),
                   "estimated": [k for k, v in d["estimate_io"].items() if v]}
        report = _report(block)
        if block.crs is not None:
            summary["crs"] = options.crs
            o = summary["origin_lon_lat_h"] = list(block.crs.origin)
            report += (f"\n\nCoordinates in {options.crs}: adjusted in a local frame (east, north, up; m) with its origin "
                       f"at lon {o[0]:.8f}°, lat {o[1]:.8f}°, h {o[2]:.3f} m (ellipsoidal); `docs/crs.md`.")
        return StageResult(artefacts={"block": block, "dbat_marks": block}, summary=summary, report=report,
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
        report = _quality_report(q, options)
        earlier = inputs.get("dbat_report")
        if earlier is not None:
            report += "\n\n" + _camera_comparison(earlier, q)
            summary["camera_vs_earlier"] = {k: (q["camera"][k][0] - earlier["camera"][k][0]) for k in q["camera"]
                                            if k in earlier["camera"]}
        summary["headline"] = _quality_headline(q, earlier)
        dbat = res.block_in.meta.get("dbat", {})
        return StageResult(artefacts={"dbat_report": q}, summary=summary, report=report,
                           tables=_quality_tables(q),
                           data={"quality": q, "earlier": earlier, "rho_high": options.rho_high,
                                 "script": dbat.get("script"),
                                 "marks": sum(int(m["count"]) for m in dbat.get("marks", [])) or None})

    def plots(self, result: StageResult, ctx: Context) -> dict:
        """Figures for report.html: the camera against DBAT's published report and an earlier
        dbat-report, its correlations, control and check differences, rays and angles."""
        from .figures import report_figures

        d = result.data
        return report_figures(d["quality"], d["script"], d["marks"], d["earlier"], d["rho_high"])


def _quality(res) -> dict:
    from .quality import corrected_space_residuals, intersection_angles, point_comparison
    from .reader import DbatCamera, dbat_from_baarda

    block = res.block_in
    st = res.state
    obs, pts = block.observations, block.points
    act = np.asarray(res.obs_active, bool)
    pix = float(block.cameras.pixel_mm[0]) if np.isfinite(block.cameras.pixel_mm[0]) else float("nan")
    rc = corrected_space_residuals(block, st, act)
    ok = act & np.isfinite(rc).all(axis=1)
    # vᵀPv with the image residuals replaced by the corrected-space ones (weighted constraints kept)
    P = np.linalg.inv(obs.cov[ok])
    qf = lambda r: float(np.einsum("ki,kij,kj->", r, P, r))
    s0c = (float(np.sqrt(max(res.vtpv - qf(res.residuals[ok]) + qf(rc[ok]), 0.0) / res.dof))
           if ok.any() and res.dof > 0 else float("nan"))
    v = res.residuals[act]
    rays = np.bincount(obs.point[act], minlength=len(pts))
    ang = np.rad2deg(intersection_angles(st.XYZ, st.X0, obs.photo[act], obs.point[act], len(pts)))
    dbat = block.meta.get("dbat", {})
    camera = {}
    names = res.cam_param_names[0]
    table = res.camera_table(0)
    if dbat.get("camera"):
        cam = DbatCamera(**{k: (tuple(x) if isinstance(x, list) else x) for k, x in dbat["camera"].items()})
        vals = dbat_from_baarda(st.cam_params[0, 0], st.cam_params[0, 1], st.cam_params[0, 2], st.cam_params[0, 3:], cam)
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
        "sigma0": res.sigma0_hat, "sigma0_corrected": s0c, "dof": int(res.dof), "pixel_mm": pix,
        "rms_px": float(np.sqrt(np.mean(np.sum(v ** 2, axis=1)))) / pix,
        "rms_mm": float(np.sqrt(np.mean(np.sum(v ** 2, axis=1)))),
        "rms_px_corrected": float(np.sqrt(np.mean(np.sum(rc[ok] ** 2, axis=1)))) / pix if ok.any() else float("nan"),
        "camera": {k: (float(a), float(b)) for k, (a, b, _, _) in camera.items()}, "dbat_camera": bool(dbat.get("camera")),
        "camera_rows": camera, "correlation": res.correlation_camera(0), "names": names,
        "control": point_comparison(pts, ctrl, st.XYZ, res.cov_points),
        "check": point_comparison(pts, chk, st.XYZ, res.cov_points),
        "rays": rays, "angles_deg": ang, "ids": pts.ids, "role": pts.role, "tie": tie,
        "labels": dbat.get("labels", {}), "object_unit": block.object_unit,
        "angle_stats": {"control": stats(ctrl), "check": stats(chk), "tie": stats(tie)},
        "ray_stats": {k: (v_["rays_hist"] if v_ else {}) for k, v_ in
                      (("control", stats(ctrl)), ("check", stats(chk)), ("tie", stats(tie)))},
    }


def _quality_report(q, options) -> str:
    u = q["object_unit"]
    rms = f"RMS {q['rms_px']:.3f} px" if np.isfinite(q["rms_px"]) else f"RMS {q['rms_mm'] * 1000:.3f} µm"
    lines = [f"σ̂0 = {q['sigma0']:.4f} from the residuals of the measured image points ({rms}), "
             f"redundancy {q['dof']}."]
    if np.isfinite(q["sigma0_corrected"]):
        lines[-1] += (f" DBAT forms the residuals of the *corrected* marks (backward model): at this solution they "
                      f"give σ̂0 = {q['sigma0_corrected']:.4f}, RMS {q['rms_px_corrected']:.3f} px (docs/dbat.md).")
    lines += ["", "Camera, in DBAT's conventions (mm; principal point from the image corner, y down):" if q["dbat_camera"]
              else "Camera (not from a DBAT script: baarda's names and conventions):", ""]
    rows = [[k, bn, f"{v:.6g}", f"{s:.3g}" if st != "fixed" else "", st] for k, (v, s, st, bn) in q["camera_rows"].items()]
    lines += [markdown_table(["DBAT", "baarda", "value", "σ", "status"], rows), ""]
    R, names = q["correlation"], q["names"]
    high = [(names[i], names[j], R[i, j]) for i in range(len(names)) for j in range(i + 1, len(names))
            if np.isfinite(R[i, j]) and abs(R[i, j]) > options.rho_high]
    lines += [f"Correlations above {options.rho_high:.0%}: " +
              (", ".join(f"{a}–{b} {r:+.1%}" for a, b, r in high) if high else "none") + ".", ""]
    for kind, title in (("control", "Control points"), ("check", "Check points (error = adjusted − surveyed)")):
        c = q[kind]
        if not c["ids"]:
            continue
        idx = {i: k for k, i in enumerate(q["ids"].tolist())}
        rows = []
        for k, pid in enumerate(c["ids"]):
            p = idx[pid]
            rows.append([pid, q["labels"].get(pid, ""), *[f"{x:.3f}" for x in c["prior"][k]],
                         "fixed" if np.all(c["prior_sigma"][k] == 0) else
                         ("" if kind == "check" else "/".join(f"{s:g}" for s in c["prior_sigma"][k])),
                         *[f"{x:.3f}" for x in c["adjusted"][k]], *[f"{x:+.3f}" for x in c["diff"][k]],
                         *[f"{x:.4f}" for x in c["sigma"][k]], int(q["rays"][p]), f"{q['angles_deg'][p]:.1f}"])
        lines += [f"{title} ({u}):", "",
                  markdown_table(["point", "label", "X prior", "Y prior", "Z prior", "σ prior", "X", "Y", "Z",
                                  "dX", "dY", "dZ", "σX", "σY", "σZ", "rays", "angle (°)"], rows), ""]
        rms, big, at = _rms_largest(c)
        lines.append(f"RMS of the {kind} differences: {rms:.3f} {u} (3-D), largest {big:.3f} {u} at {at}.")
        lines.append("")
    rows = []
    for kind, s in q["angle_stats"].items():
        if s is None:
            continue
        rows.append([kind, f"{s['rays_min']}–{s['rays_max']} ({s['rays_mean']:.1f})",
                     ", ".join(f"{n} × {r}" for r, n in s["rays_hist"].items()),
                     f"{s['min']:.1f} ({s['min_id']})", f"{s['max']:.1f} ({s['max_id']})", f"{s['mean']:.1f}"])
    lines += ["Rays and intersection angles (the largest angle between two rays of a point):", "",
              markdown_table(["points", "rays min–max (mean)", "points × rays", "angle min (°)", "angle max (°)",
                              "mean (°)"], rows), ""]
    n = options.smallest_angles
    if n and len(q["tie"]):
        t = q["tie"][np.argsort(q["angles_deg"][q["tie"]])[:n]]
        lines.append("Smallest intersection angles of tie points: " +
                     ", ".join(f"{q['ids'][i]} {q['angles_deg'][i]:.2f}° ({q['rays'][i]} rays)" for i in t) + ".")
    return "\n".join(lines)


def _rms_largest(c) -> tuple[float, float, str]:
    """RMS (3-D) of the differences of a point comparison, the largest and the point it is at."""
    d = np.asarray(c["diff"], float)
    n = np.linalg.norm(d, axis=1)
    k = int(np.argmax(n))
    return float(np.sqrt(np.mean(n ** 2))), float(n[k]), str(c["ids"][k])


def _quality_headline(q, earlier=None) -> str:
    """One line for ``baarda review``: σ̂0 and the image RMS, then the control and check differences
    (RMS 3-D, the largest and where) as the report gives them (fixed control: only how many);
    without check points the free camera parameters and the first of them (a calibration's
    principal distance); the largest change against an earlier dbat-report in its combined σ."""
    u = q["object_unit"]
    rms = f"RMS {q['rms_px']:.3f} px" if np.isfinite(q["rms_px"]) else f"RMS {q['rms_mm'] * 1000:.3f} µm"
    parts = [f"σ̂0 = {q['sigma0']:.4f} ({rms})"]
    for kind in ("control", "check"):
        c = q[kind]
        if not c["ids"]:
            continue
        if kind == "control" and np.all(np.asarray(c["prior_sigma"], float) == 0):
            parts.append(f"control fixed ({len(c['ids'])})")
            continue
        r, big, at = _rms_largest(c)
        parts.append(f"{kind} RMS {r:.3f} {u} (3-D), largest {big:.3f} {u} at {at}")
    free = [k for k, (_, _, st, _) in q["camera_rows"].items() if st != "fixed"]
    if free and not q["check"]["ids"]:
        k = free[0]
        v, s = q["camera"][k]
        mm = " mm" if k in ("cc", "px", "py", "c", "xp", "yp") else ""
        parts.append(f"{len(free)} camera parameter(s) free, {k} {v:.6g} ± {s:.3g}{mm}")
    if earlier is not None:
        z = []
        for k in free:
            if k in earlier["camera"]:
                s = np.hypot(q["camera"][k][1], earlier["camera"][k][1])
                if s > 0:
                    z.append((abs(q["camera"][k][0] - earlier["camera"][k][0]) / s, k))
        if z:
            m, k = max(z)
            parts.append(f"vs earlier: max |diff|/σ {m:.2f} ({k})")
    return "; ".join(parts)


def _quality_tables(q) -> dict:
    ids = q["ids"]
    points = TableData({"point": ids.tolist(), "role": q["role"].tolist(), "rays": q["rays"],
                        "angle_deg": q["angles_deg"]}, "rays and largest intersection angle of every point")
    out = {"points": points}
    for kind in ("control", "check"):
        c = q[kind]
        if c["ids"]:
            out[kind] = TableData({
                "point": c["ids"], "X_prior": c["prior"][:, 0], "Y_prior": c["prior"][:, 1], "Z_prior": c["prior"][:, 2],
                "X": c["adjusted"][:, 0], "Y": c["adjusted"][:, 1], "Z": c["adjusted"][:, 2],
                "dX": c["diff"][:, 0], "dY": c["diff"][:, 1], "dZ": c["diff"][:, 2],
                "sX": c["sigma"][:, 0], "sY": c["sigma"][:, 1], "sZ": c["sigma"][:, 2]},
                f"{kind} points: prior, adjusted, adjusted − prior, a-posteriori σ")
    return out


def _camera_comparison(earlier, q) -> str:
    """The camera of this report beside an earlier dbat-report's (e.g. PhotoModeler's marks against
    baarda's own detections)."""
    rows = []
    for k, (v, sg, st, bn) in q["camera_rows"].items():
        if k not in earlier["camera"] or st == "fixed":
            continue
        v0, s0 = earlier["camera"][k]
        s = np.hypot(sg, s0)
        rows.append([k, f"{v0:.6g}", f"{s0:.3g}", f"{v:.6g}", f"{sg:.3g}", f"{v - v0:+.3g}",
                     f"{(v - v0) / s:+.2f}" if s > 0 else ""])
    return ("Camera against the earlier dbat-report's (DBAT conventions); the last column divides the "
            "difference by the two σ combined as if independent — they share the photos, so this "
            "understates its significance:\n\n"
            + markdown_table(["DBAT", "earlier", "σ", "this", "σ", "difference", "diff / σ"], rows))


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
                           "u_mark": d["uv_mark"][:, 0], "v_mark": d["uv_mark"][:, 1],
                           "du_px": d["duv"][:, 0], "dv_px": d["duv"][:, 1]},
                          "paired marks and image points: differences in pixels (block − marks)")
        return StageResult(artefacts={"dbat_marks_comparison": cmp}, summary=summary, report=report,
                           tables={"pairs": table}, data={"radius_px": options.match_radius_px})

    def plots(self, result: StageResult, ctx: Context) -> dict:
        """Figure for report.html: the pairs' differences as vectors, histograms and scatter."""
        from .figures import marks_figure

        return {"differences": (marks_figure(result.artefacts["dbat_marks_comparison"], result.data["radius_px"]),
                                "Image points of the block − the script's marks (pixels, x right, y down): vectors "
                                "over the image (all photos), histograms with the bias, du against dv")}
