"""COLMAP model (binary or text) → :class:`baarda.pipeline.model.Block`.

The files are read with pycolmap (``Reconstruction(path)`` reads either format, with or without the
``rigs``/``frames`` files of COLMAP ≥ 3.12); the conversion of cameras, poses and pixels is
:mod:`baarda.pipeline.camera.convert`.  Only registered images and 2-D points that belong to a 3-D
point become observations; every keypoint is kept in ``block.meta["colmap"]`` so that
:mod:`baarda.pipeline.colmap.writer` can write the images back unchanged.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from baarda.pipeline.errors import InputError, quote
from baarda.pipeline.model import (FIXED, FREE, Block, Cameras, FrameMembers, Observations, Photos, Points, RigSensors,
                                   Rigs, SourceInfo)

from baarda.pipeline.geometry.image import mm_from_pixels
from baarda.pipeline.geometry.pose import pose_from_cv
from baarda.pipeline.camera.convert import (BROWN, COLMAP_PARAMS, FREE_BROWN, UnsupportedCamera, brown_from_colmap,
                                            colmap_ray_model_names, ray_from_colmap)

from .precheck import check_binary, check_text, check_values

MODEL_FILES = ("cameras", "images", "points3D")


def model_format(path: str | Path) -> str:
    """``"binary"`` or ``"text"``: which COLMAP model files a folder holds (InputError if neither)."""
    p = Path(path)
    if not p.is_dir():
        raise InputError("COLMAP model folder not found", path=p)
    for fmt, ext in (("binary", ".bin"), ("text", ".txt")):
        if all((p / f"{name}{ext}").is_file() for name in MODEL_FILES):
            return fmt
    missing = [f"{n}.bin/.txt" for n in MODEL_FILES if not ((p / f"{n}.bin").is_file() or (p / f"{n}.txt").is_file())]
    raise InputError(f"not a COLMAP model: missing {', '.join(missing) or 'a consistent set of .bin or .txt files'}",
                     path=p)


def read_reconstruction(path: str | Path):
    """``pycolmap.Reconstruction`` of a model folder; unreadable files raise InputError."""
    import pycolmap

    fmt = model_format(path)
    if fmt == "binary":
        check_binary(Path(path))              # names file, record and offset where pycolmap would not
    else:
        check_text(Path(path))                # names file, line and field where pycolmap would not
    rec = pycolmap.Reconstruction()
    try:
        (rec.read_binary if fmt == "binary" else rec.read_text)(str(path))
    except MemoryError:
        raise InputError(f"the {fmt} model claims more than memory holds (a damaged count?)", path=path) from None
    except Exception as e:  # pycolmap raises RuntimeError/ValueError with its own message
        raise InputError(f"pycolmap cannot read the {fmt} model (a file truncated or corrupt?): "
                         f"{_pycolmap_message(e)}", path=path) from None
    check_values(rec, Path(path), fmt)
    return rec


def _pycolmap_message(e: Exception) -> str:
    """pycolmap's message in one line, without C++ library internals or file contents."""
    text = " ".join(str(e).split())
    if not text or "std::" in text or "::_M_" in text or "bad_alloc" in text:
        return "its reader failed inside the C++ library"
    return text[:160]


