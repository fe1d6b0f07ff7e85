"""The bundle stage's report text, tables and results.json summary, from a
:class:`~baarda.pipeline.adjustment.BundleReport` (the numbers: :func:`baarda.pipeline.adjustment.adjust_block`).

:func:`summary`, :func:`tables` and :func:`report_text` are what the stage writes; nothing here computes
an adjustment or a test, it only arranges their results.
"""

from __future__ import annotations

import numpy as np
from scipy import stats as sps

from baarda.pipeline.api import Block, TableData, stats
from baarda.pipeline.adjustment import EO_NAMES, BundleResult
from baarda.pipeline.protocol import MOST_LABELS
from baarda.pipeline.protocol import global_test_protocol, global_test_text
from baarda.pipeline.report import cap_text, markdown_table

from . import external as bundle_external
from .protocol import bundle_protocol, camera_rows, image_units, protocol_lines
from .rigreport import rig_parts
from baarda.pipeline.units import ImageUnits, column_unit, fmt_obj, length_suffix, object_unit_text


def _crs_columns(res: BundleResult, block: Block) -> dict:
    """The adjusted points and their σ in the user's CRS (``block.crs``, set by a source
    that read coordinates in a CRS; the adjustment itself runs in the local east-north-up frame):
    ``<axis>_crs`` and ``s<axis>_crs``, the covariance carried over as ``J C Jᵀ``.  None without a CRS."""
    from baarda.pipeline.crs import frame_of_block

    frame = frame_of_block(block)
    if frame.is_identity:
        return {}
    XYZ = res.state.XYZ
    ok = np.isfinite(XYZ).all(axis=1)
    user = np.full_like(XYZ, np.nan)
    sig = np.full_like(XYZ, np.nan)
    if ok.any():
        user[ok] = frame.from_local(XYZ[ok])
        J = frame.jacobian(XYZ[ok])
        C = np.nan_to_num(res.cov_points[ok])
        sig[ok] = np.sqrt(np.clip(np.einsum("nij,njk,nik->ni", J, C, J), 0.0, None))
    from baarda.pipeline.units import crs_axis_suffixes

    names = [a + "_crs" + sfx for a, sfx in zip(frame.axis_names(), crs_axis_suffixes(frame))]   # E_crs_m, lat_crs_deg
    out = {a: user[:, i] for i, a in enumerate(names)}
    out.update({f"s{a}": sig[:, i] for i, a in enumerate(names)})
    return out


def _f(x, nd=4):
    return "–" if x is None or not np.isfinite(x) else f"{x:.{nd}g}"


def summary(rep) -> dict:
    """results.json's entry of the bundle stage."""
    res, o = rep.result, rep.config
    out = res.summary()
    gt = rep.global_test
    if gt is not None:
        out["global_test"] = {k: (float(v) if isinstance(v, (float, np.floating)) else v)
                              for k, v in gt.summary().items()}
    ds = rep.snooping
    if ds is not None:
        out["data_snooping"] = {"critical": ds.critical, "n_flagged": int(ds.flagged.sum())}
    jt = rep.joint
    if jt is not None:
        out["joint_test"] = {"critical": jt.critical, "alpha": jt.alpha, "n_tested": int(jt.groups.size),
                             "n_flagged": int(jt.flagged.sum())}
    if rep.ids is not None:
        out["ids"] = {"removed": rep.ids.removed_labels[:MOST_LABELS], "n_removed": len(rep.ids.removed_labels),
                      "stop": rep.ids.stop_reason}     # every one in bundle_observations, decision
    before = rep.before_ids
    if before is not None:     # the adjustment from the initial values, before any rejection
        r0 = before.result
        out["before_rejection"] = {"iterations": r0.iterations, "sigma0_hat": r0.sigma0_hat, "dof": r0.dof,
                                   "n_flagged": int(before.snooping.flagged.sum())}
    if rep.selection is not None:
        out["ap_selection"] = rep.selection.summary()
    out["sigma0_um_equivalent"] = _sigma0_um(res)
    if o.residual == "corrected":                     # the default ("measured") adds no key
        out["residual"] = "corrected"
    out["protocol"] = bundle_protocol(res, rep.ids, alpha0=o.tests.alpha0, beta0=o.tests.beta0,
                                      alpha_global=o.tests.alpha_global)
    if isinstance(out.get("check_points"), dict) and out["check_points"].get("n"):
        out["check_points"]["unit"] = res.block_in.object_unit
    flagged = out.get("data_snooping", {}).get("n_flagged")
    if rep.vc is not None:
        out["variance_components"] = {"mode": o.variance_components.mode, "groups_by": o.variance_components.groups,
                                      **rep.vc.summary()}
    out.update(bundle_external.summary_entries(rep))
    if rep.robust is not None:
        out["robust"] = rep.robust.summary()
    out["headline"] = (f"σ̂0 = {res.sigma0_hat:.3g} (dof {res.dof}, {res.iterations} iterations)"
                       + (f"; {flagged} coordinate(s) flagged by data snooping" if flagged else "")
                       + (f"; IDS removed {len(rep.ids.removed_labels)}" if rep.ids is not None else ""))
    if rep.gnss is not None:
        out["gnss"] = gnss_parts(rep)["summary"]
    if rep.eccentricity is not None:
        out["eccentricity"] = eccentricity_summary(rep)
    rig = rig_parts(rep, rep.config.rig.alpha)
    if rig is not None:
        out["rig"] = rig["summary"]
    return out


