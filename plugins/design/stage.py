"""Stages ``design`` (a planned network as a block of error-free observations) and
``design-montecarlo`` (predicted against Monte-Carlo-realised precision).  ``docs/design.md``.

The prediction itself is the ordinary ``bundle`` stage with ``variance = "a-priori"``: at error-free
observations the adjustment converges at once and its covariances are σ0² Q of the design, with
redundancy numbers, MDBs and external reliability as for any block.  The report text and the data
the figures draw are :mod:`.report`.
"""

from __future__ import annotations

import csv
import dataclasses
import functools
from pathlib import Path

import numpy as np

from baarda.pipeline import montecarlo
from baarda.pipeline.api import (Context, InputError, SourceStage, Stage, StageResult, TableData, option,
                                 parameter_covariance)
from baarda.pipeline.camera import ap_model_names, get_ap_model
from baarda.pipeline.errors import quote
from baarda.pipeline.geometry import opk_from_rotation
from baarda.pipeline.options import REQUIRED
from baarda.pipeline.synthetic.closerange import look_at
from baarda.pipeline.units import camera_parameter_units, length_suffix, object_unit_text

from . import report as design_report
from .network import PlannedCamera, joint_test, plan_block, ratio_test, realisation_errors
from .report import figure_data, viewing_directions

ROLE_ALIASES = {"control": "full", "full": "full", "xy": "xy", "z": "z", "check": "check", "tie": "tie"}


@dataclasses.dataclass(frozen=True)
class CameraOptions:
    """The planned camera."""

    c_mm: float = option(REQUIRED, "principal distance (mm)")
    pixel_mm: float = option(REQUIRED, "pixel pitch (mm)")
    resolution: list[int] = option(REQUIRED, "format in pixels [width, height]", ge=1)
    ap_model: str = option("none", "AP model (none, brown, ebner12, aicon, or a registered one)")
    xp: float = option(0.0, "principal point x (mm)", ge=-1e6)
    yp: float = option(0.0, "principal point y (mm)", ge=-1e6)
    ap: dict[str, float] = option({}, "planned AP values by name (default 0)", ge=-1e6)
    free: list[str] = option([], "parameters estimated (c, xp, yp, AP names); the others are held fixed")
    sigma: dict[str, float] = option({}, "parameters with an a-priori σ (weighted constraint)")


@dataclasses.dataclass(frozen=True)
class DesignOptions:
    stations: Path = option(REQUIRED, "CSV of the planned stations: id,X,Y,Z and omega,phi,kappa (degrees) or "
                                      "look_X,look_Y,look_Z[,roll] (a target point, roll in degrees)")
    targets: Path = option(REQUIRED, "CSV of the targets: id,X,Y,Z[,role] (role control|full|xy|z|check|tie, "
                                     "default tie)")
    camera: CameraOptions = option(REQUIRED, "the planned camera")
    sigma_px: float = option(0.1, "a-priori σ of each image coordinate (pixels)")
    sigma_control_mm: float = option(0.0, "a-priori σ of each control coordinate (mm); 0 fixes the control")
    margin_px: float = option(0.0, "a target is observed when its image lies this far inside the format")
    noise: bool = option(False, "add Gaussian noise of σ sigma_px to every image coordinate (a simulated measurement, "
                                "e.g. of an acceptance test; seeded by the project); default: the exact projections")


