"""The design stages' figures for ``report.html`` (matplotlib, drawn by the engine with Agg).

Only called from the stages' ``plots`` hooks (``plugins/design/stage.py``); every number drawn is
in the stage's result (``StageResult.data``): the planned network and its rays (``design``), the
predicted σ0² Q, its error ellipses and the plan's reliability, and the Monte Carlo realisations
(``design-montecarlo``).  Shared pieces come from :mod:`baarda.pipeline.plots` (the redundancy
histogram) and the recordings' role colours.
"""

from __future__ import annotations

import numpy as np
from scipy import stats as sps

from baarda.pipeline.plots import redundancy_numbers, role_colour, role_points
from baarda.pipeline.units import fmt_num

VIEWS = ((0, 1, "plan (X, Y)"), (0, 2, "elevation (X, Z)"))
XYZ_COLORS = ("#1f4e9c", "#d35400", "#2e8b57")


def _plt():
    import matplotlib.pyplot as plt

    return plt


def _mm(unit: str) -> float:
    """Object units → mm."""
    return 1000.0 if unit == "m" else 1.0


def _stations(ax, X0, view, ids, i, j, length, labels=True):
    """Projection centres with their viewing direction (an arrow of ``length`` object units)."""
    ax.plot(X0[:, i], X0[:, j], "s", ms=6, color="k", ls="none", label=f"stations ({len(X0)})", zorder=4)
    ax.quiver(X0[:, i], X0[:, j], length * view[:, i], length * view[:, j], angles="xy", scale_units="xy", scale=1,
              color="k", width=0.004, zorder=4)
    if labels and ids is not None:
        for s, x, y in zip(ids, X0[:, i], X0[:, j]):
            ax.annotate(str(s), (x, y), fontsize=7, xytext=(-4, 5), textcoords="offset points", ha="right")


def _frame(ax, i, j, name, unit):
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(name, fontsize=10)
    ax.set_xlabel(f"{'XYZ'[i]} ({unit})")
    ax.set_ylabel(f"{'XYZ'[j]} ({unit})")
    ax.tick_params(labelsize=8)


def _span(*arrays) -> float:
    A = np.vstack([np.asarray(a, float).reshape(-1, 3) for a in arrays])
    A = A[np.isfinite(A).all(axis=1)]
    return max(float(np.ptp(A, axis=0).max()) if len(A) > 1 else 0.0, 1e-9)


# ------------------------------------------------------------------------------------------ design
def plan_figures(data: dict) -> dict:
    """``design``: the planned network with its rays, and the rays per target / points per station."""
    block = data["block"]
    return {"plan": (planned_network(block, data["view"]),
                     "The planned network: stations (■, the arrow is the viewing direction) and targets by role in "
                     "plan and elevation; grey lines are the planned rays (every target inside the format less the "
                     "margin)."),
            "rays": (rays(block, data["rays"], data["per_station"]),
                     "Planned rays per target (a target needs 2, control excepted) and planned image points per "
                     "station (a photo needs 3).")}


def planned_network(block, view):
    plt = _plt()
    from matplotlib.collections import LineCollection

    pts, ph, obs = block.points, block.photos, block.observations
    XYZ, X0 = np.asarray(pts.XYZ, float), np.asarray(ph.X0, float)
    unit = block.object_unit
    L = 0.12 * _span(XYZ, X0)
    fig, axes = plt.subplots(1, 2, figsize=(12.5, 5.4))
    for ax, (i, j, name) in zip(axes, VIEWS):
        segs = np.stack([X0[obs.photo][:, [i, j]], XYZ[obs.point][:, [i, j]]], axis=1)
        ax.add_collection(LineCollection(segs, colors="#bbbbbb", linewidths=0.4, zorder=1,
                                         label=f"planned rays ({len(obs)})"))
        role_points(ax, XYZ, pts.role, np.ones(len(pts), bool), i, j, ms=6, ms_tie=4, zorder=3)
        _stations(ax, X0, view, ph.ids if j == 1 else None, i, j, L)     # ids in plan only (elevation: stacked)
        ax.autoscale_view()
        _frame(ax, i, j, name, unit)
    h, lab = axes[0].get_legend_handles_labels()
    fig.legend(h, lab, fontsize=8, loc="lower center", ncol=min(len(lab), 4), frameon=False)
    fig.suptitle(f"Planned network: {len(ph)} stations, {len(pts)} targets, {len(obs)} planned image points",
                 fontsize=11)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    return fig


