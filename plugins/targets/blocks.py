"""The block of ``opencv-targets``' detections (``stage.py``): a board's control points with photo
orientations by resection, or the input block's layout for ``'circles'``; pixels to mm with the
camera's pitch and format (``docs/conventions.md``), the a-priori σ of the target type."""

from __future__ import annotations

import numpy as np

from baarda.pipeline.camera.convert import BROWN
from baarda.pipeline.geometry.image import mm_from_pixels
from baarda.pipeline.api import Block
from baarda.pipeline.model import FIXED, FREE, Cameras, Observations, Pairs, Photos, Points, SourceInfo

from .boards import object_points
from .calib import initial_focal_px, resect

IOP = ("c", "xp", "yp")


def pairs_of_layout(layout: Block, block: Block) -> Pairs:
    """The layout's stereo pairs whose two photos are both in ``block`` (by photo id), re-indexed to
    ``block``'s photos: a detection that skips a photo drops its pairs, keeps the others."""
    pos = {str(p): k for k, p in enumerate(block.photos.ids)}
    ids = layout.photos.ids
    keep = [(pos[str(ids[a])], pos[str(ids[b])]) for a, b in zip(layout.pairs.left, layout.pairs.right)
            if str(ids[a]) in pos and str(ids[b]) in pos]
    return Pairs(left=np.array([a for a, _ in keep], int), right=np.array([b for _, b in keep], int))


def detection_block(dets, geom, options, sigma_px, layout, warn):
    """The block of the detections ``dets`` (``(photo id, camera, size, Detection)``): a board's
    points as full control (Z = 0) and photo orientations by resection, or, for ``'circles'``, the
    input ``layout`` block's (:func:`layout_detection_block`).  An image whose size differs from its
    camera's first is left out (``warn`` says so).  Returns ``(block, info)``."""
    size_of: dict[str, tuple[int, int]] = {}
    mismatch = set()
    kept = []
    for pid, cam, size, det in dets:
        if size_of.setdefault(cam, size) != size:
            mismatch.add(pid)
            warn(f"{pid}: image size {size[0]}×{size[1]} differs from camera '{cam}' "
                     f"({size_of[cam][0]}×{size_of[cam][1]}); skipped")
            continue
        kept.append((pid, cam, size, det))
    if layout is not None:
        return layout_detection_block(kept, layout, options, sigma_px), {"size_mismatch": mismatch,
                                                                           "cameras_px": {}}
    board_ids, board_xyz = object_points(geom)
    xyz_of = dict(zip(board_ids, board_xyz))
    cam_ids = list(dict.fromkeys(cam for _, cam, _, _ in kept))
    p = options.pixel_mm
    # principal distance per camera: option, else from the board's homographies, else the image width
    f_px = {}
    for cam in cam_ids:
        guess = options.principal_distance_mm / p if options.principal_distance_mm > 0 else None
        if guess is None and geom.has_geometry:
            views = [(np.array([xyz_of[i] for i in d.ids]), d.uv) for _, c, _, d in kept if c == cam]
            guess = initial_focal_px([v[0] for v in views], [v[1] for v in views], size_of[cam])
        f_px[cam] = guess or float(max(size_of[cam]))
    point_ids = list(dict.fromkeys(i for _, _, _, d in kept for i in d.ids))
    if geom.has_geometry:
        points = Points.make([f"{i}" for i in point_ids], XYZ=np.array([xyz_of[i] for i in point_ids]).reshape(-1, 3),
                             role="full")
    else:
        points = Points.make(point_ids, role="tie")
    pindex = {i: k for k, i in enumerate(point_ids)}
    X0 = np.full((len(kept), 3), np.nan)
    opk = np.full((len(kept), 3), np.nan)
    obs_photo, obs_point, obs_xy = [], [], []
    for k, (pid, cam, size, det) in enumerate(kept):
        if geom.has_geometry:
            pose = resect(np.array([xyz_of[i] for i in det.ids]), det.uv, f_px[cam], size)
            if pose is not None:
                X0[k], opk[k] = pose
        obs_photo += [k] * len(det)
        obs_point += [pindex[i] for i in det.ids]
        obs_xy.append(mm_from_pixels(det.uv, size, p, "opencv"))
    photos = Photos.make([pid for pid, _, _, _ in kept], camera=[cam_ids.index(c) for _, c, _, _ in kept],
                         X0=X0, opk=opk, image_path=[str(d.extra.get("file", "")) for _, _, _, d in kept])
    cameras = board_cameras(cam_ids, size_of, f_px, options)
    obs = Observations.make(obs_photo, obs_point, np.concatenate(obs_xy), sigma=sigma_px * p)
    block = Block(cameras=cameras, photos=photos, points=points, observations=obs, object_unit=options.unit,
                  meta={"targets": {"target": options.target, "pixel_convention": "opencv"}},
                  source=SourceInfo(format="OpenCV targets", pixel_format="OpenCV"))
    return block, {"size_mismatch": mismatch,
                   "cameras_px": {c: {"f_px_start": f_px[c], "size": list(size_of[c])} for c in cam_ids}}