def eccentricity_summary(rep) -> dict:
    """The eccentricity correction of circular targets (``rep.eccentricity``) in the image unit."""
    e, block = rep.eccentricity, rep.block
    iu = ImageUnits.of(block)
    used = e.final.applied & block.observations.active
    d = np.linalg.norm(iu.diff(np.asarray(e.final.correction), flip_y=True), axis=1)[used]
    circles = block.circles
    pts = np.isin(block.points.ids, circles.ids)
    return {"observations": int(used.sum()), "targets": int(pts.sum()),
            "normals_estimated": int(e.final.estimated.sum()),
            "normals_given": int((pts & np.isfinite(e.final.normal).all(axis=1) & ~e.final.estimated).sum()),
            f"rms{iu.suffix}": float(np.sqrt(np.mean(d ** 2))) if d.size else 0.0,
            f"max{iu.suffix}": float(d.max()) if d.size else 0.0,
            "rounds": len(e.changes), "changes_sigma": [float(c) for c in e.changes], "settled": bool(e.settled),
            "remaining_sigma": float(e.remaining), "tol_sigma": float(e.tol)}


def _eccentricity_lines(rep) -> list[str]:
    if rep.eccentricity is None:
        return []
    s = eccentricity_summary(rep)
    iu = ImageUnits.of(rep.block)
    u = iu.unit
    rms, mx = s[f"rms{iu.suffix}"], s[f"max{iu.suffix}"]
    return [f"- eccentricity of circular targets: {s['observations']} image points of {s['targets']} targets "
            f"corrected (ellipse centre → image of the circle's centre; normals: {s['normals_given']} given, "
            f"{s['normals_estimated']} from the neighbours' plane), RMS {rms:.3g} {u}, largest {mx:.3g} {u}; "
            f"{s['rounds']} adjustment(s) before this one, largest change of a correction per round "
            + ", ".join(f"{c:.3g}" for c in s["changes_sigma"]) + " σ"
            + ("" if s["settled"] else f" (not below {s['tol_sigma']:g} σ: max_rounds reached)")
            + f"; at this solution {s['remaining_sigma']:.2g} σ (bundle_observations.csv: ecc_x, ecc_y)"]


def _sigma0_um(res: BundleResult) -> float:
    """σ̂0 × median a-priori image σ, in µm (the papers' 'σ0 in µm' when all σ are equal)."""
    cov = res.block_in.observations.cov[res.obs_active]
    if len(cov) == 0:
        return float("nan")
    s = np.sqrt(np.median(0.5 * (cov[:, 0, 0] + cov[:, 1, 1])))
    return float(res.sigma0_hat * s * 1000.0 / res.sigma0)