class DesignSource(SourceStage):
    summary = "Network design: a planned network (stations, targets, camera, a-priori σ) as error-free observations"
    reads = ()
    writes = ("block",)
    Options = DesignOptions

    def run(self, inputs, options: DesignOptions, ctx: Context) -> StageResult:
        cam = _camera(options.camera, ctx)
        st_path = ctx.resolve(options.stations)
        tg_path = ctx.resolve(options.targets)
        sid, X0, opk, st_lines = read_stations(st_path, _target_lookup(tg_path))
        tid, XYZ, role, tg_lines = read_targets(tg_path)
        to_obj = 1e-3 if ctx.object_unit == "m" else 1.0
        block = plan_block(cam, sid, X0, opk, tid, XYZ, role, sigma_image_mm=options.sigma_px * cam.pixel_mm,
                           sigma_control=options.sigma_control_mm * to_obj,
                           margin_mm=options.margin_px * cam.pixel_mm, object_unit=ctx.object_unit)
        if options.noise:
            obs = block.observations
            noisy = np.array(obs.xy, float) + ctx.rng.normal(0.0, options.sigma_px * cam.pixel_mm, size=obs.xy.shape)
            block = block.replace(observations=obs.replace(xy=noisy))
        obs = block.observations
        rays = np.bincount(obs.point, minlength=len(tid))
        per_station = np.bincount(obs.photo, minlength=len(sid))
        for i in np.flatnonzero((rays < 2) & (role != "full")):
            raise InputError(f"target {quote(tid[i])} is seen from {rays[i]} station(s); it needs 2 "
                             "(move stations, widen the format or remove the target)", tg_path, tg_lines[i], "id")
        for i in np.flatnonzero(per_station < 3):
            raise InputError(f"station {quote(sid[i])} sees {per_station[i]} target(s); a photo needs 3",
                             st_path, st_lines[i], "id")
        summary = {**block.summary(), "stations": len(sid), "targets": len(tid),
                   "control": int(np.sum(role == "full") + np.sum(role == "xy") + np.sum(role == "z")),
                   "rays_min": int(rays.min()), "rays_mean": round(float(rays.mean()), 2),
                   "sigma_px": options.sigma_px, "sigma_image_um": options.sigma_px * cam.pixel_mm * 1e3,
                   "free_camera_parameters": list(cam.free) + list((cam.sigma or {}))}
        summary["headline"] = (f"planned network: {len(sid)} stations, {len(tid)} targets ({summary['control']} "
                               f"control), {len(obs)} image points, {_span(summary['rays_min'], int(rays.max()))} "
                               f"rays per target; σ {options.sigma_px} px")
        report = (f"Planned network: {len(sid)} stations, {len(tid)} targets "
                  f"({summary['control']} control), {len(obs)} planned image points "
                  f"({summary['rays_min']}–{int(rays.max())} rays per target, mean {summary['rays_mean']}). "
                  f"Camera c = {cam.c} mm, {cam.resolution[0]} × {cam.resolution[1]} px of {cam.pixel_mm * 1e3:g} µm, "
                  f"AP model {cam.ap_model}; free: {', '.join(cam.free) or 'none'}. A-priori σ: "
                  f"{options.sigma_px} px ({summary['sigma_image_um']:.3g} µm) per image coordinate, control "
                  f"{options.sigma_control_mm or 'fixed'}{' mm' if options.sigma_control_mm else ''}.\n\n"
                  + ("The observations are the projections plus simulated noise of that σ (`noise = true`).\n"
                     if options.noise else
                     "The observations are the exact projections; the `bundle` stage with `variance = \"a-priori\"` "
                     "predicts the precision and reliability (docs/design.md).\n"))
        tables = {"rays": TableData({"target": list(tid), "role": list(role), "rays": rays.tolist()},
                                    "planned rays per target")}
        return StageResult(artefacts={"block": block}, summary=summary, report=report, tables=tables,
                           data={"block": block, "rays": rays, "per_station": per_station,
                                 "view": viewing_directions(block.photos.opk)})

    def plots(self, result: StageResult, ctx: Context) -> dict:
        """The planned network and its rays (report.html; plugins/design/figures.py)."""
        from .figures import plan_figures

        return plan_figures(result.data)

    def log(self, result: StageResult, rec, ctx: Context) -> None:
        from baarda.pipeline.api import log_block

        log_block(rec, result.data["block"], root="planned")


def _span(lo: int, hi: int) -> str:
    return f"{lo}" if lo == hi else f"{lo}–{hi}"


def _camera(o: CameraOptions, ctx: Context) -> PlannedCamera:
    def bad(msg, key):
        return InputError(msg, ctx.project_file, ctx.option_lines.get("camera", ctx.stage_line), f"camera.{key}")

    if o.ap_model not in ap_model_names():
        raise bad(f"unknown AP model {quote(o.ap_model)}; registered: {', '.join(ap_model_names())}", "ap_model")
    if len(o.resolution) != 2:
        raise bad(f"expected [width, height], got {len(o.resolution)} numbers", "resolution")
    names = ["c", "xp", "yp"] + list(get_ap_model(o.ap_model).params)
    for key, given in (("free", o.free), ("sigma", list(o.sigma)), ("ap", list(o.ap))):
        allowed = names[3:] if key == "ap" else names
        for nm in given:
            if nm not in allowed:
                raise bad(f"{quote(nm)} is not a parameter of {o.ap_model} ({', '.join(allowed) or 'none'})", key)
    for nm, s in o.sigma.items():
        if not s > 0:
            raise bad(f"σ of {quote(nm)} must be positive (list a parameter in 'free' to estimate it freely)",
                      "sigma")
    return PlannedCamera(c=o.c_mm, pixel_mm=o.pixel_mm, resolution=(int(o.resolution[0]), int(o.resolution[1])),
                         ap_model=o.ap_model, xp=o.xp, yp=o.yp, ap=dict(o.ap), free=tuple(o.free),
                         sigma=dict(o.sigma))