def block_from_reconstruction(rec, *, pixel_mm: float = 0.001, sensor_width_mm: float = 0.0,
                              sigma_px: float = 1.0, intrinsics: str = "colmap", object_unit: str = "m",
                              source: str = "") -> tuple[Block, dict]:
    """Convert a ``pycolmap.Reconstruction`` to a Block.

    pixel_mm : nominal pixel pitch used when ``sensor_width_mm`` is 0 (c = f_px · pixel_mm).
    sensor_width_mm : when > 0, the pitch of each camera is ``sensor_width_mm / width``.
    sigma_px : a-priori sigma of each image coordinate, pixels.
    intrinsics : ``"colmap"`` frees what COLMAP's default bundle refines (focal length and the
        model's distortion parameters; principal point fixed); ``"fixed"`` holds all; ``"free"``
        frees all of the model's parameters including the principal point.
    Returns ``(block, info)``; ``info`` lists inexact camera conversions, skipped images and the
    number of duplicate observations (a point seen twice in one image: the second is inactive).
    """
    if intrinsics not in ("colmap", "fixed", "free"):
        raise ValueError(f"intrinsics must be 'colmap', 'fixed' or 'free', got {quote(intrinsics)}")
    cam_ids = sorted(rec.cameras)
    cams, inexact = [], []
    for cid in cam_ids:
        cam = rec.cameras[cid]
        size = (int(cam.width), int(cam.height))
        pitch = sensor_width_mm / size[0] if sensor_width_mm > 0 else pixel_mm
        model = cam.model.name
        ray_names = colmap_ray_model_names()
        prm = np.asarray(cam.params, float)
        if not np.all(np.isfinite(prm)) or np.any(np.abs(prm) > 1e12) or (prm.size and not prm[0] > 0):
            raise InputError(f"camera {cid} ({model}): parameters {np.array2string(prm, precision=6)} are not a "
                             "camera (the focal length must be positive, every parameter finite and below 1e12)",
                             path=source or None, field="params")
        try:
            if model in ray_names:                  # fisheye, omnidirectional, division: a ray model
                b = ray_from_colmap(model, np.asarray(cam.params), size, pitch)
                names, free = ray_names_params(b["ap_model"]), set(b["free"])
            elif model in COLMAP_PARAMS:
                b = brown_from_colmap(model, np.asarray(cam.params), size, pitch)
                b["ap_model"] = "brown"
                names, free = BROWN, set(FREE_BROWN[model])
            else:
                raise UnsupportedCamera(f"COLMAP camera model {model} is not supported (supported: "
                                        f"{', '.join(list(COLMAP_PARAMS) + list(ray_names))})")
        except UnsupportedCamera as e:
            raise InputError(f"camera {cid}: {e}", path=source or None, field="model") from None
        if not b.get("exact", True):
            inexact.append(cid)
        focal = model != "EQUIRECTANGULAR"        # COLMAP's equirectangular camera has nothing to refine
        sig_iop = [0.0 if (intrinsics == "fixed" or not focal) else FREE,
                   FREE if (intrinsics == "free" and focal) else FIXED, FREE if (intrinsics == "free" and focal) else FIXED]
        sig_ap = [FREE if (name in free and intrinsics != "fixed") else FIXED for name in names]
        cams.append((str(cid), b, size, pitch, model, sig_iop, sig_ap))
    width = max([len(c[1]["ap"]) for c in cams] + [0])
    pad = lambda v: np.concatenate([np.asarray(v, float), np.zeros(width - len(v))])
    cameras = Cameras(
        ids=np.array([c[0] for c in cams], dtype=str),
        c=[c[1]["c"] for c in cams], xp=[c[1]["xp"] for c in cams], yp=[c[1]["yp"] for c in cams],
        ap_model=np.array([c[1]["ap_model"] for c in cams], dtype=str),
        ap=np.array([pad(c[1]["ap"]) for c in cams]).reshape(len(cams), width),
        sigma_iop=np.array([c[5] for c in cams], float).reshape(-1, 3),
        sigma_ap=np.array([pad(c[6]) for c in cams], float).reshape(len(cams), width),
        format_mm=np.array([[c[2][0] * c[3], c[2][1] * c[3]] for c in cams], float).reshape(-1, 2),
        pixel_mm=[c[3] for c in cams], resolution=np.array([c[2] for c in cams], int).reshape(-1, 2),
    )
    cam_index = {cid: k for k, cid in enumerate(cam_ids)}

    img_ids = sorted(i for i, im in rec.images.items() if im.has_pose)
    skipped_images = sorted(set(rec.images) - set(img_ids))
    X0 = np.zeros((len(img_ids), 3))
    opk = np.zeros((len(img_ids), 3))
    names, keypoints, kp_point3D = [], [], []
    for k, iid in enumerate(img_ids):
        im = rec.images[iid]
        cfw = im.cam_from_world()
        X0[k], opk[k] = pose_from_cv(cfw.rotation.matrix(), cfw.translation)
        try:
            name = im.name
        except UnicodeDecodeError as e:                       # pycolmap decodes the stored bytes as UTF-8
            raise InputError(f"image {iid}: its name is not UTF-8 text ({e.reason} at byte {e.start})",
                             path=source or None, field="name") from None
        names.append(name or str(iid))
        pts2 = im.points2D
        keypoints.append(np.array([p.xy for p in pts2], float).reshape(-1, 2))
        kp_point3D.append(np.array([p.point3D_id for p in pts2], np.uint64))
    if len(set(names)) != len(names):                       # ids must be unique: fall back to image ids
        names = [str(i) for i in img_ids]
    photos = Photos.make(names, camera=[cam_index[rec.images[i].camera_id] for i in img_ids],
                         X0=X0.reshape(-1, 3), opk=opk.reshape(-1, 3))

    pt_ids = sorted(rec.points3D)
    points = Points.make([str(p) for p in pt_ids],
                         XYZ=np.array([rec.points3D[p].xyz for p in pt_ids], float).reshape(-1, 3), role="tie")

    # every keypoint of a point of the model is an observation (a keypoint without one holds
    # COLMAP's invalid id, which no point has), per image in keypoint order
    pt_sorted = np.array(pt_ids, np.uint64)
    obs_photo, obs_point, obs_uv, obs_idx = [], [], [], []
    for k, pid in enumerate(kp_point3D):
        pos = np.searchsorted(pt_sorted, pid)
        hit = pos < len(pt_sorted)
        hit[hit] = pt_sorted[pos[hit]] == pid[hit]
        j = np.flatnonzero(hit)
        obs_photo.append(np.full(j.size, k, int))
        obs_point.append(pos[j].astype(int))
        obs_uv.append(keypoints[k][j])
        obs_idx.append(j)
    cat = lambda parts, shape: np.concatenate(parts) if parts else np.zeros(shape)
    obs_photo = cat(obs_photo, 0).astype(int)
    cam_of_obs = photos.camera[obs_photo]
    uv = cat(obs_uv, (0, 2)).astype(float).reshape(-1, 2)
    obs_idx = cat(obs_idx, 0).astype(int)
    xy = mm_from_pixels(uv, cameras.resolution[cam_of_obs], cameras.pixel_mm[cam_of_obs], "colmap")
    # COLMAP can hold a 3-D point twice in one image (two keypoints in one track); baarda takes one
    # measurement per point and photo: the first is kept, the others are switched off (and still
    # written back by the writer, so a round trip keeps the model unchanged)
    obs_point = cat(obs_point, 0).astype(int)
    first = np.zeros(len(obs_photo), bool)
    if len(obs_photo):
        _, idx = np.unique(obs_photo * (len(pt_ids) + 1) + obs_point, return_index=True)
        first[idx] = True
    observations = Observations.make(obs_photo, obs_point, xy, sigma=sigma_px * cameras.pixel_mm[cam_of_obs],
                                     active=first)

    meta = {
        "colmap": {
            "camera_ids": cam_ids, "camera_models": [c[4] for c in cams],
            "image_ids": img_ids, "keypoints_px": keypoints, "point2D_idx": np.array(obs_idx, int),
            "point3D_ids": pt_ids, "duplicate": ~first,
            "colors": np.array([rec.points3D[p].color for p in pt_ids], np.uint8).reshape(-1, 3),
        },
    }
    rigs = rigs_from_reconstruction(rec, cam_index, {iid: k for k, iid in enumerate(img_ids)}, source)
    block = Block(cameras=cameras, photos=photos, points=points, observations=observations,
                  object_unit=object_unit, meta=meta, rigs=rigs,
                  source=SourceInfo(path=source or None, format="COLMAP", pixel_format="COLMAP"))
    info = {"inexact_cameras": inexact, "unregistered_images": skipped_images,
            "duplicate_observations": int((~first).sum())}
    if rigs:
        info["rigs"] = {"sensors": len(rigs.sensors), "frames": len(set(rigs.frames.frame.tolist()))}
    return block, info


