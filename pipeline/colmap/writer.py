"""Block → COLMAP model (``pycolmap.Reconstruction``, written as text or binary).

Cameras become COLMAP cameras with one trivial rig each, photos images with one trivial frame
each (pycolmap ≥ 3.12 layout: cameras, images, points3D, rigs, frames); the cameras and photos of
the block's rigs (``block.rigs``, ``docs/rigs.md``) are written as COLMAP rigs and frames.  A block read from COLMAP
(``meta["colmap"]``) is written back with its camera, image and point ids, all its keypoints, the
camera models it had and the point colours; other blocks get ids 1, 2, … and one keypoint per
observation.  Only active observations of points with known coordinates enter tracks.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from baarda.pipeline.errors import InputError

from baarda.pipeline.geometry.image import pixels_from_mm
from baarda.pipeline.geometry.pose import cv_from_pose
from baarda.pipeline.camera.convert import UnsupportedCamera, colmap_from_brown, colmap_from_ray, colmap_ray_model_names


def _pitch_and_size(cameras, k) -> tuple[float, tuple[int, int]]:
    pitch = float(cameras.pixel_mm[k])
    w, h = (int(v) for v in cameras.resolution[k])
    if not np.isfinite(pitch) or pitch <= 0 or w <= 0 or h <= 0:
        raise InputError(f"camera {cameras.ids[k]}: a COLMAP camera needs a pixel pitch and a resolution "
                         f"(pixel_mm={pitch}, resolution={w}×{h})", field="cameras")
    return pitch, (w, h)


def colmap_cameras(cameras, models=None) -> list[tuple[str, np.ndarray]]:
    """``(model, params)`` per camera; ``models`` (per camera, or None) asks for a COLMAP model.

    A requested model that cannot hold the camera's parameters falls back to ``"auto"``.
    """
    out = []
    for k in range(len(cameras)):
        pitch, size = _pitch_and_size(cameras, k)
        ap_model = str(cameras.ap_model[k])
        ray = set(colmap_ray_model_names().values())
        if ap_model in ray:                           # a COLMAP fisheye / omnidirectional / division model
            try:
                out.append(colmap_from_ray(ap_model, cameras.c[k], cameras.xp[k], cameras.yp[k], cameras.ap[k],
                                           size, pitch))
            except (UnsupportedCamera, ValueError) as e:
                raise InputError(f"camera {cameras.ids[k]}: {e}", field="ap") from None
            continue
        if ap_model not in ("brown", "none"):
            raise InputError(f"camera {cameras.ids[k]}: AP model '{ap_model}' has no COLMAP equivalent "
                             f"(only 'brown', 'none' and {', '.join(sorted(ray))} can be written)",
                             field="ap_model")
        ap = cameras.ap[k] if ap_model == "brown" else None
        want = "auto" if models is None else models[k]
        try:
            try:
                out.append(colmap_from_brown(cameras.c[k], cameras.xp[k], cameras.yp[k], ap, size, pitch, want))
            except UnsupportedCamera:
                if want == "auto":
                    raise
                out.append(colmap_from_brown(cameras.c[k], cameras.xp[k], cameras.yp[k], ap, size, pitch, "auto"))
        except (UnsupportedCamera, ValueError) as e:
            raise InputError(f"camera {cameras.ids[k]}: {e}", field="ap") from None
    return out


def reconstruction_from_block(block, *, camera_model: str = "keep"):
    """A ``pycolmap.Reconstruction`` of a block.

    camera_model : ``"keep"`` — the model the camera had in COLMAP (if it still fits, else the
        simplest that does), ``"auto"`` — the simplest exact model, or a COLMAP model name.
    Photos without orientation are skipped (reported through ``info``).
    Returns ``(reconstruction, info)``.
    """
    import pycolmap

    meta = block.meta.get("colmap") if isinstance(block.meta, dict) else None
    cams, photos, pts, obs = block.cameras, block.photos, block.points, block.observations
    same_shape = (meta is not None and len(meta.get("camera_ids", ())) == len(cams)
                  and len(meta.get("image_ids", ())) == len(photos)
                  and len(meta.get("point3D_ids", ())) == len(pts)
                  and len(meta.get("point2D_idx", ())) == len(obs))
    if camera_model == "keep":
        models = list(meta["camera_models"]) if same_shape else None
    elif camera_model == "auto":
        models = None
    else:
        models = [camera_model] * len(cams)
    cam_params = colmap_cameras(cams, models)
    cam_ids = list(meta["camera_ids"]) if same_shape else list(range(1, len(cams) + 1))
    img_ids = list(meta["image_ids"]) if same_shape else list(range(1, len(photos) + 1))

    rec = pycolmap.Reconstruction()
    rigs = block.rigs
    in_rig = set(rigs.sensors.camera.tolist()) if rigs else set()
    for k, (model, params) in enumerate(cam_params):
        cam = pycolmap.Camera.create_from_model_name(int(cam_ids[k]), model, 1.0, int(cams.resolution[k, 0]),
                                                     int(cams.resolution[k, 1]))
        cam.params = params
        if k in in_rig:
            rec.add_camera(cam)
        else:
            rec.add_camera_with_trivial_rig(cam)

    oriented = photos.has_orientation
    R, t = cv_from_pose(np.nan_to_num(photos.X0), np.nan_to_num(photos.opk))
    active = obs.active.copy()
    if same_shape and "duplicate" in meta:          # COLMAP's own second measurements, off in baarda
        active |= np.asarray(meta["duplicate"], bool)
    use = active & oriented[obs.photo] & np.isfinite(pts.XYZ[obs.point]).all(axis=1)
    # keypoints per image: the original ones (meta) or one per observation
    keypoints, obs_kp = [], np.full(len(obs), -1)
    by_photo = _groups(obs.photo, len(photos))
    for k in range(len(photos)):
        rows = by_photo[k]
        if same_shape:
            kp = np.array(meta["keypoints_px"][k], float).reshape(-1, 2)
            obs_kp[rows] = meta["point2D_idx"][rows]
        else:
            cam = photos.camera[k]
            kp = pixels_from_mm(obs.xy[rows], cams.resolution[cam], cams.pixel_mm[cam], "colmap").reshape(-1, 2)
            obs_kp[rows] = np.arange(rows.size)
        keypoints.append(kp)
    frame_of = _write_rigs(rec, block, cam_ids, img_ids, oriented, R, t) if rigs else {}
    for k in np.flatnonzero(oriented):
        image = pycolmap.Image(name=str(photos.ids[k]), keypoints=keypoints[k],
                               camera_id=int(cam_ids[photos.camera[k]]), image_id=int(img_ids[k]))
        if k in frame_of:
            image.frame_id = frame_of[k]
            rec.add_image(image)
        else:
            rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(R[k]), t[k]))

    colors = meta.get("colors") if same_shape else None
    pt_ids = list(meta["point3D_ids"]) if same_shape else None
    written = 0
    in_use = np.flatnonzero(use)
    by_point = _groups(obs.point[in_use], len(pts))
    for j in range(len(pts)):
        rows = in_use[by_point[j]]
        if rows.size == 0:
            continue
        track = pycolmap.Track()
        for r in rows:
            track.add_element(int(img_ids[obs.photo[r]]), int(obs_kp[r]))
        color = colors[j] if colors is not None else np.zeros(3, np.uint8)
        if pt_ids is not None:
            p3 = pycolmap.Point3D()
            p3.xyz, p3.track, p3.color = pts.XYZ[j], track, np.asarray(color, np.uint8)
            rec.add_point3D_with_id(int(pt_ids[j]), p3)
        else:
            rec.add_point3D(pts.XYZ[j], track, color)
        written += 1
    rec.update_point_3d_errors()
    info = {"cameras": len(cams), "images": int(oriented.sum()), "points3D": written,
            "observations": int(use.sum()), "skipped_photos": photos.ids[~oriented].tolist(),
            "camera_models": [m for m, _ in cam_params]}
    return rec, info


def _free_ids(names, taken: set) -> list[int]:
    """An integer id per name: the name itself when it is a positive integer not taken (nor used
    before), else the next free one."""
    out, used = [], set(taken)
    nxt = max(used | {0}) + 1
    for n in names:
        v = int(n) if str(n).isdigit() and int(n) > 0 else None
        if v is None or v in used:
            while nxt in used:
                nxt += 1
            v = nxt
        used.add(v)
        out.append(v)
    return out


def _write_rigs(rec, block, cam_ids, img_ids, oriented, R, t) -> dict:
    """Add the block's rigs (COLMAP ≥ 3.12 ``rigs``/``frames``) to ``rec``: each rig with its
    reference camera and every other camera's ``sensor_from_rig`` (``R = F R_s F``,
    ``t = −F R_s c``, F = diag(1, −1, −1); left unset when unknown), each frame whose reference photo
    is oriented with its ``rig_from_world`` (the reference photo's pose) and its images.  Returns
    photo index → frame id for the images to add."""
    import pycolmap

    from baarda.pipeline.adjustment import rig_structure
    from baarda.pipeline.geometry import rotation_from_opk_many

    rigs = block.rigs
    rs = rigs.sensors
    struct = rig_structure(block)
    F = np.diag([1.0, -1.0, -1.0])
    rig_names = list(dict.fromkeys(rs.rig.tolist()))
    other_cams = {int(cam_ids[k]) for k in range(len(block.cameras)) if k not in set(rs.camera.tolist())}
    rig_ids = dict(zip(rig_names, _free_ids(rig_names, other_cams)))
    cam_t = pycolmap.SensorType.CAMERA
    for name in rig_names:
        rig = pycolmap.Rig(rig_id=rig_ids[name])
        rows = np.flatnonzero(rs.rig == name)
        ref = rows[rs.reference[rows]][0]
        rig.add_ref_sensor(pycolmap.sensor_t(type=cam_t, id=int(cam_ids[rs.camera[ref]])))
        for i in rows[~rs.reference[rows]]:
            Rs = rotation_from_opk_many(rs.opk[i][None])[0]
            pose = None
            if np.isfinite(rs.centre[i]).all() and np.isfinite(rs.opk[i]).all():
                Rc = F @ Rs @ F
                pose = pycolmap.Rigid3d(pycolmap.Rotation3d(Rc), -F @ Rs @ rs.centre[i])
            rig.add_sensor(pycolmap.sensor_t(type=cam_t, id=int(cam_ids[rs.camera[i]])), pose)
        rec.add_rig(rig)
    alone = {int(img_ids[k]) for k in np.flatnonzero(oriented & (struct.photo_frame < 0))}
    frame_ids = _free_ids(struct.frame_ids.tolist(), alone)
    out = {}
    for f, fid in enumerate(frame_ids):
        ref = struct.frame_ref_photo[f]
        if not oriented[ref]:
            continue
        members = np.flatnonzero((struct.photo_frame == f) & oriented)
        rig_name = str(rs.rig[struct.photo_sensor[ref]])
        frame = pycolmap.Frame(frame_id=fid, rig_id=rig_ids[rig_name])
        for k in members:
            frame.add_data_id(pycolmap.data_t(sensor_id=pycolmap.sensor_t(type=cam_t,
                                                                          id=int(cam_ids[block.photos.camera[k]])),
                                              id=int(img_ids[k])))
            out[int(k)] = fid
        frame.rig_from_world = pycolmap.Rigid3d(pycolmap.Rotation3d(R[ref]), t[ref])
        rec.add_frame(frame)
    return out


def _groups(keys: np.ndarray, n: int) -> list[np.ndarray]:
    """Indices of ``keys`` equal to 0 … n−1, each in ascending order (one stable sort, not n scans)."""
    order = np.argsort(keys, kind="stable")
    bounds = np.searchsorted(keys[order], np.arange(n + 1))
    return [order[bounds[j]:bounds[j + 1]] for j in range(n)]


def write_colmap(block, path: str | Path, *, fmt: str = "binary", camera_model: str = "keep") -> dict:
    """Write a block as a COLMAP model folder (``fmt`` ``"binary"`` or ``"text"``); returns info."""
    if fmt not in ("binary", "text"):
        raise ValueError(f"format must be 'binary' or 'text', got {fmt!r}")
    rec, info = reconstruction_from_block(block, camera_model=camera_model)
    out = Path(path)
    out.mkdir(parents=True, exist_ok=True)
    (rec.write_binary if fmt == "binary" else rec.write_text)(str(out))
    info["path"] = str(out)
    info["format"] = fmt
    return info
