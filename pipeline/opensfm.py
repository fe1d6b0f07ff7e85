"""OpenSfM / OpenDroneMap ``reconstruction.json`` (+ ``tracks.csv``) ↔ :class:`~baarda.pipeline.model.Block`.

OpenSfM's conventions (``docs/metashape-opensfm.md``):

* camera frame x right, y down, z forward; a shot's ``rotation`` is the axis-angle (Rodrigues) vector of
  ``R`` and ``translation`` is ``t`` with ``p_cam = R X + t`` (world → camera);
* normalised image coordinates ``x_n = (u + 0.5 − W/2) / s``, ``y_n = (v + 0.5 − H/2) / s`` with
  ``s = max(W, H)`` and ``(u, v)`` OpenCV pixels (origin at the centre of the top-left pixel);
* ``perspective``: ``x_n = f · d · X/Z`` with ``d = 1 + k1 r² + k2 r⁴``;
  ``brown``: OpenCV's distortion (k1, k2, k3, p1, p2) of ``X/Z, Y/Z``, then ``x_n = focal_x · x_d + c_x``,
  ``y_n = focal_y · y_d + c_y``.

Both map exactly onto baarda's ``brown`` AP model (:func:`~baarda.pipeline.camera.convert.brown_from_opencv`
with ``fx = focal_x · s`` pixels) when ``focal_x = focal_y``; ``fisheye`` and the other projection
types are refused by name.  OpenSfM has no pixel pitch: ``pixel_mm`` is nominal (``c = f_px · pixel_mm``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from baarda.pipeline.camera.convert import BROWN, brown_from_opencv, opencv_from_brown
from baarda.pipeline.errors import InputError, read_text_limited
from baarda.pipeline.geometry.image import mm_from_pixels, pixels_from_mm
from baarda.pipeline.geometry.pose import cv_from_pose, pose_from_cv
from baarda.pipeline.model import FIXED, FREE, Block, Cameras, Observations, Photos, Points, SourceInfo

PROJECTIONS = ("perspective", "brown")
TRACKS_HEADER = "OPENSFM_TRACKS_VERSION"


def _rotvec_to_matrix(r) -> np.ndarray:
    r = np.asarray(r, float)
    th = math.sqrt(float(r @ r))
    if th < 1e-300:
        return np.eye(3)
    k = r / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * (K @ K)


def _matrix_to_rotvec(R) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.asarray(R, float)).as_rotvec()


def _num(obj, key, path, where, *, default=None, positive=False):
    if key not in obj:
        if default is not None:
            return float(default)
        raise InputError(f"{where}: missing '{key}'", path=path, field=f"{where}.{key}")
    v = obj[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InputError(f"{where}: '{key}' must be a finite number, got {v!r}", path=path, field=f"{where}.{key}")
    if positive and v <= 0:
        raise InputError(f"{where}: '{key}' must be > 0, got {v!r}", path=path, field=f"{where}.{key}")
    return float(v)


def _vec3(obj, key, path, where):
    v = obj.get(key) if isinstance(obj, dict) else None
    if (not isinstance(v, list) or len(v) != 3
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)):
        raise InputError(f"{where}: '{key}' must be a list of 3 finite numbers, got {v!r}", path=path,
                         field=f"{where}.{key}")
    return np.array(v, float)


def camera_from_opensfm(cid: str, cam: dict, path, pixel_mm: float) -> dict:
    """baarda camera ``{c, xp, yp, ap (7,), size, exact}`` of one OpenSfM camera (see the module docstring)."""
    where = f"cameras[{cid!r}]"
    if not isinstance(cam, dict):
        raise InputError(f"{where}: expected an object", path=path, field=where)
    proj = cam.get("projection_type", "perspective")
    if proj not in PROJECTIONS:
        raise InputError(f"{where}: projection_type {proj!r} is not supported (supported: "
                         f"{', '.join(PROJECTIONS)}; fisheye and spherical cameras are refused)", path=path,
                         field=f"{where}.projection_type")
    w, h = _num(cam, "width", path, where, positive=True), _num(cam, "height", path, where, positive=True)
    if w != int(w) or h != int(h):
        raise InputError(f"{where}: width and height must be whole pixels", path=path, field=f"{where}.width")
    W, H = int(w), int(h)
    s = float(max(W, H))
    if proj == "perspective":
        f = _num(cam, "focal", path, where, positive=True)
        fx = fy = f
        cx = cy = 0.0
        dist = {"k1": _num(cam, "k1", path, where, default=0.0), "k2": _num(cam, "k2", path, where, default=0.0)}
    else:
        fx = _num(cam, "focal_x", path, where, positive=True)
        fy = _num(cam, "focal_y", path, where, positive=True)
        cx, cy = _num(cam, "c_x", path, where, default=0.0), _num(cam, "c_y", path, where, default=0.0)
        dist = {k: _num(cam, k, path, where, default=0.0) for k in ("k1", "k2", "k3", "p1", "p2")}
    c, ap = brown_from_opencv(fx * s, fy * s, pixel_mm, **dist)
    # principal point: normalised (c_x, c_y) → OpenCV pixels u = c_x·s + W/2 − 0.5
    u0, v0 = cx * s + W / 2.0 - 0.5, cy * s + H / 2.0 - 0.5
    xp, yp = mm_from_pixels([u0, v0], (W, H), pixel_mm, "opencv")
    exact = fx == fy or not any(dist.values())
    return {"c": c, "xp": float(xp), "yp": float(yp), "ap": ap, "size": (W, H), "exact": exact,
            "projection_type": proj}


def opensfm_from_camera(c, xp, yp, ap, size, pixel_mm) -> dict:
    """OpenSfM ``brown`` camera dict of a baarda brown camera (inverse of :func:`camera_from_opensfm`)."""
    W, H = (int(size[0]), int(size[1]))
    s = float(max(W, H))
    v = opencv_from_brown(c, ap, pixel_mm)
    u0, v0 = pixels_from_mm([xp, yp], (W, H), pixel_mm, "opencv")
    return {"projection_type": "brown", "width": W, "height": H,
            "focal_x": v["fx"] / s, "focal_y": v["fy"] / s,
            "c_x": (float(u0) + 0.5 - W / 2.0) / s, "c_y": (float(v0) + 0.5 - H / 2.0) / s,
            "k1": v["k1"], "k2": v["k2"], "k3": v["k3"], "p1": v["p1"], "p2": v["p2"]}


def read_tracks(path: Path) -> tuple[list[str], list[str], np.ndarray, np.ndarray]:
    """``(images, track ids, xy_norm (n, 2), line numbers)`` of an OpenSfM ``tracks.csv`` (v0, v1, v2)."""
    images, tracks, xy, lines = [], [], [], []
    text = read_text_limited(path, what="tracks.csv", field="tracks")
    for ln, line in enumerate(text.replace("\r\n", "\n").replace("\r", "\n").split("\n"), 1):   # as open() reads
        if ln == 1 and line.startswith(TRACKS_HEADER):
            continue
        if not line.strip():
            continue
        parts = line.rstrip("\n").split("\t")
        if len(parts) < 5:
            raise InputError(f"expected at least 5 tab-separated columns (image, track_id, feature_id, x, y), "
                             f"got {len(parts)}", path=path, line=ln, field="x" if len(parts) == 4 else "columns")
        for k, name in ((3, "x"), (4, "y")):
            try:
                val = float(parts[k])
            except ValueError:
                raise InputError(f"{name}: expected a number, got {parts[k]!r}", path=path, line=ln,
                                 field=name) from None
            if not math.isfinite(val):
                raise InputError(f"{name}: expected a finite number, got {parts[k]!r}", path=path, line=ln,
                                 field=name)
        images.append(parts[0])
        tracks.append(parts[1])
        xy.append((float(parts[3]), float(parts[4])))
        lines.append(ln)
    return images, tracks, np.array(xy, float).reshape(-1, 2), np.array(lines, int)


def read_opensfm(path: str | Path, *, tracks: str | Path | None = None, pixel_mm: float = 0.001,
                 sigma_px: float = 1.0, intrinsics: str = "opensfm", which: int = 0,
                 gcp: str | Path | None = None, gcp_crs: str | None = None,
                 gcp_sigma=(0.02, 0.02, 0.03), gcp_check=(), gcp_sigma_px: float | None = None,
                 gcp_where: dict | None = None) -> tuple[Block, dict]:
    """Read reconstruction ``which`` of an OpenSfM ``reconstruction.json`` as a block.

    ``tracks``: the ``tracks.csv`` with the observations (default: ``tracks.csv`` beside the json,
    when present; without it the block has points but no observations).  ``intrinsics``:
    ``"opensfm"`` frees what OpenSfM's bundle refines (focal and distortion, principal point fixed),
    ``"fixed"`` none, ``"free"`` all.  ``gcp``: an ODM/OpenSfM ``gcp_list.txt`` whose targets are
    added as control points (``gcp_sigma`` E, N, U metres) or check points (``gcp_check``) with
    their pixel measurements (σ ``gcp_sigma_px``, default ``sigma_px``): :func:`_with_gcps`.
    ``gcp_where``: path and line of the options, for errors about ``gcp_crs`` and ``gcp_check``.
    """
    path = Path(path)
    if intrinsics not in ("opensfm", "fixed", "free"):
        raise ValueError(f"intrinsics must be 'opensfm', 'fixed' or 'free', got {intrinsics!r}")
    if not path.exists():
        raise InputError("reconstruction.json not found", path=path) from None
    text = read_text_limited(path, what="reconstruction.json", field="json")
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(f"not valid JSON: {e.msg}", path=path, line=e.lineno, field="json") from None
    if not isinstance(doc, list) or not doc:
        raise InputError("expected a JSON list of reconstructions (OpenSfM's reconstruction.json)", path=path,
                         field="reconstructions")
    if not 0 <= which < len(doc):
        raise InputError(f"reconstruction {which} asked for, the file holds {len(doc)}", path=path,
                         field="reconstruction")
    rec = doc[which]
    if not isinstance(rec, dict):
        raise InputError(f"reconstructions[{which}] is not an object", path=path, field=f"reconstructions[{which}]")
    rec = {"shots": {}, "points": {}, **rec}                  # ODM writes camera-only files without them
    for key in ("cameras", "shots", "points"):
        if not isinstance(rec.get(key), dict):
            raise InputError(f"reconstructions[{which}]: missing or not an object: '{key}'", path=path, field=key)
    cam_ids = list(rec["cameras"])
    cams = [camera_from_opensfm(cid, rec["cameras"][cid], path, pixel_mm) for cid in cam_ids]
    n = len(cams)
    sig_iop = np.array([[0.0 if intrinsics == "fixed" else FREE] + [FREE if intrinsics == "free" else FIXED] * 2] * n,
                       float).reshape(n, 3)
    sig_ap = np.full((n, len(BROWN)), FIXED)
    for k, cm in enumerate(cams):
        free = ("K1", "K2") if cm["projection_type"] == "perspective" else ("K1", "K2", "K3", "P1", "P2", "B1")
        if intrinsics != "fixed":
            sig_ap[k, [BROWN.index(p) for p in free]] = FREE
    cameras = Cameras(
        ids=np.array([str(c) for c in cam_ids], dtype=str), c=[cm["c"] for cm in cams],
        xp=[cm["xp"] for cm in cams], yp=[cm["yp"] for cm in cams],
        ap_model=np.array(["brown"] * n, dtype=str), ap=np.array([cm["ap"] for cm in cams]).reshape(n, len(BROWN)),
        sigma_iop=sig_iop, sigma_ap=sig_ap,
        format_mm=np.array([[cm["size"][0] * pixel_mm, cm["size"][1] * pixel_mm] for cm in cams]).reshape(n, 2),
        pixel_mm=[pixel_mm] * n, resolution=np.array([cm["size"] for cm in cams], int).reshape(n, 2))
    cam_index = {cid: k for k, cid in enumerate(cam_ids)}

    shot_ids = list(rec["shots"])
    X0, opk, cam_of = np.zeros((len(shot_ids), 3)), np.zeros((len(shot_ids), 3)), []
    for k, sid in enumerate(shot_ids):
        sh, where = rec["shots"][sid], f"shots[{sid!r}]"
        if not isinstance(sh, dict):
            raise InputError(f"{where}: expected an object", path=path, field=where)
        R = _rotvec_to_matrix(_vec3(sh, "rotation", path, where))
        t = _vec3(sh, "translation", path, where)
        if sh.get("camera") not in cam_index:
            raise InputError(f"{where}: camera {sh.get('camera')!r} is not in 'cameras'", path=path,
                             field=f"{where}.camera")
        cam_of.append(cam_index[sh["camera"]])
        X0[k], opk[k] = pose_from_cv(R, t)
    photos = Photos.make(shot_ids, camera=np.array(cam_of, int), X0=X0, opk=opk)

    pt_ids = list(rec["points"])
    XYZ = np.array([_vec3(rec["points"][p], "coordinates", path, f"points[{p!r}]") for p in pt_ids],
                   float).reshape(-1, 3)
    points = Points.make(pt_ids, XYZ=XYZ, role="tie")

    tracks_path = Path(tracks) if tracks is not None else path.with_name("tracks.csv")
    obs_photo, obs_point, uv, lines = [], [], np.zeros((0, 2)), np.zeros(0, int)
    if tracks is not None and not tracks_path.is_file():
        raise InputError("tracks file not found", path=tracks_path, field="tracks")
    used_tracks = tracks_path.is_file()
    if used_tracks:
        images, tids, xy, ln = read_tracks(tracks_path)
        ph_index = {s: k for k, s in enumerate(shot_ids)}
        pt_index = {p: k for k, p in enumerate(pt_ids)}
        keep = np.array([i in ph_index and t in pt_index for i, t in zip(images, tids)], bool)
        obs_photo = np.array([ph_index[i] for i, kp in zip(images, keep) if kp], int)
        obs_point = np.array([pt_index[t] for t, kp in zip(tids, keep) if kp], int)
        xy, lines = xy[keep], ln[keep]
        res = cameras.resolution[photos.camera[obs_photo]].astype(float)
        s = res.max(axis=1, keepdims=True)
        uv = xy * s + res / 2.0 - 0.5                    # normalised → OpenCV pixels
    obs_photo, obs_point = np.asarray(obs_photo, int), np.asarray(obs_point, int)
    cam_obs = photos.camera[obs_photo]
    xy_mm = mm_from_pixels(uv, cameras.resolution[cam_obs], cameras.pixel_mm[cam_obs], "opencv")
    first = np.zeros(len(obs_photo), bool)
    if len(obs_photo):
        _, idx = np.unique(obs_photo * (len(pt_ids) + 1) + obs_point, return_index=True)
        first[idx] = True
    observations = Observations.make(obs_photo, obs_point, xy_mm.reshape(-1, 2),
                                     sigma=sigma_px * cameras.pixel_mm[cam_obs], active=first)
    source = SourceInfo(path=str(path), format="OpenSfM", pixel_format="OpenSfM",
                        lines={(int(a), int(b)): (str(tracks_path), int(c))
                               for a, b, c in zip(obs_photo[first], obs_point[first], np.asarray(lines)[first])})
    meta = {"opensfm": {"path": str(path), "tracks": str(tracks_path) if used_tracks else None,
                        "projection_types": [cm["projection_type"] for cm in cams],
                        "reference_lla": rec.get("reference_lla")}}
    block = Block(cameras=cameras, photos=photos, points=points, observations=observations, object_unit="m",
                  meta=meta, source=source)
    info = {"inexact_cameras": [cid for cid, cm in zip(cam_ids, cams) if not cm["exact"]],
            "tracks": str(tracks_path) if used_tracks else None, "duplicate_observations": int((~first).sum()),
            "reconstructions": len(doc), "projection_types": sorted({cm["projection_type"] for cm in cams})}
    if gcp is not None:
        block, info["gcp"] = _with_gcps(block, Path(gcp), path, rec, crs=gcp_crs, sigma=gcp_sigma, check=gcp_check,
                                        sigma_px=sigma_px if gcp_sigma_px is None else gcp_sigma_px,
                                        where=gcp_where or {})
    return block, info


def _reference_lla(rec: dict, path: Path):
    """(lon°, lat°, alt m, where it came from) of the reconstruction's topocentric origin: its
    ``reference_lla`` or ``reference_lla.json`` beside the file (OpenSfM's dataset folder); None
    when neither exists."""
    ref, src = rec.get("reference_lla"), path
    if ref is None and path.with_name("reference_lla.json").is_file():
        src = path.with_name("reference_lla.json")
        try:
            ref = json.loads(src.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise InputError(f"not valid JSON: {getattr(e, 'msg', e)}", path=src, line=getattr(e, "lineno", None),
                             field="reference_lla") from None
    if ref is None:
        return None
    if not isinstance(ref, dict):
        raise InputError(f"reference_lla: expected an object, got {ref!r}", path=src, field="reference_lla")
    lat = _num(ref, "latitude", src, "reference_lla")
    lon = _num(ref, "longitude", src, "reference_lla")
    alt = _num(ref, "altitude", src, "reference_lla")
    if not (-90 <= lat <= 90 and -180 <= lon <= 360):
        raise InputError(f"reference_lla: latitude {lat:g}, longitude {lon:g} are not a place on the Earth", path=src,
                         field="reference_lla.latitude")
    return lon, lat, alt, src


GCP_MAX_KM = 50.0
"""Targets farther than this from the reconstruction's topocentric origin are refused: the
coordinates are not in the CRS the gcp list names (or the reference_lla is another place)."""


def _with_gcps(block: Block, gcp_path: Path, path: Path, rec: dict, *, crs, sigma, check, sigma_px, where):
    """``block`` with the targets of an ODM/OpenSfM ``gcp_list.txt`` (:func:`~baarda.pipeline.gcplist.read_gcp_list`)
    as control points (role ``full``, a-priori σ ``sigma`` E, N, U m) or check points (``check``)
    and their pixel measurements in the shots of the reconstruction (OpenCV pixels as OpenSfM's
    ``normalized_image_coordinates``; measurements in images that are not shots are left out, as
    OpenSfM does, and counted).

    Coordinates: the gcp list's CRS (or ``crs``; ``"local"``: already the reconstruction's frame)
    goes to the reconstruction's topocentric frame — east, north, up at ``reference_lla``, the frame
    of OpenSfM's ``topocentric_from_lla`` — through :class:`~baarda.pipeline.crs.LocalFrame` with
    that origin; the block then carries the frame (``block.crs``), so results are also reported in
    the CRS (``docs/crs.md``).  The CRS's geodetic datum is taken as the one of ``reference_lla``
    (WGS 84): a CRS on another ellipsoid is refused."""
    from baarda.pipeline.crs import WGS84_A, WGS84_F, LocalFrame, parse_crs
    from baarda.pipeline.gcplist import read_gcp_list

    g = read_gcp_list(gcp_path)
    opt_path, crs_line = where.get("path"), where.get("crs_line")
    crs_text, c_path, c_line, c_field = ((crs, opt_path, crs_line, "gcp_crs") if crs is not None
                                         else (g.crs, g.path, g.crs_line, "crs"))
    local = str(crs_text).strip().lower() in ("local", "none", "")
    if local:
        frame = LocalFrame(None)
    else:
        ref = _reference_lla(rec, path)
        if ref is None:
            raise InputError("the gcp list's coordinates are in a CRS, but the reconstruction has no reference_lla "
                             "(and there is no reference_lla.json beside it): its frame is unknown. Give gcp_crs = "
                             "\"local\" when the targets are in the reconstruction's own frame", path=path,
                             field="reference_lla")
        pc = parse_crs(crs_text, path=c_path, line=c_line, field=c_field)
        ell = pc.ellipsoid
        if ell is not None and (abs(float(ell.semi_major_metre) - WGS84_A) > 1.0
                                or abs(1.0 / float(ell.inverse_flattening or np.inf) - WGS84_F) > 1e-8):
            raise InputError(f"the CRS {str(crs_text).strip()[:60]!r} is on the ellipsoid {ell.name!r}; OpenSfM's "
                             "reference_lla is WGS 84: give the targets in a WGS 84 (or GRS 80) based CRS",
                             path=c_path, line=c_line, field=c_field)
        frame = LocalFrame(pc.to_wkt(), (ref[0], ref[1], ref[2]))
    try:
        XYZ = frame.to_local(g.geo)
    except InputError as e:
        raise InputError(e.message, path=c_path, line=c_line, field=c_field) from None
    far = np.linalg.norm(XYZ, axis=1) > GCP_MAX_KM * 1000
    if far.any():
        k = int(np.flatnonzero(far)[0])
        raise InputError(f"target {g.name[k]!r} lies {np.linalg.norm(XYZ[k]) / 1000:.0f} km from the reconstruction's "
                         f"reference_lla: its coordinates are not in {str(crs_text).strip()[:60]!r} (or the "
                         "reference is another place)", path=g.path, line=int(g.line[k]), field="geo_x")
    names = list(dict.fromkeys(g.name))
    unknown = [c for c in check if c not in names]
    if unknown:
        raise InputError(f"gcp_check: {unknown[0]!r} is not a target of {g.path.name} (targets: "
                         f"{', '.join(names[:12])}{' …' if len(names) > 12 else ''})", path=where.get("path"),
                         line=where.get("check_line"), field="gcp_check")
    pts = block.points
    clash = set(names) & set(pts.ids.tolist())
    if clash:
        name = sorted(clash)[0]
        k = g.name.index(name)
        raise InputError(f"target {name!r} has the id of a point of the reconstruction: rename the target",
                         path=g.path, line=int(g.line[k]), field="gcp_name")
    first = [g.name.index(n) for n in names]
    role = ["check" if n in check else "full" for n in names]
    sig = np.array([np.full(3, FREE) if r == "check" else np.asarray(sigma, float) for r in role]).reshape(-1, 3)
    new_pts = Points.make(names, XYZ=XYZ[first], role=role, sigma=sig)
    points = Points.make(pts.ids.tolist() + names, XYZ=np.vstack([pts.XYZ, new_pts.XYZ]),
                         role=pts.role.tolist() + role, sigma=np.vstack([pts.sigma, sig]))
    ph = block.photos
    shot_index = {str(s): k for k, s in enumerate(ph.ids.tolist())}
    rows = np.array([i for i, im in enumerate(g.image) if im in shot_index], int)
    missing = sorted({im for im in g.image if im not in shot_index})
    cams = block.cameras
    o_ph = np.array([shot_index[g.image[i]] for i in rows], int)
    o_pt = np.array([len(pts) + names.index(g.name[i]) for i in rows], int)
    cam = ph.camera[o_ph]
    res = cams.resolution[cam].astype(float)
    uv = g.pixel[rows]
    out = ~((uv >= -0.5) & (uv <= res - 0.5)).all(axis=1)
    if out.any():
        k = int(rows[np.flatnonzero(out)[0]])
        W, H = res[np.flatnonzero(out)[0]].astype(int)
        raise InputError(f"pixel ({g.pixel[k, 0]:g}, {g.pixel[k, 1]:g}) lies outside the {W} × {H} image "
                         f"{g.image[k]!r}", path=g.path, line=int(g.line[k]), field="im_x")
    xy = mm_from_pixels(uv, res, cams.pixel_mm[cam], "opencv").reshape(-1, 2)
    ob = block.observations
    observations = Observations.make(np.concatenate([ob.photo, o_ph]), np.concatenate([ob.point, o_pt]),
                                     np.vstack([ob.xy, xy]),
                                     cov=np.concatenate([ob.cov, (sigma_px * cams.pixel_mm[cam])[:, None, None] ** 2
                                                         * np.eye(2)]),
                                     active=np.concatenate([ob.active, np.ones(len(rows), bool)]))
    lines = dict(block.source.lines or {})
    lines.update({(int(a), int(b)): (str(g.path), int(c)) for a, b, c in zip(o_ph, o_pt, g.line[rows])})
    source = SourceInfo(path=block.source.path, format=block.source.format, pixel_format=block.source.pixel_format,
                        lines=lines)
    info = {"path": str(g.path), "crs": str(crs_text).strip(), "targets": len(names),
            "control": role.count("full"), "check": role.count("check"), "measurements": len(g.name),
            "used_measurements": int(len(rows)), "images_not_shots": missing,
            "origin_lon_lat_h": None if frame.is_identity else list(frame.origin)}
    meta = dict(block.meta)
    meta["opensfm"] = {**meta["opensfm"], "gcp": info}
    out_block = block.replace(points=points, observations=observations, source=source, meta=meta,
                              crs=frame.info())
    return out_block, info


def write_opensfm(block: Block, folder: str | Path) -> dict:
    """Write ``block`` as ``folder/reconstruction.json`` and ``folder/tracks.csv`` (v2).

    Cameras must be ``none`` or ``brown`` (``B2`` = 0); photos without orientation are left out.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cm = block.cameras
    cameras = {}
    for k, cid in enumerate(cm.ids.tolist()):
        if cm.ap_model[k] not in ("none", "brown"):
            raise ValueError(f"camera {cid}: AP model {cm.ap_model[k]!r} has no OpenSfM counterpart (brown or none)")
        if not np.all(cm.resolution[k] > 0) or not np.isfinite(cm.pixel_mm[k]):
            raise ValueError(f"camera {cid}: resolution and pixel_mm are needed to write OpenSfM")
        ap = cm.ap[k] if cm.ap_model[k] == "brown" else np.zeros(len(BROWN))
        cameras[cid] = opensfm_from_camera(cm.c[k], cm.xp[k], cm.yp[k], ap, cm.resolution[k], cm.pixel_mm[k])
    ph = block.photos
    ok = np.isfinite(ph.X0).all(axis=1) & np.isfinite(ph.opk).all(axis=1)
    R, t = cv_from_pose(ph.X0[ok], ph.opk[ok])
    shots = {}
    for j, k in enumerate(np.flatnonzero(ok)):
        shots[str(ph.ids[k])] = {"camera": str(cm.ids[ph.camera[k]]), "rotation": _matrix_to_rotvec(R[j]).tolist(),
                                 "translation": t[j].tolist()}
    pts = block.points
    pok = np.isfinite(pts.XYZ).all(axis=1)
    points = {str(pts.ids[i]): {"coordinates": pts.XYZ[i].tolist(), "color": [255, 255, 255]}
              for i in np.flatnonzero(pok)}
    (folder / "reconstruction.json").write_text(json.dumps([{"cameras": cameras, "shots": shots, "points": points}],
                                                           indent=1))
    ob = block.observations
    sel = ob.active & ok[ob.photo] & pok[ob.point]
    cam = ph.camera[ob.photo[sel]]
    res = cm.resolution[cam].astype(float)
    uv = pixels_from_mm(ob.xy[sel], res, cm.pixel_mm[cam], "opencv")
    xy = (uv + 0.5 - res / 2.0) / res.max(axis=1, keepdims=True)
    with open(folder / "tracks.csv", "w", encoding="utf-8") as f:
        f.write(f"{TRACKS_HEADER}_v2\n")
        for n, (p, q, (x, y)) in enumerate(zip(ob.photo[sel], ob.point[sel], xy)):
            f.write(f"{ph.ids[p]}\t{pts.ids[q]}\t{n}\t{float(x)!r}\t{float(y)!r}\t0\t255\t255\t255\t-1\t-1\n")
    return {"cameras": len(cameras), "shots": len(shots), "points": len(points), "observations": int(sel.sum()),
            "skipped_photos": ph.ids[~ok].tolist()}
