"""Figures of the ``calibration-quality`` stage (matplotlib; the engine draws them with Agg)."""

from __future__ import annotations

import numpy as np

from baarda.pipeline.units import fmt_obj, fmt_q


def _extent(x, y):
    dx, dy = x[1] - x[0], y[0] - y[1]
    return [x[0] - dx / 2, x[-1] + dx / 2, y[-1] - dy / 2, y[0] + dy / 2]


def _map(ax, fig, x, y, z, title, unit, lims=None, axes=None):
    """``axes``: ``(fx, cx, fy, cy, label unit)`` taking the grid's mm (x right, y up) to the axes'
    coordinates (pixels of a pixel source: u = fx·x + cx, v = fy·y + cy, y down); None: mm.
    ``z`` on a logarithmic colour scale (σ spans orders of magnitude between the centre and
    corners the board never reached), with contours at 1-2-5 steps."""
    from matplotlib.colors import LogNorm

    fx, cx, fy, cy, au = axes or (1.0, 0.0, 1.0, 0.0, "mm")
    x, y = fx * np.asarray(x, float) + cx, fy * np.asarray(y, float) + cy
    fin = z[np.isfinite(z) & (z > 0)]
    lo, hi = lims if lims is not None else ((fin.min(), fin.max()) if fin.size else (1e-3, 1.0))
    hi = max(hi, lo * 1.01)
    im = ax.imshow(np.where(z > 0, z, np.nan), extent=_extent(x, y), origin="upper", cmap="viridis",
                   norm=LogNorm(vmin=lo, vmax=hi))
    levels = [m * 10.0 ** e for e in range(int(np.floor(np.log10(lo))), int(np.ceil(np.log10(hi))) + 1)
              for m in (1, 2, 5) if lo < m * 10.0 ** e < hi]
    if fin.size > 4 and levels:
        cs = ax.contour(x, y, z, levels=levels, colors="w", linewidths=0.6)
        ax.clabel(cs, fontsize=7, fmt="%.3g")
    ax.set_title(title, fontsize=9)
    ax.set_xlabel(f"x [{au}]")
    ax.set_ylabel(f"y [{au}]" + (" (down)" if fy < 0 else ""))
    ax.set_aspect("equal")
    fig.colorbar(im, ax=ax, shrink=0.8, label=unit)


def quality_figures(data: dict) -> dict:
    import matplotlib.pyplot as plt

    out = {}
    for cid, d in data.items():
        m, f, unit = d["map"], d["factor"], d["unit"]
        cv = d["cv"]
        ax_px = d.get("axes")
        ncol = 3 if cv is not None else 1
        nrow = 2 if cv is not None and cv.diff_fit is not None else 1
        fig, axes = plt.subplots(nrow, ncol, figsize=(4.6 * ncol, 3.4 * nrow), squeeze=False)
        _map(axes[0, 0], fig, m.x, m.y, m.sigma * f,
             f"σ projection, {m.frame}, at {fmt_obj(m.distance, d.get('object_unit', ''))}", unit, axes=ax_px)
        if cv is not None:
            both = np.r_[(cv.norm * f).ravel(), (cv.sigma_pred * f).ravel()]
            both = both[np.isfinite(both) & (both > 0)]
            lims = (both.min(), both.max()) if both.size else None
            _map(axes[0, 1], fig, cv.x, cv.y, cv.norm * f, "|Δq| of the two halves", unit, lims, ax_px)
            _map(axes[0, 2], fig, cv.x, cv.y, cv.sigma_pred * f, "predicted √(σ₁² + σ₂²) (camera frame)", unit,
                 lims, ax_px)
            if nrow == 2:
                nf = np.hypot(cv.diff_fit[..., 0], cv.diff_fit[..., 1]) * f
                both = np.r_[nf.ravel(), (cv.sigma_fit * f).ravel()]
                both = both[np.isfinite(both) & (both > 0)]
                lims = (both.min(), both.max()) if both.size else None
                _map(axes[1, 0], fig, cv.x, cv.y, cv.ratio_fit, "|Δq| / σ after the rotation fit", "ratio",
                     axes=ax_px)
                _map(axes[1, 1], fig, cv.x, cv.y, nf,
                     f"|Δq| after fitting a {np.degrees(np.linalg.norm(cv.rotation)):.2f}° rotation", unit, lims, ax_px)
                _map(axes[1, 2], fig, cv.x, cv.y, cv.sigma_fit * f, "predicted σ after the fit", unit, lims, ax_px)
        fig.tight_layout()
        cap = f"Camera {cid}: projection uncertainty over the format"
        out[f"uncertainty_{cid}"] = (fig, cap + (" and the cross-validation" if cv is not None else ""))
    return out