def rays(block, n_rays, per_station):
    plt = _plt()
    pts, ph = block.points, block.photos
    n_rays, per_station = np.asarray(n_rays), np.asarray(per_station)
    fig, (a, b) = plt.subplots(1, 2, figsize=(12.5, 3.6), gridspec_kw={"width_ratios": [max(len(pts), 4),
                                                                                          max(len(ph), 4) + 4]})
    x = np.arange(len(pts))
    a.bar(x, n_rays, color=[role_colour(r) for r in pts.role], ec="#333", lw=0.3)
    a.axhline(2, color="#c0392b", ls="--", lw=1)
    a.set_xticks(x, [str(i) for i in pts.ids], fontsize=7, rotation=90)
    a.set_xlim(-0.6, len(pts) - 0.4)
    a.set_xlabel("target (colour: role)")
    a.set_ylabel("rays (stations)")
    a.set_title(f"Rays per target: {n_rays.min()}–{n_rays.max()}, mean {np.mean(n_rays):.2f} (dashed: the minimum 2)",
                fontsize=10)
    y = np.arange(len(ph))
    b.bar(y, per_station, color="#5b7fb5")
    b.axhline(3, color="#c0392b", ls="--", lw=1)
    b.set_xticks(y, [str(i) for i in ph.ids], fontsize=7, rotation=90 if len(ph) > 12 else 0)
    b.set_xlabel("station")
    b.set_ylabel("image points")
    b.set_title("Image points per station\n(dashed: the minimum 3)", fontsize=10)
    fig.tight_layout()
    return fig


# ------------------------------------------------------------------------------ design-montecarlo
def montecarlo_figures(data: dict) -> dict:
    """``design-montecarlo``: the network with the predicted ellipses (and the realised errors), the
    predicted σ per point (and the realised), the plan's reliability, the Monte Carlo against N(0, 1)."""
    f = data["figures"]
    mc = data.get("montecarlo")
    d0 = f["delta0"]
    out = {"network": (predicted_network(f, mc),
                       "The planned network with the points' predicted standard error ellipses (σ0² Q of the plan, "
                       "one common exaggeration)" + (" and the Monte Carlo realisations' errors at the same scale "
                                                     "(dots)" if mc is not None else "") + "."),
           "precision": (precision(f, data["predicted_points"], mc),
                         "Predicted σX, σY, σZ of every estimated point (bars)" +
                         ("; the Monte Carlo's realised σ, √(Σe²/N), as black dots." if mc is not None else "."))}
    if len(f["r_rows"]):
        out["redundancy"] = (redundancy_numbers(f["r_rows"], title="Planned redundancy numbers r = (Qvv P)ii"),
                             "Redundancy numbers of the planned image rows (x and y of every planned image point).")
        out["reliability"] = (reliability(f),
                              f"Reliability of the plan per target: the smallest redundancy number of its image "
                              f"rows, the largest MDB (δ0 = {d0:.3g}, α0 = 0.1 %, β0 = 80 %) of its image rows and "
                              "the largest effect of such an MDB on the target's own coordinates, in mm and in its "
                              "predicted σ (fixed control: no effect).")
    if mc is not None:
        out["montecarlo"] = (montecarlo(f, data["predicted_points"], mc),
                             f"{mc['points'].n} noisy realisations of the plan, adjusted: every estimation error "
                             "of a point coordinate over its predicted σ against N(0, 1), and the realised σ "
                             "against the predicted per coordinate with the χ² acceptance band.")
    return out


def ellipse_scale(f: dict) -> float:
    """One exaggeration of the standard ellipses: the largest semi-axis is 4 % of the network's extent."""
    sel = f["free"]
    amax = np.nanmax(np.r_[f["ellipse_xy"][sel, 0], f["ellipse_xz"][sel, 0], 0.0])
    return 0.04 * _span(f["XYZ"][f["used"]], f["X0"]) / amax if amax > 0 else 1.0