def report_text(rep, work=None, protocol=None) -> str:
    """report.md's section of the bundle stage; ``work``: the stage's :class:`~.progress.Work`."""
    res, o, block = rep.result, rep.config, rep.block
    L = []
    L.append(f"Bundle adjustment of {int(res.photo_used.sum())} photos, {int(res.point_used.sum())} points, "
             f"{int(res.obs_active.sum())} image points ({res.n_observation_rows} coordinates); "
             f"{res.n_unknowns} unknowns, {res.n_weighted_constraints} weighted constraints, "
             f"{len(res.distances)} distance(s); datum: {o.datum}"
             + (f" (inner constraints on {'projection centres' if o.datum_on == 'centres' else 'points'}, "
                f"{res.n_datum_constraints} constraints)" if o.datum == "free" else "") + "."
             + (" Image residuals in DBAT's definition (option residual = \"corrected\"): the corrected mark minus "
                "the ideal projection, weighted with the mark's σ." if o.residual == "corrected" else ""))
    L.append("")
    L.append(f"- iterations: {res.iterations}; vᵀPv = {res.vtpv:.6g}; dof = {res.dof}; "
             f"σ̂0 = {_f(res.sigma0_hat)} (≈ {_sigma0_equivalent(res, protocol)})")
    gt = rep.global_test
    if gt is not None:
        L.append(f"- global test: {global_test_text(global_test_protocol(gt))}")
    ds = rep.snooping
    if ds is not None:
        L.append(f"- data snooping: |w| > {ds.critical:.3f}: {int(ds.flagged.sum())} coordinate(s) flagged"
                 + (f" (expected under H0 at α0 = {ds.alpha0:g}: about {ds.alpha0 * int(res.snapshot.active.sum()):.0f})"
                    if getattr(ds, "alpha0", None) else ""))
        L.append(_tail_line(ds, res.snapshot))
        L.extend(_flagged_lines(res, ds))
    jt = rep.joint
    if jt is not None and jt.groups.size:
        L.append(f"- 2-D test per image point, T = (Pv)ᵀ(PQvvP)⁻¹(Pv)/σ0² ~ χ²(2): T > {jt.critical:.3f} "
                 f"(α = {jt.alpha:g}) at {int(jt.flagged.sum())} of {jt.groups.size} image points (expected under "
                 f"H0: about {jt.alpha * jt.groups.size:.0f}); per point in bundle_observations.csv "
                 "(T2d, T2d_critical, T2d_flagged)")
    L.extend(_ids_lines(rep))
    L.extend(_robust_lines(rep.robust))
    L.extend(_eccentricity_lines(rep))
    if res.check:
        c, ou = res.check, object_unit_text(block)
        L.append(f"- check points ({c.n}, adjusted − surveyed): Sx = {fmt_obj(c.Sx, ou)}, "
                 f"Sy = {fmt_obj(c.Sy, ou)}, Sxy = {fmt_obj(c.Sxy, ou)}, Sz = {fmt_obj(c.Sz, ou)}")
    t = res.timings
    w = work
    if w is not None and w.adjustments > 1:
        L.append(f"- stage time: {w.seconds:.3f} s for {w.adjustments} adjustments ({w.iterations} iterations "
                 "in all: every re-adjustment of the stage, and the statistics); the last adjustment:")
    elif w is not None:
        L.append(f"- stage time: {w.seconds:.3f} s (the adjustment and its statistics); the adjustment:")
    L.append(f"- time: {t.total:.3f} s (initial values {t.initial_values:.3f}, linearise "
             f"{t.linearize:.3f}, solve {t.solve:.3f}, covariance {t.covariance:.3f}; "
             f"{res.solver_route} reduced system)")
    for w in res.warnings:
        L.append(f"- warning: {w}")
    if protocol:
        L += protocol_lines(protocol)
    L.append("")
    L.append("### Camera parameters")
    L.append("")
    u = image_units(block)
    if u[0] == "px":
        L += [f"In pixels ({u[2]} source): c and the principal point's offset from the image centre (xp, yp, "
              "y up) in px, the additional parameters scaled to pixel coordinates (a parameter of unit mm⁻ᵏ "
              "times pitchᵏ: K1 px⁻², P1 px⁻¹, B1 dimensionless; docs/report.md); OpenCV's form is in the "
              "protocol summary above.", ""]
    cam_rows = []
    zero_fixed = {}                          # camera -> parameters held fixed at 0 (one line, not rows)
    for j in range(len(block.cameras)):
        if not res.camera_used[j]:
            continue
        for r in camera_rows(res, j, u):
            if r["status"] == "fixed" and r["value"] == 0.0:
                zero_fixed.setdefault(r["camera"], []).append(r["parameter"])
                continue
            cam_rows.append(f"| {r['camera']} | {r['parameter']} | {r['value']:.8g} | {_f(r['sigma'], 3)} | "
                            f"{r['unit']} | {r['status']} |")
    if len(cam_rows) > MAX_CAMERA_ROWS:
        L += [cap_text(MAX_CAMERA_ROWS, len(cam_rows), what="parameter rows", where="bundle_cameras.csv") + ":", ""]
    L.append("| camera | parameter | value | σ | unit | status |")
    L.append("|---|---|---|---|---|---|")
    L += cam_rows[:MAX_CAMERA_ROWS]
    L += _zero_fixed_lines(zero_fixed)
    shown = 0
    for j in range(len(block.cameras)):
        free = [t for t in range(len(res.cam_param_names[j])) if res.camera_free[j, t]]
        if len(free) < 2:
            continue
        shown += 1
        if shown > MAX_CORRELATION_TABLES:
            L += ["", f"Correlations of the other cameras: bundle_correlations.csv."]
            break
        R = res.correlation_camera(j)[np.ix_(free, free)]
        nm = [res.cam_param_names[j][t] for t in free]
        L += ["", f"Correlations of camera {str(block.cameras.ids[j])!r}:", "",
              "| | " + " | ".join(nm) + " |", "|---" * (len(nm) + 1) + "|"]
        for a in range(len(nm)):
            L.append(f"| {nm[a]} | " + " | ".join(f"{R[a, b]:+.2f}" for b in range(len(nm))) + " |")
    sel = rep.selection
    if sel is not None:
        L += ["", "### Additional-parameter selection", "", sel.markdown()]
    if rep.vc is not None:
        L += ["", "### Variance components", ""] + _vc_lines(rep.vc, o.variance_components, rep.global_test)
    L += bundle_external.report_entries(rep, block)
    rig = rig_parts(rep, o.rig.alpha)
    if rig is not None:
        L += rig["lines"]
    text = "\n".join(L)
    if rep.gnss is not None:          # the GNSS antennas' section
        text += "\n\n" + "\n".join(gnss_parts(rep)["lines"])
    return text


