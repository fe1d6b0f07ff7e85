"""Run pycolmap on a baarda bundle and compare the two solutions quantity by quantity (numerics).

:func:`crosscheck` is the public entry point; :func:`exceeded` lists the quantities whose
difference is beyond the tolerances, :class:`CrossCheckError` is what the stage raises then.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from baarda.pipeline.api import BaardaError, rig_result
from baarda.pipeline.geometry import rotation_angle
from baarda.pipeline.units import camera_parameter_units

from .plan import CrossCheckPlan, plan_crosscheck
from .pycolmap_ba import (PycolmapSolution, SolverSettings, build_reconstruction, estimate_covariance,
                          read_solution, solve_pycolmap)

__all__ = ["CrossCheck", "CrossCheckError", "Tolerances", "crosscheck", "exceeded", "start_values"]


class CrossCheckError(BaardaError):
    """baarda and pycolmap disagree beyond the user's tolerances (the message has the numbers)."""

    def __init__(self, message: str, failures: list | None = None):
        self.failures = list(failures or [])
        super().__init__(message)


@dataclass(frozen=True)
class Tolerances:
    """Largest accepted differences (see ``docs/crosscheck.md``)."""

    points: float = 1e-6          # object points and projection centres, fraction of the object size
    angles: float = 1e-6          # rotation difference, rad
    residuals_px: float = 1e-4    # image residuals, pixels
    cost: float = 1e-8            # relative difference of ½ Σ ‖v/σ‖²
    intrinsics: float = 1e-4      # camera parameters, in units of baarda's a-posteriori σ
    covariance: float = 1e-3      # relative difference of standard deviations (poses, intrinsics)


@dataclass
class CrossCheck:
    """Both solutions and their differences.

    ``quantities`` maps a name (points, centres, angles, residuals, cost, intrinsics,
    covariance_poses, covariance_intrinsics) to ``{"max", "rms", "unit", "n", "exact", ...}``;
    ``exact`` says whether the two must agree to rounding (tolerances apply only then).
    """

    plan: CrossCheckPlan
    pycolmap: dict
    solution: PycolmapSolution
    quantities: dict
    cameras: list                  # per compared camera parameter: dict rows for the table
    object_size: float
    start: str
    baarda_cost: float
    notes: list = field(default_factory=list)


def start_values(result, start: str = "initial", rng: np.random.Generator | None = None,
                 perturbation: float = 1e-2):
    """The block pycolmap starts from.

    ``"initial"`` — the bundle's input block (its initial values, completed by the bundle's
    resection/intersection exactly as :func:`baarda.pipeline.adjustment.adjust` does when some are missing);
    ``"perturbed"`` — baarda's adjusted poses and points disturbed by normal draws from ``rng``:
    σ = ``perturbation`` × object size for projection centres and free points, ``perturbation``
    rad for ω φ κ; intrinsics at the input block's values.
    """
    block = result.block_in
    if start == "initial":
        need = (~block.photos.has_orientation).any() or (~np.isfinite(block.points.XYZ).all(axis=1)).any()
        if need:
            from baarda.pipeline.adjustment import initial_values

            block = initial_values(block, ap_meta=result.settings.ap_meta)
        return block
    if start != "perturbed":
        raise ValueError(f"start must be 'initial' or 'perturbed', got {start!r}")
    if rng is None:
        raise ValueError("start='perturbed' needs an rng")
    adj = result.block
    size = object_size(result)
    ph, pts = adj.photos, adj.points
    var_ph = np.isinf(ph.sigma_eo)
    var_pt = np.isinf(pts.sigma)
    X0 = ph.X0 + perturbation * size * rng.standard_normal(ph.X0.shape) * var_ph[:, :3]
    opk = ph.opk + perturbation * rng.standard_normal(ph.opk.shape) * var_ph[:, 3:]
    XYZ = pts.XYZ + perturbation * size * rng.standard_normal(pts.XYZ.shape) * var_pt
    return adj.replace(cameras=block.cameras, photos=ph.replace(X0=X0, opk=opk), points=pts.replace(XYZ=XYZ))


