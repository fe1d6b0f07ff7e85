"""The bundle's protocol summary — the numbers a photogrammetrist reads first (pure numerics).

Everything comes from the :class:`~baarda.pipeline.adjustment.BundleResult`: its snapshot
(σ̂0, the global test, redundancy numbers, MDBs), residuals, point covariances, camera
covariances, scale bars, check points and warnings.  The stage puts the dict under
``summary["protocol"]``; ``report.html`` prints it first (``docs/report.md``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from baarda.pipeline.adjustment import adjust
from baarda.pipeline.api import AdjustmentError
from baarda.pipeline.camera.convert import opencv_rms, opencv_style
from baarda.pipeline.protocol import MOST_LABELS, rms, snapshot_protocol
from baarda.pipeline.units import AP_UNIT_POWER, ImageUnits, fmt_obj, fmt_q, object_unit_text

HIGH_CORRELATION = 0.9
"""|ρ| above which a pair of camera parameters is listed."""
EFFECT_MAX_UNKNOWNS = 20_000
"""The effect of the largest MDB on the points takes one more adjustment; above this many
unknowns it is left out (``reliability.effect_max`` is then null)."""
EFFECT_ITERATIONS = 2
"""Iterations of the adjustment with the MDB added (from the solution; the effect is linear)."""
MOST_CAMERA_LINES = 8
"""Cameras named in report.md's RMS line (largest RMS first; all are in the protocol)."""
PER_PHOTO_MOST = 30
"""Photos listed in ``rms_per_photo`` (largest RMS first); ``n_photos`` counts them all.  The same
number of cameras in ``rms_per_camera`` (largest RMS first) and ``cameras`` (in block order),
``n_cameras`` counting them all: every camera is in the tables (``bundle_cameras``)."""


def image_units(block) -> tuple[str, float, str | None]:
    """``(unit, scale from mm, pixel source)``: px for a pixel source with one pixel pitch, else µm
    (the first three fields of :class:`baarda.pipeline.units.ImageUnits`)."""
    unit, scale, src, _ = ImageUnits.of(block)
    return unit, scale, src


AP_PIXEL_POWER = AP_UNIT_POWER
"""Per AP model, the power k of each parameter's unit mm⁻ᵏ (``baarda.pipeline.units.AP_UNIT_POWER``, the
one table): a parameter of a term of degree k + 1 in the reduced image coordinates (K1 of ``x̄ r²``:
k = 2; P1 of ``r² + 2x̄²``: k = 1; B1 of ``x̄``: k = 0, dimensionless).  In pixel coordinates the same
term needs ``a_px = a_mm · pᵏ`` (p the pixel pitch in mm; ebner12's image base b and AICON's r0 then
in px too), so the distortion in px is the model's own formula on px.  A model not listed (a
third-party one) keeps its parameters in its own units."""

def _model_power(name) -> tuple | None:
    """A registered model's own ``pixel_power`` (the ray models declare theirs), else None."""
    from baarda.pipeline.camera import get_ap_model
    try:
        return getattr(get_ap_model(str(name)), "pixel_power", None)
    except KeyError:
        return None


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def _power_unit(base: str, k: int) -> str:
    return "1" if k == 0 else f"{base}⁻{str(k).translate(_SUPERSCRIPT)}"


def camera_rows(res, j: int, units: tuple | None = None) -> list[dict]:
    """The rows of ``res.camera_table(j)`` in the units of the block's source, each with its ``unit``:
    for a pixel source (:func:`image_units` px) c, xp, yp in px (xp, yp: the principal point's offset
    from the image centre, y up) and the APs scaled by :data:`AP_PIXEL_POWER` (K1 px⁻², P1 px⁻¹, B1
    dimensionless …); else the adjustment's mm (K1 mm⁻² …).  σ and the a-priori σ scale with their
    value; correlations are unchanged.  The one conversion of camera parameters in every table."""
    unit, scale, _ = units or image_units(res.block_in)
    base = "px" if unit == "px" else "mm"
    pitch = 1.0 / scale if unit == "px" else 1.0
    rows = res.camera_table(j)
    powers = AP_PIXEL_POWER.get(str(res.block_in.cameras.ap_model[j]), _model_power(res.block_in.cameras.ap_model[j]))
    if powers is not None and len(powers) != len(rows) - 3:
        powers = None
    out = []
    for t, r in enumerate(rows):
        if t < 3:
            f, u = 1.0 / pitch, base
        elif powers is not None:
            f, u = pitch ** powers[t - 3], _power_unit(base, powers[t - 3])
        else:
            f, u = 1.0, "model units (mm)"
        out.append({**r, "value": r["value"] * f + 0.0, "sigma": r["sigma"] * f,
                    "apriori_sigma": r["apriori_sigma"] * f, "unit": u})
    return out


