"""Stage ``independent-models``: its summary, tables and Markdown report (the stage is
:mod:`.stage`, the numerics :mod:`baarda.pipeline.imodels`)."""

from __future__ import annotations

import numpy as np

from baarda.pipeline.api import TableData
from baarda.pipeline.imodels import IndependentModelResult
from baarda.pipeline.protocol import global_test_text
from baarda.pipeline.report import markdown_table
from baarda.pipeline.units import length_suffix

from . import reliability as im_reliability


def _deg(a):
    return float(np.degrees(a))


def summary(result: IndependentModelResult, stats: dict, block) -> dict:
    blk = result.block
    gt = stats["block"]["global"]
    ds = stats["block"]["snooping"]
    models = []
    for ro, st in zip(result.relative, stats["models"]):
        d = {"model": ro.name.replace("model ", ""), "points": int(ro.active.sum()), "dof": ro.dof,
             "sigma0_hat": ro.sigma0_hat, "iterations": ro.iterations, "initial": ro.initial,
             "rcond": ro.rcond, "n_flagged": int(st["snooping"].flagged.sum()),
             "flagged": st["snooping"].flagged_labels}
        models.append(d)
    rm = blk.check
    unit = block.object_unit
    check_points = {"n": int(rm.n), **{k: float(getattr(rm, k)) for k in ("Sx", "Sy", "Sxy", "Sz")}, "unit": unit}
    f, u = (100.0, "cm") if unit == "m" else (1.0, unit)
    headline = (f"{len(result.relative)} models; block σ̂0 = {blk.sigma0_hat:.3g} (dof {blk.dof}, global test "
                f"{'rejected' if gt.rejected else 'accepted'}), {int(ds.flagged.sum())} coordinate(s) flagged"
                + (f"; check points ({rm.n}): Sxy {rm.Sxy * f:.4g} {u}, Sz {rm.Sz * f:.4g} {u}"
                   if rm.n else "; no check points"))
    return {
        "headline": headline, "check_points": check_points,
        "models": len(result.relative), "method": result.options.method,
        "parameters": result.options.parameters,
        "block": {"sigma0_hat": blk.sigma0_hat, "dof": blk.dof, "iterations": blk.iterations,
                  "global_test": gt.summary(), "n_flagged": int(ds.flagged.sum()),
                  "flagged": ds.flagged_labels, "points": int(blk.in_adjustment.sum())},
        "check_rmse": blk.check.rmse(), "object_unit": block.object_unit,
        "per_model": models, "ro_removed": stats.get("ro_removed", {}),
    }


# --------------------------------------------------------------------------- tables

RO_COLUMNS = {"by": "by_mu", "bz": "bz_mu", "omega1": "omega1_deg", "phi1": "phi1_deg", "kappa1": "kappa1_deg",
              "omega2": "omega2_deg", "phi2": "phi2_deg", "kappa2": "kappa2_deg"}
"""Relative-orientation parameters → the models table's column (one unit each): the dependent method's
by, bz, ω2, φ2, κ2 and the independent method's φ1, κ1, φ2, ω2, κ2."""


