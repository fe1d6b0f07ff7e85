"""Figures any adjustment has (matplotlib): the w-test statistics against N(0, 1), redundancy
numbers.  Part of the engine (stages' ``plots`` methods call it); the numerical libraries never
import matplotlib.  Every function returns a figure; the engine draws it with Agg."""

from __future__ import annotations

import numpy as np
from scipy import stats as sps

from .units import fmt_num


QQ_POINTS = 20_000
"""Order statistics drawn in the QQ plot (evenly spaced in rank; the extremes always)."""


def _plt():
    import matplotlib.pyplot as plt

    return plt


ROLE_MARKERS = {"full": ("^", False, "full control XYZ"), "xy": ("^", True, "planimetric control XY"),
                "z": ("v", False, "height control Z"), "check": ("D", True, "check points"),
                "tie": ("o", False, "tie points")}
"""Marker, hollow?, legend label of each point role in network figures (colours: the recordings'
``ROLE_COLORS``, so a role looks the same in report.html and in rerun)."""


FIXED_LAYOUT = "_baarda_fixed_layout"
"""Attribute :func:`fixed_layout` sets on a figure: its margins are final, :func:`~baarda.pipeline.html.png_of`
saves it as it is (no tight bounding box, no layout engine at save time)."""


def fixed_layout(fig, *, left: float = 0.75, right: float = 0.25, bottom: float = 0.6, top: float = 0.45,
                 wspace: float | None = None, hspace: float | None = None):
    """Margins of ``fig`` fixed once, in **inches** (the text around the axes has an absolute size, the
    figure's does not): ``left``/``right``/``bottom``/``top`` from the figure's edges, ``wspace``/``hspace``
    between the panels of its grid.  Replaces ``tight_layout``, which measured every tick label of every
    panel — twice, once more for the tight bounding box at saving — and was the largest share of a big
    run's figures.  Marks the figure (:data:`FIXED_LAYOUT`) so that it is saved without a tight box.
    Returns the figure."""
    w, h = fig.get_size_inches()
    kw = {"left": left / w, "right": 1 - right / w, "bottom": bottom / h, "top": 1 - top / h}
    axes = [a for a in fig.axes if a.get_subplotspec() is not None]
    if axes and (wspace is not None or hspace is not None):
        gs = axes[0].get_subplotspec().get_topmost_subplotspec().get_gridspec()   # not a colour bar's
        nrow, ncol = gs.get_geometry()
        if wspace is not None:      # matplotlib's wspace: a fraction of the mean panel width
            aw = (w - left - right - (ncol - 1) * wspace) / ncol
            kw["wspace"] = wspace / max(aw, 1e-3)
        if hspace is not None:
            ah = (h - top - bottom - (nrow - 1) * hspace) / nrow
            kw["hspace"] = hspace / max(ah, 1e-3)
    fig.subplots_adjust(**kw)
    setattr(fig, FIXED_LAYOUT, True)
    return fig


def fixed_titles():
    """A context in which new axes place their titles at a fixed height (``axes.titley`` = 1, above
    the axes by ``axes.titlepad``) instead of moving them above whatever tick labels or offset text
    reach over the axes — matplotlib's automatic placement measures every tick label of every panel
    again when it draws.  For figures with :func:`fixed_layout` and no ticks on top."""
    return _plt().rc_context({"axes.titley": 1.0})


def text_inches(text: str, fontsize: float) -> float:
    """Width of one line of ``text`` in inches at ``fontsize`` points, estimated without drawing
    (DejaVu Sans: about 0.55 em a character of mixed text) — for margins and wrapping fixed before saving."""
    return len(text) * fontsize * 0.55 / 72.0


def wrap_inches(text: str, width: float, fontsize: float) -> str:
    """``text`` broken into lines of at most ``width`` inches at ``fontsize`` (:func:`text_inches`),
    never between a number and its unit ("312 mm" stays on one line) nor around an "=" before a number."""
    import re
    import textwrap

    n = max(int(width / (fontsize * 0.55 / 72.0)), 10)
    if len(text) <= n:
        return text
    # no-break spaces (textwrap keeps them): "312 mm", "|w| = 3.29"
    glued = re.sub(r"(\d) (?=[^\W\d_]|%|°)", "\\1\u00a0", text)
    glued = re.sub(r" = (?=[-−]?\d)", "\u00a0=\u00a0", glued)
    return "\n".join(textwrap.wrap(glued, n, break_long_words=False)).replace("\u00a0", " ")


