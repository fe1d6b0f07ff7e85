"""Stage ``pycolmap-crosscheck``: solve the bundle's problem again with pycolmap and compare.

Reads ``bundle`` (the :class:`baarda.pipeline.adjustment.BundleResult` of the bundle stage; without it the
stage adjusts ``block`` itself with the bundle's default settings) and writes ``crosscheck``
(a :class:`baarda.plugins.crosscheck.compare.CrossCheck`).  The stage fails with a
:class:`~baarda.plugins.crosscheck.compare.CrossCheckError` that lists the numbers when a difference of
an *equivalent* quantity exceeds its tolerance.  Formulas, conventions and limits:
``docs/crosscheck.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np

from baarda.pipeline.adjustment import BundleResult
from baarda.pipeline.api import Context, InputError, Stage, StageResult, TableData, option
from baarda.pipeline.report import markdown_table
from baarda.pipeline.units import length_suffix, object_unit_text

from .compare import CrossCheck, CrossCheckError, Tolerances, crosscheck, exceeded
from .pycolmap_ba import SolverSettings

__all__ = ["PycolmapCrossCheck", "CrossCheckOptions"]


@dataclass(frozen=True)
class CrossCheckOptions:
    RENAMED: ClassVar[dict[str, str]] = {"max_iterations": "max_iter"}
    start: Literal["initial", "perturbed"] = option(
        "initial", "pycolmap's start: 'initial' — the block's initial values (baarda's start); 'perturbed' — "
                   "baarda's solution with poses and free points disturbed by 'perturbation'")
    perturbation: float = option(0.01, "for start = 'perturbed': σ of the disturbance, as a fraction of the object "
                                       "size (positions, points) and in rad (ω φ κ)")
    tol_points: float = option(1e-6, "largest accepted difference of object points and projection centres, as a "
                                     "fraction of the object size (bounding-box diagonal)")
    tol_angles: float = option(1e-6, "largest accepted rotation difference of a photo, rad")
    tol_residuals_px: float = option(1e-4, "largest accepted difference of an image residual, pixels (the camera's "
                                           "pixel; its a-priori σ when it has no pixel pitch)")
    tol_cost: float = option(1e-8, "largest accepted relative difference of the final cost ½Σ(v/σ)²")
    tol_intrinsics: float = option(1e-4, "largest accepted difference of a refined camera parameter, in units of "
                                         "baarda's a-posteriori σ")
    tol_covariance: float = option(1e-3, "largest accepted relative difference of a standard deviation (poses, "
                                         "camera parameters) when the covariances are comparable")
    on_exceed: Literal["error", "warn"] = option("error", "a difference beyond its tolerance fails the stage "
                                                          "('error') or only warns")
    require_equivalent: bool = option(False, "fail when baarda's problem cannot be reproduced exactly in pycolmap "
                                             "(AP model, weights, datum)")
    covariance: bool = option(True, "estimate pycolmap's covariance of poses and camera parameters and compare")
    max_iter: int = option(200, "pycolmap (Ceres) iteration limit")
    num_threads: int = option(-1, "pycolmap (Ceres) threads; -1 = all cores")
    arrow_scale: float = option(0.0, "scale of the difference arrows in the recording; 0 = automatic (the largest "
                                     "arrow is 5 % of the object size)")

    def __post_init__(self):
        for k in ("tol_points", "tol_angles", "tol_residuals_px", "tol_cost", "tol_intrinsics", "tol_covariance",
                  "perturbation", "arrow_scale"):
            if not getattr(self, k) >= 0:
                raise ValueError(f"{k} must be >= 0")
        if self.max_iter < 1:
            raise ValueError("max_iter must be >= 1")

    def tolerances(self) -> Tolerances:
        return Tolerances(points=self.tol_points, angles=self.tol_angles, residuals_px=self.tol_residuals_px,
                          cost=self.tol_cost, intrinsics=self.tol_intrinsics, covariance=self.tol_covariance)


_LABELS = {"points": "object points", "centres": "projection centres", "angles": "rotations",
           "residuals": "image residuals", "cost": "final cost ½Σ(v/σ)²", "intrinsics": "camera parameters",
           "covariance_poses": "σ of poses", "covariance_intrinsics": "σ of camera parameters",
           "rig_sensors": "rig sensor poses"}


def _tolerance_of(name: str, tol: Tolerances) -> float:
    return {"points": tol.points, "centres": tol.points, "angles": tol.angles, "residuals": tol.residuals_px,
            "cost": tol.cost, "intrinsics": tol.intrinsics, "covariance_poses": tol.covariance,
            "covariance_intrinsics": tol.covariance, "rig_sensors": tol.intrinsics}[name]


def _value_for_tolerance(name: str, v: dict) -> float:
    return v["relative"] if name in ("points", "centres") else v["max"]


class PycolmapCrossCheck(Stage):
    """Re-solve the adjusted block with pycolmap's bundle adjustment and compare both solutions."""

    summary = "cross-check the bundle against pycolmap's bundle adjustment (same model, gauge and start)"
    reads = ("block", "bundle?")
    writes = ("crosscheck",)
    Options = CrossCheckOptions

    def run(self, inputs, options: CrossCheckOptions, ctx: Context) -> StageResult:
        result = inputs.get("bundle")
        if result is None:
            block = inputs.get("block")
            if block is None:
                raise InputError("pycolmap-crosscheck needs the 'bundle' artefact (run the bundle stage first) or a "
                                 "'block'", path=ctx.project_file)
            from baarda.pipeline.adjustment import BundleSettings, adjust

            ctx.warn("no 'bundle' artefact: the block was adjusted here with the bundle's default settings")
            result = adjust(block, BundleSettings())
        if not isinstance(result, BundleResult):
            raise InputError(f"the 'bundle' artefact is a {type(result).__name__}, not a bundle result",
                             path=ctx.project_file, field="bundle")
        solver = SolverSettings(max_iter=options.max_iter, num_threads=options.num_threads,
                                covariance=options.covariance)
        ctx.progress.message("solving with pycolmap …")
        cc = crosscheck(result, start=options.start, rng=ctx.rng, perturbation=options.perturbation, solver=solver)
        tol = options.tolerances()
        if options.require_equivalent and not cc.plan.exact:
            raise CrossCheckError("pycolmap cannot reproduce this adjustment exactly (option require_equivalent): "
                                  + "; ".join(cc.plan.notes))
        failures = exceeded(cc, tol)
        if cc.pycolmap["termination"] != "CONVERGENCE":
            ctx.warn(f"pycolmap did not converge: {cc.pycolmap['termination']} ({cc.pycolmap['message']})")
        if failures:
            text = ("baarda and pycolmap differ beyond the tolerances — " + "; ".join(failures)
                    + f" (pycolmap: {cc.pycolmap['termination']} after {cc.pycolmap['iterations']} iterations; "
                    "see docs/crosscheck.md)")
            if options.on_exceed == "error":
                raise CrossCheckError(text, failures)
            for f in failures:
                ctx.warn(f"cross-check: {f}")
        summary = _summary(cc, tol, failures)
        report = _report(cc, tol, failures)
        return StageResult(artefacts={"crosscheck": cc}, summary=summary, report=report, tables=_tables(cc, result),
                           data={"cc": cc, "result": result, "arrow_scale": options.arrow_scale})

    def plots(self, result: StageResult, ctx: Context) -> dict:
        """Figures for report.html: differences in σ, the final costs, the residual distributions."""
        from .figures import crosscheck_figures

        return crosscheck_figures(result.data["cc"], result.data["result"], result.tables)

    def log(self, result: StageResult, rec, ctx: Context) -> None:
        log_crosscheck(rec, result.data["cc"], result.data["result"], result.data["arrow_scale"], result.report)


