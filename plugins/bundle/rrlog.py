"""The bundle stage's rerun recording (called only from ``BundleAdjustment.log``).

Entities (under the stage id: the recording roots every path there)
    ``world/points``                object points, coloured by role (labels = ids)
    ``world/points/precision``      their error ellipsoids (1 σ, enlarged: ``precision_scale``)
    ``world/photos/<id>``           Transform3D (world_from_cam) + Pinhole (c, format in mm, RUB)
    ``world/rejected_rays``         rays of rejected / flagged observations (red)
    ``images/<id>/observed``        image points (u = x + w/2, v = h/2 − y: mm, y down as in 2-D views)
    ``images/<id>/residuals``       residual vectors from computed to observed, × arrow scale
    ``cameras/<id>/distortion``     distortion field of the estimated APs on a grid, × scale
    ``convergence/{cost,sigma0,damping,step}/*``  vᵀPv, σ̂0, λ, largest step per ``iteration``; one
                                    that did not change (λ = 0 throughout) under ``…/constants``
    ``ids/{global_test,w}/*``       with ``blunders = "ids"``: T with F critical, max |w| (K constant:
                                    ``ids/w/constants``) per ``rejection``
    ``bundle/summary``              σ̂0, dof, vᵀPv, arrow and ellipsoid scales (the report is the
                                    runner's ``<stage>/summary``)
"""

from __future__ import annotations

import numpy as np

from baarda.pipeline.geometry import rotation_from_opk_many

from baarda.pipeline.camera import get_ap_model

from .protocol import image_units
from baarda.pipeline.api import point_ellipsoids, role_colors, thin, view_from_photo, view_vectors
from baarda.pipeline.recording import log_series

RED, GREY, BLUE = [230, 40, 40], [150, 150, 150], [40, 90, 230]


def _safe(s: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in str(s))


def _format(block, j, xy):
    f = np.asarray(block.cameras.format_mm[j], float)
    if not np.all(np.isfinite(f)) or np.any(f <= 0):
        ext = np.nanmax(np.abs(xy), axis=0) if len(xy) else np.array([10.0, 10.0])
        f = 2.0 * np.maximum(ext, 1e-3)
    return f


