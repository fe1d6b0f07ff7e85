"""The bundle stage's rerun recording (called only from ``BundleAdjustment.log``).

Entities (under the stage id: the recording roots every path there)
    ``world/points``                object points, coloured by role (labels = ids)
    ``world/points/precision``      their error ellipsoids (1 σ, enlarged: ``precision_scale``)
    ``world/photos/<id>``           Transform3D (world_from_cam) + Pinhole (c, format in mm, RUB); a
                                    photo in a rig's frame is drawn under its rig instead:
    ``world/rigs/<rig>/frames/<frame>``            Transform3D (world_from_rig: the frame's pose) and
                                    ``…/baselines`` (lines from the reference camera to each sensor)
    ``world/rigs/<rig>/frames/<frame>/<camera>``   Transform3D (rig_from_sensor: c_s, R_sᵀ) + Pinhole,
                                    and the photo's id (``AnyValues``)
    ``rigs/<rig>/sensors``          each sensor's pose in the rig with σ, baseline, stability test
                                    (Markdown), ``rigs/<rig>/sensors/<camera>`` the same as values
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

from baarda.pipeline.adjustment import rig_structure
from baarda.pipeline.geometry import rotation_from_opk_many

from baarda.pipeline.camera import get_ap_model

from .protocol import image_units
from baarda.pipeline.api import point_ellipsoids, role_colors, thin, view_from_photo, view_vectors
from baarda.pipeline.recording import ENTITIES_MAX, log_on_timeline, log_per_entity, log_series

RED, GREY, BLUE = [230, 40, 40], [150, 150, 150], [40, 90, 230]


def _safe(s: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in str(s))


def _formats(block, group, n_groups, cam_of_group):
    """:func:`_format` of every group at once (a photo's or a camera's observations): ``group`` is the
    group of each observation, ``cam_of_group`` the camera of each group; without a known format the
    extent of the group's image points (20 × 20 mm for a group without any)."""
    xy = np.abs(np.asarray(block.observations.xy, float))
    ext = np.full((n_groups, 2), -np.inf)
    np.maximum.at(ext, np.asarray(group, np.int64), np.where(np.isnan(xy), -np.inf, xy))
    seen = np.bincount(np.asarray(group, np.int64), minlength=n_groups)[:n_groups] > 0
    ext[~seen] = 10.0
    ext[np.isneginf(ext)] = np.nan                   # only NaN coordinates: as np.nanmax
    own = 2.0 * np.maximum(ext, 1e-3)
    f = np.asarray(block.cameras.format_mm, float).reshape(-1, 2)[np.asarray(cam_of_group, np.int64)]
    known = np.isfinite(f).all(axis=1) & (f > 0).all(axis=1)
    return np.where(known[:, None], f, own)