def tables(result: IndependentModelResult, stats: dict, block) -> dict:
    blk = result.block
    unit = block.object_unit
    # models and their relative orientation
    rows = {k: [] for k in ("model", "left", "right", "method", "parameters", "points", "dof",
                            "sigma0_hat", "iterations", "initial", "rcond", "bx_mu", *RO_COLUMNS.values(),
                            "global_T", "global_rejected", "max_abs_w", "flagged")}
    for (mid, left, right), ro, st in zip(result.pairs, result.relative, stats["models"]):
        ds, gt = st["snooping"], st["global"]
        rows["model"].append(mid)
        rows["left"].append(left)
        rows["right"].append(right)
        rows["method"].append(ro.method)
        rows["parameters"].append(ro.parameters)
        rows["points"].append(int(ro.active.sum()))
        rows["dof"].append(ro.dof)
        rows["sigma0_hat"].append(ro.sigma0_hat)
        rows["iterations"].append(ro.iterations)
        rows["initial"].append(ro.initial)
        rows["rcond"].append(ro.rcond)
        rows["bx_mu"].append(ro.bx)
        got = dict(zip(ro.param_names, ro.p))        # dependent: by bz ω2 φ2 κ2; independent: φ1 κ1 φ2 ω2 κ2
        for nm, col in RO_COLUMNS.items():
            v = got.get(nm)
            rows[col].append(float("nan") if v is None else _deg(v) if nm[:-1] in ("omega", "phi", "kappa") else float(v))
        rows["global_T"].append(gt.T)
        rows["global_rejected"].append(bool(gt.rejected))
        ok = np.isfinite(ds.w)
        rows["max_abs_w"].append(float(np.max(np.abs(ds.w[ok]))) if ok.any() else float("nan"))
        rows["flagged"].append(" ".join(ds.flagged_labels))
    models = TableData(rows, "per model: relative orientation (base bx and by, bz in model units, angles in "
                             "degrees; empty where the model's method has no such parameter), σ̂0, global test "
                             "and y-parallax snooping")
    # statistics rows of each relative orientation
    t = {k: [] for k in ("model", "row", "active", "v_um", "r", "w", "nabla_um", "mdb_um", "flagged")}
    pts = {k: [] for k in ("model", "point", "used", "vx_left_um", "vy_left_um", "vx_right_um",
                           "vy_right_um", "py_um", "x_model_mu", "y_model_mu", "z_model_mu")}
    for (mid, *_), ro, st in zip(result.pairs, result.relative, stats["models"]):
        ds = st["snooping"]
        s = ro.snapshot
        t["model"] += [mid] * s.n
        t["row"] += s.labels.tolist()
        t["active"] += s.active.tolist()
        t["v_um"] += (s.v * 1e3).tolist()
        t["r"] += s.r.tolist()
        t["w"] += ds.w.tolist()
        t["nabla_um"] += (ds.nabla_hat * 1e3).tolist()
        t["mdb_um"] += (ds.mdb * 1e3).tolist()
        t["flagged"] += ds.flagged.tolist()
        n = len(ro.point_ids)
        pts["model"] += [mid] * n
        pts["point"] += ro.point_ids.tolist()
        pts["used"] += ro.active.tolist()
        for k, c in enumerate(("vx_left_um", "vy_left_um", "vx_right_um", "vy_right_um")):
            pts[c] += (ro.v[:, k] * 1e3).tolist()
        pts["py_um"] += (ro.py * 1e3).tolist()
        for k, c in enumerate(("x_model_mu", "y_model_mu", "z_model_mu")):
            pts[c] += ro.XYZ[:, k].tolist()
    ro_tests = TableData(t, "relative orientation: statistics rows (y-parallax per point for coplanarity, "
                            "image coordinates for collinearity), µm; w-test, estimated error, MDB")
    ro_points = TableData(pts, "relative orientation: image residuals (observed − computed, µm), residual "
                               "y-parallax, model coordinates (model units)")
    # transformations
    o = length_suffix(unit)          # object-unit suffix of the length columns (_m, _mm)
    sd = np.sqrt(np.einsum("mii->mi", blk.Qparams)) * (blk.sigma0_hat if np.isfinite(blk.sigma0_hat) else 1.0)
    tr = {"model": blk.model_ids.tolist(), "scale": blk.params[:, 0],
          "omega_deg": np.degrees(blk.params[:, 1]), "phi_deg": np.degrees(blk.params[:, 2]),
          "kappa_deg": np.degrees(blk.params[:, 3]), f"tx{o}": blk.params[:, 4], f"ty{o}": blk.params[:, 5],
          f"tz{o}": blk.params[:, 6], "s_scale": sd[:, 0], "s_omega_deg": np.degrees(sd[:, 1]),
          "s_phi_deg": np.degrees(sd[:, 2]), "s_kappa_deg": np.degrees(sd[:, 3]), f"s_tx{o}": sd[:, 4],
          f"s_ty{o}": sd[:, 5], f"s_tz{o}": sd[:, 6]}
    transformations = TableData(tr, f"7-parameter similarity of each model into the object system "
                                    f"(X = s Mᵀ x + T, {unit}); standard deviations a posteriori")
    s0 = blk.sigma0_hat if np.isfinite(blk.sigma0_hat) else 1.0
    sx = np.sqrt(np.maximum(np.einsum("pii->pi", blk.cov_XYZ), 0)) * s0 / result.options.sigma0
    points = TableData({"point": blk.point_ids.tolist(), "role": blk.role.tolist(),
                        "models": blk.n_models, "in_adjustment": blk.in_adjustment,
                        f"X{o}": blk.XYZ[:, 0], f"Y{o}": blk.XYZ[:, 1], f"Z{o}": blk.XYZ[:, 2],
                        f"sX{o}": sx[:, 0], f"sY{o}": sx[:, 1], f"sZ{o}": sx[:, 2],
                        **im_reliability.point_columns(blk.cov_XYZ, (s0 / result.options.sigma0) ** 2, suffix=o)},
                       f"adjusted object points ({unit}); σ a posteriori; projection centres 'pc:<photo>'; "
                       "1-σ error ellipsoid (semi-axes, direction of the largest), plan ellipse, height σ")
    ds = stats["block"]["snooping"]
    s = blk.snapshot
    G = blk.obs_model.size
    w = ds.w[:3 * G].reshape(G, 3)
    r = s.r[:3 * G].reshape(G, 3)
    res = {"model": blk.model_ids[blk.obs_model].tolist(), "point": blk.point_ids[blk.obs_point].tolist(),
           "role": blk.role[blk.obs_point].tolist()}
    for k, c in enumerate("xyz"):
        res[f"v{c}{o}"] = blk.v_object[:, k]
    for k, c in enumerate("xyz"):
        res[f"v{c}_model_mu"] = blk.v_model[:, k]
    for k, c in enumerate("xyz"):
        res[f"r_{c}"] = r[:, k]
    for k, c in enumerate("xyz"):
        res[f"w_{c}"] = w[:, k]
    residuals = TableData(res, f"model-point residuals, observed − computed: in the object frame ({unit}) "
                               "and in model units; redundancy and w-test per coordinate")
    C = blk.control_point.size
    control = TableData({"point": blk.point_ids[blk.control_point].tolist(),
                         "axis": ["XYZ"[a] for a in blk.control_axis],
                         f"v{o}": blk.v_control, "r": s.r[3 * G:3 * G + C], "w": ds.w[3 * G:3 * G + C]},
                        f"weighted control coordinates: residual surveyed − adjusted ({unit}), redundancy, w")
    chk = blk.check
    check = TableData({"point": list(chk.ids), f"dX{o}": chk.errors[:, 0], f"dY{o}": chk.errors[:, 1],
                       f"dZ{o}": chk.errors[:, 2]}, f"check points: adjusted − surveyed ({unit})")
    for t in (ro_tests, ro_points, points, residuals):       # per point / per observation: outputs = "summary" skips them
        t.detail = True
    return {"models": models, "ro_tests": ro_tests, "ro_points": ro_points,
            "transformations": transformations, "points": points, "residuals": residuals,
            "control": control, "check_points": check}