def _ids_lines(rep) -> list[str]:
    """Iterated data snooping: what it rejected, the adjustment before the rejections, the rejected rows."""
    ids, res, before = rep.ids, rep.result, rep.before_ids
    if ids is None:
        return []
    L = [f"- iterated data snooping (|w| > {ids.critical:.3f}, one coordinate at a time): "
         f"{len(ids.removed)} coordinate(s) rejected; stop: {ids.stop_reason}"]
    if before is not None:
        r0, ds0 = before.result, before.snooping
        n0 = int(r0.snapshot.active.sum())
        L += [f"  - before the rejections ({r0.iterations} iterations from the initial values): σ̂0 = "
              f"{_f(r0.sigma0_hat)}, {int(ds0.flagged.sum())} coordinate(s) with |w| > {ds0.critical:.3f} "
              f"(expected under H0: about {ds0.alpha0 * n0:.0f})",
              "  " + _tail_line(ds0, r0.snapshot), "  " + _radius_line(res, ids)]
    return L + _rejected_lines(res, ids)


def _robust_lines(rob, most: int = 30) -> list[str]:
    """The robust estimate in the report: estimator, convergence, the down-weighted coordinates."""
    if rob is None:
        return []
    r = rob.irls
    d = r.downweighted
    L = [f"- robust estimation: {r.method} (c = {r.c:g}, residuals / {_ROBUST_SCALE[r.standardise]}), "
         f"{r.iterations} weighted adjustment(s), {'converged' if r.converged else 'NOT converged'}; "
         f"{d.size} coordinate(s) down-weighted (ω < {r.threshold:g}); the values above are the final weighted "
         "adjustment's (a-priori σ / √ω)"]
    if d.size:
        L += ["", f"  Down-weighted (smallest ω first; all in bundle_observations.csv, robust_wx / robust_wy):", "",
              "  | observation | ω | u |", "  |---|---|---|"]
        L += [f"  | {r.labels[i]} | {r.weights[i]:.3g} | {r.u[i]:+.2f} |" for i in d[:most]]
        if d.size > most:
            L.append(f"  | … | {d.size - most} more | |")
        L.append("")
    return L


_ROBUST_SCALE = {"redundancy": "σ √r of the unweighted adjustment", "apriori": "a-priori σ",
                 "current": "σ √r of the current weighted adjustment"}


def _robust_columns(rob, k: int) -> dict:
    """Per observation: the final robust weight of x and y (only with robust estimation)."""
    if rob is None:
        return {}
    w = np.asarray(rob.irls.weights).reshape(k, 2)
    return {"robust_wx": w[:, 0], "robust_wy": w[:, 1]}


def _vc_lines(vc, o, gt=None) -> list[str]:
    """Each group's factor on its a-priori σ, σ(f), r_g and the test of f = 1; ``o``: the config's
    variance_components group; ``gt``: the global test, whose verdict the groups' must not contradict
    without the reason beside them."""
    first = vc.first
    L = [f"Förstner's estimate, iterated ({vc.iterations} re-adjustment(s), "
         f"{'converged' if vc.converged else 'NOT converged'}); image groups per {o.groups}. "
         f"f = estimated σ / a-priori σ; test of H0: f = 1 by T = f² ~ χ²(r)/r, two-sided at α = {vc.alpha:g}. "
         + ("The adjustment above and its tests use the a-priori σ × f." if o.mode == "apply"
            else "Estimated only: the adjustment above keeps the a-priori σ "
                 f"(σ̂0 = {_f(first.sigma0_hat)}) — variance_components.mode = \"apply\" re-weights it."), "",
         f"First adjustment, on the a-priori σ: {first.iterations} iterations, σ̂0 = {_f(first.sigma0_hat)}, "
         f"dof {first.dof}.", "",
         "| group | rows | r | f | σ(f) | T | p | H0: f = 1 |", "|---|---|---|---|---|---|---|---|"]
    for g in vc.groups:
        if g.estimable:
            L.append(f"| {g.name} | {g.n} | {g.redundancy:.1f} | {g.factor:.4g} | {g.sigma_factor:.2g} | "
                     f"{g.T:.4g} | {g.p_value:.3g} | {'rejected' if g.rejected else 'accepted'} |")
        else:
            L.append(f"| {g.name} | {g.n} | {g.redundancy:.3g} | 1 (not estimable: r < 1) | – | – | – | – |")
    L.extend(_vc_vs_global(vc, o, gt))
    return L


