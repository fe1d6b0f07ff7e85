"""Stage ``design-montecarlo``: what its report says and its figures draw (the stages are
:mod:`.stage`, the realisations and tests :mod:`.network`, the drawing :mod:`.figures`)."""

from __future__ import annotations

import numpy as np

from baarda.pipeline.adjustment import own_effects, row_mdb
from baarda.pipeline.geometry import rotation_from_opk_many
from baarda.pipeline.report import markdown_table
from baarda.pipeline.stats.critical import delta0 as _delta0
from baarda.pipeline.stats.ellipses import plan_ellipses


def viewing_directions(opk) -> np.ndarray:
    """(m, 3) unit viewing directions of the stations in object space: the camera's −z axis
    (a point in front has W < 0), i.e. minus the third row of ``R_cam_from_world``."""
    return -rotation_from_opk_many(opk)[:, 2, :]


def figure_data(res, cov_points, free_pt, delta0: float | None = None) -> dict:
    """What the design-montecarlo figures draw, from the prediction ``res`` (the bundle of the plan):
    the planned network, the points' standard error ellipses in plan (X, Y) and elevation (X, Z) from
    σ0² Q (``a``, ``b``, bearing in degrees: :func:`plan_ellipses`), and per target the internal and
    external reliability of its image rows: the smallest redundancy number, the largest MDB (δ0 σ0 /
    √(PQvvP)ᵢᵢ, px) and the largest effect of an MDB on the target's own coordinates (object units and
    in its predicted σ).  ``delta0`` defaults to δ0(0.1 %, 80 %)."""
    block = res.block_in
    d0 = _delta0() if delta0 is None else float(delta0)
    C = np.asarray(cov_points, float)
    xz = C[:, [0, 2, 1]][:, :, [0, 2, 1]]
    n = len(block.points)
    obs = block.observations
    act = np.asarray(res.row_active, bool)                            # (k, 2)
    tgt = np.repeat(obs.point[:, None], 2, axis=1)
    px = np.asarray(block.cameras.pixel_mm, float)[block.photos.camera[obs.photo]][:, None]
    if res.snapshot is None:                                          # no precision: no reliability
        r = mdb_px = vp = sp = np.full(act.shape, np.nan)
    else:
        r = np.asarray(res.snapshot.r, float).reshape(-1, 2)
        mdb_px = row_mdb(res, d0) / px
        _, vp, sp, *_ = own_effects(res, d0).largest()
    r_min = np.full(n, np.inf)
    np.minimum.at(r_min, tgt[act], r[act])
    mdb_max = np.full(n, -np.inf)
    np.maximum.at(mdb_max, tgt[act], mdb_px[act])
    eff = np.where(act & np.isfinite(sp), np.abs(vp), -np.inf)
    eff_max = np.full(n, -np.inf)
    np.maximum.at(eff_max, tgt, eff)
    effs = np.where(act & np.isfinite(sp), sp, -np.inf)
    eff_sig = np.full(n, -np.inf)
    np.maximum.at(eff_sig, tgt, effs)
    clean = lambda a: np.where(np.isfinite(a), a, np.nan)
    return {"ids": np.asarray(block.points.ids), "role": np.asarray(block.points.role),
            "XYZ": np.array(res.state.XYZ, float), "X0": np.array(res.state.X0, float),
            "view": viewing_directions(res.state.opk), "used": np.asarray(res.point_used, bool),
            "free": np.asarray(free_pt), "object_unit": block.object_unit,
            "ellipse_xy": np.column_stack(plan_ellipses(C)), "ellipse_xz": np.column_stack(plan_ellipses(xz)),
            "r_rows": r[act & np.isfinite(r)], "delta0": d0, "r_min": clean(r_min), "mdb_max_px": clean(mdb_max),
            "effect_max": clean(eff_max), "effect_max_sigma": clean(eff_sig)}


def correlated(res, rho_max):
    out = []
    for j, names in enumerate(res.cam_param_names):
        C = res.cov_cameras[j]
        d = np.sqrt(np.clip(np.diag(C), 0, None))
        for a in range(len(names)):
            for b in range(a + 1, len(names)):
                if d[a] > 0 and d[b] > 0:
                    r = C[a, b] / (d[a] * d[b])
                    if abs(r) > rho_max:
                        out.append((names[a], names[b], float(r)))
    return out