def _rms_rows(v, act, keys, ids) -> list[dict]:
    """RMS of x, y and all coordinates per key (photo or camera), by bincount: O(observations)."""
    keys = np.asarray(keys, int)
    m = len(ids)
    ax, ay = act[:, 0], act[:, 1]
    sx = np.bincount(keys[ax], weights=v[ax, 0] ** 2, minlength=m)
    sy = np.bincount(keys[ay], weights=v[ay, 1] ** 2, minlength=m)
    nx = np.bincount(keys[ax], minlength=m)
    ny = np.bincount(keys[ay], minlength=m)
    npt = np.bincount(keys[act.any(axis=1)], minlength=m)
    with np.errstate(invalid="ignore", divide="ignore"):
        rx, ry, ra = np.sqrt(sx / nx), np.sqrt(sy / ny), np.sqrt((sx + sy) / (nx + ny))
    return [{"id": str(ids[k]), "n": int(npt[k]), "x": float(rx[k]), "y": float(ry[k]), "all": float(ra[k])}
            for k in np.flatnonzero(npt)]


def bundle_protocol(res, rejections=None, *, alpha0: float, beta0: float,
                    alpha_global: float | str = 0.05) -> dict:
    """The protocol dict of a bundle result (see :mod:`baarda.pipeline.protocol` for the keys); ``rejections``: the
    iterated data snooping that rejected rows (its count and labels), if any."""
    block = res.block_in
    unit, scale, src = image_units(block)
    snap = res.snapshot
    orows = res.obs_rows()
    if snap is not None:
        out = snapshot_protocol(snap, name="bundle", alpha0=alpha0, beta0=beta0, unit=unit, scale=scale,
                                alpha_global=alpha_global,
                                coordinate_rows=orows[:, 1] if len(orows) == snap.n else None)
    else:
        out = {"adjustment": "bundle", "sigma0": float(res.sigma0), "sigma0_hat": float(res.sigma0_hat),
               "dof": int(res.dof), "unit": unit}
    out["object_unit"] = object_unit_text(block)
    out["kind"] = "bundle"
    out["source_units"] = "px" if src else "mm"
    if src:
        out["pixel_source"] = src
    obs = block.observations
    act = np.asarray(res.row_active, bool) & np.asarray(res.obs_active, bool)[:, None]
    v = np.asarray(res.residuals, float) * scale
    out["rms"] = {"x": rms(v[act[:, 0], 0]), "y": rms(v[act[:, 1], 1]), "all": rms(v[act]),
                  "n": int(act.any(axis=1).sum())}
    if src:
        out["opencv_rms_px"] = opencv_rms(v[act.all(axis=1)])
    cam_of_obs = block.photos.camera[obs.photo]
    per_camera = _rms_rows(v, act, cam_of_obs, block.cameras.ids)
    out["n_cameras"] = len(per_camera)
    out["rms_per_camera"] = sorted(per_camera, key=lambda r: -r["all"])[:PER_PHOTO_MOST] \
        if len(per_camera) > PER_PHOTO_MOST else per_camera
    per_photo = _rms_rows(v, act, obs.photo, block.photos.ids)
    per_photo.sort(key=lambda r: -r["all"])
    out["n_photos"] = len(per_photo)
    out["rms_per_photo"] = per_photo[:PER_PHOTO_MOST]

    # object points: a-posteriori precision
    pts = block.points
    sp = res.point_sigmas()
    ou = object_unit_text(block)
    est = res.point_used & np.all(np.isfinite(sp), axis=1) & (sp.sum(axis=1) > 0)
    if est.any():
        s = sp[est]
        ids = pts.ids[est]
        imax = np.argmax(s, axis=0)
        out["point_precision"] = {"n": int(est.sum()), "unit": ou,
                                  "rms": [rms(s[:, t]) for t in range(3)],
                                  "max": [float(s[imax[t], t]) for t in range(3)],
                                  "max_ids": [str(ids[imax[t]]) for t in range(3)]}

    # scale bars: adjusted − measured
    bars = []
    a_idx, b_idx = res.distance_points
    XYZ = res.state.XYZ
    for d, a, b in zip(res.distances, a_idx, b_idx):
        adj = float(np.linalg.norm(XYZ[a] - XYZ[b]))
        bars.append({"from": str(d.a), "to": str(d.b), "measured": float(d.distance), "adjusted": adj,
                     "residual": adj - float(d.distance), "sigma": float(d.sigma)})
    if bars:
        out["scale_bars"] = {"unit": ou, "bars": bars, "rms": rms([b["residual"] for b in bars])}

    # control points: adjusted − given on the constrained coordinates
    given = np.isfinite(pts.sigma) & (pts.sigma > 0) & res.point_used[:, None] & np.isfinite(pts.XYZ)
    given &= (pts.role != "check")[:, None]
    if given.any():
        d = np.where(given, XYZ - pts.XYZ, np.nan)
        rows = np.flatnonzero(given.any(axis=1))
        k = rows[np.argmax(np.nanmax(np.abs(d[rows]), axis=1))]
        out["control"] = {"n": int(rows.size), "unit": ou, "rms": [rms(d[:, t]) for t in range(3)],
                          "max_abs": float(np.nanmax(np.abs(d[k]))), "max_id": str(pts.ids[k]),
                          "max_3d": float(np.sqrt(np.nansum(d[k] ** 2)))}
    n_fixed = int(((pts.sigma == 0).all(axis=1) & res.point_used).sum())
    if n_fixed:
        out.setdefault("control", {"unit": ou})["n_fixed"] = n_fixed
    if res.check:
        out["check"] = {k: getattr(res.check, k) for k in ("n", "Sx", "Sy", "Sxy", "Sz")}
        out["check"]["unit"] = ou

    # reliability: the largest MDB of an image coordinate and its effect on the points
    if snap is not None:
        rel = out["reliability"]
        k = rel.pop("mdb_max_row", None)
        if k is not None and len(orows) == snap.n and np.isfinite(rel["mdb_max"]):
            rel["mdb_unit"] = unit
            rel.update(_mdb_effect(res, int(orows[k, 0]), int(orows[k, 1]), rel["mdb_max"] / scale))
        if rejections is not None:
            out["tests"]["n_rejected"] = len(rejections.removed)
            out["tests"]["rejected"] = [str(x) for x in rejections.removed_labels[:MOST_LABELS]]

    used = np.flatnonzero(res.camera_used)
    out["n_cameras_used"] = int(used.size)
    out["cameras"] = [_camera(res, j, src, scale) for j in used[:PER_PHOTO_MOST]]
    out["warnings"] = [str(w) for w in res.warnings]
    return out