def _vc_vs_global(vc, o, gt) -> list[str]:
    """One verdict per hypothesis: the global test (H0: σ̂0 = σ0, all groups pooled) beside the groups'
    tests of f = 1, with the reason when they differ."""
    if gt is None or not np.isfinite(gt.T):
        return []
    bad = [g.name for g in vc.groups if g.estimable and g.rejected]
    est = [g for g in vc.groups if g.estimable]
    line = f"Global test of the adjustment above: {gt.verdict}"
    if o.mode == "apply":
        why = ("it tests the re-weighted adjustment, whose σ̂0 the estimated factors bring to 1 by construction; "
               "the table tests each group's a-priori σ" if bad and not gt.rejected else "")
    elif bad and not gt.rejected:
        why = ("it pools every group (σ̂0² ≈ Σ r_g f_g² / Σ r_g), so groups whose σ are too large and too small "
               "compensate; the table tests each group's own a-priori σ")
    elif gt.rejected and not bad and est:
        why = ("the pooled test has the redundancy of all groups and detects a deviation that no single group's "
               "smaller redundancy does")
    else:
        why = ""
    if bad:
        line += f"; f = 1 rejected for {', '.join(bad)}"
    elif est:
        line += "; f = 1 accepted for every group"
    return ["", line + (f" — they differ because {why}." if why else ".")]


MAX_CAMERA_ROWS = 20
"""Rows of camera parameters in report.md (a COLMAP block of 23 cameras has 46; all in bundle_cameras.csv)."""
MAX_CORRELATION_TABLES = 4
"""Cameras whose correlation matrix report.md prints (all are in bundle_correlations.csv)."""


def _zero_fixed_lines(zero_fixed: dict) -> list[str]:
    """'held fixed at 0' per group of cameras with the same parameters (every row is in
    bundle_cameras.csv); a COLMAP block of 23 cameras gets one line instead of 138 rows."""
    groups: dict[tuple, list[str]] = {}
    for cam, names in zero_fixed.items():
        groups.setdefault(tuple(names), []).append(cam)
    out = []
    for names, cams in groups.items():
        who = f"camera {cams[0]}" if len(cams) == 1 else (
            f"cameras {', '.join(cams)}" if len(cams) <= 6 else f"{len(cams)} cameras ({cams[0]} … {cams[-1]})")
        out.append(f"- {who}: {', '.join(names)} held fixed at 0")
    return ([""] + out) if out else []


def _sigma0_equivalent(res: BundleResult, protocol) -> str:
    """σ̂0 × the median a-priori image σ in the unit of the source (µm, or px for a pixel source)."""
    um = _sigma0_um(res)
    if protocol and protocol.get("unit") == "px":
        return f"{_f(um / 1000.0 / float(res.block_in.cameras.pixel_mm[0]), 3)} px"
    return f"{_f(um, 3)} µm"


def _flagged_lines(res: BundleResult, ds, most: int = MOST_LABELS) -> list[str]:
    """The largest flagged standardized residuals, with photo, point and coordinate (``most`` rows: the
    report's one cap of a list, so report.html does not cut the table a second time)."""
    idx = np.flatnonzero(ds.flagged)
    if not len(idx):
        return []
    u, k, _ = image_units(res.block_in)
    idx = idx[np.argsort(-np.abs(ds.w[idx]))]
    head = (f"The {most} largest |w| of {len(idx)} flagged" if len(idx) > most else f"All {len(idx)} flagged, largest |w| first")
    rows = ["", f"  {head} (every one in bundle_observations.csv, column `decision`):", "",
            f"  | observation | v ({u}) | r | w | ∇̂ ({u}) | MDB ({u}) |", "  |---|---|---|---|---|---|"]
    snap = res.snapshot
    for i in idx[:most]:
        rows.append(f"  | {snap.labels[i]} | {k * snap.v[i]:+.3f} | {snap.r[i]:.3f} | {ds.w[i]:+.2f} | "
                    f"{k * ds.nabla_hat[i]:+.3f} | {k * ds.mdb[i]:.3f} |")
    return rows + [""]


def _tail_line(ds, snap) -> str:
    """How the standardized residuals' tails compare with the normal distribution they follow under
    H0 — more large |w| than α0·n means gross errors or a-priori σ that do not fit the data."""
    w = np.abs(ds.w[np.asarray(snap.active, bool) & (np.asarray(snap.r) > 1e-9)])
    if not w.size:
        return "- w: no controlled coordinates"
    parts = [f"|w| > {k:g}: {100 * np.mean(w > k):.2f} % (normal {200 * sps.norm.sf(k):.2f} %)" for k in (2.0, 3.0, 4.0)]
    return "- distribution of w over " + f"{w.size} coordinates: " + "; ".join(parts)