def report(result: IndependentModelResult, stats: dict, s: dict, block) -> str:
    blk = result.block
    unit = block.object_unit
    lines = [f"{s['models']} models, relative orientation by **{s['method']}** "
             f"({s['parameters']} parameters); block adjustment with one 7-parameter similarity per "
             f"model over {s['block']['points']} points "
             f"({'with' if result.options.projection_centres else 'without'} projection centres).", ""]
    rows = []
    for d, st in zip(s["per_model"], stats["models"]):
        gt = st["global"]
        verdict = "no redundancy" if gt.dof <= 0 else ("rejected" if gt.rejected else "accepted")
        rows.append([d["model"], d["points"], d["dof"], d["sigma0_hat"], f"{d['rcond']:.1e}", verdict,
                     ", ".join(lab.replace(f"model {d['model']} ", "") for lab in d["flagged"]) or "–"])
    lines += [markdown_table(["model", "points", "dof", "σ̂0", "rcond", "global test", "flagged (w-test)"],
                             rows, ".3f"), ""]
    if any(s["ro_removed"].values()):
        lines += ["Removed by iterated data snooping before forming the models: "
                  + "; ".join(f"{k}: {', '.join(lab.replace(k + ' ', '') for lab in v)}"
                              for k, v in s["ro_removed"].items() if v) + ".", ""]
    b = s["block"]
    gt = b["global_test"]
    lines += [f"Block: σ̂0 = **{b['sigma0_hat']:.3f}**, dof {b['dof']}, {b['iterations']} iteration(s); "
              f"global test {global_test_text(gt)}; "
              f"{b['n_flagged']} coordinate(s) flagged by data snooping"
              + (f": {', '.join(b['flagged'][:10])}{' …' if len(b['flagged']) > 10 else ''}" if b["flagged"] else "")
              + ".", ""]
    rm = s["check_rmse"]
    f = 100.0 if unit == "m" else 1.0
    u = "cm" if unit == "m" else unit
    if rm["n"]:
        lines += [f"Check points ({rm['n']}), adjusted − surveyed:", "",
                  markdown_table(["Sx", "Sy", "Sxy", "Sz"],
                                 [[rm["Sx"] * f, rm["Sy"] * f, rm["Sxy"] * f, rm["Sz"] * f]], ".4f")
                  + f"  ({u})", ""]
    else:
        lines += ["No check points in the models.", ""]
    return "\n".join(lines)


# --------------------------------------------------------------------------- recording


def robust_report(rob) -> str:
    if rob is None:
        return ""
    d = rob.downweighted
    out = ["", "", f"### Robust estimation ({rob.method}, c = {rob.c:g})", "",
           "IRLS on the model block linearised at its solution, residuals standardised by σ √r of the adjustment; "
           f"{rob.iterations} weighted adjustment(s), {'converged' if rob.converged else 'NOT converged'}; "
           f"{d.size} row(s) end with weight < {rob.threshold:g} (independent-models_robust.csv). Report only."]
    if d.size:
        out += ["", "| row | weight | u |", "|---|---|---|"]
        out += [f"| {rob.labels[i]} | {rob.weights[i]:.3g} | {rob.u[i]:+.2f} |" for i in d[:40]]
    return "\n".join(out)


def robust_table(rob) -> TableData:
    n = len(rob.weights)
    return TableData({"row": [str(x) for x in rob.labels], "weight": [round(float(x), 6) for x in rob.weights],
                      "u": [None if not np.isfinite(x) else round(float(x), 4) for x in rob.u],
                      "downweighted": [bool(x) for x in np.isin(np.arange(n), rob.downweighted)]},
                     f"robust estimation ({rob.method}, c = {rob.c:g}): every row's final IRLS weight and "
                     "standardised residual u")