def _mdb_effect(res, o: int, coord: int, mdb_mm: float) -> dict:
    """Adjust again with the MDB added to coordinate ``coord`` of observation ``o``: the largest
    shift of an object point (external reliability of the weakest observation)."""
    if res.n_unknowns > EFFECT_MAX_UNKNOWNS or o < 0:
        return {"effect_max": None, "effect_point": ""}
    block = res.block_in
    xy = np.array(block.observations.xy, float)
    xy[o, coord] += mdb_mm
    shifted = block.replace(observations=block.observations.replace(xy=xy))
    # Two Gauss–Newton steps from the solution: the effect is that of the linear model (the first
    # step), the second only confirms it; a step that does not converge still carries the state.
    settings = dataclasses.replace(res.settings, max_iter=EFFECT_ITERATIONS)
    try:
        state = adjust(shifted, settings, row_active=res.row_active, obs_active=res.obs_active, start=res.state,
                       compute_initial=False, covariance=False).state
    except AdjustmentError as e:
        state = getattr(e, "state", None)
        if state is None:
            return {"effect_max": None, "effect_point": "", "effect_note": f"not computed: {str(e)[:120]}"}
    d = np.linalg.norm(state.XYZ - res.state.XYZ, axis=1)
    d[~res.point_used] = 0.0
    k = int(np.argmax(d))
    return {"effect_max": float(d[k]), "effect_point": str(block.points.ids[k]),
            "effect_observation": f"photo {block.photos.ids[block.observations.photo[o]]} point "
                                  f"{block.points.ids[block.observations.point[o]]} {'xy'[coord]}"}