def role_colour(role: str):
    """A point role's colour as matplotlib RGB (the recordings' ``ROLE_COLORS``)."""
    from .recording import ROLE_COLORS, UNKNOWN_ROLE_COLOR

    return np.asarray(ROLE_COLORS.get(role, UNKNOWN_ROLE_COLOR), float) / 255.0


def role_points(ax, XYZ, role, mask, i: int, j: int, *, ms: float = 5, ms_tie: float = 3, zorder=None):
    """Points ``mask`` of ``XYZ`` (axes ``i``, ``j``) by role: marker, colour and a legend entry
    with the count for each role present (known roles in :data:`ROLE_MARKERS` order first)."""
    role = np.asarray(role)
    present = set(np.unique(role[mask]).tolist())
    for rl in [r for r in ROLE_MARKERS if r in present] + sorted(present - set(ROLE_MARKERS)):
        m = mask & (role == rl)
        marker, hollow, label = ROLE_MARKERS.get(rl, ("o", False, rl))
        col = role_colour(rl)
        ax.plot(XYZ[m, i], XYZ[m, j], marker, ms=ms_tie if rl == "tie" else ms, color=col,
                mfc="none" if hollow else col, mew=1.0, ls="none", label=f"{label} ({int(m.sum())})", zorder=zorder)


def w_distribution(w, critical: float, title: str = "w-test statistics"):
    """Histogram of w against N(0, 1) and the normal QQ plot."""
    plt = _plt()
    w = np.asarray(w, float)
    w = w[np.isfinite(w)]
    with fixed_titles():
        fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.6))
    lim = max(4.5, float(np.max(np.abs(w))) if w.size else 4.5)
    bins = np.linspace(-lim, lim, max(15, min(80, int(np.sqrt(max(w.size, 1))) * 2)))
    # one filled outline, not a rectangle artist per bin (80 of them were half of this figure's drawing)
    a.hist(w, bins=bins, density=True, histtype="stepfilled", color="#8fb3de", ec="#4a6fa0", lw=0.6,
           label=f"w ({w.size})")
    x = np.linspace(-lim, lim, 400)
    a.plot(x, sps.norm.pdf(x), color="k", lw=1.2, label="N(0, 1)")
    for s in (-critical, critical):
        a.axvline(s, color="#c0392b", ls="--", lw=1)
    a.set_xlabel("w")
    a.set_title(f"{title}: histogram; critical |w| = {critical:.3g}", fontsize=10)
    a.legend(fontsize=8)
    if w.size:
        k = np.unique(np.linspace(0, w.size - 1, min(w.size, QQ_POINTS)).round().astype(int))
        q = sps.norm.ppf((k + 0.5) / w.size)      # every quantile of a small sample, a thinned set of a large one
        b.plot(q, np.sort(w)[k], ".", ms=3, color="#1f4e9c")
    b.plot([-lim, lim], [-lim, lim], color="k", lw=0.8)
    b.axhline(critical, color="#c0392b", ls="--", lw=1)
    b.axhline(-critical, color="#c0392b", ls="--", lw=1)
    b.set_xlabel("N(0, 1) quantile")
    b.set_ylabel("sorted w")
    b.set_title("normal QQ plot", fontsize=10)
    a.set_title(wrap_inches(a.get_title(), 3.9, 10), fontsize=10)
    fixed_layout(fig, left=0.55, right=0.2, bottom=0.55, top=0.3 + 0.17 * a.get_title().count("\n"), wspace=0.8)
    return fig


def redundancy_numbers(r, labels_x=None, title="Redundancy numbers r = (Qvv P)ii"):
    plt = _plt()
    r = np.asarray(r, float)
    with fixed_titles():
        fig, ax = plt.subplots(figsize=(6.5, 3.4))
    ax.hist(r, bins=np.linspace(0, 1, 41), histtype="stepfilled", color="#9bc49b", ec="#3f7a3f", lw=0.6)
    ax.axvline(np.mean(r) if r.size else 0, color="k", lw=1, label=f"mean {np.mean(r):.3f}" if r.size else "")
    ax.set_xlabel("r")
    ax.set_ylabel("rows")
    ax.set_title(f"{title}; smallest {np.min(r):.3g}" if r.size else title, fontsize=10)
    ax.legend(fontsize=8)
    ax.set_title(wrap_inches(ax.get_title(), 5.5, 10), fontsize=10)
    fixed_layout(fig, left=0.85, right=0.2, bottom=0.55, top=0.3 + 0.17 * ax.get_title().count("\n"))
    return fig


