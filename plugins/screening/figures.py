"""helmert-screening's figure for report.html: the residuals of each pair's 2-D Helmert
transformation as vectors on the right photo, flagged points in red, and |w| per point."""

from __future__ import annotations

import numpy as np

from baarda.pipeline.units import fmt_num


def helmert_residuals(art) -> dict:
    import matplotlib.pyplot as plt

    out = {}
    for p in art.pairs:
        s = p.screening
        v = np.asarray(s.adjustment.v, float).reshape(-1, 2)
        xy = np.asarray(s.xy_right, float)
        flag = np.asarray(s.flagged, bool).reshape(-1, 2).any(axis=1)
        w = np.abs(np.asarray(s.snooping.w, float).reshape(-1, 2)).max(axis=1)
        fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.8), gridspec_kw={"width_ratios": [1.2, 1]})
        span = float(np.ptp(xy, axis=0).max()) or 1.0
        vmax = float(np.hypot(v[:, 0], v[:, 1]).max()) or 1.0
        k = 0.12 * span / vmax
        for m, col, lab in ((~flag, "#1f4e9c", "accepted"), (flag, "#c0392b", "flagged")):
            if m.any():
                a.quiver(xy[m, 0], xy[m, 1], k * v[m, 0], k * v[m, 1], angles="xy", scale_units="xy", scale=1,
                         color=col, width=0.005, label=lab)
        a.plot(xy[:, 0], xy[:, 1], ".", color="#555", ms=3)
        a.update_datalim(xy + k * v)         # quiver does not count the arrow heads in the limits
        a.autoscale_view()
        for i, (x, y) in zip(s.point_ids, xy):
            a.annotate(str(i), (x, y), fontsize=8, xytext=(3, 3), textcoords="offset points")
        a.set_aspect("equal", adjustable="datalim")
        a.legend(fontsize=8)
        a.set_title(f"{p.left} → {p.right}: residuals (observed − computed) × {fmt_num(k, 3)}; longest {vmax:.3g} mm",
                    fontsize=10)
        a.set_xlabel("x (mm)")
        a.set_ylabel("y (mm)")
        crit = float(s.snooping.critical)
        b.bar(np.arange(len(w)), w, color=np.where(flag, "#c0392b", "#8fb3de"))
        b.axhline(crit, color="k", ls="--", lw=1, label=f"critical {crit:.3g}")
        b.set_xticks(np.arange(len(w)), [str(i) for i in s.point_ids], fontsize=8)
        b.set_title("largest |w| of each point (data snooping)", fontsize=10)
        b.legend(fontsize=8)
        fig.tight_layout()
        out[f"residuals_{p.left}-{p.right}"] = (fig, f"Helmert screening {p.left} → {p.right}: residual vectors and |w|")
    return out