def object_size(result) -> float:
    """Diagonal of the bounding box of the adjusted points in the adjustment (object units)."""
    XYZ = result.state.XYZ[result.point_used]
    XYZ = XYZ[np.isfinite(XYZ).all(axis=1)]
    if len(XYZ) < 2:
        X0 = result.state.X0[result.photo_used]
        XYZ = np.vstack([XYZ, X0]) if len(X0) else XYZ
    return float(np.linalg.norm(XYZ.max(axis=0) - XYZ.min(axis=0))) if len(XYZ) >= 2 else 1.0


def _stats(d: np.ndarray) -> tuple[float, float]:
    d = np.asarray(d, float)
    d = d[np.isfinite(d)]
    if d.size == 0:
        return float("nan"), float("nan")
    return float(np.max(np.abs(d))), float(np.sqrt(np.mean(d * d)))


def crosscheck(result, *, start: str = "initial", rng: np.random.Generator | None = None,
               perturbation: float = 1e-2, solver: SolverSettings | None = None) -> CrossCheck:
    """Solve ``result``'s problem with pycolmap and compare (see ``docs/crosscheck.md``).

    Parameters
    ----------
    result : a converged :class:`baarda.pipeline.adjustment.BundleResult` (with covariances, for the σ's).
    start : ``"initial"`` or ``"perturbed"`` (see :func:`start_values`).
    rng : generator for ``"perturbed"``.
    solver : Ceres settings (:class:`baarda.plugins.crosscheck.pycolmap_ba.SolverSettings`).
    """
    solver = solver or SolverSettings()
    plan = plan_crosscheck(result)
    begin = start_values(result, start, rng, perturbation)
    rec, recmap = build_reconstruction(result, plan, begin)
    summary, adjuster = solve_pycolmap(rec, recmap, plan, solver)
    sol = read_solution(rec, recmap, plan.sigma_mm, result.block_in)
    cov = estimate_covariance(rec, adjuster, recmap, plan, result.block_in) if solver.covariance else {}
    solution = PycolmapSolution(X0=sol["X0"], opk=sol["opk"], XYZ=sol["XYZ"], cam=sol["cam"],
                                residuals=sol["residuals"], initial_cost=summary["initial_cost"],
                                final_cost=summary["final_cost"], iterations=summary["iterations"],
                                termination=summary["termination"], seconds=summary["seconds"],
                                setup_seconds=summary["setup_seconds"], cov_eo=cov.get("cov_eo"),
                                cov_cameras=cov.get("cov_cameras"), covariance_seconds=cov.get("seconds", np.nan),
                                message=summary["message"],
                                extra={"covariance_error": cov.get("error"), "size": recmap.size,
                                       "sensor": sol.get("sensor")})
    return _compare(result, plan, solution, summary, start)


