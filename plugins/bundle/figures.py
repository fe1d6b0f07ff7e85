"""The bundle's figures for ``report.html`` (matplotlib, drawn by the engine with Agg).

Only called from :meth:`BundleAdjustment.plots`; the numbers come from the
:class:`~baarda.pipeline.adjustment.BundleResult` and its snapshot, never recomputed.
"""

from __future__ import annotations

import numpy as np

from baarda.pipeline.api import stats
from baarda.pipeline.camera import get_ap_model

from baarda.pipeline.plots import (BIG, MAP_CELLS, ImageFrame, fixed_layout, integer_ticks, map_ticks, mark_outside, plain_ticks,
                                   fixed_titles, redundancy_numbers, robust_limits, role_points, text_inches, value_map, w_distribution,
                                   wrap_inches)


from .protocol import image_units
from baarda.pipeline.units import fmt_num, fmt_obj, fmt_q, object_unit_text

MAX_DISTORTION_CAMERAS = 2
"""Cameras whose distortion is drawn (most image points first; a COLMAP block may have dozens)."""
MAX_ELLIPSES = 3000
"""Points whose error ellipse is drawn (the first ones; the rest would be ink, not information)."""
MAX_PHOTOS = 8
"""Photos drawn in the residual figure (the largest RMS first)."""
MAX_LABELS = 40
"""Check points named in the plan of check-point errors at most (the largest plan errors; every id is in
bundle_points.csv)."""
MAX_ARROWS = 600
"""Residual arrows drawn per photo at most (evenly spaced in the photo's order, plus every flagged one)."""


def _plt():
    import matplotlib.pyplot as plt

    return plt


def _img(value, unit: str, sig: int = 3) -> str:
    """An image-space quantity (residual, σ, MDB, distortion) in the image unit as is — µm for a
    metric source (0.630 µm, not 630 nm), px for a pixel source."""
    return fmt_q(value, unit, sig, rescale=False)


