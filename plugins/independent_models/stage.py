"""Stage ``independent-models``: independent-model block triangulation (paper 001's comparison).

Numerics in the library :mod:`baarda.pipeline.imodels` (relative orientation, intersection,
similarity, the block adjustment, wired by ``independent_model_block``); statistics by
:mod:`baarda.pipeline.stats`.  This module holds the options, the run and the recording; the
summary, tables and report text are :mod:`.report`.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar, Literal

import numpy as np

from baarda.pipeline.api import (AdjustmentArtefact, Context, InputError, RobustConfig, Stage, StageResult,
                                 option, role_colors)
from baarda.pipeline.options import check_bounds
from baarda.pipeline.imodels import IndependentModelResult, independent_model_block
from baarda.pipeline.recording import log_series
from baarda.pipeline.stats import (SnoopingLevels, data_snooping, global_test, irls, iterated_data_snooping,
                                   weighted_refit)

from . import reliability as im_reliability
from . import report as im_report


@dataclasses.dataclass(frozen=True)
class IndependentModelsOptions(SnoopingLevels):
    """The stage's options; ``alpha0`` and ``beta0`` are the statistics library's
    :class:`~baarda.pipeline.stats.SnoopingLevels`, the ``robust`` table its
    :class:`~baarda.pipeline.stats.RobustConfig` (declared once for every stage)."""

    RENAMED: ClassVar[dict[str, str]] = {"critical": "critical_w", "pc_sigma_factor": "sigma_pc_scale"}
    MOVED: ClassVar[dict[str, str]] = {"robust": "robust.method", "robust_c": "robust.c"}
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
    robust: RobustConfig = option(
        RobustConfig(), "also estimate the model block robustly (IRLS on its linearisation at the solution, "
                        "docs/statistics.md) and report the down-weighted model coordinates (weight < 0.5); "
                        "report only")

    def __post_init__(self):
        check_bounds(self)


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
        from baarda.pipeline.imodels.relor import WEAK_RCOND

        for ro in result.relative:
            if ro.rcond < WEAK_RCOND:
                ctx.warn(f"{ro.name}: weak geometry (reciprocal condition {ro.rcond:.1e}): points near "
                         "a critical surface")
        stats = _statistics(result, o)
        stats["ro_removed"] = ids_removed
        ext = im_reliability.block_external(result.block, o.alpha0, o.beta0)
        summary = im_report.summary(result, stats, block)
        summary["external_reliability"] = im_reliability.summary(ext)
        tables = im_report.tables(result, stats, block)
        if ext is not None:
            tables["external"] = im_reliability.table(ext, block.object_unit)
        robust = _robust(result.block, o)
        if robust is not None:
            summary["robust"] = robust.summary()
            tables["robust"] = im_report.robust_table(robust)
        # the block's rows are model coordinates and control, not image observations: (-1, -1)
        obs_rows = np.full((result.block.snapshot.n, 2), -1, int)
        artefacts = {
            "independent-models": result,
            "adjustment": AdjustmentArtefact("independent-models", result.block.snapshot,
                                             result.block, obs_rows,
                                             linearise=lambda b=result.block: (b.linear_model(), b.snapshot.n)),
        }
        return StageResult(artefacts=artefacts, summary=summary,
                           report=im_report.report(result, stats, summary, block)
                           + "\n".join(im_reliability.report_lines(ext, block.object_unit))
                           + im_report.robust_report(robust), tables=tables,
                           data={"result": result, "stats": stats, "block": block, "bundle": inputs.get("bundle"),
                                 "arrow_scale": o.arrow_scale})

    def plots(self, result: StageResult, ctx: Context) -> dict:
        """Figures for report.html: check-point errors (beside those of the run's bundle, the
        ``bundle`` artefact it reads when there is one), y-parallaxes, model-point residuals
        (plugins/independent_models/figures.py)."""
        from .figures import independent_model_figures

        d = result.data
        name = next((f.stage for f in reversed(ctx.findings) if f.use == "bundle"), "bundle") if ctx else "bundle"
        bundle = (name, d["bundle"]) if d.get("bundle") is not None and d["bundle"].check.ids else None
        return independent_model_figures(d["result"], d["stats"], result.tables, d["block"].object_unit, bundle)

    def log(self, result: StageResult, rec, ctx: Context) -> None:
        log_independent_models(rec, result.data["result"], result.data["stats"],
                               arrow_scale=result.data["arrow_scale"])


# --------------------------------------------------------------------------- statistics

def _statistics(result: IndependentModelResult, o) -> dict:
    per_model = []
    for ro in result.relative:
        ds = data_snooping(ro.snapshot, o.alpha0, o.beta0, o.critical_w)
        gt = global_test(ro.snapshot, alpha=o.alpha_global, alpha0=o.alpha0, beta0=o.beta0)
        per_model.append({"snooping": ds, "global": gt})
    blk = result.block
    ds = data_snooping(blk.snapshot, o.alpha0, o.beta0, o.critical_w)
    gt = global_test(blk.snapshot, alpha=o.alpha_global, alpha0=o.alpha0, beta0=o.beta0)
    return {"models": per_model, "block": {"snooping": ds, "global": gt}}

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
    if len(chk.ids):
        idx = [int(np.flatnonzero(blk.point_ids == i)[0]) for i in chk.ids]
        kk = _auto_scale(chk.errors, extent, arrow_scale)
        rec.log(f"{root}/block/check_errors", rr.Arrows3D(
            origins=pts[idx] - chk.errors, vectors=chk.errors * kk, labels=list(chk.ids),
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
    r = o.robust
    if r.method == "none":
        return None
    refit, _ = weighted_refit(model_block, model_block.snapshot.active)
    return irls(refit, model_block.snapshot, r.method, r.c or None, standardise=r.standardise, max_iter=200)