def _camera(res, j: int, src: str | None, scale: float) -> dict:
    cams = res.block_in.cameras
    rows = res.camera_table(j)
    names = res.cam_param_names[j]
    R = res.correlation_camera(j)
    free = [t for t in range(len(names)) if res.camera_free[j, t]]
    high = [{"p1": names[a], "p2": names[b], "rho": float(R[a, b])}
            for i, a in enumerate(free) for b in free[i + 1:] if abs(R[a, b]) > HIGH_CORRELATION]
    cam = {"camera": str(cams.ids[j]), "model": str(cams.ap_model[j]),
           "parameters": [{"name": r["parameter"], "value": r["value"], "sigma": r["sigma"],
                           "status": r["status"], "unit": r["unit"]} for r in camera_rows(res, j)],
           "high_correlations": high}
    if src:
        st = res.state.cam_params[j]
        conv = "colmap" if src == "COLMAP" else "opencv"
        cv = opencv_style(st[0], st[1], st[2], str(cams.ap_model[j]), st[3:3 + len(names) - 3],
                          res.cov_cameras[j], cams.resolution[j], cams.pixel_mm[j], conv, drop_shear=True)
        cam["pixels"] = {"c": float(st[0]) * scale, "xp": float(st[1]) * scale + 0.0, "yp": float(st[2]) * scale + 0.0,
                         "sigma_c": float(rows[0]["sigma"]) * scale}
        if cv is not None:
            cam["opencv"] = cv
            if "B2" in names and st[names.index("B2")] != 0.0:
                cam["opencv_note"] = (f"baarda's B2 = {st[names.index('B2')]:.3g} (shear) has no OpenCV "
                                      "counterpart and is left out of the OpenCV values")
    return cam


def _f(x, nd=4) -> str:
    return "–" if x is None or not np.isfinite(x) else f"{x:.{nd}g}"


