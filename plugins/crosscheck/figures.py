"""Figures of ``pycolmap-crosscheck`` for report.html: the cross-method comparison (matplotlib; the
engine draws them with Agg).  The differences are the stage's own (its ``points`` and ``photos``
tables, :class:`~baarda.plugins.crosscheck.compare.CrossCheck`'s solution, costs and camera rows);
σ are baarda's a-posteriori standard deviations from the bundle result."""

from __future__ import annotations

import numpy as np

from baarda.pipeline.units import fmt_q


def _plt():
    import matplotlib.pyplot as plt

    return plt


def _columns(table, *names):
    """The named columns, found by name or by name + unit suffix (``dX`` → ``dX_m`` / ``dX_mu``)."""
    def find(n):
        return n if n in table.columns else next(c for c in table.columns if c.rsplit("_", 1)[0] == n)
    return [np.asarray(table.columns[find(n)], float) for n in names]


def normalised_differences(d, sigma):
    """``|d| / σ`` per coordinate where σ > 0 is finite for every coordinate of the table, else ``|d|``;
    returns (values, in_sigma)."""
    d, sigma = np.abs(np.asarray(d, float)), None if sigma is None else np.asarray(sigma, float)
    if sigma is not None and sigma.shape == d.shape and np.all(np.isfinite(sigma) & (sigma > 0)):
        return (d / sigma).ravel(), True
    return d.ravel(), False


def _log_hist(ax, series, xlabel):
    """Histograms of positive magnitudes on a logarithmic axis (exact zeros counted in the legend)."""
    vals = [np.asarray(v, float)[np.isfinite(v)] for _, v, _ in series]
    pos = np.concatenate([v[v > 0] for v in vals]) if vals else np.zeros(0)
    if pos.size == 0:
        ax.text(0.5, 0.5, "all differences exactly 0", ha="center", va="center", transform=ax.transAxes)
        ax.set_xlabel(xlabel)
        return
    lo, hi = np.log10(pos.min()), np.log10(pos.max())
    bins = np.logspace(lo - 0.1, hi + 0.1 + (hi - lo < 0.5) * 0.5, 40)
    for (label, _, col), v in zip(series, vals):
        zero = int((v == 0).sum())
        ax.hist(v[v > 0], bins=bins, color=col, alpha=0.6,
                label=f"{label} ({v.size}" + (f"; {zero} exactly 0)" if zero else ")"))
    from matplotlib.ticker import MaxNLocator

    ax.set_xscale("log")
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel(xlabel)
    ax.set_ylabel("count")
    ax.legend(fontsize=8)


def differences(cc, result, tables):
    """Object points and projection centres: |pycolmap − baarda| per coordinate in units of baarda's σ
    (in object units where baarda has no σ); camera parameters: difference / σ per parameter."""
    plt = _plt()
    unit = result.block_in.object_unit
    pv, ph = cc.plan.point_variable, cc.plan.photo_variable
    d_pts = np.column_stack(_columns(tables["points"], "dX", "dY", "dZ"))
    d_ctr = np.column_stack(_columns(tables["photos"], "dX0", "dY0", "dZ0"))
    s_pts = result.point_sigmas()[pv] if getattr(result, "cov_points", None) is not None else None
    s_ctr = result.eo_sigmas()[ph][:, :3] if getattr(result, "cov_eo", None) is not None else None
    vp, sp = normalised_differences(d_pts, s_pts)
    vc, sc = normalised_differences(d_ctr, s_ctr)
    ncol = 3 if cc.cameras else 2
    fig, axes = plt.subplots(1, ncol, figsize=(5.2 * ncol, 3.9))
    _log_hist(axes[0], [("object-point coordinates", vp, "#1f4e9c")],
              "|pycolmap − baarda| / σ" if sp else f"|pycolmap − baarda| ({unit})")
    qp, qc = cc.quantities["points"], cc.quantities["centres"]
    axes[0].set_title(f"object points: largest |difference| {fmt_q(qp['max'], qp.get('unit', unit), 3)}", fontsize=10)
    _log_hist(axes[1], [("projection-centre coordinates", vc, "#c0392b")],
              "|pycolmap − baarda| / σ" if sc else f"|pycolmap − baarda| ({unit})")
    axes[1].set_title(f"projection centres: largest |difference| {fmt_q(qc['max'], qc.get('unit', unit), 3)}",
                      fontsize=10)
    if cc.cameras:
        a = axes[2]
        names = list(dict.fromkeys(r["parameter"] for r in cc.cameras))
        unit_i = cc.quantities["intrinsics"]["unit"]
        key = "difference_sigma" if unit_i == "σ" else None
        v = [r[key] if key else (r["difference"] / abs(r["baarda"]) if r["baarda"] else np.nan) for r in cc.cameras]
        a.plot([names.index(r["parameter"]) for r in cc.cameras], v, "o", ms=4, color="#2c7a3f", alpha=0.7,
               ls="none")      # one line of markers for every refined camera's rows (a COLMAP block: hundreds)
        a.axhline(0, color="k", lw=0.7)
        a.set_xticks(range(len(names)), names, fontsize=8)
        a.set_xlim(-0.6, len(names) - 0.4)
        a.set_xlabel("camera parameter (every refined camera)")
        a.set_ylabel("(pycolmap − baarda) / σ" if key else "(pycolmap − baarda) / |baarda|")
        a.set_title(f"camera parameters ({len(cc.cameras)}): largest {fmt_q(cc.quantities['intrinsics']['max'], unit_i, 3)}",
                    fontsize=10)
        a.ticklabel_format(axis="y", style="sci", scilimits=(-3, 3))
    from baarda.pipeline.plots import fixed_layout

    fixed_layout(fig, left=0.75, right=0.2, bottom=0.6, top=0.5, wspace=1.05)    # margins in inches, set once
    return fig