def _group_median(values, group, n_groups):
    """``np.median`` of ``values`` per group (NaN for an empty group), in one sort."""
    values = np.asarray(values, float)
    group = np.asarray(group, np.int64)
    order = np.lexsort((values, group))
    counts = np.bincount(group, minlength=n_groups)[:n_groups]
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    out = np.full(n_groups, np.nan)
    has = counts > 0
    lo = values[order[start[has] + (counts[has] - 1) // 2]]
    hi = values[order[start[has] + counts[has] // 2]]
    out[has] = (lo + hi) / 2.0
    return out


def _colors(flags, yes, no) -> np.ndarray:
    return np.where(np.asarray(flags, bool)[:, None], np.asarray(yes, np.uint8), np.asarray(no, np.uint8)).astype(np.uint8)


def log_bundle(rec, rep, report: str, max_photos: int | None = None) -> None:
    """The recording of the workflow's :class:`~baarda.pipeline.adjustment.BundleReport` ``rep``.
    Every used photo is logged unless ``max_photos`` is given (then every k-th, and the recording's
    notes say so).  Per-observation and per-photo data go through rerun's columnar API
    (:func:`~baarda.pipeline.recording.log_per_entity`): each array is converted once and every
    photo's entity gets its slice, so the time is linear in the observations, not in photos ×
    observations."""
    import pyarrow as pa
    import rerun as rr

    res, decision, options = rep.result, rep.decision, rep.config.output
    block = res.block_in
    st = res.state
    pts, photos, obs = block.points, block.photos, block.observations
    used = res.point_used
    point_ids = pa.array(np.asarray(pts.ids).astype(str))
    rec.log("world/points", rr.Points3D(st.XYZ[used], labels=point_ids.filter(pa.array(used)),
                                        colors=role_colors(pts.role[used]),
                                        radii=rr.Radius.ui_points(4.0)), static=True)
    pscale = _log_precision(rec, res, used)
    R = rotation_from_opk_many(np.nan_to_num(st.opk))
    v = res.residuals
    fin = np.isfinite(v).all(axis=1)
    n_ph = len(photos)
    fmts = _formats(block, obs.photo, n_ph, photos.camera)          # per photo
    scale = options.arrow_scale
    if scale <= 0:
        act = res.obs_active & fin
        rms = float(np.sqrt(np.mean(v[act] ** 2))) if act.any() else 0.0
        ext = float(np.nanmedian(fmts.max(axis=1))) if n_ph else 1.0
        scale = 0.03 * ext / rms if rms > 0 else 1.0
    computed = obs.xy - np.nan_to_num(v)
    bad = np.isin(decision, ("rejected", "flagged"))
    shown = thin(rec, np.flatnonzero(res.photo_used), max_photos, "photos")
    pids = [_safe(p) for p in np.asarray(photos.ids)[shown].tolist()]
    # the photos' cameras: one Transform3D + Pinhole per photo, from whole arrays
    d = np.linalg.norm(st.XYZ[obs.point] - st.X0[obs.photo], axis=1)
    dok = np.isfinite(d)
    depth = _group_median(d[dok], obs.photo[dok], n_ph)
    depth = np.where(np.isfinite(depth), depth, 1.0)[shown]
    cp = st.cam_params[photos.camera[shown]]
    f = fmts[shown]
    K = np.zeros((shown.size, 3, 3))
    K[:, 0, 0] = K[:, 1, 1] = cp[:, 0]
    K[:, 0, 2] = f[:, 0] / 2 + cp[:, 1]
    K[:, 1, 2] = f[:, 1] / 2 - cp[:, 2]
    K[:, 2, 2] = 1.0
    many = shown.size > ENTITIES_MAX
    if many:       # one entity per photo would make the file unreadable: centres here, 2-D data on a timeline
        rec.note(f"{shown.size} photos (more than {ENTITIES_MAX}): the cameras are drawn as their projection "
                 "centres (world/photos, labelled), and the image points and residual arrows of all photos are "
                 "one 2-D view (images/all) over the timeline 'photo': step k is the k-th photo, named in "
                 "images/all/photo")
        rec.log("world/photos", rr.Points3D(st.X0[shown], labels=pa.array(pids), colors=GREY,
                                            radii=rr.Radius.ui_points(3.0)), static=True)
        log_on_timeline(rec, "images/all/photo", "photo", np.ones(shown.size, int),
                        rr.AnyValues.columns(photo=pa.array(np.asarray(photos.ids)[shown].astype(str))))
    else:
        rig = rig_structure(block) if block.rigs else None
        alone = np.ones(shown.size, bool) if rig is None else rig.photo_frame[shown] < 0
        if alone.any():
            a = np.flatnonzero(alone)
            log_per_entity(rec, [f"world/photos/{pids[k]}" for k in a], np.ones(a.size, int),
                           rr.Transform3D.columns(translation=st.X0[shown[a]], mat3x3=R[shown[a]].transpose(0, 2, 1)),
                           rr.Pinhole.columns(image_from_camera=K[a], resolution=f[a],
                                              camera_xyz=rr.ViewCoordinates.RUB, image_plane_distance=0.1 * depth[a]))
        if not alone.all():
            _log_rig_frames(rec, res, rig, shown[~alone], K[~alone], f[~alone], 0.1 * depth[~alone])
    if block.rigs:
        _log_rig_sensors(rec, res, rep.config.rig.alpha)
    # image points and residual arrows of the photos shown, grouped by photo (in observation order)
    pos = np.full(n_ph, -1)
    pos[shown] = np.arange(shown.size)
    rows = np.flatnonzero(pos[obs.photo] >= 0)
    rows = rows[np.argsort(pos[obs.photo[rows]], kind="stable")]
    rph = obs.photo[rows]
    counts = np.bincount(pos[rph], minlength=shown.size)
    half = np.where(np.isfinite(fmts), fmts, 0.0) / 2          # view_from_photo's offset, per photo
    xy_view = view_from_photo(obs.xy[rows], None) + half[rph]
    observed = rr.Points2D.columns(positions=xy_view, labels=point_ids.take(pa.array(obs.point[rows])),
                                   colors=_colors(bad[rows], RED, BLUE), radii=rr.Radius.ui_points(3.0))
    if many:
        log_on_timeline(rec, "images/all/observed", "photo", counts, observed)
    else:
        log_per_entity(rec, [f"images/{p}/observed" for p in pids], counts, observed)
    del observed, xy_view                   # handed to rerun: the per-observation columns freed as they go
    ok = rows[fin[rows]]
    okc = np.bincount(pos[obs.photo[ok]], minlength=shown.size)
    with_arrows = np.flatnonzero(okc > 0)
    arrows = rr.Arrows2D.columns(origins=view_from_photo(computed[ok], None) + half[obs.photo[ok]],
                                 vectors=view_vectors(v[ok] * scale), colors=_colors(bad[ok], RED, GREY))
    if many:
        log_on_timeline(rec, "images/all/residuals", "photo", okc, arrows)
    else:
        log_per_entity(rec, [f"images/{pids[k]}/residuals" for k in with_arrows], okc[with_arrows], arrows)
    del arrows, computed, rows, ok
    # rejected / flagged rays
    rb = np.flatnonzero(bad & res.photo_used[obs.photo] & used[obs.point])
    if rb.size:
        strips = np.stack([st.X0[obs.photo[rb]], st.XYZ[obs.point[rb]]], axis=1)
        rec.log("world/rejected_rays", rr.LineStrips3D(strips, colors=RED,
                                                       labels=[f"{photos.ids[obs.photo[k]]}/{pts.ids[obs.point[k]]}: "
                                                               f"{decision[k]}" for k in rb]), static=True)
    # distortion field of the estimated APs (labelled in px for a pixel source, else µm)
    unit, uscale, _ = image_units(block)
    cam_fmts = _formats(block, photos.camera[obs.photo], len(block.cameras), np.arange(len(block.cameras)))
    fields, scales = [], []
    for j in np.flatnonzero(res.camera_used):
        mdl = get_ap_model(block.cameras.ap_model[j])
        if mdl.n_params == 0:
            continue
        fmt = cam_fmts[j]
        gx, gy = np.meshgrid(np.linspace(-fmt[0] / 2, fmt[0] / 2, 15), np.linspace(-fmt[1] / 2, fmt[1] / 2, 11))
        xb, yb = gx.ravel(), gy.ravel()
        prm = np.broadcast_to(st.cam_params[j, 3:3 + mdl.n_params], (xb.size, mdl.n_params))
        dx, dy = mdl.distortion(xb, yb, prm, np.full(xb.size, st.cam_params[j, 0]), res.camera_meta[j])
        mag = np.hypot(dx, dy)
        if not mag.max() > 0:          # no distortion at all (APs zero, e.g. fixed): no empty view
            continue
        dscale = 0.05 * fmt.max() / mag.max()
        fields.append((_safe(block.cameras.ids[j]), view_from_photo(np.column_stack([xb, yb]), fmt),
                       view_vectors(np.column_stack([dx, dy]) * dscale), mag))
        scales.append(dscale)
    if fields:
        cids = [c for c, *_ in fields]
        mags = np.concatenate([m for *_, m in fields]) * uscale
        labels = np.char.add(np.char.mod(f"%.{2 if unit == 'px' else 1}f ", mags), unit)
        field_arrows = rr.Arrows2D.columns(origins=np.concatenate([o for _, o, _, _ in fields]),
                                           vectors=np.concatenate([w for _, _, w, _ in fields]),
                                           labels=pa.array(labels.tolist()))
        if len(cids) > ENTITIES_MAX:
            rec.note(f"{len(cids)} cameras with a distortion field (more than {ENTITIES_MAX}): one 2-D view "
                     "(cameras/all) over the timeline 'camera', step k the k-th camera, named in cameras/all/camera")
            log_on_timeline(rec, "cameras/all/distortion", "camera", [len(m) for *_, m in fields], field_arrows)
            log_on_timeline(rec, "cameras/all/camera", "camera", np.ones(len(cids), int),
                            rr.AnyValues.columns(camera=pa.array(cids), arrow_scale=np.asarray(scales, float)))
        else:
            log_per_entity(rec, [f"cameras/{c}/distortion" for c in cids], [len(m) for *_, m in fields], field_arrows)
            log_per_entity(rec, [f"cameras/{c}/distortion_scale" for c in cids], np.ones(len(cids), int),
                           rr.AnyValues.columns(arrow_scale=np.asarray(scales, float)))
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


def _log_rig_frames(rec, res, rig, photos, K, wh, plane) -> None:
    """The rigs' frames (``world/rigs/<rig>/frames/<frame>``: the frame's pose as ``world_from_rig``)
    with each photo of the frame as its sensor's camera below it (``…/<camera>``: ``rig_from_sensor``
    = centre ``c_s`` and ``R_sᵀ`` in the rig frame, then the photo's Pinhole ``K``, ``wh``, ``plane``
    at most half the longest baseline)
    — the viewer composes them to the photo's pose ``X0 = X0_f + R_fᵀ c_s``, ``R = R_s R_f`` — and a
    line from the reference camera to each other sensor (``…/baselines``, in the rig frame).  ``rig``
    is the block's :class:`~baarda.pipeline.adjustment.rig.RigStructure` (the frames' order of
    ``res.state.frame``)."""
    import pyarrow as pa
    import rerun as rr

    st, block = res.state, res.block_in
    rs = block.rigs.sensors
    frame_of, sensor_of = rig.photo_frame[photos], rig.photo_sensor[photos]
    frames = np.unique(frame_of)
    Rf = rotation_from_opk_many(np.nan_to_num(st.frame[frames, 3:]))
    fpath = {int(fr): f"world/rigs/{_safe(rs.rig[rig.photo_sensor[rig.frame_ref_photo[fr]]])}/frames/{_safe(rig.frame_ids[fr])}"
             for fr in frames}
    size = float(np.max(np.linalg.norm(st.sensor[:, :3], axis=1), initial=0.0)) or float(np.median(plane))
    plane = np.minimum(plane, 0.5 * size)      # the cameras of a frame drawn apart (frusta at most half a baseline)
    log_per_entity(rec, [fpath[int(fr)] for fr in frames], np.ones(frames.size, int),
                   rr.Transform3D.columns(translation=st.frame[frames, :3], mat3x3=Rf.transpose(0, 2, 1)),
                   rr.TransformAxes3D.columns(axis_length=np.full(frames.size, 0.5 * size)))
    Rs = rotation_from_opk_many(np.nan_to_num(st.sensor[sensor_of, 3:]))
    cams = block.cameras.ids[rs.camera[sensor_of]]
    paths = [f"{fpath[int(fr)]}/{_safe(c)}" for fr, c in zip(frame_of, cams)]
    log_per_entity(rec, paths, np.ones(photos.size, int),
                   rr.Transform3D.columns(translation=st.sensor[sensor_of, :3], mat3x3=Rs.transpose(0, 2, 1)),
                   rr.Pinhole.columns(image_from_camera=K, resolution=wh, camera_xyz=rr.ViewCoordinates.RUB,
                                      image_plane_distance=plane),
                   rr.AnyValues.columns(photo=pa.array(np.asarray(block.photos.ids)[photos].astype(str))))
    # baselines: reference camera (the rig origin) to each other sensor of the frame, in the rig frame
    other = ~rs.reference[sensor_of]
    counts = np.bincount(np.searchsorted(frames, frame_of[other]), minlength=frames.size)
    has = np.flatnonzero(counts > 0)
    if has.size:
        order = np.argsort(frame_of[other], kind="stable")
        ends = st.sensor[sensor_of[other][order], :3]
        strips = [np.stack([np.zeros(3), e]) for e in ends]
        log_per_entity(rec, [f"{fpath[int(frames[k])]}/baselines" for k in has], counts[has],
                       rr.LineStrips3D.columns(strips=strips, colors=np.tile(np.array([230, 150, 30], np.uint8),
                                                                             (len(strips), 1))))


def _log_rig_sensors(rec, res, alpha: float) -> None:
    """Each sensor's pose in its rig with its a-posteriori σ, the baseline with σ and the stability
    test (``rig_result``): a Markdown table per rig (``rigs/<rig>/sensors``, a text view) and the
    values per sensor (``rigs/<rig>/sensors/<camera>``, ``AnyValues``; lengths in the object unit,
    angles in degrees, as ``bundle_rig.csv``)."""
    import rerun as rr

    from baarda.pipeline.api import log_text, rig_result
    from baarda.pipeline.units import fmt_q, length_suffix, object_unit_text

    rr_ = rig_result(res, alpha=alpha)
    if rr_ is None:
        return
    ou = object_unit_text(res.block_in)
    suf = length_suffix(ou)
    names = [f"{n}{suf}" for n in "XYZ"] + [f"{n}_deg" for n in ("omega", "phi", "kappa")]
    scale = np.r_[1.0, 1.0, 1.0, np.degrees(np.ones(3))]
    by_rig: dict[str, list] = {}
    for s in rr_.sensors:
        by_rig.setdefault(s.rig, []).append(s)
    for rig, sensors in by_rig.items():
        L = [f"**Rig {rig}**, {rr_.n_frames} frames: each camera's pose in the rig (centre in the reference camera's "
             f"image frame, x right, y up, z back, {ou}; ω, φ, κ of R_sensor_from_rig) with its a-posteriori σ", ""]
        for s in sensors:
            path = f"rigs/{_safe(rig)}/sensors/{_safe(s.camera)}"
            if s.reference_sensor:
                L.append(f"- **{s.camera}**: the reference camera (the rig frame)")
                rec.log(path, rr.AnyValues(reference_camera=[True]), static=True)   # not "reference": congruence logs that name as text
                continue
            status = "fixed" if all(t == "fixed" for t in s.status) else (
                "weighted" if "weighted" in s.status else "estimated")
            t = s.stability
            L.append(f"- **{s.camera}** ({status}): baseline {fmt_q(s.baseline, ou)} ± {fmt_q(s.sigma_baseline, ou, 2)}; "
                     + ", ".join(f"{'XYZ'[k]} {fmt_q(s.value[k], ou)} ± {fmt_q(s.sigma[k], ou, 2)}" for k in range(3))
                     + "; " + ", ".join(f"{'ωφκ'[k - 3]} {np.degrees(s.value[k]):.5f}° ± {np.degrees(s.sigma[k]):.2g}°"
                                        for k in range(3, 6))
                     + ("" if t is None else f"; against the calibration T = {t['T']:.3g} vs {t['critical']:.3g}: "
                        + ("stable" if t["stable"] else "**changed**")))
            vals = {n: float(v) for n, v in zip(names, s.value * scale)}
            vals.update({"s" + n: float(v) for n, v in zip(names, s.sigma * scale)})
            vals.update({f"baseline{suf}": float(s.baseline), f"sbaseline{suf}": float(s.sigma_baseline),
                         "status": status})
            if t is not None:
                vals.update({"T_stability": float(t["T"]), "T_critical": float(t["critical"]),
                             "stable": bool(t["stable"])})
            rec.log(path, rr.AnyValues(**vals), static=True)
        if rr_.stability is not None and sum(s.stability is not None for s in sensors) > 1:
            t = rr_.stability
            L += ["", f"All sensors with a calibration together: T = {t['T']:.3g} vs {t['critical']:.3g} "
                      f"({t['distribution']}, α = {t['alpha']:g}): " + ("stable" if t["stable"] else "**changed**")]
        log_text(rec, f"rigs/{_safe(rig)}/sensors", "\n".join(L))


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
