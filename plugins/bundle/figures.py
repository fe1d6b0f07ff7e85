"""The bundle's figures for ``report.html`` (matplotlib, drawn by the engine with Agg).

Only called from :meth:`BundleAdjustment.plots`; the numbers come from the
:class:`~baarda.pipeline.adjustment.BundleResult` and its snapshot, never recomputed.
"""

from __future__ import annotations

import numpy as np

from baarda.pipeline.api import stats
from baarda.pipeline.camera import get_ap_model

from baarda.pipeline.plots import map_ticks, redundancy_numbers, role_points, w_distribution

from .protocol import image_units
from baarda.pipeline.units import fmt_obj, fmt_q, object_unit_text

MAX_DISTORTION_CAMERAS = 4
"""Cameras whose distortion is drawn (most image points first; a COLMAP block may have dozens)."""
MAX_ELLIPSES = 3000
"""Points whose error ellipse is drawn (the first ones; the rest would be ink, not information)."""
MAX_PHOTOS = 12
"""Photos drawn in the residual figure (the largest RMS first)."""


def _plt():
    import matplotlib.pyplot as plt

    return plt


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


def residual_vectors(res, decision=None, images: dict | None = None):
    """Residual vectors (observed − computed) per photo over the format, the photos with the
    largest RMS first; one arrow scale for all panels.  ``images``: photo id → image file, drawn
    behind the arrows (the pixel grid mapped onto the format: the sensor centre is the origin)."""
    plt = _plt()
    block = res.block_in
    obs, cams = block.observations, block.cameras
    unit, scale, _ = image_units(block)
    g = scale if unit == "px" else 1.0          # format coordinates: px for a pixel source, else mm
    act = np.asarray(res.obs_active, bool)
    v = np.asarray(res.residuals, float)
    ss = np.bincount(obs.photo[act], weights=(v[act] ** 2).sum(axis=1), minlength=len(block.photos))
    cnt = np.bincount(obs.photo[act], minlength=len(block.photos))
    photos = np.flatnonzero(cnt)
    r = np.sqrt(ss[photos] / cnt[photos])
    photos = photos[np.argsort(-r, kind="stable")][:MAX_PHOTOS]
    n = len(photos)
    ncol = min(4, n)
    nrow = int(np.ceil(n / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.3 * ncol, 3.0 * nrow + 0.4), squeeze=False)
    vmax = np.nanpercentile(np.hypot(v[act, 0], v[act, 1]), 95) if act.any() else 1.0
    for ax, p in zip(axes.ravel(), photos):
        j = block.photos.camera[p]
        fw, fh = np.asarray(cams.format_mm[j], float) * g
        m = act & (obs.photo == p)
        xy = obs.xy[m] * g
        size = max(fw, fh) if fw > 0 else np.ptp(xy) or 1.0
        k = 0.08 * size / (g * vmax or 1.0)      # format units of arrow per format unit of residual
        flag = np.zeros(m.sum(), bool) if decision is None else np.isin(np.asarray(decision)[m], ["flagged", "rejected"])
        vm = v[m] * g
        ax.quiver(xy[~flag, 0], xy[~flag, 1], k * vm[~flag, 0], k * vm[~flag, 1], angles="xy", scale_units="xy",
                  scale=1, color="#1f4e9c", width=0.006)
        if flag.any():
            ax.quiver(xy[flag, 0], xy[flag, 1], k * vm[flag, 0], k * vm[flag, 1], angles="xy", scale_units="xy",
                      scale=1, color="#c0392b", width=0.008)
        ax.plot(xy[:, 0], xy[:, 1], ".", ms=2, color="#555")
        src = (images or {}).get(str(block.photos.ids[p]))
        back = _backdrop(src) if src else None
        if back is not None and fw > 0:
            ax.imshow(back, cmap="gray", extent=(-fw / 2, fw / 2, -fh / 2, fh / 2), origin="upper", alpha=0.45,
                      zorder=0)
        if fw > 0:
            ax.add_patch(plt.Rectangle((-fw / 2, -fh / 2), fw, fh, fill=False, ec="#999", lw=0.8))
        rm = np.sqrt(np.mean(v[m] ** 2)) * scale
        ax.set_title(f"photo {block.photos.ids[p]}: RMS {fmt_q(rm, unit, 3)}", fontsize=9)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    fig.suptitle(f"Image residuals (observed − computed) over the format ({'px' if unit == 'px' else 'mm'}, y up); an arrow of "
                 f"{0.08 * 100:.0f} % of the format is {fmt_q(vmax * scale, unit, 3)} (95th percentile); red: flagged/rejected",
                 fontsize=10)
    fig.tight_layout()
    return fig