def ray_names_params(ap_model: str) -> tuple[str, ...]:
    from baarda.pipeline.camera import get_ap_model
    return tuple(get_ap_model(ap_model).params)


F_CV = np.diag([1.0, -1.0, -1.0])


def rigs_from_reconstruction(rec, cam_index: dict, photo_index: dict, source: str = "") -> Rigs:
    """The rigs of a COLMAP ≥ 3.12 model (``rigs``/``frames`` files) with more than one camera, as
    :class:`~baarda.pipeline.model.Rigs` (``docs/rigs.md``): the reference sensor is the rig's,
    every other camera's ``sensor_from_rig`` (``p_s = R p_rig + t``, y-down/z-forward) becomes
    its centre ``c = −F Rᵀ t`` and ω, φ, κ of ``F R F`` (F = diag(1, −1, −1)), estimated (COLMAP's
    bundle refines it by default; unknown when the model has none); frames hold their registered
    images.  Trivial rigs (one camera each) give no rig: those photos are adjusted one by one."""
    from baarda.pipeline.geometry import opk_from_rotation

    rig_col, cam_col, ref_col, centre, opk = [], [], [], [], []
    frame_col, photo_col = [], []
    rig_of_cam = {}
    for rid in sorted(rec.rigs):
        rig = rec.rigs[rid]
        cams = [s for s in rig.sensor_ids() if s.type.name == "CAMERA" and s.id in cam_index]
        if len(cams) < 2:
            continue
        for sid in sorted(cams, key=lambda s: (not rig.is_ref_sensor(s), s.id)):
            ref = bool(rig.is_ref_sensor(sid))
            c, o = np.zeros(3), np.zeros(3)
            if not ref:
                pose = rig.sensor_from_rig(sid) if rig.has_sensor_from_rig(sid) else None
                if pose is None:
                    c, o = np.full(3, np.nan), np.full(3, np.nan)
                else:
                    R = np.asarray(pose.rotation.matrix(), float)
                    c = -F_CV @ R.T @ np.asarray(pose.translation, float)
                    o = opk_from_rotation(F_CV @ R @ F_CV)
            rig_col.append(str(rid))
            cam_col.append(cam_index[sid.id])
            ref_col.append(ref)
            centre.append(c)
            opk.append(o)
            rig_of_cam[sid.id] = rid
    if not rig_col:
        return Rigs()
    for fid in sorted(rec.frames):
        fr = rec.frames[fid]
        if fr.rig_id not in set(rig_of_cam.values()):
            continue
        for d in sorted(fr.data_ids, key=lambda d: d.id):
            if d.sensor_id.type.name == "CAMERA" and d.id in photo_index:
                frame_col.append(str(fid))
                photo_col.append(photo_index[d.id])
    sigma = np.where(np.array(ref_col)[:, None], FIXED, FREE) * np.ones((len(rig_col), 6))
    sensors = RigSensors.make(rig_col, cam_col, ref_col, centre=np.array(centre), opk=np.array(opk), sigma=sigma)
    frames = FrameMembers(frame=np.array(frame_col, dtype=str), photo=np.array(photo_col, int))
    return Rigs(sensors, frames, path=source or None)


def read_colmap(path: str | Path, **kw) -> tuple[Block, dict]:
    """Read a COLMAP model folder (binary or text) into a Block; see :func:`block_from_reconstruction`."""
    rec = read_reconstruction(path)
    block, info = block_from_reconstruction(rec, source=str(path), **kw)
    info["format"] = model_format(path)
    return block, info