def board_cameras(cam_ids, size_of, f_px, options) -> Cameras:
    """One camera per name: principal distance ``f_px`` × pitch, the options' unknowns free."""
    p = options.pixel_mm
    unknown = set(options.unknowns)
    n_ap = len(BROWN) if options.ap_model == "brown" else 0
    sig_iop = [FREE if name in unknown else FIXED for name in IOP]
    sig_ap = [FREE if name in unknown else FIXED for name in BROWN[:n_ap]]
    k = len(cam_ids)
    res = np.array([size_of[c] for c in cam_ids], int).reshape(k, 2)
    return Cameras.make(cam_ids, [f_px[c] * p for c in cam_ids], 0.0, 0.0, ap_model=options.ap_model,
                        ap=np.zeros((k, n_ap)), sigma_iop=sig_iop,
                        sigma_ap=np.tile(np.array(sig_ap, float), (k, 1)).reshape(k, n_ap),
                        format_mm=res * p, pixel_mm=p, resolution=res)

def layout_detection_block(kept, layout, options, sigma_px) -> Block:
    """'circles': the input block's cameras, the detected photos and points, new observations."""
    ph_idx = layout.photos.index_of([pid for pid, _, _, _ in kept])
    used_points = list(dict.fromkeys(i for _, _, _, d in kept for i in d.ids))
    pt_idx = layout.points.index_of(used_points)
    pindex = {i: k for k, i in enumerate(used_points)}
    cams = layout.cameras
    obs_photo, obs_point, obs_xy, sig = [], [], [], []
    for k, (pid, _, size, det) in enumerate(kept):
        ci = layout.photos.camera[ph_idx[k]]
        pitch = cams.pixel_mm[ci] if np.isfinite(cams.pixel_mm[ci]) else options.pixel_mm
        obs_photo += [k] * len(det)
        obs_point += [pindex[i] for i in det.ids]
        obs_xy.append(mm_from_pixels(det.uv, size, pitch, "opencv"))
        sig += [sigma_px * pitch] * len(det)
    obs = Observations.make(obs_photo, obs_point, np.concatenate(obs_xy), sigma=np.array(sig))
    meta = {**layout.meta, "targets": {"target": "circles", "pixel_convention": "opencv"}}
    photos = layout.photos.take(ph_idx)
    photos = photos.replace(image_path=[str(d.extra.get("file", "")) for _, _, _, d in kept])
    block = Block(cameras=cams, photos=photos, points=layout.points.take(pt_idx),
                  observations=obs, object_unit=layout.object_unit, meta=meta, crs=layout.crs,
                  ap_meta=layout.ap_meta, scale_bars=layout.scale_bars,
                  source=SourceInfo(path=layout.source.path, format="OpenCV targets", pixel_format="OpenCV"))
    return block.replace(pairs=pairs_of_layout(layout, block))


def consistent_rig_ids(block, warn) -> Block:
    """A chessboard's corner order is ambiguous by a half turn of the board (OpenCV may number a view
    from either end): for a rig the photos of one frame must number the corners alike.  A photo of a
    non-reference sensor whose orientation relative to its frame's reference photo (from the
    approximate orientations) is a half turn off the relative orientation most frames agree on gets
    its corners renumbered (id → n − 1 − id) and its approximate orientation turned with them; a
    warning names it.  Other blocks are returned unchanged."""
    from baarda.pipeline.adjustment import rig_structure
    from baarda.pipeline.geometry import opk_from_rotation_many, rotation_from_opk_many

    struct = rig_structure(block)
    ph, pts, obs = block.photos, block.points, block.observations
    n = len(pts)
    if struct is None or not np.array_equal(pts.ids, np.array([str(i) for i in range(n)])):
        return block
    R = rotation_from_opk_many(ph.opk)
    nonref = np.flatnonzero((struct.photo_frame >= 0) & ~block.rigs.sensors.reference[np.maximum(struct.photo_sensor, 0)])
    C = pts.XYZ.mean(axis=0)
    half = np.diag([-1.0, -1.0, 1.0])                  # a half turn about the board normal (Z)
    X0, opk = np.array(ph.X0), np.array(ph.opk)
    point = np.array(obs.point)
    for s in np.unique(struct.photo_sensor[nonref]):
        mine = nonref[struct.photo_sensor[nonref] == s]
        ref = struct.frame_ref_photo[struct.photo_frame[mine]]
        rel = R[mine] @ np.transpose(R[ref], (0, 2, 1))
        ang = lambda A, B: np.degrees(np.arccos(np.clip((np.trace(A @ B.T) - 1) / 2, -1, 1)))
        agree = [sum(ang(rel[a], rel[b]) < 20 for b in range(len(mine))) for a in range(len(mine))]
        best = rel[int(np.argmax(agree))]
        for a, p in enumerate(mine):
            if ang(rel[a], best) < 20:
                continue
            Rf = R[p] @ half.T
            if ang(Rf @ R[ref[a]].T, best) >= 20:
                continue
            rows = obs.photo == p
            point[rows] = n - 1 - point[rows]
            X0[p] = C + half @ (ph.X0[p] - C)
            opk[p] = opk_from_rotation_many(Rf[None])[0]
            warn(f"photo {str(ph.ids[p])!r}: chessboard corners numbered from the other end than in its frame's "
                 f"reference photo {str(ph.ids[ref[a]])!r}; renumbered (id → {n - 1} − id)")
    if np.array_equal(point, obs.point):
        return block
    return block.replace(photos=ph.replace(X0=X0, opk=opk), observations=obs.replace(point=point))