def headline(block, free_pt, sig_pts, mc) -> str:
    """One line for ``baarda review``: the predicted median σ of the points (mm, as the report), then
    the realisations' mean σ̂0, the points' rms ratio realised/predicted and the joint test's p."""
    k = 1000.0 if block.object_unit == "m" else 1.0
    med = np.median(sig_pts[free_pt] * k, axis=0) if free_pt.size else np.full(3, np.nan)
    out = f"predicted median σ X, Y, Z {', '.join(f'{v:.3g}' for v in med)} mm"
    if mc is None:
        return out + "; no realisations"
    tp = mc["points"]
    out += (f"; {tp.n} realisations: mean σ̂0 {np.mean(mc['sigma0_hat']):.3f}, rms ratio {tp.pooled_ratio:.3f} "
            f"({int(tp.rejected.sum())}/{tp.ratio.size} outside)")
    if "joint" in mc:
        out += f", joint test p = {mc['joint']['p']:.3f}"
    return out


def report(block, res, free_pt, sig_pts, cam_rows, sig_cam, pairs, mc, o) -> str:
    unit = block.object_unit
    k = 1000.0 if unit == "m" else 1.0
    s = sig_pts[free_pt] * k
    lines = [f"Predicted precision (σ0² Q, σ0 = {res.sigma0:g}) of {free_pt.size} estimated points: "
             f"median σ X, Y, Z = {', '.join(f'{v:.3g}' for v in np.median(s, axis=0))} mm, "
             f"largest {', '.join(f'{v:.3g}' for v in s.max(axis=0))} mm.", ""]
    if cam_rows:
        lines += ["Camera parameters (predicted σ):", "",
                  markdown_table(["parameter", "σ"], [[nm, float(v)] for (*_, nm), v in zip(cam_rows, sig_cam)],
                                 floatfmt=".3g"), ""]
    if pairs:
        lines += [f"Poorly separable (|ρ| > {o.rho_max}): " + ", ".join(f"{a}–{b} ({r:+.2f})" for a, b, r in pairs)
                  + ". A parameter the network cannot determine at all makes the bundle stop and name it.", ""]
    else:
        lines += [f"No two camera parameters correlate beyond |ρ| = {o.rho_max}.", ""]
    if mc is not None:
        tp, tc = mc["points"], mc["cameras"]
        lines += [f"Monte Carlo: {tp.n} realisations (image noise and weighted control from the a-priori σ), each "
                  "adjusted from the plan. Ratio realised/predicted σ per component, accepted in "
                  f"[{tp.lower:.3f}, {tp.upper:.3f}] (χ²({tp.n}), α = {o.alpha}):", "",
                  markdown_table(["", "components", "rms ratio", "outside", "expected outside", "pooled p"], [
                      ["points", tp.ratio.size, tp.pooled_ratio, int(tp.rejected.sum()),
                       round(o.alpha * tp.ratio.size, 1), tp.pooled_p],
                      ["camera", tc.ratio.size, tc.pooled_ratio, int(tc.rejected.sum()),
                       round(o.alpha * tc.ratio.size, 1), tc.pooled_p]], floatfmt=".3f"), "",
                  f"Mean σ̂0 of the realisations: {np.mean(mc['sigma0_hat']):.3f} (expected 1). The pooled p treats "
                  "components as independent; points of one network are correlated, so it is indicative only."]
        if "joint" in mc:
            jt = mc["joint"]
            rank = "" if jt["rank"] == tc.ratio.size + tp.ratio.size else f" (rank {jt['rank']}: the datum's defect)"
            lines += ["", f"Joint test of all {tc.ratio.size + tp.ratio.size} estimated coordinates and camera "
                      f"parameters with their full predicted covariance{rank}: mean eᵀC⁺e / k = "
                      f"{jt['normalised']:.3f} (1 expected), "
                      f"χ²({jt['dof']}) = {jt['statistic']:.1f}, two-sided p = {jt['p']:.3f}."]
        lines.append("")
    return "\n".join(lines)
