"""Stage ``bundle``: self-calibrating bundle block adjustment (see docs/bundle.md).

Numerics in :mod:`baarda.pipeline.adjustment`; statistics from
:mod:`baarda.pipeline.stats`; this module maps options onto the block and the solver, runs AP
selection and blunder handling, and writes report, tables and the recording.
"""

from __future__ import annotations

import dataclasses
import difflib
from typing import ClassVar, Literal

import numpy as np
from scipy import stats as sps

from baarda.pipeline.errors import AdjustmentError, InputError
from baarda.pipeline.model import Block
from baarda.pipeline.options import REQUIRED, option
from baarda.pipeline.report import write_table
from baarda.pipeline.stage import Context, StageResult, TableData
from baarda.pipeline import stats
from baarda.pipeline.contracts import AdjustmentArtefact

from baarda.pipeline.adjustment import estimate_components
from baarda.pipeline.adjustment import (EO_NAMES, BundleResult, BundleSettings, Distance, adjust, padded_ap,
                                        result_of, select_aps)
from baarda.pipeline.camera import ap_model_names, get_ap_model
from baarda.plugins.bundle import external as bundle_external

from .protocol import bundle_protocol, camera_rows, image_units, protocol_lines



@dataclasses.dataclass(frozen=True)
class ScaleBarOptions:
    """One scale bar: a measured distance between two object points."""

    from_: str | int = option(REQUIRED, "id of the point at one end", key="from")
    to: str | int = option(REQUIRED, "id of the point at the other end")
    distance: float = option(REQUIRED, "measured distance (object units)")
    sigma: float = option(REQUIRED, "its standard deviation (object units)")

    def __post_init__(self):
        if not (self.sigma > 0 and self.distance > 0):
            raise ValueError(f"a scale bar needs a positive distance and sigma, got {self.distance}, {self.sigma}")