def log_bundle(rec, rep, report: str, max_photos: int | None = None) -> None:
    """The recording of the workflow's :class:`~baarda.pipeline.adjustment.BundleReport` ``rep``.
    Every used photo is logged unless ``max_photos`` is given (then every k-th, and the recording's
    notes say so)."""
    import rerun as rr

    res, decision, options = rep.result, rep.decision, rep.config.output
    block = res.block_in
    st = res.state
    pts, photos, obs = block.points, block.photos, block.observations
    used = res.point_used
    rec.log("world/points", rr.Points3D(st.XYZ[used], labels=pts.ids[used].tolist(),
                                        colors=role_colors(pts.role[used]),
                                        radii=rr.Radius.ui_points(4.0)), static=True)
    pscale = _log_precision(rec, res, used)
    R = rotation_from_opk_many(np.nan_to_num(st.opk))
    v = res.residuals
    fin = np.isfinite(v).all(axis=1)
    scale = options.arrow_scale
    if scale <= 0:
        act = res.obs_active & fin
        rms = float(np.sqrt(np.mean(v[act] ** 2))) if act.any() else 0.0
        ext = float(np.nanmedian([_format(block, j, obs.xy[obs.photo == i]).max()
                                  for i, j in enumerate(photos.camera)])) if len(photos) else 1.0
        scale = 0.03 * ext / rms if rms > 0 else 1.0
    computed = obs.xy - np.nan_to_num(v)
    bad = np.isin(decision, ("rejected", "flagged"))
    for i in thin(rec, np.flatnonzero(res.photo_used), max_photos, "photos"):
        pid = _safe(photos.ids[i])
        j = photos.camera[i]
        sel = np.flatnonzero(obs.photo == i)
        fmt = _format(block, j, obs.xy[sel])
        c = float(st.cam_params[j, 0])
        rec.log(f"world/photos/{pid}", rr.Transform3D(translation=st.X0[i], mat3x3=R[i].T), static=True)
        rec.log(f"world/photos/{pid}", rr.Pinhole(focal_length=c, width=float(fmt[0]), height=float(fmt[1]),
                                                   principal_point=[fmt[0] / 2 + st.cam_params[j, 1],
                                                                    fmt[1] / 2 - st.cam_params[j, 2]],
                                                   camera_xyz=rr.ViewCoordinates.RUB,
                                                   image_plane_distance=float(0.1 * _depth(st, i, obs, sel))),
                static=True)
        labels = pts.ids[obs.point[sel]].tolist()
        rec.log(f"images/{pid}/observed", rr.Points2D(view_from_photo(obs.xy[sel], fmt), labels=labels,
                                                      colors=[RED if b else BLUE for b in bad[sel]],
                                                      radii=rr.Radius.ui_points(3.0)), static=True)
        ok = sel[fin[sel]]
        if ok.size:
            vec = v[ok] * scale
            rec.log(f"images/{pid}/residuals",
                    rr.Arrows2D(origins=view_from_photo(computed[ok], fmt), vectors=view_vectors(vec),
                                colors=[RED if b else GREY for b in bad[ok]]), static=True)
    # rejected / flagged rays
    rb = np.flatnonzero(bad & res.photo_used[obs.photo] & used[obs.point])
    if rb.size:
        strips = [np.vstack([st.X0[obs.photo[k]], st.XYZ[obs.point[k]]]) for k in rb]
        rec.log("world/rejected_rays", rr.LineStrips3D(strips, colors=RED,
                                                       labels=[f"{photos.ids[obs.photo[k]]}/{pts.ids[obs.point[k]]}: "
                                                               f"{decision[k]}" for k in rb]), static=True)
    # distortion field of the estimated APs (labelled in px for a pixel source, else µm)
    unit, uscale, _ = image_units(block)
    for j in np.flatnonzero(res.camera_used):
        mdl = get_ap_model(block.cameras.ap_model[j])
        if mdl.n_params == 0:
            continue
        fmt = _format(block, j, obs.xy[np.isin(obs.photo, np.flatnonzero(photos.camera == j))])
        gx, gy = np.meshgrid(np.linspace(-fmt[0] / 2, fmt[0] / 2, 15), np.linspace(-fmt[1] / 2, fmt[1] / 2, 11))
        xb, yb = gx.ravel(), gy.ravel()
        prm = np.broadcast_to(st.cam_params[j, 3:3 + mdl.n_params], (xb.size, mdl.n_params))
        dx, dy = mdl.distortion(xb, yb, prm, np.full(xb.size, st.cam_params[j, 0]), res.camera_meta[j])
        mag = np.hypot(dx, dy)
        if not mag.max() > 0:          # no distortion at all (APs zero, e.g. fixed): no empty view
            continue
        dscale = 0.05 * fmt.max() / mag.max()
        rec.log(f"cameras/{_safe(block.cameras.ids[j])}/distortion",
                rr.Arrows2D(origins=view_from_photo(np.column_stack([xb, yb]), fmt),
                            vectors=view_vectors(np.column_stack([dx, dy]) * dscale),
                            labels=[f"{m * uscale:.{2 if unit == 'px' else 1}f} {unit}" for m in mag]), static=True)
        rec.log(f"cameras/{_safe(block.cameras.ids[j])}/distortion_scale", rr.AnyValues(arrow_scale=dscale),
                static=True)
    if rep.gnss is not None:     # GNSS antennas: observed positions, residual arrows computed → observed (scaled)
        gs, gnss = rep.gnss.rows, block.gnss
        g_obs, g_v = gnss.XYZ[gs.index], gs.v
        g_photos = block.photos.ids[gnss.photo[gs.index]].astype(str).tolist()
        g_rms = float(np.sqrt(np.mean(g_v ** 2)))
        g_sc = 0.03 * float(np.ptp(st.X0[res.photo_used], axis=0).max()) / g_rms if g_rms > 0 else 1.0
        rec.log("world/gnss/antennas", rr.Points3D(g_obs, labels=g_photos, radii=rr.Radius.ui_points(5.0)), static=True)
        rec.log("world/gnss/residuals", rr.Arrows3D(origins=g_obs - g_v * g_sc, vectors=g_v * g_sc), static=True)
        rec.log("world/gnss/arrow_scale", rr.AnyValues(arrow_scale=g_sc), static=True)
    rec.log("bundle/summary", rr.AnyValues(sigma0_hat=res.sigma0_hat, dof=res.dof, vtpv=res.vtpv,
                                           arrow_scale=scale, precision_scale=pscale,
                                           iterations=res.iterations), static=True)
    dof = max(res.dof, 1)
    # one view each (their scales differ by orders of magnitude); a series that stays the same for the
    # whole run (λ = 0 when no step was damped) is a static value under convergence/<group>/constants
    hist = res.history
    it = hist.iteration.tolist()
    log_series(rec, "convergence/cost", it, {"vtpv": hist.vtpv.tolist()})
    log_series(rec, "convergence/sigma0", it, {"sigma0_hat": np.sqrt(hist.vtpv / dof).tolist()})
    log_series(rec, "convergence/damping", it, {"lambda": hist.lam.tolist()})
    log_series(rec, "convergence/step", it, {"max_step_sigma": hist.max_step_sigma.tolist()})
    # iterated data snooping inside the bundle: one step per rejection (the same groups as blunder-rejection)
    ids = rep.ids
    if ids is not None and ids.history:
        steps = [int(h.iteration) for h in ids.history]
        log_series(rec, "ids/global_test", steps, {"T": [float(h.T) for h in ids.history]},
                   {"F_critical": [float(h.critical) for h in ids.history]}, timeline="rejection")
        log_series(rec, "ids/w", steps, {"w_max": [abs(float(h.w_max)) for h in ids.history]},
                   {"K": [float(ids.critical)] * len(steps)}, timeline="rejection")


def _log_precision(rec, res, used) -> float:
    """The adjusted points' 1-σ error ellipsoids, enlarged to 1 % of the network's size (the factor
    is returned and logged); nothing when the bundle computed no point covariances."""
    import rerun as rr

    cov = getattr(res, "cov_points", None)
    if cov is None:
        return float("nan")
    idx = np.flatnonzero(used)
    c, half, q, scale = point_ellipsoids(res.state.XYZ[idx], np.asarray(cov)[idx])
    if not len(c):
        return float("nan")
    rec.log("world/points/precision", rr.Ellipsoids3D(centers=c, half_sizes=half, quaternions=q,
                                                      colors=[40, 170, 170], fill_mode="MajorWireframe"),
            static=True)
    return float(scale)


def _depth(st, i, obs, sel):
    if sel.size == 0:
        return 1.0
    d = np.linalg.norm(st.XYZ[obs.point[sel]] - st.X0[i], axis=1)
    d = d[np.isfinite(d)]
    return float(np.median(d)) if d.size else 1.0