# ---------------------------------------------------------------------------------------------- CSV
def _rows(path: Path, required: tuple[str, ...]):
    """(header, [(line, {column: text})]) of a CSV with a header line; '#' starts a comment line."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise InputError(f"cannot read the file ({e.strerror})", path) from None
    lines = [(k + 1, ln) for k, ln in enumerate(text.splitlines()) if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise InputError("empty file; expected a header line " + ",".join(required), path, 1)
    hline, htext = lines[0]
    header = [h.strip() for h in next(csv.reader([htext]))]
    for col in required:
        if col not in header:
            raise InputError(f"missing column {quote(col)} (header: {', '.join(map(quote, header))})", path, hline, col)
    out = []
    for ln, raw in lines[1:]:
        vals = [v.strip() for v in next(csv.reader([raw]))]
        if len(vals) != len(header):
            raise InputError(f"expected {len(header)} fields, got {len(vals)}", path, ln)
        out.append((ln, dict(zip(header, vals))))
    if not out:
        raise InputError("no rows after the header", path, hline)
    return header, out


def _num(row, key, path, ln) -> float:
    try:
        v = float(row[key])
    except ValueError:
        raise InputError(f"expected a number, got {quote(row[key])}", path, ln, key) from None
    if not np.isfinite(v):
        raise InputError(f"expected a finite number, got {quote(row[key])}", path, ln, key)
    return v


def _unique(ids, lines, path):
    seen = {}
    for i, ln in zip(ids, lines):
        if i in seen:
            raise InputError(f"duplicate id {quote(i)} (first on line {seen[i]})", path, ln, "id")
        seen[i] = ln


def _target_lookup(path: Path) -> dict:
    try:
        tid, XYZ, _, _ = read_targets(path)
    except InputError:
        return {}                       # read_targets reports it when the targets are read
    return dict(zip(tid, XYZ))


def read_targets(path: Path):
    """``ids, XYZ (n, 3), role (n,), lines`` of a targets CSV."""
    header, rows = _rows(path, ("id", "X", "Y", "Z"))
    ids, XYZ, role, lines = [], [], [], []
    for ln, r in rows:
        if not r["id"]:
            raise InputError("empty id", path, ln, "id")
        ids.append(r["id"])
        XYZ.append([_num(r, k, path, ln) for k in ("X", "Y", "Z")])
        rl = r.get("role", "") or "tie"
        if rl.lower() not in ROLE_ALIASES:
            raise InputError(f"unknown role {quote(rl)}; expected one of {', '.join(ROLE_ALIASES)}", path, ln, "role")
        role.append(ROLE_ALIASES[rl.lower()])
        lines.append(ln)
    _unique(ids, lines, path)
    return np.array(ids, str), np.array(XYZ, float), np.array(role, str), lines


def read_stations(path: Path, targets: dict | None = None):
    """``ids, X0 (m, 3), opk (m, 3) rad, lines`` of a stations CSV (angles or a look-at point; the
    look-at point may be a target id in ``look_at``)."""
    header, rows = _rows(path, ("id", "X", "Y", "Z"))
    angles = all(k in header for k in ("omega", "phi", "kappa"))
    look = all(k in header for k in ("look_X", "look_Y", "look_Z")) or "look_at" in header
    if angles == look:
        raise InputError("give either omega,phi,kappa (degrees) or look_X,look_Y,look_Z / look_at (a target id)",
                         path, rows[0][0] - 1 if rows else 1, "header")
    ids, X0, opk, lines = [], [], [], []
    for ln, r in rows:
        if not r["id"]:
            raise InputError("empty id", path, ln, "id")
        C = np.array([_num(r, k, path, ln) for k in ("X", "Y", "Z")])
        if angles:
            o = np.radians([_num(r, k, path, ln) for k in ("omega", "phi", "kappa")])
        else:
            if r.get("look_at"):
                if targets is None or r["look_at"] not in targets:
                    raise InputError(f"look_at {quote(r['look_at'])} is not a target id", path, ln, "look_at")
                T = np.asarray(targets[r["look_at"]], float)
            else:
                T = np.array([_num(r, k, path, ln) for k in ("look_X", "look_Y", "look_Z")])
            if np.linalg.norm(T - C) == 0:
                raise InputError("the look-at point is the station itself", path, ln, "look_X")
            roll = np.radians(_num(r, "roll", path, ln)) if r.get("roll") else 0.0
            o = opk_from_rotation(look_at(C, T, roll=roll))
        ids.append(r["id"])
        X0.append(C)
        opk.append(o)
        lines.append(ln)
    _unique(ids, lines, path)
    return np.array(ids, str), np.array(X0, float), np.array(opk, float), lines


# ---------------------------------------------------------------------------------------------- Monte Carlo
@dataclasses.dataclass(frozen=True)
class DesignMonteCarloOptions:
    n_sim: int = option(20, "noisy realisations of the planned network, each adjusted (0: the prediction only)")
    alpha: float = option(0.05, "significance level of the χ² test of each realised σ against the prediction")
    rho_max: float = option(0.9, "camera parameters correlated beyond |ρ| = rho_max are reported as poorly "
                                 "separable")
    joint_test: bool = option(True, "also test all estimated point coordinates and camera parameters jointly "
                                    "against their full predicted covariance (one solve per parameter)")
    seed: int | None = option(None, "seed of the realisations; default: the project's seed for this stage")


def _one(block, settings, rng, i):
    return realisation_errors(block, settings, rng)


def prediction(res) -> dict:
    """σ0² Q of the bundle result (whichever variance it reported): points (n, 3, 3), cameras."""
    f = res.sigma0 ** 2 / res.variance_factor
    return {"points": res.cov_points * f, "cameras": [C * f for C in res.cov_cameras], "eo": res.cov_eo * f}


class DesignMonteCarlo(Stage):
    summary = "Network design: predicted precision against N noisy realisations of the planned network, adjusted"
    reads = ("bundle",)
    writes = ("design",)
    Options = DesignMonteCarloOptions

    def run(self, inputs, options: DesignMonteCarloOptions, ctx: Context) -> StageResult:
        res = inputs["bundle"]
        block = res.block_in
        if not (isinstance(block.meta, dict) and block.meta.get("design")):
            raise InputError("design-montecarlo needs the bundle of a planned network (a 'design' stage before the "
                             "bundle)", ctx.project_file, ctx.stage_line, "use")
        if res.settings.variance != "a-priori":
            ctx.warn("the bundle ran with variance = \"a-posteriori\" (σ̂0 of error-free observations is 0); "
                     "this stage uses σ0² Q — set bundle.variance = \"a-priori\" for its own report")
        pred = prediction(res)
        free_pt = np.flatnonzero(res.point_used & ~(block.points.sigma == 0).all(axis=1))
        sig_pts = np.sqrt(np.einsum("nii->ni", pred["points"]))
        cam_rows = []
        for j, names in enumerate(res.cam_param_names):
            for t, nm in enumerate(names):
                if res.camera_sigma[j, t] != 0:
                    cam_rows.append((j, t, f"{block.cameras.ids[j]}.{nm}"))
        sig_cam = np.array([np.sqrt(pred["cameras"][j][t, t]) for j, t, _ in cam_rows])
        out = {"predicted_points": sig_pts, "predicted_cameras": sig_cam}
        summary = {"n_sim": options.n_sim, "points": int(free_pt.size), "camera_parameters": len(cam_rows)}
        tables = {}
        pairs = design_report.correlated(res, options.rho_max)
        summary["correlated_camera_parameters"] = [f"{a}~{b} ({r:+.2f})" for a, b, r in pairs]
        mc = None
        if options.n_sim > 0:
            seed = options.seed if options.seed is not None else ctx.rng
            with ctx.progress.bar(options.n_sim, "realisations") as bar:
                errs = montecarlo.map_realisations(functools.partial(_one, block, res.settings), options.n_sim,
                                                   seed, progress=lambda done, n: bar.update(done - bar.n))
            E_pts = np.stack([e["XYZ"][free_pt] for e in errs])             # (N, q, 3)
            t_pts = ratio_test(E_pts.reshape(options.n_sim, -1), sig_pts[free_pt].reshape(-1), options.alpha)
            E_cam = np.stack([[e["cam"][j, t] for j, t, _ in cam_rows] for e in errs]) if cam_rows else \
                np.zeros((options.n_sim, 0))
            t_cam = ratio_test(E_cam, sig_cam, options.alpha)
            mc = {"points": t_pts, "cameras": t_cam, "sigma0_hat": np.array([e["sigma0_hat"] for e in errs]),
                  "errors_points": E_pts, "dof": int(errs[0]["dof"])}
            if options.joint_test:
                specs = [f"point {i}" for i in block.points.ids[free_pt]] + [f"camera {c}" for c in block.cameras.ids]
                names, C = parameter_covariance(res, specs)
                C = C * res.sigma0 ** 2 / res.variance_factor
                pos = {nm: k for k, nm in enumerate(names)}
                keep = [pos[f"point {i} {a}"] for i in block.points.ids[free_pt] for a in "XYZ"] + \
                    [pos[f"camera {block.cameras.ids[j]} {res.cam_param_names[j][t]}"] for j, t, _ in cam_rows]
                E = np.concatenate([E_pts.reshape(options.n_sim, -1), E_cam], axis=1)
                mc["joint"] = joint_test(E, C[np.ix_(keep, keep)])
                summary["joint"] = {k: (round(v, 4) if k != "dof" else v) for k, v in mc["joint"].items()
                                    if k != "per_realisation"}
            out["montecarlo"] = mc
            r = t_pts.ratio.reshape(-1, 3)
            o = length_suffix(object_unit_text(block))      # σ columns carry the object unit (_m, _mm)
            tables["points"] = TableData({
                "point": block.points.ids[free_pt].tolist(), "role": block.points.role[free_pt].tolist(),
                **{f"sigma_{a}_pred{o}": sig_pts[free_pt, k].tolist() for k, a in enumerate("XYZ")},
                **{f"ratio_{a}": r[:, k].tolist() for k, a in enumerate("XYZ")},
                "rejected": t_pts.rejected.reshape(-1, 3).any(axis=1).tolist()},
                f"predicted σ ({object_unit_text(block)}) and realised/predicted ratio from {options.n_sim} realisations")
            # one parameter per row, each in its own unit (as bundle_cameras): a `unit` column
            cam_units = {j: camera_parameter_units(block.cameras.ap_model[j], len(res.cam_param_names[j]) - 3)
                         for j in {j for j, *_ in cam_rows}}
            tables["cameras"] = TableData({
                "parameter": [nm for *_, nm in cam_rows], "sigma_pred": sig_cam.tolist(),
                "unit": [cam_units[j][t] for j, t, _ in cam_rows],
                "ratio": t_cam.ratio.tolist(), "rejected": t_cam.rejected.tolist()},
                f"camera parameters: predicted σ (in the row's `unit`: c, xp, yp mm, K1 mm⁻² …) and "
                f"realised/predicted ratio ({options.n_sim} realisations)", units={"ratio": ""})
            summary.update({
                "points_pooled_ratio": round(t_pts.pooled_ratio, 4), "points_pooled_p": round(t_pts.pooled_p, 4),
                "points_rejected": int(t_pts.rejected.sum()), "points_components": int(t_pts.ratio.size),
                "cameras_pooled_ratio": round(t_cam.pooled_ratio, 4) if cam_rows else None,
                "cameras_rejected": int(t_cam.rejected.sum()),
                "ratio_interval": [round(t_pts.lower, 4), round(t_pts.upper, 4)],
                "sigma0_hat_mean": round(float(np.mean(mc["sigma0_hat"])), 4)})
        report = design_report.report(block, res, free_pt, sig_pts, cam_rows, sig_cam, pairs, mc, options)
        summary["headline"] = design_report.headline(block, free_pt, sig_pts, mc)
        data = {**out, "figures": figure_data(res, pred["points"], free_pt)}
        return StageResult(artefacts={"design": out}, summary=summary, report=report, tables=tables, data=data)

    def plots(self, result: StageResult, ctx: Context) -> dict:
        """Predicted precision and reliability of the plan, and the Monte Carlo against the prediction
        (report.html; plugins/design/figures.py)."""
        from .figures import montecarlo_figures

        return montecarlo_figures(result.data)