@dataclasses.dataclass(frozen=True)
class BundleOptions:
    RENAMED: ClassVar[dict[str, str]] = {"image_sigma_scale": "sigma_image_scale"}
    datum: Literal["control", "free"] = option(
        "control", "datum: by control points / weighted constraints, or a free network with inner constraints")
    datum_points: list[str] = option(
        [], "free network: ids of the points carrying the inner constraints (empty: every tie and check point)")
    datum_on: Literal["points", "centres"] = option(
        "points", "free network: inner constraints on object points or on the projection centres")
    ap_model: str = option("", "AP model of every camera (none, ebner12, brown, aicon, or a registered "
                               "third-party model); empty: as in the block")
    ap_models: dict[str, str] = option({}, "AP model per camera id (overrides ap_model)")
    iop: Literal["block", "free", "fixed"] = option(
        "block", "c, xp, yp: a-priori sigmas from the block, all free, or all fixed")
    aps: Literal["block", "free", "fixed"] = option(
        "block", "additional parameters: sigmas from the block, all free, or all fixed")
    fix: list[str] = option([], "parameter names held fixed in every camera (e.g. ['K3', 'P1', 'P2'])")
    free: list[str] = option([], "parameter names made free in every camera (applied after 'fix')")
    sigma: dict[str, float] = option({}, "parameter name -> a-priori sigma (weighted constraint), every camera")
    ebner_b: float = option(0.0, "image base b (mm) of ebner12; 0: 0.4 × format width (60 % overlap)")
    sigma_eo: list[float] = option(
        [], "weighted constraints on the given exterior orientations: a-priori σ [X0, Y0, Z0 (object units), "
            "ω, φ, κ (degrees)] for every photo whose orientation the block gives (0 fixes, inf frees); "
            "empty: as in the block")
    distances: list[ScaleBarOptions] = option(
        [], "extra scale bars: tables {from, to, distance, sigma} (object units); block scale bars are used too")
    sigma0: float = option(1.0, "a-priori standard deviation of unit weight")
    variance: Literal["a-posteriori", "a-priori"] = option(
        "a-posteriori", "covariances from σ̂0 (a-posteriori) or σ0 (a-priori: network design, docs/design.md)")
    sigma_image_scale: float = option(
        1.0, "multiply the a-priori σ of every image coordinate by this factor (a variance component, e.g. "
             "σ̂0 of an earlier run on the same weights)")
    max_iter: int = option(30, "maximum number of iterations")
    tol_obs: float = option(1e-5, "converged when a correction moves no observation by more than this × its σ")
    tol_rel: float = option(1e-12, "... or when vᵀPv changes by less than this fraction")
    damping: bool = option(True, "Levenberg–Marquardt damping when a Gauss–Newton step does not reduce vᵀPv")
    on_weak: Literal["error", "drop"] = option(
        "error", "photos with < 3 points, points in < 2 photos: stop with an error, or drop them with a warning")
    ap_selection: bool = option(False, "select APs: remove |ρ| > rho_max one after another, then t-tests")
    rho_max: float = option(0.75, "AP selection: correlation limit (the paper's 0.75)")
    ap_alpha: float = option(0.05, "AP selection: significance level of the t-test (two-sided)")
    ap_significance: Literal["remove", "report"] = option(
        "remove", "AP selection: remove insignificant APs one at a time, or only report them")
    blunders: Literal["none", "data-snooping", "ids"] = option(
        "none", "blunder handling inside the bundle: none, data snooping (flag), iterated data snooping (reject)")
    alpha0: float = option(0.001, "significance level of the w-test (two-sided, per observation)")
    beta0: float = option(0.80, "power for the MDBs")
    max_rejections: int = option(50, "iterated data snooping: at most this many rejected coordinates")
    ids_stop: Literal["global-test", "w-test"] = option(
        "global-test", "iterated data snooping stops when the global test accepts (Kok), or goes on while "
                       "any |w| exceeds the critical value (for a-priori σ scaled from these data, where "
                       "the global test accepts by construction)")
    robust: Literal["none", "huber", "danish", "l1"] = option(
        "none", "robust estimation by IRLS (docs/statistics.md): none, or Huber, Danish or L1 weights on the image "
                "coordinates; the adjusted values, σ̂0 and the tests are those of the final weighted adjustment, the "
                "down-weighted coordinates are listed (report, results.json, robust_wx/robust_wy in "
                "bundle_observations.csv)")
    robust_c: float = option(0.0, "robust estimation: tuning constant in standardised residuals; 0 = Huber 1.5, "
                                  "Danish 2.5 (L1: the floor of |u|, 0.001)", ge=0.0)
    robust_standardise: Literal["redundancy", "apriori", "current"] = option(
        "redundancy", "robust estimation: residuals divided by σ √r of the unweighted adjustment, by the a-priori σ, "
                      "or by σ √r of the current weighted adjustment (a covariance computation per iteration)")
    covariance: bool = option(True, "compute covariances, redundancy numbers and w-tests")
    solver: Literal["auto", "dense", "sparse"] = option(
        "auto", "reduced camera system: dense Cholesky, or sparse (METIS ordering, supernodal Cholesky, selected "
                "inversion) for large blocks; auto chooses by size and fill (docs/bundle.md)")
    arrow_scale: float = option(0.0, "scale of residual arrows in the recording (0: automatic)")
    variance_components: Literal["none", "estimate", "apply"] = option(
        "none", "variance components per observation group (Förstner, iterated; docs/bundle.md): none, estimate "
                "and report them (the adjustment keeps the a-priori σ), or apply them (the adjustment, its tests "
                "and data snooping use the re-weighted σ)")
    vc_groups: Literal["camera", "photo", "source", "all"] = option(
        "camera", "variance components: image coordinates grouped per camera, per photo, per source file, or one "
                  "group; control, "
                  "EO priors, weighted camera parameters and scale bars are groups of their own")
    vc_photo_groups: dict[str, list[str]] = option(
        {}, "variance components: user-defined image groups, name -> photo ids (override vc_groups for those photos)")
    vc_alpha: float = option(0.05, "variance components: significance level of each group's test of f = 1 (two-sided)")
    vc_iterations: int = option(20, "variance components: at most this many re-adjustments")
    external_reliability: bool = option(
        True, "effect of every coordinate's MDB on its own point and its own photo's orientation (bundle_observations.csv "
              "ext_*, report, results.json; docs/statistics.md)")
    confidence: float = option(
        0.0, "confidence of the points' error ellipsoids, plan ellipses and height intervals in bundle_points.csv "
             "(χ² quantiles with 3, 2, 1 dof); 0 = the 1-σ figures", ge=0.0, lt=1.0)
    covariance_of: list[str] = option(
        [], "parameters whose joint covariance is written to bundle_covariance.csv, e.g. "
            "['photo 001', 'point 17', 'camera cam', 'point 18 Z'] (a photo's X0…kappa, a point's X, Y, Z, a camera's "
            "c, xp, yp, APs, or one component)")

    def __post_init__(self):
        names = ap_model_names()
        for m in [self.ap_model] * bool(self.ap_model) + list(self.ap_models.values()):
            if m not in names:
                raise ValueError(f"unknown AP model {m!r}; registered: {', '.join(names)}")
        for k in ("alpha0", "beta0", "ap_alpha"):
            if not 0 < getattr(self, k) < 1:
                raise ValueError(f"{k} must lie strictly between 0 and 1")
        if not 0 < self.rho_max < 1:
            raise ValueError("rho_max must lie strictly between 0 and 1")
        if self.sigma0 <= 0:
            raise ValueError("sigma0 must be positive")
        if self.max_iter < 1:
            raise ValueError("max_iter must be at least 1")
        known = {"c", "xp", "yp"}
        for m in [self.ap_model] * bool(self.ap_model) + list(self.ap_models.values()):
            known |= set(get_ap_model(m).params)
        for name, s in self.sigma.items():
            if self.ap_model and name not in known:
                close = difflib.get_close_matches(name, sorted(known), n=1, cutoff=0.5)
                raise ValueError(f"sigma.{name}: not a parameter of the camera model(s) "
                                 f"({', '.join(sorted(known))})" + (f"; did you mean {close[0]!r}?" if close else ""))
            if not isinstance(s, (int, float)) or s < 0:
                raise ValueError(f"sigma.{name}: expected a non-negative number, got {s!r}")
        if self.sigma_eo and (len(self.sigma_eo) != 6 or not all(
                isinstance(v, (int, float)) and v >= 0 for v in self.sigma_eo)):
            raise ValueError(f"sigma_eo: expected 6 non-negative numbers [X0, Y0, Z0, ω, φ, κ (deg)], "
                             f"got {self.sigma_eo!r}")
        if not self.sigma_image_scale > 0:
            raise ValueError("sigma_image_scale must be positive")
        if self.robust != "none" and (self.blunders == "ids" or not self.covariance):
            raise ValueError(f"robust = {self.robust!r} needs covariance = true and excludes blunders = 'ids' "
                             "(robust weights and rejections are two answers to the same question)")
        if not 0 < self.vc_alpha < 1:
            raise ValueError("vc_alpha must lie strictly between 0 and 1")
        if self.vc_iterations < 1:
            raise ValueError("vc_iterations must be at least 1")
        if self.variance_components != "none" and not self.covariance:
            raise ValueError("variance_components needs the redundancy numbers: set covariance = true")