def _ellipse(cov2):
    w, V = np.linalg.eigh(np.asarray(cov2, float))
    w = np.sqrt(np.clip(w, 0, None))
    t = np.linspace(0, 2 * np.pi, 40)
    return V @ np.vstack([w[0] * np.cos(t), w[1] * np.sin(t)])


def network(res):
    """Plan (X, Y) and elevation (X, Z) of projection centres and points, with the points'
    standard error ellipses exaggerated by one common factor."""
    plt = _plt()
    from matplotlib.collections import LineCollection

    block = res.block_in
    pts, used = block.points, res.point_used
    XYZ, X0 = res.state.XYZ, res.state.X0[res.photo_used]
    C = res.cov_points
    sig = res.point_sigmas()
    ok = used & np.all(np.isfinite(sig), axis=1)
    span = max(float(np.ptp(np.vstack([XYZ[used], X0]), axis=0)[:2].max()), 1e-9)
    smax = float(np.max(sig[ok])) if ok.any() else 0.0
    k = 0.04 * span / smax if smax > 0 else 1.0
    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    for ax, (i, j, name) in zip(axes, [(0, 1, "plan (X, Y)"), (0, 2, "elevation (X, Z)")]):
        role_points(ax, XYZ, pts.role, used, i, j)
        ax.plot(X0[:, i], X0[:, j], "s", ms=5, color="k", label=f"projection centres ({len(X0)})")
        sel = np.flatnonzero(ok)[:MAX_ELLIPSES]
        segs = [np.column_stack([XYZ[p, i] + e[0], XYZ[p, j] + e[1]])
                for p in sel for e in [_ellipse(C[p][np.ix_([i, j], [i, j])]) * k]]
        ax.add_collection(LineCollection(segs, colors="#28a0a0", linewidths=0.6))   # the recordings' ellipsoid colour
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(name, fontsize=10)
        ax.set_xlabel(f"{'XYZ'[i]} ({object_unit_text(block)})")
        ax.set_ylabel(f"{'XYZ'[j]} ({object_unit_text(block)})")
        map_ticks(ax, np.r_[XYZ[used, i], X0[:, i]])
        ax.tick_params(labelsize=8)
    axes[0].legend(fontsize=7, loc="best")
    fig.suptitle(f"Network; standard error ellipses × {k:.3g} (largest σ {fmt_obj(smax, object_unit_text(block), 3)})", fontsize=10)
    fig.tight_layout()
    return fig