def predicted_network(f: dict, mc=None):
    plt = _plt()
    from matplotlib.collections import EllipseCollection

    XYZ, X0, sel = f["XYZ"], f["X0"], f["free"]
    unit = f["object_unit"]
    k = ellipse_scale(f)
    L = 0.12 * _span(XYZ[f["used"]], X0)
    fig, axes = plt.subplots(1, 2, figsize=(12.5, 5.6))
    for ax, (i, j, name), key in zip(axes, VIEWS, ("ellipse_xy", "ellipse_xz")):
        if mc is not None:
            E = mc["errors_points"]                                       # (N, q, 3)
            P = XYZ[sel][None] + k * E
            ax.plot(P[..., i].ravel(), P[..., j].ravel(), ".", ms=1.5, color="#7f8c8d", alpha=0.6, zorder=2,
                    label=f"realised errors × {fmt_num(k, 3)} ({E.shape[0]} runs)")
        a, b, t = f[key][sel].T
        ax.add_collection(EllipseCollection(2 * k * a, 2 * k * b, t, units="xy", offsets=XYZ[sel][:, [i, j]],
                                            offset_transform=ax.transData, facecolors="none", edgecolors="#28a0a0",
                                            linewidths=1.0, zorder=3))
        ax.plot([], [], color="#28a0a0", label=f"predicted standard ellipses × {fmt_num(k, 3)}")
        role_points(ax, XYZ, f["role"], f["used"], i, j, ms=6, ms_tie=4, zorder=3)
        _stations(ax, X0, f["view"], None, i, j, L, labels=False)
        ax.update_datalim(np.vstack([XYZ[sel][:, [i, j]] + k * a.max(), XYZ[sel][:, [i, j]] - k * a.max()]))
        ax.autoscale_view()
        _frame(ax, i, j, name, unit)
    h, lab = axes[0].get_legend_handles_labels()
    fig.legend(h, lab, fontsize=8, loc="lower center", ncol=min(len(lab), 4), frameon=False)
    amax = _mm(unit) * np.nanmax(f["ellipse_xy"][sel, 0])
    fig.suptitle(f"Predicted precision of the plan: standard error ellipses × {fmt_num(k, 3)} (largest plan semi-axis "
                 f"{amax:.3g} mm)", fontsize=11)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    return fig


def precision(f: dict, sigma_points, mc=None):
    plt = _plt()
    sel = f["free"]
    s = _mm(f["object_unit"]) * np.asarray(sigma_points, float)[sel]          # (q, 3) mm
    ids = [str(i) for i in f["ids"][sel]]
    x = np.arange(len(sel))
    w = 0.27
    fig, ax = plt.subplots(figsize=(max(8.0, min(0.32 * len(sel) + 2, 18)), 4.0))
    for c in range(3):
        ax.bar(x + (c - 1) * w, s[:, c], width=w, color=XYZ_COLORS[c],
               label=f"σ{'XYZ'[c]} predicted (median {np.median(s[:, c]):.3g} mm)")
    if mc is not None:
        real = mc["points"].ratio.reshape(-1, 3) * s
        for c in range(3):
            ax.plot(x + (c - 1) * w, real[:, c], ".", color="k", ms=4, label="realised σ (Monte Carlo)" if c == 0 else None)
    ax.set_xticks(x, ids, fontsize=7, rotation=90)
    ax.set_xlim(-0.6, len(sel) - 0.4)
    ax.set_xlabel("point")
    ax.set_ylabel("σ (mm)")
    ax.set_title(f"Predicted precision of {len(sel)} estimated points; largest σX, σY, σZ "
                 f"{', '.join(f'{v:.3g}' for v in s.max(axis=0))} mm", fontsize=10)
    ax.legend(fontsize=8, ncol=2, loc="upper left", bbox_to_anchor=(0, -0.25), frameon=False)
    fig.tight_layout()
    return fig