CAMERAS_MOST = 20
"""Cameras listed in the summary (``n_cameras`` counts them all; every parameter is in the cameras table)."""


def _summary(cc: CrossCheck, tol: Tolerances, failures: list) -> dict:
    q = {k: {a: b for a, b in v.items()} for k, v in cc.quantities.items()}
    return {"headline": _headline(cc, failures), "equivalent": cc.plan.exact, "covariance_comparable": cc.plan.covariance_comparable,
            "passed": not failures, "failures": failures, "start": cc.start, "object_size": cc.object_size,
            "quantities": q, "pycolmap": dict(cc.pycolmap),
            "cameras": [{"id": p.id, "mode": p.mode, "colmap_model": p.colmap_model} for p in cc.plan.cameras[:CAMERAS_MOST]],
            "n_cameras": len(cc.plan.cameras),
            "refine": cc.plan.refine, "notes": cc.notes}


def _headline(cc: CrossCheck, failures: list) -> str:
    """One line for the run's comparison: verdict, the largest point and residual differences."""
    q = cc.quantities
    diffs = ", ".join(f"{_LABELS[k]} max {q[k]['max']:.2g} {q[k]['unit']}" for k in ("points", "residuals")
                      if k in q and q[k]["n"])
    if failures:
        verdict = f"baarda and pycolmap differ beyond the tolerances ({len(failures)} quantit{'y' if len(failures) == 1 else 'ies'})"
    elif cc.plan.exact:
        verdict = "baarda and pycolmap agree within the tolerances"
    else:
        verdict = "not an equivalent problem for pycolmap (see notes); differences only"
    return f"{verdict}: {diffs}" if diffs else verdict