def costs(cc):
    """pycolmap's initial and final cost and baarda's final cost ½Σ(v/σ)², side by side."""
    plt = _plt()
    q = cc.quantities["cost"]
    labels = ["pycolmap\ninitial", "pycolmap\nfinal", "baarda\nfinal"]
    vals = np.array([q["pycolmap_initial"], q["pycolmap"], q["baarda"]], float)
    fig, ax = plt.subplots(figsize=(6.2, 3.8))
    bars = ax.bar(range(3), vals, color=["#bbb", "#e67e22", "#1f4e9c"])
    for b, v in zip(bars, vals):
        ax.annotate(f"{v:.10g}", (b.get_x() + b.get_width() / 2, v), ha="center", va="bottom", fontsize=8,
                    xytext=(0, 2), textcoords="offset points")
    if np.all(vals > 0):
        ax.set_yscale("log")
        ax.set_ylim(vals.min() / 3, vals.max() * 5)
    ax.set_xticks(range(3), labels, fontsize=9)
    ax.set_ylabel("½Σ(v/σ)²")
    py = cc.pycolmap
    ax.set_title(f"final cost: relative difference {q['max']:.2g}; pycolmap {py['termination']} after "
                 f"{py['iterations']} iterations", fontsize=9)
    from baarda.pipeline.plots import fixed_layout, wrap_inches

    ax.set_title(wrap_inches(ax.get_title(), 5.4, 9), fontsize=9)
    fixed_layout(fig, left=0.9, right=0.2, bottom=0.65, top=0.35 + 0.15 * ax.get_title().count("\n"))
    return fig


def residual_data(cc, result):
    """(baarda's v/σ, pycolmap's v/σ, pycolmap − baarda in the stage's residual unit) over the
    observations of pycolmap's problem, (k, 2) each; σ is the a-priori σ of each camera's
    observations (pycolmap's pixel), the unit the camera's pixel (σ without a pitch), as the stage."""
    block = result.block_in
    used = cc.plan.obs_used
    cam = block.photos.camera[block.observations.photo[used]]
    sig = cc.plan.sigma_mm[cam][:, None]
    rb = np.asarray(result.residuals, float)[used]
    rp = np.asarray(cc.solution.residuals, float)[used]
    has_pixel = np.isfinite(block.cameras.pixel_mm) & (block.cameras.pixel_mm > 0)
    pitch = np.where(has_pixel, block.cameras.pixel_mm, cc.plan.sigma_mm)[cam][:, None]
    return rb / sig, rp / sig, (rp - rb) / pitch


def residuals(cc, result):
    """Image residuals of both solutions in units of the a-priori σ (histograms), and the
    differences pycolmap − baarda per coordinate (in the stage's unit: pixels, or σ without pitch)."""
    plt = _plt()
    vb, vp, dv = residual_data(cc, result)
    used = cc.plan.obs_used
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.8))
    allv = np.concatenate([vb.ravel(), vp.ravel()])
    allv = allv[np.isfinite(allv)]
    lim = float(np.quantile(np.abs(allv), 0.999)) if allv.size else 1.0
    bins = np.linspace(-lim, lim, 61)
    a.hist(vb.ravel(), bins=bins, histtype="stepfilled", color="#1f4e9c", alpha=0.35, label="baarda")
    a.hist(vp.ravel(), bins=bins, histtype="step", color="#e67e22", lw=1.5, label="pycolmap")
    a.set_xlabel("residual v / σ (x and y; 0.1 % beyond the range not drawn)")
    a.set_ylabel("coordinates")
    a.set_title(f"image residuals of {int(used.sum())} observations", fontsize=10)
    a.legend(fontsize=8)
    q = cc.quantities["residuals"]
    _log_hist(b, [("x and y", np.abs(dv).ravel(), "#7d3c98")], f"|pycolmap − baarda| ({q['unit']})")
    b.set_title(f"residual differences: largest {fmt_q(q['max'], q['unit'], 3)}, RMS {fmt_q(q['rms'], q['unit'], 3)}",
                fontsize=10)
    from baarda.pipeline.plots import fixed_layout

    fixed_layout(fig, left=0.8, right=0.2, bottom=0.6, top=0.35, wspace=0.9)
    return fig


def crosscheck_figures(cc, result, tables) -> dict:
    verdict = "equivalent problems: differences are rounding" if cc.plan.exact else \
        "not an equivalent problem for pycolmap: differences only"
    return {
        "differences": (differences(cc, result, tables),
                        f"pycolmap − baarda ({verdict}): object points and projection centres per coordinate in "
                        "units of baarda's σ, camera parameters"),
        "costs": (costs(cc), "Final cost ½Σ(v/σ)² of both solutions and pycolmap's start"),
        "residuals": (residuals(cc, result), "Image residuals of both solutions and their differences"),
    }