def _compare(result, plan: CrossCheckPlan, sol: PycolmapSolution, summary: dict, start: str) -> CrossCheck:
    block = result.block_in
    st = result.state
    size = object_size(result)
    exact = plan.exact
    q = {}
    notes = list(plan.notes)
    unit = block.object_unit

    pv = plan.point_variable
    d = np.linalg.norm(sol.XYZ[pv] - st.XYZ[pv], axis=1)
    mx, rms = _stats(d)
    q["points"] = {"max": mx, "rms": rms, "unit": unit, "n": int(pv.sum()), "relative": mx / size, "exact": exact}
    ph = plan.photo_variable
    d = np.linalg.norm(sol.X0[ph] - st.X0[ph], axis=1)
    mx, rms = _stats(d)
    q["centres"] = {"max": mx, "rms": rms, "unit": unit, "n": int(ph.sum()), "relative": mx / size, "exact": exact}
    ang = rotation_angle(sol.opk[ph], st.opk[ph]) if ph.any() else np.zeros(0)
    mx, rms = _stats(ang)
    q["angles"] = {"max": mx, "rms": rms, "unit": "rad", "n": int(ph.sum()), "exact": exact}

    # residuals in pixels (the camera's pixel, or its σ when it has none)
    obs = block.observations
    used = plan.obs_used
    cam = block.photos.camera[obs.photo]
    has_pixel = np.isfinite(block.cameras.pixel_mm) & (block.cameras.pixel_mm > 0)
    pitch = np.where(has_pixel, block.cameras.pixel_mm, plan.sigma_mm)
    dv = (sol.residuals[used] - result.residuals[used]) / pitch[cam[used]][:, None]
    mx, rms = _stats(dv.ravel())
    with_pixel = has_pixel[cam[used]]
    runit = "px" if with_pixel.all() else ("σ" if not with_pixel.any() else "px (σ without pixel pitch)")
    q["residuals"] = {"max": mx, "rms": rms, "unit": runit, "n": int(used.sum()), "exact": exact,
                      "max_um": float(np.nanmax(np.abs(sol.residuals[used] - result.residuals[used]))) * 1e3
                      if used.any() else float("nan")}
    # cost ½ Σ ‖v/σ_j‖² (pycolmap's own, in its pixels = σ)
    w = result.residuals[used] / plan.sigma_mm[cam[used]][:, None]
    cost_b = 0.5 * float(np.sum(w * w))
    # relative to the larger cost; error-free data (a planned network: cost 0) against a floor of
    # 1e-12 σ² per observation instead of 1e-300 (which printed a relative difference of 1e+279)
    rel = abs(sol.final_cost - cost_b) / max(cost_b, sol.final_cost, 1e-12 * max(int(used.sum()), 1))
    q["cost"] = {"max": rel, "rms": rel, "unit": "relative", "n": 1, "exact": exact,
                 "baarda": cost_b, "pycolmap": sol.final_cost, "pycolmap_initial": sol.initial_cost}

    # intrinsics of refined cameras, in units of baarda's σ
    rows = []
    for p in plan.cameras:
        if not p.refined:
            continue
        j = p.index
        names = result.cam_param_names[j]
        pc = sol.cam[j]
        vals = {"c": pc["c"], "xp": pc["xp"], "yp": pc["yp"],
                **dict(zip(pc.get("names", ("K1", "K2", "K3", "P1", "P2", "B1", "B2")), pc["ap"]))}
        units = camera_parameter_units(result.block_in.cameras.ap_model[j], len(names) - 3)     # mm, mm⁻² …
        for t, name in enumerate(names):
            if not np.isinf(result.camera_sigma[j, t]):
                continue
            b = float(st.cam_params[j, t])
            s = float(np.sqrt(max(result.cov_cameras[j][t, t], 0.0)))
            diff = float(vals[name]) - b
            rows.append({"camera": p.id, "parameter": name, "baarda": b, "pycolmap": float(vals[name]),
                         "difference": diff, "sigma_baarda": s, "unit": units[t],
                         "difference_sigma": diff / s if s > 0 else np.nan})
    ds = np.array([r["difference_sigma"] for r in rows], float)
    iunit = "σ"
    if rows and not np.isfinite(ds).any():      # the bundle computed no covariance: relative to the value
        ds = np.array([r["difference"] / abs(r["baarda"]) if r["baarda"] != 0 else np.nan for r in rows], float)
        iunit = "relative"
        notes.append("baarda's result has no covariance: camera parameters compared relative to their values")
    mx, rms = _stats(ds)
    q["intrinsics"] = {"max": mx, "rms": rms, "unit": iunit, "n": len(rows), "exact": exact}
    if sol.extra.get("sensor") is not None and plan.sensor_constant is not None:
        q["rig_sensors"] = _sensor_differences(result, plan, sol.extra["sensor"], exact)

    # covariances: pycolmap's (σ = 1 of its pixel = σ0 1) scaled by the same variance factor as baarda's
    dof = result.dof
    var = 2.0 * sol.final_cost / dof if dof > 0 else 1.0
    cmp_cov = plan.covariance_comparable
    if sol.cov_eo is not None:
        sp = np.sqrt(np.clip(np.einsum("mii->mi", sol.cov_eo[ph]), 0, None) * var)
        sb = result.eo_sigmas()[ph]
        ok = np.isfinite(sp) & (sb > 0)
        r = sp[ok] / sb[ok] - 1.0
        mx, rms = _stats(r)
        q["covariance_poses"] = {"max": mx, "rms": rms, "unit": "relative σ", "n": int(ok.sum()),
                                 "exact": cmp_cov}
        rr = []
        for j, (names, C) in (sol.cov_cameras or {}).items():
            idx = [result.cam_param_names[j].index(n) for n in names]
            sb = np.sqrt(np.clip(np.diag(result.cov_cameras[j])[idx], 0, None))
            sp = np.sqrt(np.clip(np.diag(C), 0, None) * var)
            good = sb > 0
            rr.extend((sp[good] / sb[good] - 1.0).tolist())
            for row in rows:
                if row["camera"] == plan.cameras[j].id and row["parameter"] in names:
                    row["sigma_pycolmap"] = float(sp[names.index(row["parameter"])])
        mx, rms = _stats(np.array(rr))
        q["covariance_intrinsics"] = {"max": mx, "rms": rms, "unit": "relative σ", "n": len(rr), "exact": cmp_cov}
        if not cmp_cov:
            notes.append("covariances not comparable (pycolmap's problem holds parameters baarda adjusts, or the "
                         "gauge/weights differ): shown for information")
    elif sol.extra.get("covariance_error"):
        notes.append(f"pycolmap covariance: {sol.extra['covariance_error']}")
    if not exact:
        notes.append("the two problems are not equivalent (see above): differences are reported, tolerances not "
                     "applied")
    return CrossCheck(plan=plan, pycolmap=summary, solution=sol, quantities=q, cameras=rows, object_size=size,
                      start=start, baarda_cost=cost_b, notes=notes)