def _report(cc: CrossCheck, tol: Tolerances, failures: list) -> str:
    rows = []
    for name, v in cc.quantities.items():
        if not v["n"]:
            continue
        limit = _tolerance_of(name, tol)
        value = _value_for_tolerance(name, v)
        status = ("exceeded" if v["exact"] and np.isfinite(value) and value > limit
                  else ("ok" if v["exact"] else "not equivalent"))
        unit = "of object size" if name in ("points", "centres") else v["unit"]
        rows.append([_LABELS[name], v["n"], f"{v['max']:.3g} {v['unit']}", f"{v['rms']:.3g} {v['unit']}",
                     f"{limit:g} {unit}", status])
    py = cc.pycolmap
    head = (f"pycolmap's bundle adjustment ({py['linear_solver']}, start: {cc.start}) converged with "
            f"{py['termination']} after {py['iterations']} iterations in {py['seconds']:.3f} s; final cost "
            f"½Σ(v/σ)² = {cc.quantities['cost']['pycolmap']:.6g} (baarda {cc.baarda_cost:.6g}).  "
            f"Object size {cc.object_size:.4g}.  The problems are "
            + ("**equivalent**: every difference below is rounding and convergence."
               if cc.plan.exact else "**not equivalent** (notes below): differences are reported only."))
    cams = markdown_table(["camera", "COLMAP model", "mode"],
                          [[p.id, p.colmap_model, p.mode] for p in cc.plan.cameras])
    parts = [head, "", markdown_table(["quantity", "n", "max", "RMS", "tolerance", "status"], rows), "", cams]
    if cc.cameras:
        parts += ["", markdown_table(["camera", "parameter", "baarda", "pycolmap", "difference / σ"],
                                     [[r["camera"], r["parameter"], f"{r['baarda']:.10g}", f"{r['pycolmap']:.10g}",
                                       f"{r['difference_sigma']:.2g}"] for r in cc.cameras])]
    if failures:
        parts += ["", "**Exceeded:** " + "; ".join(failures)]
    if cc.notes:
        parts += ["", "Notes:", ""] + [f"- {n}" for n in cc.notes]
    return "\n".join(parts)