def _radius_line(res: BundleResult, ids) -> str:
    """Where in the format the rejected coordinates lie: median distance from the principal point."""
    obs = res.block_in.observations
    cp = res.state.cam_params[res.block_in.photos.camera[obs.photo]]
    rad = np.hypot(obs.xy[:, 0] - cp[:, 1], obs.xy[:, 1] - cp[:, 2])
    act = np.asarray(res.snapshot.active, bool).reshape(-1, 2).any(axis=1) | (np.bincount(
        np.asarray(ids.removed, int) // 2, minlength=len(obs)) > 0)
    rej = np.unique(np.asarray(ids.removed, int) // 2)
    u, k, _ = image_units(res.block_in)
    u, k = ("px", k) if u == "px" else ("mm", 1.0)
    return (f"- distance from the principal point: median {k * np.median(rad[rej]):.2f} {u} for the rejected "
            f"image points, {k * np.median(rad[act]):.2f} {u} for all")


def _rejected_lines(res: BundleResult, ids, most: int = 30) -> list[str]:
    """The rejected coordinates in the order of rejection, with w when rejected and the predicted
    residual in the final adjustment (v_pred/σ, the w-test the row would have if it were back)."""
    if not ids.removed:
        return []
    snap = ids.snapshot
    u, scale, _ = image_units(res.block_in)
    steps = [h for h in ids.history if h.removed]
    rows = ["", f"  Rejected (in order; all in bundle_observations.csv, decision = rejected):", "",
            f"  | # | observation | w when rejected | v_pred now ({u}) | v_pred/σ now |", "  |---|---|---|---|---|"]
    for k, (i, h) in enumerate(zip(ids.removed[:most], steps)):
        vp = snap.v_pred[i] if snap.v_pred is not None else np.nan
        sp = snap.sigma_v_pred[i] if snap.sigma_v_pred is not None else np.nan
        rows.append(f"  | {k + 1} | {snap.labels[i]} | {h.w_max:+.2f} | {scale * vp:+.3f} | {vp / sp:+.2f} |")
    if len(ids.removed) > most:
        rows.append(f"  | … | {len(ids.removed) - most} more | | | |")
    return rows + [""]


def _joint_columns(jt, k: int) -> dict:
    """Per observation: the 2-D statistic, its critical value and the decision (nan / False for
    image points without two active coordinates)."""
    T = np.full(k, np.nan)
    flag = np.zeros(k, bool)
    crit = np.full(k, np.nan)
    if jt is not None and jt.groups.size:
        g = np.asarray(jt.groups, int)
        T[g] = jt.T
        flag[g] = jt.flagged
        crit[g] = jt.critical
    return {"T2d": T, "T2d_critical": crit, "T2d_flagged": flag}


def _image_columns(block, iu, v, nab, mdbs) -> tuple[dict, dict]:
    """Image coordinates (mm; for a pixel source also the pixel coordinates x_px, y_px = u, v in the
    source's convention) and residuals, estimated errors and MDBs in µm (metric source) or px (pixel
    source, y along the pixel rows: down, so its sign is that of −y in mm).  ``(columns, units)``."""
    obs = block.observations
    s = iu.suffix
    cols = {"x_mm": obs.xy[:, 0], "y_mm": obs.xy[:, 1]}
    if iu.is_pixels:
        uv = iu.coordinates(block, obs.xy, obs.photo)
        cols.update({"x_px": uv[:, 0], "y_px": uv[:, 1]})
    dv, dn, dm = iu.diff(v, flip_y=True), iu.diff(nab, flip_y=True), iu.diff(mdbs)
    cols.update({f"vx{s}": dv[:, 0], f"vy{s}": dv[:, 1]})
    return cols, {f"nabla_x{s}": dn[:, 0], f"nabla_y{s}": dn[:, 1], f"mdb_x{s}": dm[:, 0], f"mdb_y{s}": dm[:, 1]}


def _eccentricity_columns(rep, iu) -> dict:
    """Per observation: the eccentricity correction the adjustment subtracted from the measured centre
    (only when the block has circular targets and the correction is on)."""
    if rep.eccentricity is None:
        return {}
    d = iu.diff(np.asarray(rep.eccentricity.final.correction), flip_y=True)
    return {f"ecc_x{iu.suffix}": d[:, 0], f"ecc_y{iu.suffix}": d[:, 1]}


def units_from_suffix(columns) -> dict:
    """Each column's unit from its name's suffix (docs/conventions.md, *Column names*); "" for none."""
    return {c: column_unit(c) for c in columns}


def tables(rep) -> dict:
    """The bundle stage's CSV tables (bundle_<name>.csv)."""
    res, decision, block = rep.result, rep.decision, rep.block
    units = image_units(block)
    obs = block.observations
    ph_ids = block.photos.ids[obs.photo]
    pt_ids = block.points.ids[obs.point]
    v = res.residuals
    r = res.redundancy
    snap = res.snapshot
    if snap is not None:
        w = stats.w_test(snap).reshape(-1, 2)
        mdbs = stats.mdb(snap).reshape(-1, 2)
        nab = stats.estimated_errors(snap).reshape(-1, 2)
    else:
        w = mdbs = nab = np.full((len(obs), 2), np.nan)
    tables = {}
    iu = ImageUnits.of(block)
    img, img_tests = _image_columns(block, iu, v, nab, mdbs)
    cols = {"photo": ph_ids, "point": pt_ids, **img,             # id arrays, not lists of 2 × k str objects (36 MB)
            "rx": r[:, 0], "ry": r[:, 1], "wx": w[:, 0], "wy": w[:, 1], **img_tests,
            **_joint_columns(rep.joint, len(obs)),
            **bundle_external.observation_columns(bundle_external.external_view(rep), len(obs),
                                                  length_suffix(object_unit_text(block))),
            **_robust_columns(rep.robust, len(obs)),
            **_eccentricity_columns(rep, iu),
            "decision": decision.tolist()}
    tables["observations"] = TableData(
        cols,
        f"every image observation: coordinates (mm{'; x_px, y_px: pixel coordinates u, v of the ' + str(iu.source) + ' source, y down' if iu.is_pixels else ''}), "
        f"residual v = observed − computed ({iu.unit}), redundancy, w-test, estimated error ∇̂ and MDB ({iu.unit}), "
        "2-D test of the point (χ²(2)), "
        "largest effect of each MDB on its own point / photo (ext_*: object units, degrees, in σ), δ̄0",
        units=units_from_suffix(cols))
    pts = block.points
    sp = res.point_sigmas()
    rays = np.bincount(obs.point[res.obs_active], minlength=len(pts))
    XYZ = res.state.XYZ
    dXYZ = np.where((pts.role == "check")[:, None], XYZ - pts.XYZ, np.nan)
    ou = object_unit_text(block)
    o = length_suffix(ou)
    pcols = {
        "point": pts.ids, "role": pts.role, f"X{o}": XYZ[:, 0], f"Y{o}": XYZ[:, 1], f"Z{o}": XYZ[:, 2],
        f"sX{o}": sp[:, 0], f"sY{o}": sp[:, 1], f"sZ{o}": sp[:, 2], "rays": rays,
        f"dX_check{o}": dXYZ[:, 0], f"dY_check{o}": dXYZ[:, 1], f"dZ_check{o}": dXYZ[:, 2],
        **bundle_external.point_columns(res, rep.config.output.confidence, o), **_crs_columns(res, block)}
    tables["points"] = TableData(
        pcols,
        f"adjusted object points ({block.object_unit}) with a-posteriori σ; check points: adjusted − surveyed; "
        "error ellipsoid (semi-axes, direction of the largest), plan ellipse (bearing from +X), height interval; "
        "*_crs: the same points and σ in the CRS the coordinates were given in (docs/crs.md), where there is one", units=units_from_suffix(pcols))
    chk = pts.role == "check"
    if chk.any():
        ccols = {"point": pts.ids[chk].tolist(), f"dX{o}": dXYZ[chk, 0], f"dY{o}": dXYZ[chk, 1], f"dZ{o}": dXYZ[chk, 2]}
        tables["check_points"] = TableData(ccols, f"check points: adjusted − surveyed ({ou})",
                                           units=units_from_suffix(ccols))
    rows = [r for j in range(len(block.cameras)) for r in camera_rows(res, j, units)]
    tables["cameras"] = TableData({k: [r[k] for r in rows] for k in
                                   ("camera", "parameter", "value", "sigma", "status", "apriori_sigma", "unit")},
                                  "camera parameters with σ in the unit of column 'unit': " + (
                                      f"pixels ({units[2]} source: c, xp, yp in px, the APs scaled to pixel "
                                      "coordinates, docs/report.md)" if units[0] == "px" else "mm (APs mm⁻ᵏ)"))
    se = res.eo_sigmas()
    X0, opk = res.state.X0, res.state.opk
    cols = {"photo": block.photos.ids.tolist()}
    for t, n in enumerate(EO_NAMES):
        val = X0[:, t] if t < 3 else np.degrees(opk[:, t - 3])
        sd = se[:, t] if t < 3 else np.degrees(se[:, t])
        cols[n + (o if t < 3 else "_deg")] = val
        cols["s" + n + (o if t < 3 else "_deg")] = sd
    tables["eo"] = TableData(cols, f"exterior orientation with a-posteriori σ (centres in {ou}, angles in degrees)")
    corr_rows = []
    for j in range(len(block.cameras)):
        R = res.correlation_camera(j)
        nm = res.cam_param_names[j]
        for a in range(len(nm)):
            for b in range(a + 1, len(nm)):
                if R[a, a] > 0 and R[b, b] > 0:
                    corr_rows.append((str(block.cameras.ids[j]), nm[a], nm[b], float(R[a, b])))
    tables["correlations"] = TableData({"camera": [c[0] for c in corr_rows], "p1": [c[1] for c in corr_rows],
                                        "p2": [c[2] for c in corr_rows], "rho": [c[3] for c in corr_rows]},
                                       "correlations between the estimated camera parameters")
    h = res.history
    tables["convergence"] = TableData({"iteration": h.iteration.tolist(), "vtpv": h.vtpv.tolist(),
                                       "lambda": h.lam.tolist(), "max_step_sigma": h.max_step_sigma.tolist()},
                                      "vᵀPv, damping and largest correction (in σ of an observation) per iteration")
    tables["observations"].detail = tables["points"].detail = True     # outputs = "summary" skips them
    tables.update(bundle_external.tables(rep))
    if rep.gnss is not None:
        tables["gnss"] = gnss_parts(rep)["table"]
    rig = rig_parts(rep, rep.config.rig.alpha)
    if rig is not None:
        tables.update(rig["tables"])
    return tables


def gnss_parts(rep) -> dict:
    """The GNSS antennas as observations of the bundle (``block.gnss``, the report's ``gnss``): per photo
    the residuals ``v = X_antenna − (X0 + Rᵀ e)`` (object units; E N U in a CRS's local frame, else X Y Z),
    a-priori σ, redundancy numbers, w-tests and MDBs; the report section, table and summary."""
    res = rep.result
    gs, ds = rep.gnss.rows, rep.gnss.snooping
    blk = res.block_in
    G = len(gs.index)
    w, mdb = ds.w.reshape(G, 3), ds.mdb.reshape(G, 3)
    flagged = rep.gnss.flagged
    ax = ("E", "N", "U") if blk.crs is not None else ("X", "Y", "Z")
    ids = blk.photos.ids[blk.gnss.photo[gs.index]].astype(str).tolist()
    u = blk.object_unit
    cols = {"photo": ids}
    o = length_suffix(u)             # v, σ and MDB in the object unit: vE_m, sE_m, mdbE_m
    for name, arr, sfx in (("v", gs.v, o), ("s", gs.sigma, o), ("r", gs.r, ""), ("w", w, ""), ("mdb", mdb, o)):
        cols.update({f"{name}{a}{sfx}": arr[:, t] for t, a in enumerate(ax)})
    cols["flagged"] = flagged
    rms = np.sqrt(np.mean(gs.v ** 2, axis=0))
    om = float(np.sum(gs.snapshot.Pv * gs.snapshot.v))
    rsum = float(gs.r.sum())
    lines = ["### GNSS antennas", "",
             f"{G} antenna positions observed: `X_antenna + v = X0 + R_cam_from_worldᵀ · e` (lever arm e in the "
             f"camera frame). Residuals ({u}): RMS {ax[0]} {rms[0]:.4g}, {ax[1]} {rms[1]:.4g}, {ax[2]} {rms[2]:.4g}; "
             f"their share of vᵀPv {om:.4g} on redundancy {rsum:.4g} (Ω/r = {om / rsum if rsum > 0 else float('nan'):.3g}"
             f"); w-test critical value {ds.critical:.3g}: {int(flagged.sum())} antenna(s) flagged.", ""]
    order = np.argsort(-np.abs(w).max(axis=1))
    show = order[:min(G, 15)]
    head = ["photo"] + [f"v{a}" for a in ax] + [f"r{a}" for a in ax] + [f"w{a}" for a in ax] + ["flagged"]
    lines.append(("Largest |w| first" + (f" ({len(show)} of {G})" if len(show) < G else "") + ":"))
    lines += ["", markdown_table(head, [[ids[g]] + [f"{x:.4f}" for x in gs.v[g]] + [f"{x:.3f}" for x in gs.r[g]]
                                        + [f"{x:.2f}" for x in w[g]] + ["yes" if flagged[g] else ""] for g in show])]
    summary = {"antennas": G, "rms": rms.tolist(), "axes": list(ax), "unit": u, "omega": om, "redundancy": rsum,
               "critical": float(ds.critical), "flagged": int(flagged.sum()),
               "flagged_photos": [ids[g] for g in np.flatnonzero(flagged)]}
    table = TableData(cols, f"GNSS antenna residuals v = observed − computed ({u}), a-priori σ, redundancy numbers, "
                            "w-tests and MDBs per photo")
    return {"summary": summary, "lines": lines, "table": table, "photos": ids, "v": gs.v,
            "observed": blk.gnss.XYZ[gs.index]}