def configure_block(block: Block, o: BundleOptions) -> Block:
    """Apply the options' camera model and parameter status to the block's cameras."""
    cams = block.cameras
    models = cams.ap_model.copy().astype(object)
    if o.ap_model:
        models[:] = o.ap_model
    for cid, m in o.ap_models.items():
        if cid not in cams.ids:
            raise InputError(f"ap_models: unknown camera {cid!r}", field="ap_models")
        models[list(cams.ids).index(cid)] = m
    changed = models != cams.ap_model
    cams = cams.replace(ap_model=np.array(models, dtype=str))
    ap, sig = padded_ap(cams)
    for j in np.flatnonzero(changed):
        mdl = get_ap_model(models[j])
        ap[j] = 0.0
        sig[j] = 0.0
        sig[j, :mdl.n_params] = np.asarray(mdl.default_sigma, float)
    siop = np.array(cams.sigma_iop, float)
    if o.iop != "block":
        siop[:] = np.inf if o.iop == "free" else 0.0
    for j in range(len(cams)):
        mdl = get_ap_model(cams.ap_model[j])
        p = mdl.n_params
        if o.aps != "block":
            sig[j, :p] = np.inf if o.aps == "free" else 0.0
        names = ["c", "xp", "yp"] + list(mdl.params)
        for rule, value in [(o.fix, 0.0), (o.free, np.inf)]:
            for name in rule:
                if name in names:
                    t = names.index(name)
                    if t < 3:
                        siop[j, t] = value
                    else:
                        sig[j, t - 3] = value
        for name, s in o.sigma.items():
            if name in names:
                t = names.index(name)
                if t < 3:
                    siop[j, t] = float(s)
                else:
                    sig[j, t - 3] = float(s)
    known = {n for m in set(cams.ap_model.tolist()) for n in ["c", "xp", "yp"] + list(get_ap_model(m).params)}
    for name in list(o.fix) + list(o.free) + list(o.sigma):
        if name not in known:
            raise InputError(f"parameter {name!r} belongs to none of the cameras' models "
                             f"({', '.join(sorted(known))})", field="fix/free/sigma")
    block = block.replace(cameras=cams.replace(ap=ap, sigma_ap=sig, sigma_iop=siop))
    if o.sigma_eo:
        ph = block.photos
        se = np.array(ph.sigma_eo, float)
        se[ph.has_orientation] = np.r_[o.sigma_eo[:3], np.radians(o.sigma_eo[3:])]
        block = block.replace(photos=ph.replace(sigma_eo=se))
    if o.sigma_image_scale != 1.0:
        obs = block.observations
        block = block.replace(observations=obs.replace(cov=obs.cov * o.sigma_image_scale ** 2))
    return block


def settings_from(o: BundleOptions, block: Block, threads: int = 1) -> BundleSettings:
    ap_meta = {}
    if o.ebner_b > 0:
        ap_meta = {cid: {"b": o.ebner_b} for cid in block.cameras.ids.tolist()}
    return BundleSettings(
        datum=o.datum, datum_points=tuple(o.datum_points) or None, datum_centres=o.datum_on == "centres",
        sigma0=o.sigma0, variance=o.variance,
        max_iter=o.max_iter, tol_obs=o.tol_obs, tol_rel=o.tol_rel, damping=o.damping,
        distances=tuple(Distance(str(d.from_), str(d.to), d.distance, d.sigma) for d in o.distances),
        on_weak=o.on_weak, ap_meta=ap_meta, covariance=o.covariance, solver=o.solver, threads=threads)