def _tables(cc: CrossCheck, result) -> dict:
    st, sol, plan = result.state, cc.solution, cc.plan
    pts = result.block_in.points
    j = np.flatnonzero(plan.point_variable)
    d = sol.XYZ[j] - st.XYZ[j]
    ou = object_unit_text(result.block_in)
    o = length_suffix(ou)
    points = TableData({"id": pts.ids[j].tolist(), f"X_baarda{o}": st.XYZ[j, 0], f"Y_baarda{o}": st.XYZ[j, 1],
                        f"Z_baarda{o}": st.XYZ[j, 2], f"dX{o}": d[:, 0], f"dY{o}": d[:, 1], f"dZ{o}": d[:, 2]},
                       f"object points: baarda's adjusted coordinates and pycolmap − baarda ({ou})", detail=True)
    ph = result.block_in.photos
    k = np.flatnonzero(plan.photo_variable)
    dX = sol.X0[k] - st.X0[k]
    dA = (sol.opk[k] - st.opk[k] + np.pi) % (2 * np.pi) - np.pi
    photos = TableData({"id": ph.ids[k].tolist(), f"dX0{o}": dX[:, 0], f"dY0{o}": dX[:, 1], f"dZ0{o}": dX[:, 2],
                        "domega_rad": dA[:, 0], "dphi_rad": dA[:, 1], "dkappa_rad": dA[:, 2]},
                       f"exterior orientation: pycolmap − baarda (centres in {ou}, angles in rad)")
    q = TableData({"quantity": list(cc.quantities), "n": [v["n"] for v in cc.quantities.values()],
                   "max": [v["max"] for v in cc.quantities.values()],
                   "rms": [v["rms"] for v in cc.quantities.values()],
                   "unit": [v["unit"] for v in cc.quantities.values()],
                   "equivalent": [v["exact"] for v in cc.quantities.values()]},
                  "agreement per quantity")
    out = {"quantities": q, "points": points, "photos": photos}
    if cc.cameras:
        keys = ["camera", "parameter", "baarda", "pycolmap", "difference", "sigma_baarda", "unit", "difference_sigma"]
        out["cameras"] = TableData({key: [r.get(key) for r in cc.cameras] for key in keys},
                                   "refined camera parameters in the row's `unit` (c, xp, yp mm, K1 mm⁻² …); the "
                                   "difference also in σ of baarda's value", units={"difference_sigma": ""})
    return out


def log_crosscheck(rec, cc: CrossCheck, result, arrow_scale: float = 0.0, report: str = "") -> None:
    """Both solutions and their differences under ``crosscheck/…`` (called from ``log`` only)."""
    import rerun as rr

    from baarda.pipeline.api import log_text, log_values

    st, sol, plan = result.state, cc.solution, cc.plan
    used = plan.point_variable | plan.point_constant
    Pb, Pp = st.XYZ[used], sol.XYZ[used]
    okp = np.isfinite(Pp).all(axis=1) & np.isfinite(Pb).all(axis=1)
    ph = plan.photo_variable | plan.photo_constant
    Cb, Cp = st.X0[ph], sol.X0[ph]
    okc = np.isfinite(Cp).all(axis=1) & np.isfinite(Cb).all(axis=1)
    dmax = max(float(np.max(np.linalg.norm(Pp[okp] - Pb[okp], axis=1), initial=0.0)),
               float(np.max(np.linalg.norm(Cp[okc] - Cb[okc], axis=1), initial=0.0)))
    scale = arrow_scale if arrow_scale > 0 else (0.05 * cc.object_size / dmax if dmax > 0 else 1.0)
    small = rr.Radius.ui_points(2.0)
    rec.log("crosscheck/baarda/points", rr.Points3D(Pb[okp], colors=[40, 120, 230], radii=small), static=True)
    rec.log("crosscheck/pycolmap/points", rr.Points3D(Pp[okp], colors=[230, 120, 40], radii=small), static=True)
    rec.log("crosscheck/baarda/centres", rr.Points3D(Cb[okc], colors=[40, 120, 230], radii=rr.Radius.ui_points(5.0)),
            static=True)
    rec.log("crosscheck/pycolmap/centres", rr.Points3D(Cp[okc], colors=[230, 120, 40],
                                                       radii=rr.Radius.ui_points(5.0)), static=True)
    rec.log("crosscheck/differences/points", rr.Arrows3D(origins=Pb[okp], vectors=(Pp[okp] - Pb[okp]) * scale,
                                                          colors=[220, 30, 30]), static=True)
    rec.log("crosscheck/differences/centres", rr.Arrows3D(origins=Cb[okc], vectors=(Cp[okc] - Cb[okc]) * scale,
                                                           colors=[220, 30, 200]), static=True)
    log_values(rec, "crosscheck/differences/scale", {"arrow_scale": scale, "max_difference": dmax})
    log_values(rec, "crosscheck/agreement", {k: {"max": v["max"], "rms": v["rms"]} for k, v in cc.quantities.items()})
    if report:
        log_text(rec, "crosscheck/report",
                 f"Difference arrows are drawn × {scale:.4g} (pycolmap − baarda).\n\n{report}")