def _backdrop(path: str, longest: int = 1200):
    """The photo as a grey image (downsampled; None when it cannot be read)."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        return None
    f = max(img.shape) / longest
    if f > 1:
        img = cv2.resize(img, (int(img.shape[1] / f), int(img.shape[0] / f)), interpolation=cv2.INTER_AREA)
    return img


def residual_vectors(res, decision=None, images: dict | None = None, *, vectors=None,
                     what: str = "Image residuals (observed − computed)"):
    """Residual vectors (observed − computed) per photo over the format, the photos with the
    largest RMS first; one arrow scale for all panels.  A pixel source is drawn in its image's pixel
    frame (origin top-left, v down, 0 … width × 0 … height: the ``x_px, y_px`` and ``vx_px, vy_px``
    of bundle_observations.csv), a metric source in mm with the origin at the format centre and y up
    (:class:`~baarda.pipeline.plots.ImageFrame`).  ``images``: photo id → image file, drawn behind
    the arrows.  ``vectors`` (k, 2) mm draws other per-observation vectors instead (``what`` names them)."""
    plt = _plt()
    block = res.block_in
    obs = block.observations
    unit, scale, _ = image_units(block)
    frame = ImageFrame(block)
    g = scale if frame.pixels else 1.0          # drawn units per mm: px for a pixel source, else mm
    act = np.asarray(res.obs_active, bool)
    v = np.asarray(res.residuals if vectors is None else vectors, float)
    # the RMS per photo of the protocol and bundle_photos: coordinates in the adjustment (a rejected
    # coordinate is drawn, red, but not counted)
    used = np.asarray(res.row_active, bool) & act[:, None]
    ss = np.bincount(obs.photo, weights=np.where(used, v, 0.0).__pow__(2).sum(axis=1), minlength=len(block.photos))
    cnt = np.bincount(obs.photo, weights=used.sum(axis=1), minlength=len(block.photos)) / 2.0
    photos = np.flatnonzero(cnt)
    r = np.sqrt(ss[photos] / cnt[photos])
    photos = photos[np.argsort(-r, kind="stable")][:MAX_PHOTOS]
    n = len(photos)
    ncol = min(4, n)
    nrow = int(np.ceil(n / ncol))
    with fixed_titles():
        fig, axes = plt.subplots(nrow, ncol, figsize=(3.3 * ncol, 3.0 * nrow + 0.4), squeeze=False)
    vmax = np.nanpercentile(np.hypot(v[act, 0], v[act, 1]), 95) if act.any() else 1.0
    for ax, p in zip(axes.ravel(), photos):
        j = block.photos.camera[p]
        m = act & (obs.photo == p)
        xy = frame.positions(obs.xy[m], obs.photo[m])
        ext = frame.extent(j)
        size = max(abs(ext[1] - ext[0]), abs(ext[3] - ext[2])) if ext else (np.ptp(xy) or 1.0)
        k = 0.08 * size / (g * vmax or 1.0)      # drawn units of arrow per drawn unit of residual
        flag = np.zeros(m.sum(), bool) if decision is None else np.isin(np.asarray(decision)[m], ["flagged", "rejected"])
        vm = frame.vectors(v[m])
        n_all = len(xy)
        if n_all > MAX_ARROWS:      # a dense photo: evenly spaced arrows and every flagged one
            keep = np.zeros(n_all, bool)
            keep[np.linspace(0, n_all - 1, MAX_ARROWS).round().astype(int)] = True
            keep |= flag
            xy, vm, flag = xy[keep], vm[keep], flag[keep]
        ax.quiver(xy[~flag, 0], xy[~flag, 1], k * vm[~flag, 0], k * vm[~flag, 1], angles="xy", scale_units="xy",
                  scale=1, color="#1f4e9c", width=0.006)
        if flag.any():
            ax.quiver(xy[flag, 0], xy[flag, 1], k * vm[flag, 0], k * vm[flag, 1], angles="xy", scale_units="xy",
                      scale=1, color="#c0392b", width=0.008)
        ax.plot(xy[:, 0], xy[:, 1], ".", ms=2, color="#555")
        src = (images or {}).get(str(block.photos.ids[p]))
        back = _backdrop(src) if src else None
        if back is not None and ext is not None:
            ax.imshow(back, cmap="gray", extent=ext, origin="upper", alpha=0.45, zorder=0)
        frame.finish(ax, j, ticks=False)
        _few_ticks(ax)
        um = used[obs.photo == p]
        rm = np.sqrt(np.mean(v[obs.photo == p][um] ** 2)) * scale if um.any() else float("nan")
        ax.set_title(wrap_inches(f"photo {block.photos.ids[p]}: RMS {_img(rm, unit, 3)}", 3.1, 9)
                     + (f"\n{len(xy)} of {n_all} arrows drawn" if len(xy) < n_all else ""), fontsize=9)
        ax.tick_params(labelsize=7)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    head = wrap_inches(f"{what} over the format ({frame.describe()}); an arrow of {0.08 * 100:.0f} % of the format is "
                       f"{_img(vmax * scale, unit, 3)} (95th percentile); red: flagged/rejected", 3.3 * ncol - 0.2, 10)
    fig.suptitle(head, fontsize=10)
    titles = max(ax.get_title().count("\n") for ax in axes.ravel()[:n]) if n else 0
    fixed_layout(fig, left=0.5, right=0.12, bottom=0.3, top=0.35 + 0.18 * head.count("\n") + 0.32 + 0.15 * titles,
                 wspace=0.55, hspace=0.5 + 0.15 * titles)
    return fig


def _few_ticks(ax, n: int = 5) -> None:
    """At most ``n`` + 1 ticks a side of an image panel: a format needs no more to be read, and every
    tick is a line and a text to lay out and draw (8 panels of 9 × 7 ticks were a third of the figure)."""
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(n))
    ax.yaxis.set_major_locator(MaxNLocator(n))


def _ellipse(cov2):
    w, V = np.linalg.eigh(np.asarray(cov2, float))
    w = np.sqrt(np.clip(w, 0, None))
    t = np.linspace(0, 2 * np.pi, 40)
    return V @ np.vstack([w[0] * np.cos(t), w[1] * np.sin(t)])


def network(res):
    """Plan (X, Y) and elevation (X, Z) of projection centres and points, with the points'
    standard error ellipses exaggerated by one common factor.  The axes show the bulk of the points
    and every projection centre (:func:`~baarda.pipeline.plots.robust_limits`): a few far,
    badly determined points are drawn at the edge and counted, they do not shrink the network to
    a corner.  The ellipse factor makes the 95th percentile of σ a visible size."""
    plt = _plt()
    from matplotlib.collections import LineCollection

    block = res.block_in
    pts, used = block.points, res.point_used
    XYZ, X0 = res.state.XYZ, res.state.X0[res.photo_used]
    C = res.cov_points
    sig = res.point_sigmas()
    ou = block.object_unit
    ok = used & np.all(np.isfinite(sig), axis=1) & (np.max(np.nan_to_num(sig), axis=1) > 0)
    big = int(used.sum()) > BIG
    lims = [robust_limits(XYZ[used, t], keep=X0[:, t]) for t in range(3)]
    span = max(max(h - l for l, h in lims[:2]), 1e-9)
    smax = float(np.max(sig[ok])) if ok.any() else 0.0
    s95 = float(np.quantile(sig[ok].max(axis=1), 0.95)) if ok.any() else 0.0
    k = 0.03 * span / s95 if s95 > 0 else 0.0
    pts_ok = XYZ[ok & np.isfinite(XYZ).all(axis=1)]
    if k > 0 and len(pts_ok) > 20 and not big:   # a dense cloud: ellipses of the 95th percentile ≈ the typical spacing
        from scipy.spatial import cKDTree

        nn = cKDTree(pts_ok).query(pts_ok, k=2)[0][:, 1]
        spacing = float(np.median(nn[nn > 0])) if np.any(nn > 0) else 0.0
        if spacing > 0:
            k = min(k, spacing / s95)
    with fixed_titles():
        fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    for ax, (i, j, name) in zip(axes, [(0, 1, "plan (X, Y)"), (0, 2, "elevation (X, Z)")]):
        if big:          # a big block: the points as a density, rasterised
            ax.hexbin(XYZ[used, i], XYZ[used, j], gridsize=60, bins="log", cmap="Greys", mincnt=1,
                      extent=(*lims[i], *lims[j]), linewidths=0.1, rasterized=True)
        else:
            role_points(ax, XYZ, pts.role, used, i, j)
        ax.plot(X0[:, i], X0[:, j], "s", ms=5 if len(X0) < 500 else 2, color="k",
                label=f"projection centres ({len(X0)})", rasterized=len(X0) > 2000)
        if k > 0 and not big:
            inside = ((XYZ[:, i] >= lims[i][0]) & (XYZ[:, i] <= lims[i][1]) & (XYZ[:, j] >= lims[j][0])
                      & (XYZ[:, j] <= lims[j][1]))
            sel = np.flatnonzero(ok & inside)[:MAX_ELLIPSES]
            segs = [np.column_stack([XYZ[p, i] + e[0], XYZ[p, j] + e[1]])
                    for p in sel for e in [_ellipse(C[p][np.ix_([i, j], [i, j])]) * k]]
            dense = len(sel) > 300          # many ellipses: thin and translucent, the points stay visible
            ax.add_collection(LineCollection(segs, colors="#28a0a0", linewidths=0.3 if dense else 0.6,
                                             alpha=0.5 if dense else 1.0))   # the recordings' ellipsoid colour
        mark_outside(ax, XYZ[used, i], XYZ[used, j], lims[i], lims[j], label="points beyond the axes (at the edge)")
        ax.set_aspect("equal", adjustable="box")
        ax.set_title(name, fontsize=10)
        ax.set_xlabel(f"{'XYZ'[i]} ({object_unit_text(block)})")
        ax.set_ylabel(f"{'XYZ'[j]} ({object_unit_text(block)})")
        map_ticks(ax, np.r_[XYZ[used, i], X0[:, i]])
        ax.tick_params(labelsize=8)
    axes[0].legend(fontsize=7, loc="best")
    if k > 0 and not big:
        head = (f"standard error ellipses × {fmt_num(k, 3)} (σ: 95th percentile {fmt_obj(s95, object_unit_text(block), 3)}, "
                f"largest {fmt_obj(smax, object_unit_text(block), 3)})")
    elif k > 0:
        head = (f"point density ({int(used.sum())} points); σ: 95th percentile {fmt_obj(s95, object_unit_text(block), 3)}, "
                f"largest {fmt_obj(smax, object_unit_text(block), 3)} (every σ in bundle_points.csv)")
    elif used.any() and np.all(np.isfinite(sig[used])) and not np.any(sig[used]):
        head = "every point held fixed (σ = 0): no error ellipse to draw"
    else:
        head = "no standard errors of the points (covariance not computed)"
    head = wrap_inches(f"Network; {head}", 11.6, 10)
    fig.suptitle(head, fontsize=10)
    xs = np.abs(np.r_[XYZ[used, 0], X0[:, 0]])
    long_x = bool(np.max(xs[np.isfinite(xs)], initial=0.0) >= 1e4)       # map_ticks slants the x labels
    fixed_layout(fig, left=1.05, right=0.2, bottom=0.9 if long_x else 0.7, top=0.62 + 0.17 * head.count("\n"), wspace=1.1)
    return fig


def checkpoint_errors(res):
    plt = _plt()
    block = res.block_in
    pts = block.points
    chk = np.flatnonzero((pts.role == "check") & res.point_used)
    d = res.state.XYZ[chk] - pts.XYZ[chk]
    ou = block.object_unit
    with fixed_titles():
        fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2), gridspec_kw={"width_ratios": [1.3, 1]})
    # the network's extent from the adjusted points (tie points have no given coordinates: nan)
    xy_used = res.state.XYZ[res.point_used][:, :2]
    xy_used = xy_used[np.isfinite(xy_used).all(axis=1)]
    span = max(float(np.ptp(xy_used, axis=0).max()) if len(xy_used) else 0.0, 1e-9)
    h = np.hypot(d[:, 0], d[:, 1])
    dmax = float(np.nanmax(h)) if np.isfinite(h).any() else 0.0
    k = 0.1 * span / dmax if dmax > 0 else 1.0
    a.plot(res.state.XYZ[res.point_used, 0], res.state.XYZ[res.point_used, 1], ".", color="#bbb", ms=3)
    a.quiver(pts.XYZ[chk, 0], pts.XYZ[chk, 1], k * d[:, 0], k * d[:, 1], angles="xy", scale_units="xy", scale=1,
             color="#d35400", width=0.005)
    a.update_datalim(pts.XYZ[chk, :2] + k * d[:, :2])      # the arrow heads inside the axes
    a.autoscale_view()
    named = np.argsort(-np.nan_to_num(np.hypot(d[:, 0], d[:, 1]), nan=-1.0), kind="stable")[:MAX_LABELS]
    for i in named:          # the ids of the largest errors (a text each: not hundreds)
        a.annotate(str(pts.ids[chk][i]), (pts.XYZ[chk[i], 0], pts.XYZ[chk[i], 1]), fontsize=7, xytext=(3, 3),
                   textcoords="offset points")
    a.set_aspect("equal", adjustable="datalim")
    map_ticks(a, res.state.XYZ[res.point_used, 0])
    if dmax > 0:
        a.set_title(f"check points: plan error vectors × {fmt_num(k, 3)} (adjusted − surveyed; largest "
                    f"{fmt_q(dmax, ou, 3)})" + (f"; ids of the {len(named)} largest of {len(chk)}"
                                                if len(named) < len(chk) else ""), fontsize=10)
    else:
        a.set_title("check points: adjusted − surveyed is 0 in plan at every point (no vectors to draw)", fontsize=10)
    b.bar(np.arange(len(chk)), d[:, 2], color="#5b7fb5")
    b.set_xticks(np.arange(len(chk)), [str(x) for x in pts.ids[chk]], fontsize=7, rotation=90)
    b.axhline(0, color="k", lw=0.7)
    b.set_title(f"dZ ({ou})", fontsize=10)
    a.set_title(wrap_inches(a.get_title(), 5.6, 10), fontsize=10)
    longest = max((text_inches(str(x), 7) for x in pts.ids[chk]), default=0.2)     # the ids, turned upright
    fixed_layout(fig, left=1.05, right=0.2, bottom=max(0.7, longest + 0.25), top=0.35 + 0.17 * a.get_title().count("\n"),
                 wspace=1.0)
    return fig


def convergence(history):
    """vᵀPv and the largest correction per iteration of a :class:`~baarda.pipeline.adjustment.Convergence`."""
    plt = _plt()
    it = history.iteration
    with fixed_titles():
        fig, a = plt.subplots(figsize=(6.5, 3.4))
    vtpv = np.asarray(history.vtpv, float)
    pos = vtpv[np.isfinite(vtpv) & (vtpv > 0)]
    log = pos.size > 1 and pos.max() / pos.min() > 10        # a log axis only where it spans a decade
    (a.semilogy if log else a.plot)(it, np.where(vtpv > 0, vtpv, np.nan) if log else vtpv, "o-", color="#1f4e9c",
                                    label="vᵀPv")
    if not log:
        a.ticklabel_format(axis="y", useOffset=False, style="plain")
    step = history.max_step_sigma
    shown = np.isfinite(step) & (step > 0)
    if shown.any():
        a2 = a.twinx()
        a2.semilogy(it[shown], step[shown], "s--", color="#d35400", label="largest correction / σ")
        a2.set_ylabel("largest correction (σ of an observation)", fontsize=8, color="#d35400")
    a.set_xlabel("iteration")
    a.set_ylabel("vᵀPv")
    integer_ticks(a, "x")
    from matplotlib.ticker import LogLocator

    # minor ticks of a log axis at 2 and 5 of each decade, not at 2 … 9 (120 ticks over 10 decades of
    # steps were most of this small figure's drawing)
    if log:
        plain_ticks(a, "y")
        a.yaxis.set_minor_locator(LogLocator(10.0, subs=(2.0, 5.0)))
    if shown.any():
        plain_ticks(a2, "y")
        a2.yaxis.set_minor_locator(LogLocator(10.0, subs=(2.0, 5.0)))
    a.set_title("Convergence", fontsize=10)
    fixed_layout(fig, left=1.0, right=1.0 if shown.any() else 0.2, bottom=0.55, top=0.3)
    return fig


def distortion(res, j: int, n: int = 60):
    """Radial profile along the x and y axes and the 2-D distortion field of camera ``j``, with
    ±1σ from the covariance of its additional parameters."""
    plt = _plt()
    cams = res.block_in.cameras
    model = get_ap_model(str(cams.ap_model[j]))
    names = res.cam_param_names[j]
    p = len(names) - 3
    if p == 0:
        return None
    ap = res.state.cam_params[j, 3:3 + p][None, :]
    c = float(res.state.cam_params[j, 0])
    meta = res.camera_meta[j]
    fw, fh = cams.format_mm[j]
    if not (fw > 0):
        obs = res.block_in.observations
        m = res.block_in.photos.camera[obs.photo] == j
        fw = fh = 2 * float(np.max(np.abs(obs.xy[m]))) if m.any() else 1.0
    Cap = np.asarray(res.cov_cameras[j], float)[3:3 + p, 3:3 + p]
    unit, scale, _ = image_units(res.block_in)
    g, gu = (scale, "px") if unit == "px" else (1.0, "mm")      # the format: px for a pixel source

    def delta(x, y):
        dx, dy = model.distortion(x, y, np.repeat(ap, len(x), 0), np.full(len(x), c), meta)
        J = model.jacobian_params(x, y, np.repeat(ap, len(x), 0), np.full(len(x), c), meta)
        sx = np.sqrt(np.clip(np.einsum("ni,ij,nj->n", J[:, 0], Cap, J[:, 0]), 0, None))
        sy = np.sqrt(np.clip(np.einsum("ni,ij,nj->n", J[:, 1], Cap, J[:, 1]), 0, None))
        return np.asarray(dx) * scale, np.asarray(dy) * scale, sx * scale, sy * scale

    with fixed_titles():
        fig, (a, b) = plt.subplots(1, 2, figsize=(10.5, 3.9))
    t = np.linspace(0, fw / 2, n)
    dx, _, sx, _ = delta(t, np.zeros(n))
    t2 = np.linspace(0, fh / 2, n)
    _, dy, _, sy = delta(np.zeros(n), t2)
    a.plot(g * t, dx, color="#1f4e9c", label="Δx along +x")
    a.plot(g * t2, dy, color="#d35400", label="Δy along +y")
    for tt, d, sd, col in ((t, dx, sx, "#1f4e9c"), (t2, dy, sy, "#d35400")):
        a.fill_between(g * tt, d - sd, d + sd, color=col, alpha=0.3, lw=0)
        a.plot(g * tt, d - sd, color=col, lw=0.6, ls=":")
        a.plot(g * tt, d + sd, color=col, lw=0.6, ls=":")
    a.axhline(0, color="k", lw=0.6)
    a.set_xlabel(f"distance from the principal point ({gu})")
    a.set_ylabel(f"distortion ({unit})")
    # σ itself on the right axis: a band of a well-determined camera is thinner than the line
    a2 = a.twinx()
    a2.plot(g * t, sx, color="#1f4e9c", lw=1, ls="--", label="σ(Δx)")
    a2.plot(g * t2, sy, color="#d35400", lw=1, ls="--", label="σ(Δy)")
    a2.set_ylim(0, 1.15 * max(float(np.max(sx)), float(np.max(sy)), 1e-12))
    a2.set_ylabel(f"σ of the distortion ({unit}, dashed)", fontsize=8)
    plain_ticks(a2, "y")
    smax = max(float(np.max(sx)), float(np.max(sy)))
    a.set_title(f"camera {cams.ids[j]} ({cams.ap_model[j]}): profiles ±1σ (largest σ {_img(smax, unit, 3)})",
                fontsize=10)
    h1, l1 = a.get_legend_handles_labels()
    h2, l2 = a2.get_legend_handles_labels()
    a.legend(h1 + h2, l1 + l2, fontsize=8)
    ng = 13
    X, Y = np.meshgrid(np.linspace(-fw / 2, fw / 2, ng), np.linspace(-fh / 2, fh / 2, ng))
    dx, dy, sx, sy = delta(X.ravel(), Y.ravel())
    mag = np.hypot(dx, dy)
    k = 0.06 * g * max(fw, fh) / (mag.max() or 1.0)
    # drawn as the residuals are: a pixel source in its image's pixel frame (v down), else mm, y up
    frame = ImageFrame(res.block_in)
    P = frame.camera_positions(np.column_stack([X.ravel(), Y.ravel()]), j) if frame.pixels else \
        np.column_stack([X.ravel(), Y.ravel()])
    D = frame.vectors(np.column_stack([dx, dy]) / scale) * (1.0 if frame.pixels else scale)
    b.quiver(P[:, 0], P[:, 1], k * D[:, 0], k * D[:, 1], angles="xy", scale_units="xy", scale=1, color="#1f4e9c",
             width=0.004)
    cs = b.contourf(P[:, 0].reshape(X.shape), P[:, 1].reshape(X.shape), np.hypot(sx, sy).reshape(X.shape), levels=10,
                    cmap="Oranges", alpha=0.5)
    fig.colorbar(cs, ax=b, label=f"σ of the distortion ({unit})")
    frame.finish(b, j if frame.extent(j) is not None else None, pad=0.04)
    b.set_title(f"field over the format; longest arrow {_img(mag.max(), unit, 3)}", fontsize=10)
    a.set_title(wrap_inches(a.get_title(), 4.6, 10), fontsize=10)
    fixed_layout(fig, left=0.85, right=0.5, bottom=0.55, top=0.3 + 0.17 * a.get_title().count("\n"), wspace=1.5)
    return fig


def reliability_maps(res):
    """Redundancy numbers and MDBs where they are: over the image format (every photo's image
    points, format coordinates) and over the object (plan view, per point).  Per image point the
    smaller r and the larger MDB of its x and y; per object point the smallest r and the largest
    MDB of its image coordinates.  A big block is drawn as hexbins of the cell's mean r / largest
    MDB (:func:`~baarda.pipeline.plots.value_map`).  None without statistics."""
    snap = res.snapshot
    if snap is None:
        return None
    plt = _plt()
    block = res.block_in
    obs, pts = block.observations, block.points
    unit, scale, _ = image_units(block)
    frame = ImageFrame(block)        # over the format: a pixel source in its pixel frame (v down)
    gu = frame.describe()
    act = np.asarray(res.obs_active, bool)
    r = np.where(act, np.nanmin(np.asarray(res.redundancy, float), axis=1), np.nan)
    mdb = np.asarray(stats.mdb(snap), float).reshape(-1, 2)
    with np.errstate(invalid="ignore"):
        m_img = np.where(act, np.nanmax(np.where(np.isfinite(mdb), mdb, -np.inf), axis=1), np.nan) * scale
    m_img[~np.isfinite(m_img)] = np.nan
    xy = frame.positions(obs.xy, obs.photo)
    # per object point: smallest r, largest MDB of its image coordinates
    n_pts = len(pts)
    r_pt = np.full(n_pts, np.inf)
    m_pt = np.full(n_pts, -np.inf)
    fin = np.isfinite(r)
    np.minimum.at(r_pt, obs.point[fin], r[fin])
    fin = np.isfinite(m_img)
    np.maximum.at(m_pt, obs.point[fin], m_img[fin])
    r_pt[~np.isfinite(r_pt)] = np.nan
    m_pt[~np.isfinite(m_pt)] = np.nan
    XYZ = res.state.XYZ
    used = res.point_used & np.isfinite(XYZ).all(axis=1)
    # over the object: the view onto its two widest axes (plan X, Y for an aerial block; X, Z for a
    # façade or a panel standing upright, whose plan is a line)
    spans = [np.subtract(*robust_limits(XYZ[used, t])[::-1]) if used.any() else 1.0 for t in range(3)]
    ia, ib = sorted(np.argsort(spans)[::-1][:2])
    view = "plan (X, Y)" if (ia, ib) == (0, 1) else f"view ({'XYZ'[ia]}, {'XYZ'[ib]})"
    mfin = m_img[np.isfinite(m_img)]
    mtop = float(np.quantile(mfin, 0.98)) if mfin.size else 1.0
    mlo = float(np.quantile(mfin, 0.02)) if mfin.size else 0.0     # similar MDBs: colours over their spread
    mlo = mlo if mlo < mtop else 0.0
    with fixed_titles():
        fig, axes = plt.subplots(2, 2, figsize=(11.5, 7.0))
    big = act.sum() > MAP_CELLS
    what = "hexbin: mean r / largest MDB of each cell" if big else "one dot per image point"
    panels = [(axes[0, 0], xy[:, 0], xy[:, 1], r, "viridis", 0.0, 1.0, "min", f"redundancy r over the format ({gu})"),
              (axes[0, 1], xy[:, 0], xy[:, 1], m_img, "magma_r", mlo, mtop, "max", f"MDB over the format ({gu})"),
              (axes[1, 0], XYZ[used, ia], XYZ[used, ib], r_pt[used], "viridis", 0.0, 1.0, "min",
               f"smallest r of each point, {view} ({object_unit_text(block)})"),
              (axes[1, 1], XYZ[used, ia], XYZ[used, ib], m_pt[used], "magma_r", mlo, mtop, "max",
               f"largest MDB of each point's image coordinates, {view} ({object_unit_text(block)})")]
    for n, (ax, x, y, c, cmap, lo, hi, red, title) in enumerate(panels):
        h = value_map(ax, x, y, c, cmap=cmap, vmin=lo, vmax=hi, reduce="mean" if red == "min" and big else red,
                      s=4 if n < 2 else 8)
        cb = fig.colorbar(h, ax=ax, extend=("both" if mlo > 0 else "max") if n % 2 else "neither", fraction=0.046,
                          pad=0.03)
        cb.set_label("r" if n % 2 == 0 else f"MDB ({unit})", fontsize=8)
        cb.ax.tick_params(labelsize=7)
        if n < 2:
            frame.finish(ax, np.unique(block.photos.camera))     # every camera's frame
            _few_ticks(ax)
        else:
            xl = robust_limits(x)
            yl = robust_limits(y)
            mark_outside(ax, x, y, xl, yl, label="points beyond the axes (at the edge)")
            if ax.get_legend_handles_labels()[0]:
                ax.legend(fontsize=7, loc="best")
            ax.set_aspect("equal", adjustable="box")
            map_ticks(ax, x)
            ax.set_xlabel(f"{'XYZ'[ia]} ({object_unit_text(block)})", fontsize=7)
            ax.set_ylabel(f"{'XYZ'[ib]} ({object_unit_text(block)})", fontsize=7)
        ax.set_title(wrap_inches(title, 3.6, 9), fontsize=9)
        ax.tick_params(labelsize=7)
    head = wrap_inches(f"Reliability maps ({what}); MDB colours from the 2nd to the 98th percentile, "
                       f"{_img(mlo, unit, 3)} – {_img(mtop, unit, 3)}", 11.0, 10)
    fig.suptitle(head, fontsize=10)
    lines = [max(axes[i, 0].get_title().count("\n"), axes[i, 1].get_title().count("\n")) for i in (0, 1)]
    fixed_layout(fig, left=0.9, right=0.8, bottom=0.75, top=0.66 + 0.17 * head.count("\n") + 0.17 * lines[0],
                 wspace=1.55, hspace=0.95 + 0.15 * lines[1])
    return fig


def bundle_figures(res, decision=None, eccentricity=None) -> dict:
    """Every figure of a bundle result: name → (figure, caption), the most telling first (report.html
    shows a stage's first figures and folds the rest): residuals, network, distortion (where the
    camera's additional parameters are estimated), reliability maps, check points; then w, redundancy
    numbers, convergence."""
    out = {}
    images = res.block_in.photos.images()     # photo id → image file (``Photos.image_path``), where a source found it
    v = np.asarray(res.residuals, float)[np.asarray(res.obs_active, bool)]
    if np.any(np.abs(v) > 1e-12):        # a planned network (error-free observations) has no residual to draw
        out["residuals"] = (residual_vectors(res, decision, images),
                            "Residual vectors per photo over the format" + (" and the photo" if images else ""))
    if eccentricity is not None:     # the corrections of circular targets' centres (BundleReport.eccentricity)
        out["eccentricity"] = (residual_vectors(res, decision, images, vectors=eccentricity.final.correction,
                                                what="Eccentricity corrections (ellipse centre − image of the "
                                                     "circle's centre)"),
                               "Eccentricity of the circular targets' imaged centres, subtracted from the "
                               "detections (the photos with the largest corrections first)")
    out["network"] = (network(res), "Network: plan and elevation with standard error ellipses")
    snap = res.snapshot
    cams = res.block_in.cameras
    obs = res.block_in.observations
    n_obs = np.bincount(res.block_in.photos.camera[obs.photo[res.obs_active]], minlength=len(cams))
    with_ap = (np.asarray(res.camera_used, bool) & (np.asarray(cams.ap_model).astype(str) != "none")
               & (np.any(np.asarray(res.camera_free)[:, 3:], axis=1) | np.any(res.state.cam_params[:, 3:] != 0, axis=1)))
    order = np.argsort(-n_obs, kind="stable")          # a BAL block has a camera per photo: no loop over them
    drawn = [int(j) for j in order[with_ap[order]][:MAX_DISTORTION_CAMERAS]]
    for j in drawn:
        fig = distortion(res, j)
        if fig is not None:
            out[f"distortion_{cams.ids[j]}"] = (fig, f"Distortion of camera {cams.ids[j]} with ±1σ")
    if snap is not None:
        maps = reliability_maps(res)
        if maps is not None:
            out["reliability"] = (maps, "Redundancy numbers and MDBs over the image format and over the object (plan)")
    if res.check:
        out["checkpoints"] = (checkpoint_errors(res), "Check-point error vectors")
    if snap is not None:
        ok = stats.controlled(snap)
        ds = stats.data_snooping(snap)
        out["w"] = (w_distribution(ds.w[ok], ds.critical), "w against N(0, 1): histogram and QQ plot")
        out["redundancy"] = (redundancy_numbers(np.asarray(snap.r)[np.asarray(snap.active, bool)]),
                             "Redundancy numbers of the observation rows")
    out["convergence"] = (convergence(res.history), "Convergence of vᵀPv")
    return out