def checkpoint_errors(res):
    plt = _plt()
    block = res.block_in
    pts = block.points
    chk = np.flatnonzero((pts.role == "check") & res.point_used)
    d = res.state.XYZ[chk] - pts.XYZ[chk]
    ou = block.object_unit
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
    for p, x, y in zip(pts.ids[chk], pts.XYZ[chk, 0], pts.XYZ[chk, 1]):
        a.annotate(str(p), (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
    a.set_aspect("equal", adjustable="datalim")
    map_ticks(a, res.state.XYZ[res.point_used, 0])
    a.set_title(f"check points: plan error vectors × {k:.3g} (adjusted − surveyed)", fontsize=10)
    b.bar(np.arange(len(chk)), d[:, 2], color="#5b7fb5")
    b.set_xticks(np.arange(len(chk)), [str(x) for x in pts.ids[chk]], fontsize=7, rotation=90)
    b.axhline(0, color="k", lw=0.7)
    b.set_title(f"dZ ({ou})", fontsize=10)
    fig.tight_layout()
    return fig


def convergence(history):
    """vᵀPv and the largest correction per iteration of a :class:`~baarda.pipeline.adjustment.Convergence`."""
    plt = _plt()
    it = history.iteration
    fig, a = plt.subplots(figsize=(6.5, 3.4))
    vtpv = history.vtpv
    (a.semilogy if np.any(vtpv > 0) else a.plot)(it, np.where(vtpv > 0, vtpv, np.nan) if np.any(vtpv > 0) else vtpv,
                                                 "o-", color="#1f4e9c", label="vᵀPv")
    step = history.max_step_sigma
    shown = np.isfinite(step) & (step > 0)
    if shown.any():
        a2 = a.twinx()
        a2.semilogy(it[shown], step[shown], "s--", color="#d35400", label="largest correction / σ")
        a2.set_ylabel("largest correction (σ of an observation)", fontsize=8, color="#d35400")
    a.set_xlabel("iteration")
    a.set_ylabel("vᵀPv")
    a.set_title("Convergence", fontsize=10)
    fig.tight_layout()
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

    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.6))
    t = np.linspace(0, fw / 2, n)
    dx, _, sx, _ = delta(t, np.zeros(n))
    a.plot(g * t, dx, color="#1f4e9c", label="Δx along +x")
    a.fill_between(g * t, dx - sx, dx + sx, color="#1f4e9c", alpha=0.2)
    t2 = np.linspace(0, fh / 2, n)
    _, dy, _, sy = delta(np.zeros(n), t2)
    a.plot(g * t2, dy, color="#d35400", label="Δy along +y")
    a.fill_between(g * t2, dy - sy, dy + sy, color="#d35400", alpha=0.2)
    a.axhline(0, color="k", lw=0.6)
    a.set_xlabel(f"distance from the principal point ({gu})")
    a.set_ylabel(f"distortion ({unit})")
    a.set_title(f"camera {cams.ids[j]} ({cams.ap_model[j]}): profiles, ±1σ bands", fontsize=10)
    a.legend(fontsize=8)
    ng = 13
    X, Y = np.meshgrid(np.linspace(-fw / 2, fw / 2, ng), np.linspace(-fh / 2, fh / 2, ng))
    dx, dy, sx, sy = delta(X.ravel(), Y.ravel())
    mag = np.hypot(dx, dy)
    k = 0.06 * g * max(fw, fh) / (mag.max() or 1.0)
    b.quiver(g * X.ravel(), g * Y.ravel(), k * dx, k * dy, angles="xy", scale_units="xy", scale=1, color="#1f4e9c",
             width=0.004)
    cs = b.contourf(g * X, g * Y, np.hypot(sx, sy).reshape(X.shape), levels=10, cmap="Oranges", alpha=0.5)
    fig.colorbar(cs, ax=b, label=f"σ of the distortion ({unit})")
    b.set_aspect("equal")
    b.set_title(f"field over the format ({gu}); longest arrow {fmt_q(mag.max(), unit, 3)}", fontsize=10)
    fig.tight_layout()
    return fig


def bundle_figures(res, decision=None) -> dict:
    """Every figure of a bundle result: name → (figure, caption)."""
    out = {}
    images = res.block_in.photos.images()     # photo id → image file (``Photos.image_path``), where a source found it
    out["residuals"] = (residual_vectors(res, decision, images),
                        "Residual vectors per photo over the format" + (" and the photo" if images else ""))
    snap = res.snapshot
    if snap is not None:
        ok = stats.controlled(snap)
        ds = stats.data_snooping(snap)
        out["w"] = (w_distribution(ds.w[ok], ds.critical), "w against N(0, 1): histogram and QQ plot")
        out["redundancy"] = (redundancy_numbers(np.asarray(snap.r)[np.asarray(snap.active, bool)]),
                             "Redundancy numbers of the observation rows")
    cams = res.block_in.cameras
    obs = res.block_in.observations
    n_obs = np.bincount(res.block_in.photos.camera[obs.photo[res.obs_active]], minlength=len(cams))
    drawn = [j for j in np.argsort(-n_obs, kind="stable")
             if res.camera_used[j] and str(cams.ap_model[j]) != "none"
             and (np.any(res.camera_free[j, 3:]) or np.any(res.state.cam_params[j, 3:] != 0))][:MAX_DISTORTION_CAMERAS]
    for j in drawn:
        if True:
            fig = distortion(res, j)
            if fig is not None:
                out[f"distortion_{cams.ids[j]}"] = (fig, f"Distortion of camera {cams.ids[j]} with ±1σ")
    out["network"] = (network(res), "Network: plan and elevation with standard error ellipses")
    if res.check:
        out["checkpoints"] = (checkpoint_errors(res), "Check-point error vectors")
    out["convergence"] = (convergence(res.history), "Convergence of vᵀPv")
    return out