def protocol_lines(p: dict) -> list[str]:
    """The protocol as Markdown lines for ``report.md`` (the HTML page prints the same dict)."""
    u, ou = p.get("unit", ""), None
    L = ["", "### Protocol summary", ""]
    r = p.get("rms")
    if r:
        L.append(f"- RMS image residuals ({r['n']} image points): x {fmt_q(r['x'], u)}, y {fmt_q(r['y'], u)}, "
                 f"all coordinates {fmt_q(r['all'], u)}"
                 + (f"; OpenCV's RMS re-projection error (√(Σ|v|²/points)) {_f(p['opencv_rms_px'])} px"
                    if "opencv_rms_px" in p else ""))
        cams = p.get("rms_per_camera", [])
        n_cams = p.get("n_cameras", len(cams))
        if n_cams > 1:
            worst = sorted(cams, key=lambda c: -c["all"])[:MOST_CAMERA_LINES]
            L.append(f"  - per camera{' (largest ' + str(len(worst)) + ' of ' + str(n_cams) + ')' if n_cams > len(worst) else ''}: "
                     + ", ".join(f"{c['id']} {fmt_q(c['all'], u)} ({c['n']})" for c in worst))
        worst = p.get("rms_per_photo", [])[:3]
        if worst:
            L.append(f"  - largest per photo (of {p['n_photos']}): "
                     + ", ".join(f"{w['id']} {fmt_q(w['all'], u)}" for w in worst))
    pp = p.get("point_precision")
    if pp:
        ou = pp["unit"]
        L.append(f"- point precision ({pp['n']} points): RMS σX σY σZ = "
                 + " / ".join(fmt_obj(x, ou) for x in pp["rms"]) + "; max " + " / ".join(
                     f"{fmt_obj(x, ou)} ({i})" for x, i in zip(pp["max"], pp["max_ids"])))
    sb = p.get("scale_bars")
    if sb:
        L.append(f"- scale bars ({len(sb['bars'])}): RMS of adjusted − measured {fmt_obj(sb['rms'], sb['unit'])}; "
                 + ", ".join(f"{b['from']}–{b['to']} {fmt_obj(b['residual'], sb['unit'], 3)}" for b in sb["bars"][:6]))
    c = p.get("control")
    if c and c.get("n"):
        L.append(f"- control ({c['n']} weighted points, adjusted − given): RMS "
                 + " / ".join(fmt_obj(x, c['unit']) for x in c["rms"])
                 + f"; largest coordinate difference {fmt_obj(c['max_abs'], c['unit'])} at {c['max_id']}"
                 + (f" (its 3-D length {fmt_obj(c['max_3d'], c['unit'])})" if "max_3d" in c else ""))
    if c and c.get("n_fixed"):
        L.append(f"- fixed control points: {c['n_fixed']}")
    ch = p.get("check")
    if ch:
        L.append(f"- check points ({ch['n']}): RMSE Sx {fmt_obj(ch['Sx'], ch['unit'])}, Sy {fmt_obj(ch['Sy'], ch['unit'])}, Sz {fmt_obj(ch['Sz'], ch['unit'])}")
    rel = p.get("reliability")
    if rel:
        L.append(f"- reliability: smallest redundancy number {_f(rel['r_min'], 3)} ({rel['r_min_label']}), mean "
                 f"{_f(rel['r_mean'], 3)}; {rel['n_uncontrolled']} uncontrolled coordinate(s); largest MDB "
                 f"{fmt_q(rel['mdb_max'], u)} ({rel['mdb_max_label']})"
                 + (f", moving point {rel['effect_point']} by {fmt_obj(rel['effect_max'], ou or p.get('object_unit', ''))}"
                    if rel.get("effect_max") is not None else ""))
    t = p.get("tests")
    if t:
        L.append(f"- w-test |w| > {_f(t['critical_w'])}: {t['n_flagged']} flagged"
                 + (f" ({', '.join(t['flagged'])}{' …' if t['n_flagged'] > len(t['flagged']) else ''})" if t["flagged"] else "")
                 + (f"; rejected {t['n_rejected']}" if t.get("n_rejected") else "")
                 + (f"; {t['decided_by']} flags {t['n_decided']} ({', '.join(t['decided'])}; action = flag: kept, "
                    "not rejected)" if t.get("n_decided") else ""))
    cv = [c for c in p.get("cameras", []) if c.get("opencv")]
    if cv:
        names = [x["name"] for x in cv[0]["opencv"]]
        L += ["", f"Cameras as OpenCV writes them ({p.get('pixel_source')} source; fx fy cx cy in px, k and p "
                  "dimensionless; value (σ)):", "",
              "| camera | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
        L += ["| " + c["camera"] + " | " + " | ".join(f"{_f(x['value'], 7)} ({_f(x['sigma'], 2)})" for x in c["opencv"])
              + " |" for c in cv]
        L += [f"- camera {c['camera']}: {c['opencv_note']}" for c in cv if c.get("opencv_note")]
        L.append("")
    for cam in p.get("cameras", []):
        px = cam.get("pixels")
        if px and not cam.get("opencv"):
            L.append(f"- camera {cam['camera']} in pixels ({p.get('pixel_source')}): c = {_f(px['c'], 7)} ± "
                     f"{_f(px['sigma_c'], 3)} px, principal point offset ({_f(px['xp'] + 0.0, 5)}, "
                     f"{_f(px['yp'] + 0.0, 5)}) px")
        for h in cam.get("high_correlations", []):
            L.append(f"- camera {cam['camera']}: ρ({h['p1']}, {h['p2']}) = {h['rho']:+.3f}")
    return L