class BundleAdjustment:
    summary = "Self-calibrating bundle block adjustment: datum, APs, precision, reliability, data snooping"
    reads = ("block",)
    writes = ("bundle", "adjustment", "block")
    Options = BundleOptions

    def run(self, inputs, options: BundleOptions, ctx: Context) -> StageResult:
        from .progress import iteration_progress

        with iteration_progress(ctx, options.max_iter):
            return self._run(inputs, options, ctx)

    def _run(self, inputs, options: BundleOptions, ctx: Context) -> StageResult:
        block_in = inputs["block"]
        block = configure_block(block_in, options)
        bundle_external.check_requests(block, options.covariance_of, ctx)
        settings = settings_from(options, block, threads=ctx.threads)
        ctx.progress.message(f"adjusting {len(block.photos)} photos, {len(block.points)} points, "
                             f"{int(block.observations.active.sum())} observations")
        try:
            res = adjust(block, settings, covariance=options.covariance)
            selection = None
            if options.ap_selection:
                selection = select_aps(block, settings, rho_max=options.rho_max, alpha=options.ap_alpha,
                                       significance=options.ap_significance, result=res)
                res = selection.result
            vc = None
            if options.variance_components != "none":
                # from the adjustment as it stands (after AP selection: its block and settings)
                vc = _variance_components(res.block_in, res.settings, res, options, ctx)
                if options.variance_components == "apply":
                    res, block = vc.result, vc.block
            robust = _robust(block, res, options, ctx) if options.robust != "none" else None
            if robust is not None:
                res = robust.final
        except AdjustmentError as e:
            _save_state(e, block, ctx)
            raise
        for w in res.warnings:
            ctx.warn(w)
        snap = res.snapshot
        extras = {"selection": selection, "global_test": None, "snooping": None, "ids": None, "joint": None,
                  "vc": vc, "work": _current_work()}
        decision = np.array(["ok"] * len(block.observations), dtype=object)
        decision[~block.observations.active] = "inactive"
        extras["robust"] = robust
        if robust is not None:
            decision[np.unique(robust.downweighted // 2)] = "downweighted"
        rejected_rows = np.zeros(2 * len(block.observations), bool)
        if snap is not None:
            extras["global_test"] = stats.global_test(snap, alpha0=options.alpha0, beta0=options.beta0)
            if options.blunders == "ids":
                try:
                    ids = stats.iterated_data_snooping(res, snap, alpha0=options.alpha0, beta0=options.beta0,
                                                       max_iter=options.max_rejections, stop=options.ids_stop)
                except AdjustmentError as e:
                    _save_state(e, block, ctx)
                    raise
                extras["ids"] = ids
                if ids.removed:
                    extras["before_ids"] = {"result": res, "snooping": stats.data_snooping(
                        snap, alpha0=options.alpha0, beta0=options.beta0)}
                    rejected_rows[ids.removed] = True
                    res = result_of(ids.snapshot, res)
                    snap = res.snapshot
                    extras["global_test"] = stats.global_test(snap, alpha0=options.alpha0, beta0=options.beta0)
            ds = stats.data_snooping(snap, alpha0=options.alpha0, beta0=options.beta0)
            extras["snooping"] = ds
            try:
                extras["joint"] = stats.joint_test_2d(snap, alpha=options.alpha0)
            except ValueError:
                extras["joint"] = None
            flagged_obs = np.unique(np.flatnonzero(ds.flagged) // 2)
            if options.blunders != "none":
                decision[flagged_obs] = "flagged"
            decision[np.unique(np.flatnonzero(rejected_rows) // 2)] = "rejected"
        extras.update(bundle_external.compute(res, options, ctx))
        extras["gnss"] = _gnss(res, options) if snap is not None and len(res.block_in.gnss) else None
        res.extras = extras
        out_block = res.block
        if robust is not None:   # the robust weights are the estimator's, not the block's a-priori σ
            out_block = out_block.replace(observations=out_block.observations.replace(cov=block.observations.cov))
        if rejected_rows.any():
            act = out_block.observations.active.copy()
            act[np.unique(np.flatnonzero(rejected_rows) // 2)] = False
            out_block = out_block.replace(observations=out_block.observations.replace(active=act))
        artefacts = {"bundle": res, "block": out_block}
        if snap is not None:
            artefacts["adjustment"] = AdjustmentArtefact("bundle", snap, res, res.obs_rows(),
                                                         linearise=bundle_external.linearisation(res))
        else:
            artefacts["adjustment"] = None
        summary, tables = _summary(res, extras, options), _tables(res, extras, decision, block)
        report = _report(res, extras, options, block, summary.get("protocol"))
        if extras["gnss"] is not None:          # the GNSS antennas' section, table and summary entry
            summary["gnss"], tables["gnss"] = extras["gnss"]["summary"], extras["gnss"]["table"]
            report += "\n\n" + "\n".join(extras["gnss"]["lines"])
        return StageResult(artefacts=artefacts, summary=summary, report=report, tables=tables,
                           data={"result": res, "decision": decision, "options": options, "extras": extras})

    def plots(self, result: StageResult, ctx: Context) -> dict:
        """Figures for report.html (drawn by the engine; see plugins/bundle/figures.py)."""
        from .figures import bundle_figures

        return bundle_figures(result.data["result"], result.data["decision"])

    def log(self, result: StageResult, rec, ctx: Context) -> None:
        from .rrlog import log_bundle

        log_bundle(rec, result.data["result"], result.data["decision"], result.data["options"], result.report)


# ---------------------------------------------------------------------------------------------
def _save_state(err: AdjustmentError, block: Block, ctx: Context) -> None:
    """Write the last iterate an :class:`AdjustmentError` carries into the run directory
    (``<stage>_last_eo.csv``, ``_last_points.csv``, ``_last_cameras.csv``) and raise the error again
    with their names.  Returns without doing anything when there is no state or no run directory."""
    st = getattr(err, "state", None)
    if st is None or ctx.run_dir is None:
        return
    tables = _state_tables(st, block)
    names = []
    for name, table in tables.items():
        fname = f"{ctx.stage_id}_last_{name}.csv"
        write_table(ctx.run_dir / fname, table)
        names.append(fname)
    new = AdjustmentError(f"{err} — the last state is saved in {ctx.run_dir}: {', '.join(names)}", state=st)
    if hasattr(err, "history"):
        new.history = err.history
    raise new from err


def _state_tables(st, block: Block) -> dict:
    """Exterior orientations (angles in degrees), object points and camera parameters of a state."""
    ph, pts, cams = block.photos, block.points, block.cameras
    eo = {"photo": ph.ids.tolist(), "camera": cams.ids[ph.camera].tolist()}
    for t, n in enumerate(EO_NAMES):
        eo[n + ("" if t < 3 else "_deg")] = st.X0[:, t] if t < 3 else np.degrees(st.opk[:, t - 3])
    rows = [(str(cams.ids[j]), name, float(st.cam_params[j, t]))
            for j in range(len(cams))
            for t, name in enumerate(["c", "xp", "yp"] + list(get_ap_model(cams.ap_model[j]).params))]
    return {
        "eo": TableData(eo, "exterior orientation of the last iterate (angles in degrees)"),
        "points": TableData({"point": pts.ids.tolist(), "role": pts.role.tolist(), "X": st.XYZ[:, 0],
                             "Y": st.XYZ[:, 1], "Z": st.XYZ[:, 2]},
                            f"object points of the last iterate ({block.object_unit})"),
        "cameras": TableData({"camera": [r[0] for r in rows], "parameter": [r[1] for r in rows],
                              "value": [r[2] for r in rows]}, "camera parameters of the last iterate"),
    }


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
    names = frame.axis_names()
    out = {f"{a}_crs": user[:, i] for i, a in enumerate(names)}
    out.update({f"s{a}_crs": sig[:, i] for i, a in enumerate(names)})
    return out


def _f(x, nd=4):
    return "–" if x is None or not np.isfinite(x) else f"{x:.{nd}g}"


def _summary(res: BundleResult, extras, o) -> dict:
    out = res.summary()
    gt = extras.get("global_test")
    if gt is not None:
        out["global_test"] = {k: (float(v) if isinstance(v, (float, np.floating)) else v)
                              for k, v in gt.summary().items()}
    ds = extras.get("snooping")
    if ds is not None:
        out["data_snooping"] = {"critical": ds.critical, "n_flagged": int(ds.flagged.sum())}
    jt = extras.get("joint")
    if jt is not None:
        out["joint_test"] = {"critical": jt.critical, "alpha": jt.alpha, "n_tested": int(jt.groups.size),
                             "n_flagged": int(jt.flagged.sum())}
    if extras.get("ids") is not None:
        out["ids"] = {"removed": extras["ids"].removed_labels, "stop": extras["ids"].stop_reason}
    before = extras.get("before_ids")
    if before is not None:     # the adjustment from the initial values, before any rejection
        r0 = before["result"]
        out["before_rejection"] = {"iterations": r0.iterations, "sigma0_hat": r0.sigma0_hat, "dof": r0.dof,
                                   "n_flagged": int(before["snooping"].flagged.sum())}
    if extras.get("selection") is not None:
        out["ap_selection"] = extras["selection"].summary()
    out["cameras"] = [r for j in range(len(res.block_in.cameras)) for r in camera_rows(res, j)]
    out["sigma0_um_equivalent"] = _sigma0_um(res)
    out["protocol"] = bundle_protocol(res, extras, alpha0=o.alpha0, beta0=o.beta0)
    if isinstance(out.get("check_points"), dict) and out["check_points"].get("n"):
        out["check_points"]["unit"] = res.block_in.object_unit
    flagged = out.get("data_snooping", {}).get("n_flagged")
    if extras.get("vc") is not None:
        out["variance_components"] = {"mode": o.variance_components, "groups_by": o.vc_groups,
                                      **extras["vc"].summary()}
    out.update(bundle_external.summary_entries(extras, res.block_in))
    if extras.get("robust") is not None:
        out["robust"] = extras["robust"].summary()
    out["headline"] = (f"σ̂0 = {res.sigma0_hat:.3g} (dof {res.dof}, {res.iterations} iterations)"
                       + (f"; {flagged} coordinate(s) flagged by data snooping" if flagged else "")
                       + (f"; IDS removed {len(extras['ids'].removed_labels)}" if extras.get("ids") is not None else ""))
    return out


def _sigma0_um(res: BundleResult) -> float:
    """σ̂0 × median a-priori image σ, in µm (the papers' 'σ0 in µm' when all σ are equal)."""
    cov = res.block_in.observations.cov[res.obs_active]
    if len(cov) == 0:
        return float("nan")
    s = np.sqrt(np.median(0.5 * (cov[:, 0, 0] + cov[:, 1, 1])))
    return float(res.sigma0_hat * s * 1000.0 / res.sigma0)


def _current_work():
    from .progress import current_work

    return current_work()


def _report(res: BundleResult, extras, o, block, protocol=None) -> str:
    L = []
    L.append(f"Bundle adjustment of {int(res.photo_used.sum())} photos, {int(res.point_used.sum())} points, "
             f"{int(res.obs_active.sum())} image points ({res.n_observation_rows} coordinates); "
             f"{res.n_unknowns} unknowns, {res.n_weighted_constraints} weighted constraints, "
             f"{len(res.distances)} distance(s); datum: {o.datum}"
             + (f" (inner constraints on {'projection centres' if o.datum_on == 'centres' else 'points'}, "
                f"{res.n_datum_constraints} constraints)" if o.datum == "free" else "") + ".")
    L.append("")
    L.append(f"- iterations: {res.iterations}; vᵀPv = {res.vtpv:.6g}; dof = {res.dof}; "
             f"σ̂0 = {_f(res.sigma0_hat)} (≈ {_sigma0_equivalent(res, protocol)})")
    gt = extras.get("global_test")
    if gt is not None:
        L.append(f"- global test: T = σ̂0²/σ0² = {_f(gt.T)} vs F-critical {_f(gt.critical)} "
                 f"(α′ = {gt.alpha:.3g}): {'REJECTED' if gt.rejected else 'accepted'}")
    ds = extras.get("snooping")
    if ds is not None:
        L.append(f"- data snooping: |w| > {ds.critical:.3f}: {int(ds.flagged.sum())} coordinate(s) flagged"
                 + (f" (expected under H0 at α0 = {ds.alpha0:g}: about {ds.alpha0 * int(res.snapshot.active.sum()):.0f})"
                    if getattr(ds, "alpha0", None) else ""))
        L.append(_tail_line(ds, res.snapshot))
        L.extend(_flagged_lines(res, ds))
    jt = extras.get("joint")
    if jt is not None and jt.groups.size:
        L.append(f"- 2-D test per image point, T = (Pv)ᵀ(PQvvP)⁻¹(Pv)/σ0² ~ χ²(2): T > {jt.critical:.3f} "
                 f"(α = {jt.alpha:g}) at {int(jt.flagged.sum())} of {jt.groups.size} image points (expected under "
                 f"H0: about {jt.alpha * jt.groups.size:.0f}); per point in bundle_observations.csv "
                 "(T2d, T2d_critical, T2d_flagged)")
    ids = extras.get("ids")
    if ids is not None:
        L.append(f"- iterated data snooping (|w| > {ids.critical:.3f}, one coordinate at a time): "
                 f"{len(ids.removed)} coordinate(s) rejected; stop: {ids.stop_reason}")
        before = extras.get("before_ids")
        if before is not None:
            r0, ds0 = before["result"], before["snooping"]
            n0 = int(r0.snapshot.active.sum())
            L.append(f"  - before the rejections ({r0.iterations} iterations from the initial values): σ̂0 = "
                     f"{_f(r0.sigma0_hat)}, {int(ds0.flagged.sum())} coordinate(s) with |w| > {ds0.critical:.3f} "
                     f"(expected under H0: about {ds0.alpha0 * n0:.0f})")
            L.append("  " + _tail_line(ds0, r0.snapshot))
            L.append("  " + _radius_line(res, ids))
        L.extend(_rejected_lines(res, ids))
    L.extend(_robust_lines(extras.get("robust")))
    if res.check.get("n"):
        c = res.check
        L.append(f"- check points ({c['n']}, adjusted − surveyed): Sx = {_f(c['Sx'])}, Sy = {_f(c['Sy'])}, "
                 f"Sxy = {_f(c['Sxy'])}, Sz = {_f(c['Sz'])} ({block.object_unit})")
    t = res.timings
    w = extras.get("work")
    if w is not None and w.adjustments > 1:
        L.append(f"- stage time: {w.seconds:.3f} s for {w.adjustments} adjustments ({w.iterations} iterations "
                 "in all: every re-adjustment of the stage, and the statistics); the last adjustment:")
    elif w is not None:
        L.append(f"- stage time: {w.seconds:.3f} s (the adjustment and its statistics); the adjustment:")
    L.append(f"- time: {t.get('total', 0):.3f} s (initial values {t.get('initial_values', 0):.3f}, linearise "
             f"{t.get('linearize', 0):.3f}, solve {t.get('solve', 0):.3f}, covariance {t.get('covariance', 0):.3f}; "
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
    L.append("| camera | parameter | value | σ | unit | status |")
    L.append("|---|---|---|---|---|---|")
    zero_fixed = {}                          # camera -> parameters held fixed at 0 (one line, not rows)
    for j in range(len(block.cameras)):
        if not res.camera_used[j]:
            continue
        for r in camera_rows(res, j, u):
            if r["status"] == "fixed" and r["value"] == 0.0:
                zero_fixed.setdefault(r["camera"], []).append(r["parameter"])
                continue
            L.append(f"| {r['camera']} | {r['parameter']} | {r['value']:.8g} | {_f(r['sigma'], 3)} | {r['unit']} | "
                     f"{r['status']} |")
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
    sel = extras.get("selection")
    if sel is not None:
        L += ["", "### Additional-parameter selection", "", sel.markdown()]
    if extras.get("vc") is not None:
        L += ["", "### Variance components", ""] + _vc_lines(extras["vc"], o)
    L += bundle_external.report_entries(extras, block)
    return "\n".join(L)


class _Robust:
    """The robust estimate of the bundle: the IRLS result and the final weighted adjustment."""

    def __init__(self, irls, final, how):
        self.irls, self.final, self.how = irls, final, how
        self.downweighted = irls.downweighted

    def summary(self) -> dict:
        return {"how": self.how, **self.irls.summary()}


def _robust(block, res, o, ctx) -> _Robust:
    """IRLS on the bundle (stats.irls); the final adjustment with the final weights and covariances."""
    ctx.progress.message(f"robust estimation ({o.robust})")
    refit, how = stats.weighted_refit(res, redundancy=o.robust_standardise == "current")
    rob = stats.irls(refit, res.snapshot, o.robust, o.robust_c or None, standardise=o.robust_standardise,
                     max_iter=100)
    if not rob.converged:
        ctx.warn(f"robust estimation ({o.robust}) did not converge in {rob.iterations} iterations "
                 f"(largest weight change {rob.history[-1]['max_dw']:.3g})")
    if rob.iterations == 0:
        return _Robust(rob, res, how)
    obs = block.observations
    b = block.replace(observations=obs.replace(cov=stats.scale_covariance(obs.cov, np.maximum(rob.weights, 1e-8))))
    final = adjust(b, res.settings, row_active=res.row_active, start=rob.fit.result.state, compute_initial=False,
                   covariance=True)
    return _Robust(rob, final, how)


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


def _variance_components(block, settings, res, o, ctx):
    ctx.progress.message("variance components")
    try:
        return estimate_components(block, settings, image_groups=o.vc_groups, photo_groups=o.vc_photo_groups,
                                   first=res, max_iter=o.vc_iterations, alpha=o.vc_alpha, covariance=True)
    except KeyError as e:
        raise InputError(f"vc_photo_groups: unknown photo {e}", field="vc_photo_groups") from None


def _vc_lines(vc, o) -> list[str]:
    """Each group's factor on its a-priori σ, σ(f), r_g and the test of f = 1."""
    first = vc.first
    L = [f"Förstner's estimate, iterated ({vc.iterations} re-adjustment(s), "
         f"{'converged' if vc.converged else 'NOT converged'}); image groups per {o.vc_groups}. "
         f"f = estimated σ / a-priori σ; test of H0: f = 1 by T = f² ~ χ²(r)/r, two-sided at α = {vc.alpha:g}. "
         + ("The adjustment above and its tests use the a-priori σ × f." if o.variance_components == "apply"
            else "Estimated only: the adjustment above keeps the a-priori σ "
                 f"(σ̂0 = {_f(first.sigma0_hat)}) — variance_components = \"apply\" re-weights it."), "",
         f"First adjustment, on the a-priori σ: {first.iterations} iterations, σ̂0 = {_f(first.sigma0_hat)}, "
         f"dof {first.dof}.", "",
         "| group | rows | r | f | σ(f) | T | p | H0: f = 1 |", "|---|---|---|---|---|---|---|---|"]
    for g in vc.groups:
        if g.estimable:
            L.append(f"| {g.name} | {g.n} | {g.redundancy:.1f} | {g.factor:.4g} | {g.sigma_factor:.2g} | "
                     f"{g.T:.4g} | {g.p_value:.3g} | {'rejected' if g.rejected else 'accepted'} |")
        else:
            L.append(f"| {g.name} | {g.n} | {g.redundancy:.3g} | 1 (not estimable: r < 1) | – | – | – | – |")
    return L


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


def _flagged_lines(res: BundleResult, ds, most: int = 15) -> list[str]:
    """The largest flagged standardized residuals, with photo, point and coordinate."""
    idx = np.flatnonzero(ds.flagged)
    if not len(idx):
        return []
    u, k, _ = image_units(res.block_in)
    idx = idx[np.argsort(-np.abs(ds.w[idx]))]
    rows = ["", f"  Largest flagged (of {len(idx)}; all in bundle_observations.csv, column `decision`):", "",
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
    return {"T2d": T, "T2d_critical": crit, "T2d_flagged": flag.tolist()}


def _pixel_columns(units, v, nab, mdbs) -> dict:
    """For a pixel source: residuals, estimated errors and MDBs of each image point in px (the mm
    columns stay: they are the adjustment's own numbers)."""
    if units[0] != "px":
        return {}
    k = units[1]
    return {"vx_px": k * v[:, 0], "vy_px": k * v[:, 1], "nabla_x_px": k * nab[:, 0], "nabla_y_px": k * nab[:, 1],
            "mdb_x_px": k * mdbs[:, 0], "mdb_y_px": k * mdbs[:, 1]}


def _tables(res: BundleResult, extras, decision, block) -> dict:
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
    tables["observations"] = TableData({
        "photo": ph_ids.tolist(), "point": pt_ids.tolist(), "x": obs.xy[:, 0], "y": obs.xy[:, 1],
        "vx": v[:, 0], "vy": v[:, 1], "rx": r[:, 0], "ry": r[:, 1], "wx": w[:, 0], "wy": w[:, 1],
        "nabla_x": nab[:, 0], "nabla_y": nab[:, 1], "mdb_x": mdbs[:, 0], "mdb_y": mdbs[:, 1],
        **_pixel_columns(units, v, nab, mdbs),
        **_joint_columns(extras.get("joint"), len(obs)),
        **bundle_external.observation_columns(extras.get("external"), len(obs)),
        **_robust_columns(extras.get("robust"), len(obs)),
        "decision": decision.tolist()},
        "every image observation: residual (mm), redundancy, w-test, MDB (mm)"
        + (f"; the same in pixels ({units[2]} source): *_px" if units[0] == "px" else "")
        + ", 2-D test of the point (χ²(2)), "
        "largest effect of each MDB on its own point / photo (ext_*: object units, degrees, in σ), δ̄0")
    pts = block.points
    sp = res.point_sigmas()
    rays = np.bincount(obs.point[res.obs_active], minlength=len(pts))
    XYZ = res.state.XYZ
    dXYZ = np.where((pts.role == "check")[:, None], XYZ - pts.XYZ, np.nan)
    tables["points"] = TableData({
        "point": pts.ids.tolist(), "role": pts.role.tolist(), "X": XYZ[:, 0], "Y": XYZ[:, 1], "Z": XYZ[:, 2],
        "sX": sp[:, 0], "sY": sp[:, 1], "sZ": sp[:, 2], "rays": rays,
        "dX_check": dXYZ[:, 0], "dY_check": dXYZ[:, 1], "dZ_check": dXYZ[:, 2],
        **bundle_external.point_columns(res, extras.get("confidence", 0.0)), **_crs_columns(res, block)},
        f"adjusted object points ({block.object_unit}) with a-posteriori σ; check points: adjusted − surveyed; "
        "error ellipsoid (semi-axes, direction of the largest), plan ellipse (bearing from +X), height interval; "
        "*_crs: the same points and σ in the CRS the coordinates were given in (docs/crs.md), where there is one")
    chk = pts.role == "check"
    if chk.any():
        tables["check_points"] = TableData({
            "point": pts.ids[chk].tolist(), "dX": dXYZ[chk, 0], "dY": dXYZ[chk, 1], "dZ": dXYZ[chk, 2]},
            f"check points: adjusted − surveyed ({block.object_unit})")
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
        cols[n + ("" if t < 3 else "_deg")] = val
        cols["s" + n + ("" if t < 3 else "_deg")] = sd
    tables["eo"] = TableData(cols, "exterior orientation with a-posteriori σ (angles in degrees)")
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
    tables["convergence"] = TableData({k: [h[k] for h in res.history] for k in
                                       ("iteration", "vtpv", "lambda", "max_step_sigma")},
                                      "vᵀPv, damping and largest correction (in σ of an observation) per iteration")
    tables.update(bundle_external.tables(extras))
    return tables


def _gnss(res: BundleResult, o) -> dict | None:
    """The GNSS antennas as observations of the bundle (``block.gnss``): per photo the residuals
    ``v = X_antenna − (X0 + Rᵀ e)`` (object units; E N U in a CRS's local frame, else X Y Z), a-priori σ,
    redundancy numbers, w-tests and MDBs (:func:`baarda.pipeline.adjustment.global_rows`, the
    statistics library's data snooping at the stage's α0, β0); the report section, table and summary."""
    from baarda.pipeline.adjustment import global_rows

    gs = global_rows(res).get("gnss")
    if gs is None:
        return None
    blk = res.block_in
    ds = stats.data_snooping(gs.snapshot, alpha0=o.alpha0, beta0=o.beta0)
    G = len(gs.index)
    w, mdb = ds.w.reshape(G, 3), ds.mdb.reshape(G, 3)
    flagged = ds.flagged.reshape(G, 3).any(axis=1)
    ax = ("E", "N", "U") if blk.crs is not None else ("X", "Y", "Z")
    ids = blk.photos.ids[blk.gnss.photo[gs.index]].astype(str).tolist()
    u = blk.object_unit
    cols = {"photo": ids}
    for name, arr in (("v", gs.v), ("s", gs.sigma), ("r", gs.r), ("w", w), ("mdb", mdb)):
        cols.update({f"{name}{a}": arr[:, t] for t, a in enumerate(ax)})
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
    from baarda.pipeline.report import markdown_table

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
