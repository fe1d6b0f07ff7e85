"""The congruence stage's figure: plan displacement vectors with their confidence ellipses and MDD
circles, and below it the displacement along Z of every point with its 95 % interval (a movement
along the viewing direction or a height change does not show in the plan)."""

from __future__ import annotations

import numpy as np

from baarda.pipeline.units import fmt_num, fmt_q


def displacement_figure(c):
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Ellipse

    r, ref, ep = c["result"], c["ref"], c["epoch"]
    X = ep.XYZ[c["ib"], :2]
    d = c["d"][:, :2]
    s0 = r.sigma0
    span = float(np.ptp(X, axis=0).max()) or 1.0
    scale_ref = max(float(np.max(np.linalg.norm(d, axis=1))), max(p.mdd for p in r.points), 1e-300)
    scale = 0.12 * span / scale_ref
    fig, (ax, az) = plt.subplots(2, 1, figsize=(7.5, 8.0), gridspec_kw={"height_ratios": [3, 1.2]})
    colours = {"moved": "#c0392b", "stable": "#1f4e9c", "object point": "#7f8c8d"}
    for k, p in enumerate(r.points):
        col = colours[c["status"][k]]
        x, y = X[k]
        ax.add_patch(Circle((x, y), p.mdd * scale, fill=False, ls=":", lw=0.8, color="#999999"))
        C = p.Q[:2, :2] * s0 * s0
        w, V = np.linalg.eigh(C)
        ang = np.degrees(np.arctan2(V[1, 1], V[0, 1]))
        k95 = np.sqrt(5.991)
        ax.add_patch(Ellipse((x + d[k, 0] * scale, y + d[k, 1] * scale), 2 * k95 * np.sqrt(max(w[1], 0)) * scale,
                             2 * k95 * np.sqrt(max(w[0], 0)) * scale, angle=ang, fill=False, color=col, lw=0.8))
        ax.annotate("", (x + d[k, 0] * scale, y + d[k, 1] * scale), (x, y),
                    arrowprops=dict(arrowstyle="->", color=col, lw=1.2))
        ax.plot([x], [y], "o", ms=3, color=col)
        ax.text(x, y, f" {c['common'][k]}", fontsize=7, color=col, va="bottom")
    u = ref.object_unit
    ax.set_aspect("equal")
    ax.set_xlabel(f"X [{u}]")
    ax.set_ylabel(f"Y [{u}]")
    ax.set_title(f"Plan displacements {ref.name} → {ep.name} (arrows × {fmt_num(scale, 3)}); 95 % ellipses,\n"
                 f"dotted circles: MDD (largest {fmt_q(max(p.mdd for p in r.points), u)}); red: moved",
                 fontsize=9)
    ax.margins(0.1)
    _z_panel(az, c, colours, u)
    fig.tight_layout()
    return fig


def _z_panel(az, c, colours, u):
    """dZ of each common point with ±1.96 σ, moved points in red."""
    r = c["result"]
    s0 = r.sigma0
    dz = np.asarray(c["d"])[:, 2]
    sz = np.array([np.sqrt(max(p.Q[2, 2], 0.0)) * s0 for p in r.points])
    f, du = (1e3, "mm") if u == "m" and np.nanmax(np.abs(dz) + 1.96 * sz) < 0.1 else (1.0, u)
    dz, sz = dz * f, sz * f
    k = np.arange(len(dz))
    cols = [colours[st] for st in c["status"]]
    az.axhline(0.0, color="#999999", lw=0.6)
    az.errorbar(k, dz, yerr=1.96 * sz, fmt="none", ecolor="#bbbbbb", elinewidth=0.8)
    az.scatter(k, dz, s=12, c=cols, zorder=3)
    if len(k) <= 40:
        az.set_xticks(k, [str(x) for x in c["common"]], fontsize=7, rotation=0 if len(k) <= 25 else 90)
    else:
        az.set_xlabel("point (in the order of the table)")
    az.set_ylabel(f"dZ [{du}]")
    az.set_title("Displacement along Z with its 95 % interval (±1.96 σ)", fontsize=9)
