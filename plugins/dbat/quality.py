"""DBAT-style quality figures of an adjusted block — pure numerics (arrays in, arrays and dicts out).

* :func:`intersection_angles` — per point the largest angle between the lines of two of its rays,
  in [0°, 90°] (DBAT's "Point Angles"; 0 for a point seen once).
* :func:`corrected_space_residuals` — residuals as DBAT forms them for a backward (PhotoModeler)
  model: the *corrected* measurement minus the ideal projection, ``g(l − pp) − x̄``.  baarda's own
  residuals are those of the measured coordinates (``docs/dbat.md``); this gives DBAT's σ̂0 and
  point RMS from baarda's solution for comparison.
* :func:`point_comparison` — prior, adjusted, difference and σ of control or check points.
* :func:`compare_marks` — two sets of image points of the same photos paired by position (e.g.
  PhotoModeler's marks and OpenCV detections): counts, bias and RMS in pixels.
"""

from __future__ import annotations

import numpy as np

from baarda.pipeline.adjustment import project_observations
from baarda.pipeline.camera import get_ap_model


def intersection_angles(XYZ, X0, obs_photo, obs_point, n_points: int) -> np.ndarray:
    """(n_points,) the largest angle (radians) between the lines of two rays of each point, each angle
    folded into [0, π/2] (rays 100° apart intersect at 80°); 0 with fewer than two rays, nan for a
    point without coordinates."""
    XYZ = np.asarray(XYZ, float)
    d = XYZ[obs_point] - np.asarray(X0, float)[obs_photo]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    out = np.zeros(n_points)
    order = np.argsort(obs_point, kind="stable")
    bounds = np.searchsorted(obs_point[order], np.arange(n_points + 1))
    for p in range(n_points):
        rows = order[bounds[p]:bounds[p + 1]]
        if len(rows) >= 2:
            u = d[rows]
            cos = np.clip(np.abs(u @ u.T), 0.0, 1.0)
            out[p] = float(np.arccos(cos.min()))
    out[~np.isfinite(XYZ).all(axis=1)] = np.nan
    return out


def corrected_space_residuals(block, state, active=None) -> np.ndarray:
    """(k, 2) ``g(l − pp) − x̄`` (mm) for every observation of a camera whose model has ``correct``
    (the backward model); ``nan`` rows for other cameras."""
    obs = block.observations
    k = len(obs)
    out = np.full((k, 2), np.nan)
    cams = block.cameras
    cam_of_obs = block.photos.camera[obs.photo]
    ideal = project_observations(obs.photo, obs.point, state.XYZ, state.X0, state.opk, block.photos.camera,
                                 state.cam_params[:, :3], ["none"] * len(cams)).xy
    for j, name in enumerate(cams.ap_model.tolist()):
        model = get_ap_model(name)
        if not callable(getattr(model, "correct", None)):
            continue
        sel = cam_of_obs == j
        if active is not None:
            sel &= active
        pp = state.cam_params[j, 1:3]
        lb = obs.xy[sel] - pp
        prm = np.tile(state.cam_params[j, 3:3 + model.n_params], (int(sel.sum()), 1))
        gx, gy = model.correct(lb[:, 0], lb[:, 1], prm, state.cam_params[j, 0], {})
        out[sel] = np.column_stack([gx, gy]) - (ideal[sel] - pp)
    return out


def point_comparison(points, idx, adjusted, cov_points) -> dict:
    """Prior, adjusted, difference (adjusted − prior) and a-posteriori σ of points ``idx``."""
    idx = np.asarray(idx, int)
    prior = np.asarray(points.XYZ, float)[idx]
    adj = np.asarray(adjusted, float)[idx]
    sig = np.sqrt(np.clip(np.diagonal(np.asarray(cov_points, float)[idx], axis1=1, axis2=2), 0, None))
    return {"ids": points.ids[idx].tolist(), "prior": prior, "prior_sigma": np.asarray(points.sigma, float)[idx],
            "adjusted": adj, "diff": adj - prior, "sigma": sig}


def compare_marks(marks, block, radius_px: float) -> dict:
    """Pair the image points of ``marks`` and ``block`` photo by photo (same photo id) by position:
    nearest neighbours, one-to-one, within ``radius_px``.  Differences ``block − marks`` in pixels of
    the marks' camera (x right, y down), from the image mm of both blocks (each converted with its
    own pixel convention)."""
    pm = float(marks.cameras.pixel_mm[0])
    photos, pairs = [], {"photo": [], "mark_point": [], "point": [], "uv_mark": [], "duv": []}
    W, H = marks.cameras.resolution[0]
    for k, pid in enumerate(marks.photos.ids.tolist()):
        om = marks.observations.photo == k
        hit = np.flatnonzero(block.photos.ids == pid)
        ob = block.observations.photo == hit[0] if hit.size else np.zeros(len(block.observations), bool)
        a = marks.observations.xy[om] / pm * [1.0, -1.0]          # pixels about the centre, y down
        b = block.observations.xy[ob] / pm * [1.0, -1.0]
        ida = marks.points.ids[marks.observations.point[om]]
        idb = block.points.ids[block.observations.point[ob]]
        row = {"photo": pid, "marks": int(om.sum()), "points": int(ob.sum()), "matched": 0, "same_id": 0,
               "bias_px": [np.nan, np.nan], "rms_px": [np.nan, np.nan]}
        if len(a) and len(b):
            d = np.linalg.norm(a[:, None] - b[None], axis=2)
            i_near = d.argmin(axis=1)
            j_near = d.argmin(axis=0)
            ia = np.flatnonzero((j_near[i_near] == np.arange(len(a))) & (d[np.arange(len(a)), i_near] <= radius_px))
            jb = i_near[ia]
            duv = b[jb] - a[ia]
            row.update(matched=int(len(ia)), same_id=int((ida[ia] == idb[jb]).sum()))
            if len(ia):
                row["bias_px"] = duv.mean(axis=0).tolist()
                row["rms_px"] = np.sqrt((duv ** 2).mean(axis=0)).tolist()
            pairs["photo"] += [pid] * len(ia)
            pairs["mark_point"] += ida[ia].tolist()
            pairs["point"] += idb[jb].tolist()
            pairs["uv_mark"].append(a[ia] + [W / 2, H / 2])
            pairs["duv"].append(duv)
        photos.append(row)
    uvm = np.concatenate(pairs["uv_mark"]) if pairs["uv_mark"] else np.zeros((0, 2))
    duv = np.concatenate(pairs["duv"]) if pairs["duv"] else np.zeros((0, 2))
    pairs["uv_mark"], pairs["duv"] = uvm, duv
    allrow = {"marks": int(len(marks.observations)), "points": int(len(block.observations)),
              "matched": int(len(duv)), "same_id": int(sum(r["same_id"] for r in photos)),
              "bias_px": duv.mean(axis=0).tolist() if len(duv) else [np.nan, np.nan],
              "rms_px": np.sqrt((duv ** 2).mean(axis=0)).tolist() if len(duv) else [np.nan, np.nan],
              "sd_px": duv.std(axis=0, ddof=1).tolist() if len(duv) > 1 else [np.nan, np.nan]}
    return {"photos": photos, "all": allrow, "pairs": pairs}