def reliability(f: dict):
    plt = _plt()
    ids = [str(i) for i in f["ids"]]
    x = np.arange(len(ids))
    cols = [role_colour(r) for r in f["role"]]
    mm = _mm(f["object_unit"])
    panels = [(f["r_min"], "smallest r", "smallest redundancy number of the target's rows", ""),
              (f["mdb_max_px"], "largest MDB (px)", "largest MDB of the target's image rows", " px"),
              (mm * f["effect_max"], "effect (mm)", "largest effect of an MDB on the target's own coordinates",
               " mm"),
              (f["effect_max_sigma"], "effect / σ", "the same in the coordinate's predicted σ", " σ")]
    fig, axes = plt.subplots(len(panels), 1, figsize=(max(8.0, min(0.32 * len(ids) + 2, 18)), 8.4), sharex=True)
    for ax, (v, ylab, title, u) in zip(axes, panels):
        ax.bar(x, np.nan_to_num(v, nan=0.0), color=cols, ec="#333", lw=0.3)
        fin = np.isfinite(v)
        if fin.any():
            q = int(np.nanargmax(v)) if "smallest" not in ylab else int(np.nanargmin(v))
            title += f"; {'smallest' if 'smallest' in ylab else 'largest'} {v[q]:.3g}{u} at {ids[q]}"
        ax.set_ylabel(ylab)
        ax.set_title(title, fontsize=9)
        ax.tick_params(labelsize=7)
    axes[-1].set_xticks(x, ids, fontsize=7, rotation=90)
    axes[-1].set_xlim(-0.6, len(ids) - 0.4)
    axes[-1].set_xlabel("target (colour: role)")
    fig.suptitle("Reliability of the plan per target", fontsize=11)
    fig.tight_layout()
    return fig


def montecarlo(f: dict, sigma_points, mc):
    plt = _plt()
    sel = f["free"]
    sig = np.asarray(sigma_points, float)[sel]                                # (q, 3) object units
    E = mc["errors_points"]                                                   # (N, q, 3)
    z = (E / sig[None]).ravel()
    t = mc["points"]
    fig, (a, b) = plt.subplots(1, 2, figsize=(12.5, 4.4))
    lim = max(4.0, float(np.max(np.abs(z))) if z.size else 4.0)
    a.hist(z, bins=np.linspace(-lim, lim, 41), density=True, color="#8fb3de", ec="#4a6fa0", lw=0.5,
           label=f"error / predicted σ ({z.size})")
    xx = np.linspace(-lim, lim, 300)
    a.plot(xx, sps.norm.pdf(xx), color="k", lw=1.2, label="N(0, 1)")
    a.set_xlabel("estimation error / predicted σ")
    a.set_ylabel("density")
    a.set_title(f"{t.n} realisations × {sig.size} coordinates: mean {np.mean(z):+.3f}, sd {np.std(z):.3f}",
                fontsize=10)
    a.legend(fontsize=8)
    mm = _mm(f["object_unit"])
    pred = mm * sig
    real = t.ratio.reshape(-1, 3) * pred
    rej = t.rejected.reshape(-1, 3)
    lo, hi = float(np.min(pred)) * 0.9, float(np.max(pred)) * 1.1
    g = np.array([lo, hi])
    b.fill_between(g, t.lower * g, t.upper * g, color="#e8eef7", label=f"accepted ({1 - t.alpha:.0%}, χ²({t.n}))")
    b.plot(g, g, color="k", lw=0.8, label="realised = predicted")
    for c in range(3):
        b.plot(pred[:, c], real[:, c], "o", ms=4, color=XYZ_COLORS[c], ls="none", label=f"{'XYZ'[c]}")
    if rej.any():
        b.plot(pred[rej], real[rej], "o", ms=9, mfc="none", mec="#c0392b", ls="none",
               label=f"outside the band ({int(rej.sum())} of {rej.size}; {t.alpha * rej.size:.1f} expected)")
    b.set_xlim(lo, hi)
    b.set_ylim(0, max(hi * t.upper, float(np.max(real)) * 1.05))
    b.set_xlabel("predicted σ (mm)")
    b.set_ylabel("realised σ (mm)")
    b.set_title(f"per coordinate: rms ratio realised/predicted {t.pooled_ratio:.3f}", fontsize=10)
    b.legend(fontsize=7, loc="lower right")
    fig.suptitle("Monte Carlo against the prediction", fontsize=11)
    fig.tight_layout()
    return fig
