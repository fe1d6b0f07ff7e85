"""Report text and tables of the ``dbat`` stages (``stage.py``): what the ``dbat`` source read,
and the ``dbat-report`` quality section (σ̂0, camera with σ and correlations, control and check
points, intersection angles, the comparison with an earlier DBAT run)."""

from __future__ import annotations

import numpy as np

from baarda.pipeline.report import markdown_table
from baarda.pipeline.api import TableData
from baarda.pipeline.units import length_suffix

from .reader import AP_NAMES, DBAT_SIGN, DbatInfo


def _fmt_sigma(s):
    s = np.asarray(s, float)
    if np.all(s == 0):
        return "fixed"
    return "/".join(f"{v:g}" for v in s)


def source_report(block) -> str:
    d: DbatInfo = block.meta["dbat"]
    cam = d.camera
    pts, obs = block.points, block.observations
    c = block.cameras
    W, H = cam.image
    p = float(c.pixel_mm[0])
    lines = [f"Read the DBAT script `{d.script}` ({d.name or 'no name'}): {len(block.photos)} photos "
             f"({d.images_found} image files found), "
             f"{int((pts.role == 'full').sum())} control, {int((pts.role == 'check').sum())} check and "
             f"{int((pts.role == 'tie').sum())} tie points, {len(obs)} marks. Object unit "
             f"{block.object_unit}. No orientations: the bundle resects every photo from the control points "
             "and intersects the rest.", ""]
    rows = [[m.file.rsplit("/", 1)[-1], m.count, ", ".join(f"{s:g}" for s in m.sigma_px),
             m.sigma_source] for m in d.marks]
    lines += [markdown_table(["marks file", "marks", "σ (px)", "σ from"], rows), ""]
    if d.dropped_points:
        lines += [f"Left out (DBAT's check_ray_count, min_rays = {d.min_rays}): {len(d.dropped_points)} "
                  f"tie/check point(s) with fewer rays and their {d.dropped_marks} mark(s).", ""]
    if d.unmeasured_control:
        lines += [f"Control points without any mark (they do not enter the adjustment): "
                  f"{', '.join(d.unmeasured_control)}.", ""]
    sw = cam.sensor[0]
    lines += [f"Camera *{cam.name}*: DBAT lens model {cam.model} → baarda `{c.ap_model[0]}`; "
              f"{W} × {H} px, sensor {'auto' if sw is None else f'{sw:g}'} × {cam.sensor[1]:g} mm, pixel "
              f"{p * 1000:.5f} µm (DBAT's pixel: sensor width / W, or height / H when the width is auto). "
              f"Initial values: `{d.io_initial}`.", ""]
    est = d.estimate_io
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
    rows = [[pts.ids[i], d.labels.get(str(pts.ids[i]), ""), *[f"{v:.4f}" for v in pts.XYZ[i]],
             _fmt_sigma(pts.sigma[i]), int(rays[i])] for i in ctrl]
    lines += ["Control points (prior):", "",
              markdown_table(["point", "label", "X", "Y", "Z", "σ X/Y/Z", "rays"], rows), ""]
    chk = np.flatnonzero(pts.role == "check")
    if chk.size:
        rows = [[pts.ids[i], d.labels.get(str(pts.ids[i]), ""), *[f"{v:.4f}" for v in pts.XYZ[i]], int(rays[i])]
                for i in chk]
        lines += ["Check points (adjusted as tie points, compared afterwards):", "",
                  markdown_table(["point", "label", "X", "Y", "Z", "rays"], rows), ""]
    if d.unknown_operations:
        lines += [f"Operations baarda does not carry out: {', '.join(d.unknown_operations)}.", ""]
    lines.append(f"Operations in the script: {', '.join(d.operations) or 'none'}.")
    return "\n".join(lines)


def source_tables(block) -> dict:
    pts, obs = block.points, block.observations
    d: DbatInfo = block.meta["dbat"]
    rays = np.bincount(obs.point, minlength=len(pts))
    o = length_suffix(block.object_unit)
    points = TableData({
        "point": pts.ids.tolist(), "label": [d.labels.get(str(i), "") for i in pts.ids],
        "role": pts.role.tolist(), "X" + o: pts.XYZ[:, 0], "Y" + o: pts.XYZ[:, 1], "Z" + o: pts.XYZ[:, 2],
        "sX" + o: pts.sigma[:, 0], "sY" + o: pts.sigma[:, 1], "sZ" + o: pts.sigma[:, 2], "rays": rays,
    }, f"object points as read ({block.object_unit}; prior coordinates and σ; tie points have none)", detail=True)
    ph = block.photos
    photos = TableData({
        "photo": ph.ids.tolist(), "file": ph.image_path.tolist(),
        "marks": np.bincount(obs.photo, minlength=len(ph)),
    }, "photos: image file (empty when not found) and number of marks")
    return {"points": points, "photos": photos}


def quality_report(q, options) -> str:
    u = q["object_unit"]
    rms = f"RMS {q['rms_px']:.3f} px" if np.isfinite(q["rms_px"]) else f"RMS {q['rms_mm'] * 1000:.3f} µm"
    if q.get("residual") == "corrected":
        lines = [f"σ̂0 = {q['sigma0']:.4f} in DBAT's residual definition ({rms}), redundancy {q['dof']}: the bundle "
                 "adjusted the *corrected* marks (option residual = \"corrected\"), as DBAT does (docs/dbat.md)."]
    else:
        lines = [f"σ̂0 = {q['sigma0']:.4f} from the residuals of the measured image points ({rms}), "
                 f"redundancy {q['dof']}."]
    if np.isfinite(q["sigma0_corrected"]) and q.get("residual") != "corrected":
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


def quality_headline(q, earlier=None) -> str:
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


def quality_tables(q) -> dict:
    ids = q["ids"]
    points = TableData({"point": ids.tolist(), "role": q["role"].tolist(), "rays": q["rays"],
                        "angle_deg": q["angles_deg"]}, "rays and largest intersection angle of every point",
                       detail=True)
    out = {"points": points}
    o = length_suffix(q["object_unit"])
    for kind in ("control", "check"):
        c = q[kind]
        if c["ids"]:
            out[kind] = TableData({
                "point": c["ids"], **{f"{a}_prior{o}": c["prior"][:, i] for i, a in enumerate("XYZ")},
                **{f"{a}{o}": c["adjusted"][:, i] for i, a in enumerate("XYZ")},
                **{f"d{a}{o}": c["diff"][:, i] for i, a in enumerate("XYZ")},
                **{f"s{a}{o}": c["sigma"][:, i] for i, a in enumerate("XYZ")}},
                f"{kind} points ({q['object_unit']}): prior, adjusted, adjusted − prior, a-posteriori σ")
    return out


def camera_comparison(earlier, q) -> str:
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