def _sensor_differences(result, plan: CrossCheckPlan, sensor: np.ndarray, exact: bool) -> dict:
    """pycolmap's estimated sensor_from_rig poses against baarda's, in baarda's σ (docs/rigs.md)."""
    rr = rig_result(result)
    d = []
    for i, s in enumerate(rr.sensors):
        if s.reference_sensor or plan.sensor_constant[i]:
            continue
        diff = sensor[i] - s.value
        diff[3:] = (diff[3:] + np.pi) % (2 * np.pi) - np.pi
        sg = s.sigma
        d.append(np.where(sg > 0, diff / np.where(sg > 0, sg, 1.0), np.nan))
    ds = np.concatenate(d) if d else np.zeros(0)
    mx, rms = _stats(ds)
    return {"max": mx, "rms": rms, "unit": "σ", "n": len(d), "exact": exact}


def exceeded(cc: CrossCheck, tol: Tolerances) -> list[str]:
    """Human-readable list of the exact quantities whose difference exceeds its tolerance."""
    q = cc.quantities
    out = []

    def check(name, value, limit, text):
        if q.get(name, {}).get("exact") and np.isfinite(value) and value > limit:
            out.append(text)

    unit = q["points"]["unit"]
    for name, label in (("points", "object points"), ("centres", "projection centres")):
        v = q[name]
        check(name, v["relative"], tol.points,
              f"{label}: max {v['max']:.3g} {unit} = {v['relative']:.3g} of the object size "
              f"({cc.object_size:.4g} {unit}); tolerance {tol.points:g}")
    v = q["angles"]
    check("angles", v["max"], tol.angles, f"rotations: max {v['max']:.3g} rad; tolerance {tol.angles:g} rad")
    v = q["residuals"]
    check("residuals", v["max"], tol.residuals_px,
          f"image residuals: max {v['max']:.3g} {v['unit']} ({v['max_um']:.3g} µm); tolerance {tol.residuals_px:g}")
    v = q["cost"]
    check("cost", v["max"], tol.cost,
          f"final cost ½Σ(v/σ)²: baarda {v['baarda']:.10g}, pycolmap {v['pycolmap']:.10g} "
                                      f"(relative {v['max']:.3g}); tolerance {tol.cost:g}")
    v = q["intrinsics"]
    if v["n"]:
        worst = max(cc.cameras, key=lambda r: abs(r["difference"]) / (r["sigma_baarda"] or abs(r["baarda"]) or 1.0))
        u = v["unit"]
        check("intrinsics", v["max"], tol.intrinsics,
              f"camera parameters: max {v['max']:.3g} {u} (camera {worst['camera']} {worst['parameter']}: baarda "
              f"{worst['baarda']:.9g}, pycolmap {worst['pycolmap']:.9g}); tolerance {tol.intrinsics:g} {u}")
    v = q.get("rig_sensors")
    if v and v["n"]:
        check("rig_sensors", v["max"], tol.intrinsics,
              f"rig sensor poses: max {v['max']:.3g} σ of baarda's; tolerance {tol.intrinsics:g} σ")
    for name, label in (("covariance_poses", "pose standard deviations"),
                        ("covariance_intrinsics", "camera-parameter standard deviations")):
        if name in q and q[name]["n"]:
            v = q[name]
            check(name, v["max"], tol.covariance,
                  f"{label}: max relative difference {v['max']:.3g}; tolerance {tol.covariance:g}")
    return out
