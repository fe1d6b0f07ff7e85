"""Stage ``independent-models``: independent-model block triangulation (paper 001's comparison).

Numerics in :mod:`.relor`, :mod:`.intersection`, :mod:`.similarity`, :mod:`.block`, wired by
:func:`.workflow.independent_model_block`; statistics by :mod:`baarda.pipeline.stats`.  This module only
adds options, tables, the report and the recording.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar, Literal

import numpy as np

from baarda.pipeline.errors import InputError
from baarda.pipeline.options import option
from baarda.pipeline.report import markdown_table
from baarda.pipeline.recording import log_series, role_colors
from baarda.pipeline.stage import Context, Stage, StageResult, TableData
from baarda.pipeline.stats import data_snooping, global_test, iterated_data_snooping
from baarda.pipeline.contracts import AdjustmentArtefact
from . import reliability as im_reliability

from .workflow import IndependentModelResult, independent_model_block



@dataclasses.dataclass(frozen=True)
class IndependentModelsOptions:
    RENAMED: ClassVar[dict[str, str]] = {"critical": "critical_w", "pc_sigma_factor": "sigma_pc_scale"}
    method: Literal["coplanarity", "collinearity"] = option(
        "coplanarity", "relative orientation: coplanarity condition (Gauss–Helmert) or collinearity "
                       "with the model points as unknowns (same optimum)")
    parameters: Literal["dependent", "independent"] = option(
        "dependent", "relative-orientation parameters: 'dependent' (left photo fixed; by, bz, ω2, φ2, κ2) "
                     "or 'independent' (base along x; φ1, κ1, φ2, ω2, κ2)")
    initial: Literal["auto", "zero", "essential"] = option(
        "auto", "initial values of the relative orientation: zero angles (normal case), the 8-point "
                "essential matrix, or both and keep the better ('auto')")
    pairing: Literal["auto", "pairs", "consecutive"] = option(
        "auto", "models from the block's stereo pairs ('pairs'), from neighbouring photos "
                "('consecutive'), or pairs when the block has them ('auto')")
    strips: list[list[str]] = option(
        [], "with 'consecutive': photo ids of each strip in order, e.g. [[\"11\", \"12\"], [\"21\", \"22\"]]; "
            "empty: photo-table order, neighbours with ≥ 5 common points")
    model_weights: Literal["propagated", "intersection", "equal"] = option(
        "propagated", "weights of the model coordinates: image errors propagated through the relative "
                      "orientation and the intersection ('propagated'), each point's covariance from the "
                      "space intersection alone ('intersection'), or one diagonal covariance per model "
                      "(RMS of those, 'equal')")
    projection_centres: bool = option(True, "include the projection centres as model points (tie "
                                            "neighbouring models of a strip)")
    sigma_pc_scale: float = option(1.0, "projection centres get the median model-point covariance "
                                         "times this factor squared")
    sigma0: float = option(1.0, "a-priori σ0 of the image covariances")
    alpha0: float = option(0.001, "significance level of the w-test (two-sided, per observation)")
    beta0: float = option(0.80, "power for the MDBs and the B-method")
    critical_w: float | None = option(None, "critical value of the w-test (default Φ⁻¹(1 − α0/2) = 3.29 "
                                          "for 0.1 %; 4.13 for Baarda's B-method)")
    ro_snooping: Literal["report", "iterated"] = option(
        "report", "y-parallax snooping per model: only report, or remove rejected points by iterated "
                  "data snooping before forming the model")
    min_rcond: float = option(1e-10, "smallest reciprocal condition of a relative orientation's "
                                     "scaled normal matrix; below it the pair is reported as critical")
    skip_failed_models: bool = option(False, "skip a pair whose relative orientation fails (with a note) "
                                             "instead of stopping")
    arrow_scale: float | None = option(None, "scale of residual arrows in the recording (default: the "
                                             "largest arrow is 5 % of the block's extent)")
    robust: Literal["none", "huber", "danish", "l1"] = option(
        "none", "also estimate the model block robustly (IRLS on its linearisation at the solution, "
                "docs/statistics.md) and report the down-weighted model coordinates (weight < 0.5); report only")
    robust_c: float = option(0.0, "robust estimation: tuning constant in standardised residuals; 0 = Huber 1.5, "
                                  "Danish 2.5 (L1: the floor of |u|, 0.001)", ge=0.0)

    def __post_init__(self):
        if not (0.0 < self.alpha0 < 1.0 and 0.0 < self.beta0 < 1.0):
            raise ValueError("alpha0 and beta0 must lie between 0 and 1")
        if not (self.sigma0 > 0 and self.sigma_pc_scale > 0):
            raise ValueError("sigma0 and sigma_pc_scale must be positive")


class IndependentModels(Stage):
    summary = ("Independent-model block triangulation: relative orientation per pair, model "
               "coordinates, 7-parameter block adjustment, data snooping, check-point RMSE")
    reads = ("block", "bundle?")
    writes = ("independent-models", "adjustment")
    Options = IndependentModelsOptions

    def run(self, inputs, options: IndependentModelsOptions, ctx: Context) -> StageResult:
        block = inputs["block"]
        o = options
        ids_removed: dict[str, list[str]] = {}

        def screen(ro):
            res = iterated_data_snooping(ro, ro.snapshot, o.alpha0, o.beta0, o.critical_w)
            ids_removed[ro.name] = res.removed_labels
            return ro.rerun(res.active) if res.removed else ro

        try:
            result = independent_model_block(
                block, method=o.method, parameters=o.parameters, pairing=o.pairing,
                strips=[list(s) for s in o.strips], model_weights=o.model_weights,
                projection_centres=o.projection_centres, sigma_pc_scale=o.sigma_pc_scale,
                initial=o.initial, sigma0=o.sigma0, min_rcond=o.min_rcond,
                screen_model=screen if o.ro_snooping == "iterated" else None,
                skip_failed_models=o.skip_failed_models, progress=ctx.progress.track)
        except InputError as e:
            raise InputError(e.message, e.path or ctx.project_file, e.line, e.field) from None
        for w in result.warnings + result.notes:
            ctx.warn(w)
        from .relor import WEAK_RCOND

        for ro in result.relative:
            if ro.rcond < WEAK_RCOND:
                ctx.warn(f"{ro.name}: weak geometry (reciprocal condition {ro.rcond:.1e}): points near "
                         "a critical surface")
        stats = _statistics(result, o)
        stats["ro_removed"] = ids_removed
        ext = im_reliability.block_external(result.block, o.alpha0, o.beta0)
        summary = _summary(result, stats, block)
        summary["external_reliability"] = im_reliability.summary(ext)
        tables = _tables(result, stats, block)
        if ext is not None:
            tables["external"] = im_reliability.table(ext)
        robust = _robust(result.block, o)
        if robust is not None:
            summary["robust"] = robust.summary()
            tables["robust"] = _robust_table(robust)
        # the block's rows are model coordinates and control, not image observations: (-1, -1)
        obs_rows = np.full((result.block.snapshot.n, 2), -1, int)
        artefacts = {
            "independent-models": result,
            "adjustment": AdjustmentArtefact("independent-models", result.block.snapshot,
                                             result.block, obs_rows,
                                             linearise=lambda b=result.block: (b.linear_model(), b.snapshot.n)),
        }
        return StageResult(artefacts=artefacts, summary=summary,
                           report=_report(result, stats, summary, block)
                           + "\n".join(im_reliability.report_lines(ext, block.object_unit))
                           + _robust_report(robust), tables=tables,
                           data={"result": result, "stats": stats, "block": block, "bundle": inputs.get("bundle"),
                                 "arrow_scale": o.arrow_scale})

    def plots(self, result: StageResult, ctx: Context) -> dict:
        """Figures for report.html: check-point errors (beside those of the run's bundle, the
        ``bundle`` artefact it reads when there is one), y-parallaxes, model-point residuals
        (plugins/independent_models/figures.py)."""
        from .figures import independent_model_figures

        d = result.data
        name = next((f.stage for f in reversed(ctx.findings) if f.use == "bundle"), "bundle") if ctx else "bundle"
        bundle = (name, d["bundle"]) if d.get("bundle") is not None and d["bundle"].check.get("ids") else None
        return independent_model_figures(d["result"], d["stats"], result.tables, d["block"].object_unit, bundle)

    def log(self, result: StageResult, rec, ctx: Context) -> None:
        log_independent_models(rec, result.data["result"], result.data["stats"],
                               arrow_scale=result.data["arrow_scale"])


# --------------------------------------------------------------------------- statistics

def _statistics(result: IndependentModelResult, o) -> dict:
    per_model = []
    for ro in result.relative:
        ds = data_snooping(ro.snapshot, o.alpha0, o.beta0, o.critical_w)
        gt = global_test(ro.snapshot, alpha0=o.alpha0, beta0=o.beta0)
        per_model.append({"snooping": ds, "global": gt})
    blk = result.block
    ds = data_snooping(blk.snapshot, o.alpha0, o.beta0, o.critical_w)
    gt = global_test(blk.snapshot, alpha0=o.alpha0, beta0=o.beta0)
    return {"models": per_model, "block": {"snooping": ds, "global": gt}}


def _deg(a):
    return float(np.degrees(a))


def _summary(result: IndependentModelResult, stats: dict, block) -> dict:
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
    rm = blk.check["rmse"]
    unit = block.object_unit
    check_points = {"n": int(rm["n"]), **{k: float(rm[k]) for k in ("Sx", "Sy", "Sxy", "Sz")}, "unit": unit}
    f, u = (100.0, "cm") if unit == "m" else (1.0, unit)
    headline = (f"{len(result.relative)} models; block σ̂0 = {blk.sigma0_hat:.3g} (dof {blk.dof}, global test "
                f"{'rejected' if gt.rejected else 'accepted'}), {int(ds.flagged.sum())} coordinate(s) flagged"
                + (f"; check points ({rm['n']}): Sxy {rm['Sxy'] * f:.4g} {u}, Sz {rm['Sz'] * f:.4g} {u}"
                   if rm["n"] else "; no check points"))
    return {
        "headline": headline, "check_points": check_points,
        "models": len(result.relative), "method": result.options["method"],
        "parameters": result.options["parameters"],
        "block": {"sigma0_hat": blk.sigma0_hat, "dof": blk.dof, "iterations": blk.iterations,
                  "global_test": gt.summary(), "n_flagged": int(ds.flagged.sum()),
                  "flagged": ds.flagged_labels, "points": int(blk.in_adjustment.sum())},
        "check_rmse": dict(blk.check["rmse"]), "object_unit": block.object_unit,
        "per_model": models, "ro_removed": stats.get("ro_removed", {}),
    }


# --------------------------------------------------------------------------- tables

def _tables(result: IndependentModelResult, stats: dict, block) -> dict:
    blk = result.block
    unit = block.object_unit
    # models and their relative orientation
    rows = {k: [] for k in ("model", "left", "right", "method", "parameters", "points", "dof",
                            "sigma0_hat", "iterations", "initial", "rcond", "bx", "p1", "p2", "p3", "p4",
                            "p5", "names", "global_T", "global_rejected", "max_abs_w", "flagged")}
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
        rows["bx"].append(ro.bx)
        for k, (nm, v) in enumerate(zip(ro.param_names, ro.p)):
            rows[f"p{k + 1}"].append(_deg(v) if nm[:-1] in ("omega", "phi", "kappa") else float(v))
        rows["names"].append(" ".join(f"{n}{'[deg]' if n[:-1] in ('omega', 'phi', 'kappa') else ''}"
                                      for n in ro.param_names))
        rows["global_T"].append(gt.T)
        rows["global_rejected"].append(bool(gt.rejected))
        ok = np.isfinite(ds.w)
        rows["max_abs_w"].append(float(np.max(np.abs(ds.w[ok]))) if ok.any() else float("nan"))
        rows["flagged"].append(" ".join(ds.flagged_labels))
    models = TableData(rows, "per model: relative orientation (p1…p5 named in 'names', angles in degrees), "
                             "σ̂0, global test and y-parallax snooping")
    # statistics rows of each relative orientation
    t = {k: [] for k in ("model", "row", "active", "v_um", "r", "w", "nabla_um", "mdb_um", "flagged")}
    pts = {k: [] for k in ("model", "point", "used", "vx_left_um", "vy_left_um", "vx_right_um",
                           "vy_right_um", "py_um", "x_model", "y_model", "z_model")}
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
        for k, c in enumerate(("x_model", "y_model", "z_model")):
            pts[c] += ro.XYZ[:, k].tolist()
    ro_tests = TableData(t, "relative orientation: statistics rows (y-parallax per point for coplanarity, "
                            "image coordinates for collinearity), µm; w-test, estimated error, MDB")
    ro_points = TableData(pts, "relative orientation: image residuals (observed − computed, µm), residual "
                               "y-parallax, model coordinates")
    # transformations
    sd = np.sqrt(np.einsum("mii->mi", blk.Qparams)) * (blk.sigma0_hat if np.isfinite(blk.sigma0_hat) else 1.0)
    tr = {"model": blk.model_ids.tolist(), "scale": blk.params[:, 0],
          "omega_deg": np.degrees(blk.params[:, 1]), "phi_deg": np.degrees(blk.params[:, 2]),
          "kappa_deg": np.degrees(blk.params[:, 3]), "tx": blk.params[:, 4], "ty": blk.params[:, 5],
          "tz": blk.params[:, 6], "s_scale": sd[:, 0], "s_omega_deg": np.degrees(sd[:, 1]),
          "s_phi_deg": np.degrees(sd[:, 2]), "s_kappa_deg": np.degrees(sd[:, 3]), "s_tx": sd[:, 4],
          "s_ty": sd[:, 5], "s_tz": sd[:, 6]}
    transformations = TableData(tr, f"7-parameter similarity of each model into the object system "
                                    f"(X = s Mᵀ x + T, {unit}); standard deviations a posteriori")
    s0 = blk.sigma0_hat if np.isfinite(blk.sigma0_hat) else 1.0
    sx = np.sqrt(np.maximum(np.einsum("pii->pi", blk.cov_XYZ), 0)) * s0 / result.options["sigma0"]
    points = TableData({"point": blk.point_ids.tolist(), "role": blk.role.tolist(),
                        "models": blk.n_models, "in_adjustment": blk.in_adjustment,
                        "X": blk.XYZ[:, 0], "Y": blk.XYZ[:, 1], "Z": blk.XYZ[:, 2],
                        "sX": sx[:, 0], "sY": sx[:, 1], "sZ": sx[:, 2],
                        **im_reliability.point_columns(blk.cov_XYZ, (s0 / result.options["sigma0"]) ** 2)},
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
        res[f"v{c}"] = blk.v_object[:, k]
    for k, c in enumerate("xyz"):
        res[f"v{c}_model"] = blk.v_model[:, k]
    for k, c in enumerate("xyz"):
        res[f"r_{c}"] = r[:, k]
    for k, c in enumerate("xyz"):
        res[f"w_{c}"] = w[:, k]
    residuals = TableData(res, f"model-point residuals, observed − computed: in the object frame ({unit}) "
                               "and in model units; redundancy and w-test per coordinate")
    C = blk.control_point.size
    control = TableData({"point": blk.point_ids[blk.control_point].tolist(),
                         "axis": ["XYZ"[a] for a in blk.control_axis],
                         "v": blk.v_control, "r": s.r[3 * G:3 * G + C], "w": ds.w[3 * G:3 * G + C]},
                        f"weighted control coordinates: residual surveyed − adjusted ({unit}), redundancy, w")
    chk = blk.check
    check = TableData({"point": chk["ids"].tolist(), "dX": chk["dXYZ"][:, 0], "dY": chk["dXYZ"][:, 1],
                       "dZ": chk["dXYZ"][:, 2]}, f"check points: adjusted − surveyed ({unit})")
    return {"models": models, "ro_tests": ro_tests, "ro_points": ro_points,
            "transformations": transformations, "points": points, "residuals": residuals,
            "control": control, "check_points": check}


def _report(result: IndependentModelResult, stats: dict, s: dict, block) -> str:
    blk = result.block
    unit = block.object_unit
    lines = [f"{s['models']} models, relative orientation by **{s['method']}** "
             f"({s['parameters']} parameters); block adjustment with one 7-parameter similarity per "
             f"model over {s['block']['points']} points "
             f"({'with' if result.options['projection_centres'] else 'without'} projection centres).", ""]
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
              f"global test T = {gt['T']:.3f} vs {gt['critical']:.3f} → "
              f"{'rejected' if gt['rejected'] else 'accepted'}; "
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

def _auto_scale(vectors: np.ndarray, extent: float, arrow_scale) -> float:
    if arrow_scale is not None:
        return float(arrow_scale)
    m = np.nanmax(np.linalg.norm(vectors, axis=1)) if vectors.size else 0.0
    return float(0.05 * extent / m) if m > 0 else 1.0


def log_independent_models(rec, result: IndependentModelResult, stats: dict, root: str = "independent-models",
                           arrow_scale: float | None = None) -> None:
    """Each model in its own frame, the models in the block, tie discrepancies, control residuals."""
    import rerun as rr

    blk = result.block
    lines = ["Arrows are residuals scaled for display: observed − computed, drawn from the computed "
             "to the observed position."]
    # models in their own frames
    for (mid, left, right), ro, mc in zip(result.pairs, result.relative, result.models):
        base = f"{root}/models/{mid}"
        ok = np.all(np.isfinite(ro.XYZ), axis=1)
        ext = float(np.ptp(ro.XYZ[ok], axis=0).max()) if ok.sum() > 1 else abs(ro.bx)
        col = np.where(ro.active[ok, None], [[70, 130, 220]], [[220, 60, 60]]).astype(np.uint8)
        rec.log(f"{base}/points", rr.Points3D(ro.XYZ[ok], labels=ro.point_ids[ok].tolist(), colors=col,
                                              radii=0.005 * ext), static=True)
        rec.log(f"{base}/projection_centres", rr.Points3D(np.vstack([ro.X0_left, ro.X0_right]),
                                                          labels=[left, right], colors=[[30, 30, 30]]),
                static=True)
        rec.log(f"{base}/base", rr.LineStrips3D([np.vstack([ro.X0_left, ro.X0_right])]), static=True)
        vec = np.column_stack([np.zeros(ok.sum()), ro.py[ok], np.zeros(ok.sum())])
        k = _auto_scale(vec, ext, None)
        rec.log(f"{base}/y_parallax", rr.Arrows3D(origins=ro.XYZ[ok], vectors=vec * k,
                                                  labels=[f"{1e3 * p:.1f} µm" for p in ro.py[ok]]), static=True)
        rec.log(f"{base}/relative_orientation", rr.AnyValues(
            **{nm: [float(v)] for nm, v in zip(ro.param_names, ro.p)}, sigma0_hat=[float(ro.sigma0_hat)],
            dof=[int(ro.dof)]), static=True)
        lines.append(f"- {base}/y_parallax: residual y-parallax ×{k:.3g} along the model y-axis")
    # the block
    pts = blk.XYZ
    ok = np.all(np.isfinite(pts), axis=1)
    colors = role_colors(blk.role)
    rec.log(f"{root}/block/points", rr.Points3D(pts[ok], colors=colors[ok], labels=blk.point_ids[ok].tolist(),
                                                radii=0.006), static=True)
    extent = float(np.ptp(pts[ok], axis=0).max()) if ok.sum() > 1 else 1.0
    for mi, mc in enumerate(result.models):
        Xm = blk.transform(mi, mc.xyz)
        rec.log(f"{root}/block/models/{mc.id}", rr.Points3D(Xm, labels=mc.point_ids.tolist(), radii=0.003),
                static=True)
    # tie discrepancies: computed (adjusted point) → observed (model point transformed)
    origins = pts[blk.obs_point]
    vec = np.nan_to_num(blk.v_object)
    k = _auto_scale(vec, extent, arrow_scale)
    tie = blk.n_models[blk.obs_point] > 1
    rec.log(f"{root}/block/tie_discrepancies", rr.Arrows3D(
        origins=origins[tie], vectors=vec[tie] * k,
        labels=[f"{blk.model_ids[m]}:{blk.point_ids[p]}" for m, p in zip(blk.obs_model[tie], blk.obs_point[tie])]),
        static=True)
    lines.append(f"- {root}/block/tie_discrepancies: model point (transformed) − adjusted point ×{k:.3g}")
    # control residuals: computed (adjusted) → observed (surveyed)
    if blk.control_point.size:
        cp = blk.control_point
        v = np.zeros((cp.size, 3))
        v[np.arange(cp.size), blk.control_axis] = np.nan_to_num(blk.v_control)
        kc = _auto_scale(v, extent, arrow_scale)
        rec.log(f"{root}/block/control_residuals", rr.Arrows3D(
            origins=pts[cp], vectors=v * kc,
            labels=[f"{blk.point_ids[p]} {'XYZ'[a]}" for p, a in zip(cp, blk.control_axis)]), static=True)
        lines.append(f"- {root}/block/control_residuals: surveyed − adjusted ×{kc:.3g}")
    chk = blk.check
    if len(chk["ids"]):
        idx = [int(np.flatnonzero(blk.point_ids == i)[0]) for i in chk["ids"]]
        kk = _auto_scale(chk["dXYZ"], extent, arrow_scale)
        rec.log(f"{root}/block/check_errors", rr.Arrows3D(
            origins=pts[idx] - chk["dXYZ"], vectors=chk["dXYZ"] * kk, labels=chk["ids"].tolist(),
            colors=[[40, 170, 60]]), static=True)
        lines.append(f"- {root}/block/check_errors: adjusted − surveyed (from the surveyed point) ×{kk:.3g}")
    # convergence of the block adjustment: σ̂0 per iteration through the one series writer (a single
    # iteration, or one that never changed, is a static value under …/block/constants)
    dof = max(blk.dof, 1)
    log_series(rec, f"{root}/block", np.arange(len(blk.history)),
               {"sigma0_hat": [float(np.sqrt(vtpv / dof)) for vtpv in blk.history]})
    lines.append(f"- {root}/block/sigma0_hat: σ̂0 per iteration of the block adjustment "
                 f"(a static value in {root}/block/constants when it did not change)")
    rec.log(f"{root}/legend", rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN), static=True)


def _robust(model_block, o):
    """IRLS on the model block's linearisation at its solution (report only)."""
    if o.robust == "none":
        return None
    from baarda.pipeline.stats import irls, weighted_refit

    refit, _ = weighted_refit(model_block, model_block.snapshot.active)
    return irls(refit, model_block.snapshot, o.robust, o.robust_c or None, max_iter=200)


def _robust_report(rob) -> str:
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


def _robust_table(rob) -> TableData:
    n = len(rob.weights)
    return TableData({"row": [str(x) for x in rob.labels], "weight": [round(float(x), 6) for x in rob.weights],
                      "u": [None if not np.isfinite(x) else round(float(x), 4) for x in rob.u],
                      "downweighted": [bool(x) for x in np.isin(np.arange(n), rob.downweighted)]},
                     f"robust estimation ({rob.method}, c = {rob.c:g}): every row's final IRLS weight and "
                     "standardised residual u")