def map_ticks(ax, x_values=()) -> None:
    """Object coordinates written out in full on both axes (no offset like "+1e6", no "×1e6"
    multiplier: a map coordinate is read as it is surveyed), five or six ticks, and the x labels
    slanted when the coordinates are long (10 000 or more)."""
    from matplotlib.ticker import MaxNLocator

    ax.ticklabel_format(useOffset=False, style="plain")
    ax.xaxis.set_major_locator(MaxNLocator(5))
    ax.yaxis.set_major_locator(MaxNLocator(6))
    x = np.asarray(x_values, float)
    x = x[np.isfinite(x)]
    if len(x) and np.max(np.abs(x)) >= 1e4:                # long map coordinates: slanted, apart
        ax.tick_params(axis="x", labelrotation=25)


def vector_scale(xy, d, span_fraction: float = 0.1) -> float:
    """Arrow scale so that the longest vector ``d`` (k, 2) is ``span_fraction`` of the extent of
    the positions ``xy`` (m, 2)."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    d = np.asarray(d, float).reshape(-1, 2)
    xy = xy[np.isfinite(xy).all(axis=1)]
    d = d[np.isfinite(d).all(axis=1)]
    span = float(np.ptp(xy, axis=0).max()) if len(xy) > 1 else 0.0
    dmax = float(np.max(np.hypot(d[:, 0], d[:, 1]))) if len(d) else 0.0
    return span_fraction * (span or dmax or 1.0) / dmax if dmax > 0 else 1.0


def point_errors(sets, unit: str, title: str, components=("X", "Y", "Z"), background=None, reference=None):
    """Point differences as vectors in plan and per component as bars (one figure).

    ``sets``: list of dicts ``{"label", "ids" (n,), "xy" (n, 2) plan positions, "d" (n, 3)
    differences, "sigma" (n, 3) or None (drawn as ±1σ error bars), "color"}`` — e.g. check-point
    errors of two methods, or control and check differences.  All sets share one arrow scale.
    ``background``: (m, 2) other points drawn grey in the plan.  ``reference``: ``{"label",
    "ids", "d" (k, 3)}`` drawn as black crosses on the bars (published values).  Bars: one group
    per point id (in the order of first appearance), one bar per set."""
    plt = _plt()
    comps = [("XYZ".index(c), c) for c in components]
    fig = plt.figure(figsize=(12.5, 1.2 + 2.1 * max(len(comps), 2)))
    gs = fig.add_gridspec(len(comps), 2, width_ratios=[1, 1.35])
    a = fig.add_subplot(gs[:, 0])
    sets = [s for s in sets if len(s["ids"])]
    all_xy = np.vstack([np.asarray(s["xy"], float).reshape(-1, 2) for s in sets]) if sets else np.zeros((0, 2))
    all_d = np.vstack([np.asarray(s["d"], float).reshape(-1, 3)[:, :2] for s in sets]) if sets else np.zeros((0, 2))
    ext = all_xy if background is None else np.vstack([all_xy, np.asarray(background, float).reshape(-1, 2)])
    k = vector_scale(ext, all_d)
    if background is not None and len(background):
        bg = np.asarray(background, float)
        a.plot(bg[:, 0], bg[:, 1], ".", color="#bbb", ms=3, zorder=0)
    for s in sets:
        xy, d = np.asarray(s["xy"], float).reshape(-1, 2), np.asarray(s["d"], float).reshape(-1, 3)
        a.quiver(xy[:, 0], xy[:, 1], k * d[:, 0], k * d[:, 1], angles="xy", scale_units="xy", scale=1,
                 color=s["color"], width=0.005, label=s["label"])
        a.plot(xy[:, 0], xy[:, 1], "o", ms=3, color=s["color"])
        fin = np.isfinite(d[:, :2]).all(axis=1)
        a.update_datalim(xy[fin] + k * d[fin, :2])          # the arrow heads inside the axes
        for p, (x, y) in zip(s["ids"], xy):
            a.annotate(str(p), (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
    a.autoscale_view()
    a.set_aspect("equal", adjustable="box")
    map_ticks(a, ext[:, 0] if len(ext) else ())
    a.set_xlabel(f"X ({unit})")
    a.set_ylabel(f"Y ({unit})")
    a.set_title(f"plan: vectors × {fmt_num(k, 3)}", fontsize=10)
    if sets:                                   # below the plan: a flat plan leaves no free corner
        a.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=min(len(sets), 3), frameon=False)
    ids = []
    for s in sets:
        ids += [str(i) for i in s["ids"] if str(i) not in ids]
    pos = {i: n for n, i in enumerate(ids)}
    members = {i: [n for n, s in enumerate(sets) if i in {str(j) for j in s["ids"]}] for i in ids}
    width = 0.8 / max(max((len(m) for m in members.values()), default=1), 1)
    axes = []
    for row, (c, name) in enumerate(comps):
        b = fig.add_subplot(gs[row, 1], sharex=axes[0] if axes else None)
        axes.append(b)
        for n, s in enumerate(sets):
            d = np.asarray(s["d"], float).reshape(-1, 3)
            x = np.array([pos[str(i)] + (members[str(i)].index(n) - (len(members[str(i)]) - 1) / 2) * width
                          for i in s["ids"]], float)     # a point's bars side by side, centred on its tick
            sg = None if s.get("sigma") is None else np.asarray(s["sigma"], float).reshape(-1, 3)[:, c]
            b.bar(x, d[:, c], width=width, color=s["color"], yerr=sg, ecolor="#333", capsize=2,
                  error_kw={"lw": 0.8}, label=s["label"] + (" ± 1σ" if sg is not None else ""))
        if reference is not None and len(reference["ids"]):
            rd = np.asarray(reference["d"], float).reshape(-1, 3)
            rx = [pos.get(str(i)) for i in reference["ids"]]
            keep = [j for j, x in enumerate(rx) if x is not None]
            b.plot([rx[j] for j in keep], rd[keep, c], "x", color="k", ms=7, mew=1.5, label=reference["label"])
        b.axhline(0, color="k", lw=0.7)
        b.set_ylabel(f"d{name} ({unit})")
        if row == 0:
            b.set_title(title, fontsize=10)
            b.legend(fontsize=7, loc="best")
    if axes:
        axes[-1].set_xticks(np.arange(len(ids)), ids, fontsize=7, rotation=90 if len(ids) > 12 else 0)
        for b in axes[:-1]:
            b.tick_params(labelbottom=False)
        axes[-1].set_xlabel("point")
    fig.tight_layout()
    return fig


def sigma_dots(ax, names, values, band: float = 1.0, label: str = "", color="#1f4e9c", offset: float = 0.0,
               marker="o", positions=None):
    """Differences in units of σ per named quantity as dots over the tick labels ``names``, with a
    shaded ±``band`` σ band; ``positions`` (default 0, 1, …) place ``values`` at some of the ticks."""
    x = (np.arange(len(names)) if positions is None else np.asarray(positions, float)) + offset
    ax.axhspan(-band, band, color="#e8eef7", zorder=0)
    ax.axhline(0, color="k", lw=0.7)
    ax.plot(x, np.asarray(values, float), marker, ls="none", color=color, ms=6, label=label)
    ax.set_xticks(np.arange(len(names)), [str(n) for n in names], fontsize=8)
    ax.set_xlim(-0.6, len(names) - 0.4)
    return ax


BIG = 20_000
"""Points above which a figure draws aggregated data (hexbin of means, quantiles, decimation)
instead of one marker per point, and rasterises what it still draws point by point."""
MAP_CELLS = 5_000
"""Points above which :func:`value_map` draws hexbins (a map of 14 000 coloured dots is an 850 kB PNG
and less readable than the cells' means)."""
RASTER = 2_000
"""Markers above which a scatter is rasterised (``rasterized=True``: one bitmap, not an artist
per point, if the figure is ever saved as a vector file)."""


def robust_limits(values, *, keep=(), q: float = 0.02, pad: float = 0.08, spread: float = 1.0):
    """Axis limits (lo, hi) that show the bulk of ``values`` and every value of ``keep`` (e.g. the
    projection centres), not a few far outliers: the ``q`` … ``1 − q`` quantiles widened by
    ``spread`` × their range where the data reach that far, then padded by ``pad``.  Values outside
    are for :func:`mark_outside`."""
    v = np.asarray(values, float).ravel()
    v = v[np.isfinite(v)]
    k = np.asarray(keep, float).ravel()
    k = k[np.isfinite(k)]
    if not v.size and not k.size:
        return (-1.0, 1.0)
    if v.size:
        a, b = np.quantile(v, [q, 1 - q]) if v.size >= 20 else (v.min(), v.max())
        w = max(b - a, 1e-12)
        lo, hi = max(v.min(), a - spread * w), min(v.max(), b + spread * w)
    else:
        lo, hi = k.min(), k.max()
    if k.size:
        lo, hi = min(lo, k.min()), max(hi, k.max())
    w = max(hi - lo, 1e-9 * max(abs(lo), abs(hi), 1.0))
    return (lo - pad * w, hi + pad * w)


def mark_outside(ax, x, y, xlim, ylim, *, label: str = "outside the axes, drawn at the edge", color="#c0392b"):
    """Points beyond the limits drawn on the edge of the axes (clipped position, a red ✕) with a
    legend entry counting them; returns how many there are.  Sets the limits."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    out = ok & ((x < xlim[0]) | (x > xlim[1]) | (y < ylim[0]) | (y > ylim[1]))
    n = int(out.sum())
    if n:
        ax.plot(np.clip(x[out], *xlim), np.clip(y[out], *ylim), "x", color=color, ms=6, mew=1.5, ls="none",
                label=f"{n} {label}", clip_on=False, zorder=5)
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    return n


def integer_ticks(ax, axis: str = "x") -> None:
    """Integer ticks only (iterations, counts): no 0.5 iteration."""
    from matplotlib.ticker import MaxNLocator

    (ax.xaxis if axis == "x" else ax.yaxis).set_major_locator(MaxNLocator(integer=True))


def plain_ticks(ax, axis: str = "y") -> None:
    """Tick labels as plain numbers with 4 significant digits ("7232", "0.0012", "1e-05"), also on a
    log axis: no "7.239×10³" and no offset; minor ticks unlabelled."""
    from matplotlib.ticker import FuncFormatter, NullFormatter

    a = ax.yaxis if axis == "y" else ax.xaxis
    a.set_major_formatter(FuncFormatter(lambda v, _: f"{v:.4g}"))
    a.set_minor_formatter(NullFormatter())


def hex_reduce(x, y, c, gridsize: int, reduce: str = "mean"):
    """The cells of matplotlib's ``hexbin(x, y, gridsize=gridsize)`` (its grid: the data's extent,
    ``gridsize`` hexagons across, two interleaved lattices) and the ``reduce`` ("mean", "min", "max")
    of ``c`` in each, in numpy: ``(cx, cy, value, extent)`` of the occupied cells in hexbin's order of
    cells — ``hexbin(cx, cy, extent=extent, gridsize=gridsize, mincnt=1)`` draws the same cells, one
    point in each, and ``set_array(value)`` colours them."""
    from matplotlib import transforms

    x, y, c = (np.asarray(a, float).ravel() for a in (x, y, c))
    nonsingular = getattr(transforms, "_nonsingular", transforms.nonsingular)    # hexbin's own (matplotlib 3.11)
    xmin, xmax = nonsingular(float(x.min()), float(x.max()), expander=0.1)
    ymin, ymax = nonsingular(float(y.min()), float(y.max()), expander=0.1)
    extent = (xmin, xmax, ymin, ymax)
    nx = int(gridsize)
    ny = int(nx / np.sqrt(3))
    pad = 1e-9 * (xmax - xmin)
    x0, x1 = xmin - pad, xmax + pad
    sx, sy = (x1 - x0) / nx, (ymax - ymin) / ny
    ix, iy = (x - x0) / sx, (y - ymin) / sy
    ix1, iy1 = np.round(ix), np.round(iy)
    ix2, iy2 = np.floor(ix), np.floor(iy)
    first = (ix - ix1) ** 2 + 3.0 * (iy - iy1) ** 2 < (ix - ix2 - 0.5) ** 2 + 3.0 * (iy - iy2 - 0.5) ** 2
    inside = np.where(first, (ix1 >= 0) & (ix1 <= nx) & (iy1 >= 0) & (iy1 <= ny),
                      (ix2 >= 0) & (ix2 < nx) & (iy2 >= 0) & (iy2 < ny))
    # hexbin's cell numbers: lattice 1 (centres on the integers) first, then lattice 2 (half-integers)
    n1 = (nx + 1) * (ny + 1)
    key = np.where(first, ix1 * (ny + 1) + iy1, n1 + ix2 * ny + iy2)[inside].astype(np.int64)
    cv = c[inside]
    n = n1 + nx * ny
    cnt = np.bincount(key, minlength=n)
    cells = np.flatnonzero(cnt)
    if reduce == "mean":
        val = np.bincount(key, weights=cv, minlength=n)[cells] / cnt[cells]
    else:
        val = np.full(n, np.inf if reduce == "min" else -np.inf)
        (np.minimum if reduce == "min" else np.maximum).at(val, key, cv)
        val = val[cells]
    two = cells >= n1
    kx = np.where(two, (cells - n1) // max(ny, 1) + 0.5, cells // (ny + 1))
    ky = np.where(two, (cells - n1) % max(ny, 1) + 0.5, cells % (ny + 1))
    return x0 + kx * sx, ymin + ky * sy, val, extent


def value_map(ax, x, y, c, *, cmap="viridis", vmin=None, vmax=None, gridsize: int = 40, reduce="mean",
              s: float = 6, big: int = MAP_CELLS):
    """Values ``c`` at positions (x, y) as a colour map: one marker per position for a small set
    (rasterised above :data:`RASTER`), a hexbin of the ``reduce`` ("mean", "min", "max") of each cell
    above ``big`` (:data:`MAP_CELLS`) — the figure of a block of millions stays a few hundred kB.  Returns the mappable
    (for a colour bar)."""
    x, y, c = (np.asarray(a, float).ravel() for a in (x, y, c))
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(c)
    x, y, c = x[ok], y[ok], c[ok]
    if len(c) > big:
        cx, cy, cc, extent = hex_reduce(x, y, c, gridsize, reduce)
        # the cells reduced in numpy, drawn as hexbin's count of one point at each centre on the same grid
        # (the same extent), coloured by the value: hexbin's own C= gathers the values in a Python list
        # per point and reduces every cell by a Python call (0.3 s a map of 300 000 image points)
        h = ax.hexbin(cx, cy, gridsize=gridsize, extent=extent, cmap=cmap, vmin=vmin, vmax=vmax, mincnt=1,
                      linewidths=0.1, rasterized=True)
        if len(h.get_array()) != len(cc):       # never: the grid is hexbin's; a safe way all the same
            h.remove()
            return ax.hexbin(x, y, C=c, gridsize=gridsize, reduce_C_function={"mean": np.mean, "min": np.min,
                             "max": np.max}[reduce], cmap=cmap, vmin=vmin, vmax=vmax, mincnt=1, linewidths=0.1)
        h.set_array(cc)
        if vmin is None or vmax is None:       # hexbin scaled the colours to its counts (all 1)
            h.set_clim(float(np.min(cc)) if vmin is None else vmin, float(np.max(cc)) if vmax is None else vmax)
        return h
    order = np.argsort(-c if reduce == "min" else c, kind="stable")      # the notable values on top
    return ax.scatter(x[order], y[order], c=c[order], s=s, cmap=cmap, vmin=vmin, vmax=vmax, lw=0,
                      rasterized=len(c) > RASTER)


class ImageFrame:
    """Image positions and vectors as a reader of the source draws them.

    A pixel source with a known image size (COLMAP, OpenCV detections, libmv, Metashape, OpenSfM) is
    drawn in its image's pixel frame: u right, v *down*, origin at the top-left corner, the axes
    0 … width × 0 … height, aspect equal — the numbers are the ``x_px``, ``y_px`` of
    ``bundle_observations.csv`` (the source's own convention, ``ImageUnits.coordinates``), vectors
    (residuals, distortion) in px with v down.  BAL has no image size and its coordinates are centred
    with y up (its files' convention, and again ``x_px, y_px`` of the table): drawn so.  A metric
    source (comparator, AICON, DBAT in mm) is drawn as photogrammetrists draw the format: mm,
    origin at its centre, y up; its vectors in the figure's unit of length per the caller."""

    def __init__(self, block):
        from .units import ImageUnits

        self.block = block
        self.iu = ImageUnits.of(block)
        self.pixels = self.iu.is_pixels
        self.y_down = self.pixels and self.iu.convention != "bal"
        self.unit = "px" if self.pixels else "mm"

    def positions(self, xy_mm, photo) -> np.ndarray:
        """Image coordinates (n, 2) in mm of photos ``photo`` (n,) → drawn positions."""
        return self.iu.coordinates(self.block, xy_mm, photo) if self.pixels else np.asarray(xy_mm, float)

    def camera_positions(self, xy_mm, camera: int) -> np.ndarray:
        """Image coordinates (n, 2) in mm of camera ``camera`` → drawn positions."""
        xy = np.asarray(xy_mm, float)
        if not self.pixels:
            return xy
        cams = self.block.cameras
        pitch = float(np.asarray(cams.pixel_mm, float)[camera])
        if not self.y_down:
            return xy / pitch
        from .geometry.image import pixels_from_mm

        return pixels_from_mm(xy, np.asarray(cams.resolution, float)[camera], pitch, self.iu.convention)

    def vectors(self, d_mm) -> np.ndarray:
        """Differences (n, 2) in mm (x right, y up) → drawn vectors: px with v down for a pixel source
        (``ImageUnits.diff(…, flip_y=True)``), mm unchanged for a metric one."""
        return self.iu.diff(d_mm, flip_y=True) if self.pixels else np.asarray(d_mm, float)

    def extent(self, camera: int):
        """(left, right, bottom, top) of camera ``camera``'s format in drawn units — for ``imshow``
        (``origin="upper"``) and the frame; None when the format is unknown (film without a format, BAL)."""
        fw, fh = np.asarray(self.block.cameras.format_mm[camera], float)
        if not (fw > 0 and fh > 0):
            return None
        if self.y_down and not np.all(np.asarray(self.block.cameras.resolution[camera]) > 0):
            return None
        c = self.camera_positions(np.array([[-fw / 2, -fh / 2], [fw / 2, fh / 2]]), camera)
        return float(c[0, 0]), float(c[1, 0]), float(c[0, 1]), float(c[1, 1])

    def axis_labels(self) -> tuple[str, str]:
        if not self.pixels:
            return "x (mm)", "y (mm, up)"
        if self.y_down:
            return "u (px)", "v (px, down)"
        return "x (px, from the centre)", "y (px, up)"

    def describe(self) -> str:
        """The frame in words for a figure's title."""
        if not self.pixels:
            return "mm, origin at the format centre, y up"
        if self.y_down:
            return "px, origin top-left, v down"
        return f"px, {self.iu.source}'s frame: origin at the centre, y up"

    def finish(self, ax, camera=None, *, frame: bool = True, pad: float = 0.02, ticks: bool = True):
        """Frames of camera(s) ``camera`` (an index or a list) drawn as grey rectangles, the limits on
        their union (padded by ``pad``) with v down for a pixel frame, aspect equal, axis labels."""
        cams = [] if camera is None else list(np.atleast_1d(camera))
        exts = [e for e in (self.extent(int(j)) for j in cams) if e is not None]
        if exts:
            import matplotlib.patches as mp

            box = np.unique(np.array([[min(l, r), max(l, r), min(b, t), max(b, t)] for l, r, b, t in exts]), axis=0)
            if frame:
                for x0, x1, y0, y1 in box:
                    ax.add_patch(mp.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec="#999", lw=0.8))
            x0, x1, y0, y1 = box[:, 0].min(), box[:, 1].max(), box[:, 2].min(), box[:, 3].max()
            px, py = pad * (x1 - x0), pad * (y1 - y0)
            ax.set_xlim(x0 - px, x1 + px)
            ax.set_ylim((y1 + py, y0 - py) if self.y_down else (y0 - py, y1 + py))
        elif self.y_down and not ax.yaxis_inverted():
            ax.invert_yaxis()
        ax.set_aspect("equal", adjustable="box" if exts else "datalim")
        if ticks:
            xl, yl = self.axis_labels()
            ax.set_xlabel(xl, fontsize=7)
            ax.set_ylabel(yl, fontsize=7)
