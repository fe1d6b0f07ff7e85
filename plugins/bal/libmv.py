"""libmv / Blender camera-tracking problems (ceres ``data/libmv-ba-problems``) → Block.

Binary layout (ceres ``examples/libmv_bundle_adjuster.cc``): byte 0 ``v`` (little endian) or ``V``
(big endian); byte 1 ``P`` (markers in pixels) or ``N`` (normalized); 8 float32 intrinsics
``f, cx, cy, k1, k2, k3, p1, p2`` shared by all cameras; int32 ``n_cams`` then per camera int32
image, 9 float32 column-major ``R``, 3 float32 ``t``; int32 ``n_points`` then int32 track, 3 float32
``X``; int32 ``n_markers`` then int32 image, int32 track, float32 ``x, y``.

Camera model (``OpenCVReprojectionError`` there)::

    P = R X + t,  xn = P_x/P_z,  yn = P_y/P_z,  r² = xn² + yn²
    xd = xn (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 xn yn + p2 (r² + 2 xn²)
    yd = yn (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p2 xn yn + p1 (r² + 2 yn²)
    u = f xd + cx,  v = f yd + cy

i.e. OpenCV's model with a y-down, z-forward camera frame: the brown mapping of
:func:`baarda.pipeline.camera.convert.brown_from_opencv` applies exactly (``fx = fy = f``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baarda.pipeline.geometry.rotations import nearest_rotation

from baarda.pipeline.api import Block, InputError
from baarda.pipeline.model import FIXED, FREE, Cameras, Observations, Photos, Points, SourceInfo

from baarda.pipeline.geometry.image import mm_from_pixels
from baarda.pipeline.geometry.pose import pose_from_cv
from baarda.pipeline.camera.convert import BROWN, brown_from_opencv


@dataclass(frozen=True, eq=False)
class LibmvProblem:
    """The arrays of a libmv problem file (as stored; float32 widened to float64)."""

    intrinsics: np.ndarray   # (8,) f, cx, cy, k1, k2, k3, p1, p2
    image: np.ndarray        # (m,) image number of each camera
    R: np.ndarray            # (m, 3, 3) y-down cam_from_world rotation
    t: np.ndarray            # (m, 3)
    track: np.ndarray        # (n,) track number of each point
    X: np.ndarray            # (n, 3)
    marker_image: np.ndarray  # (k,)
    marker_track: np.ndarray  # (k,)
    marker_xy: np.ndarray    # (k, 2) pixels from the top-left corner (or normalized)
    pixel_space: bool = True
    path: str = ""


class _Cursor:
    def __init__(self, data: bytes, endian: str, path):
        self.data, self.pos, self.endian, self.path = data, 2, endian, path

    def take(self, dtype: str, count: int, what: str) -> np.ndarray:
        dt = np.dtype(self.endian + dtype)
        end = self.pos + dt.itemsize * count
        if end > len(self.data):
            raise InputError(f"file ends at byte {len(self.data)} while reading {what} (needs byte {end}; "
                             "truncated?)", path=self.path, field=what)
        out = np.frombuffer(self.data, dt, count, self.pos).astype(float if dtype == "f4" else int)
        self.pos = end
        return out

    def records(self, layout: list[tuple[str, str, int]], what: str) -> dict:
        """``n`` (int32) followed by n records of the given (name, dtype, count) fields."""
        n = int(self.take("i4", 1, f"number of {what}")[0])
        if n < 0:
            raise InputError(f"negative number of {what}: {n}", path=self.path, field=what)
        dt = np.dtype([(name, self.endian + t, (c,) if c > 1 else ()) for name, t, c in layout])
        end = self.pos + dt.itemsize * n
        if end > len(self.data):
            got = (len(self.data) - self.pos) // dt.itemsize
            raise InputError(f"file ends after {got} of {n} {what} (truncated?)", path=self.path, field=what)
        rec = np.frombuffer(self.data, dt, n, self.pos)
        self.pos = end
        return {name: np.array(rec[name]) for name, _, _ in layout}


def _finite(values: np.ndarray, path, what: str, offset: int, size: int) -> None:
    """Every value of every record finite; else name the record and its byte offset."""
    bad = ~np.isfinite(values).all(axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(f"{what} record {k} (byte offset {offset + k * size}) holds a value that is not a finite "
                         "number", path=path, field=what)


def _unique(keys: np.ndarray, path, what: str, key: str, offset: int, size: int) -> None:
    """No two records with the same key (a camera, track or marker listed twice)."""
    keys = np.asarray(keys).reshape(-1)
    order = np.argsort(keys, kind="stable")
    twice = np.flatnonzero(np.diff(keys[order]) == 0)
    if twice.size:
        k = int(order[twice[0] + 1])
        raise InputError(f"{what} record {k} (byte offset {offset + k * size}) repeats the {key} of record "
                         f"{int(order[twice[0]])}", path=path, field=what)


ROTATION_TOL = 1e-4
"""Largest |R Rᵀ − I| element of a stored camera rotation (float32 in the file: ~1e-7 for a real one);
beyond it, or with det R < 0, the rotation is refused rather than replaced by the nearest rotation."""


def _rotations(R: np.ndarray, path, offset: int, size: int) -> None:
    """Every camera rotation orthonormal within :data:`ROTATION_TOL` and proper (det +1)."""
    if not len(R):
        return
    err = np.abs(np.einsum("kij,klj->kil", R, R) - np.eye(3)).max(axis=(1, 2))
    bad = (err > ROTATION_TOL) | (np.linalg.det(R) < 0)
    if bad.any():
        k = int(np.argmax(bad))
        what = (f"is not orthonormal (largest |R Rᵀ − I| element {err[k]:.3g} > {ROTATION_TOL:g})" if err[k] > ROTATION_TOL
                else "is a reflection (det R < 0)")
        raise InputError(f"cameras record {k} (byte offset {offset + k * size}): the rotation R {what}", path=path,
                         field="cameras.R")


def read_libmv(path: str | Path) -> LibmvProblem:
    """Parse a libmv problem file (InputError naming the section on any format error)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError("libmv problem file not found", path=path) from None
    except IsADirectoryError:
        raise InputError("expected a file, got a directory", path=path) from None
    if len(data) < 2 or data[0:1] not in (b"v", b"V"):
        raise InputError("not a libmv problem: byte 0 must be 'v' or 'V' (endianness)", path=path, field="endianness")
    if data[1:2] not in (b"P", b"N"):
        raise InputError("byte 1 must be 'P' (pixels) or 'N' (normalized)", path=path, field="marker space")
    cur = _Cursor(data, "<" if data[0:1] == b"v" else ">", path)
    intr = cur.take("f4", 8, "intrinsics")
    _finite(intr[None], path, "intrinsics", 2, 32)
    if not intr[0] > 0:
        raise InputError(f"focal length f = {intr[0]:g} must be positive (byte offset 2)", path=path,
                         field="intrinsics")
    at = at_cams = cur.pos + 4
    cams = cur.records([("image", "i4", 1), ("R", "f4", 9), ("t", "f4", 3)], "cameras")
    _finite(np.hstack([cams["R"].reshape(-1, 9), cams["t"].reshape(-1, 3)]), path, "cameras", at, 52)
    _unique(cams["image"], path, "cameras", "image", at, 52)
    at = cur.pos + 4
    pts = cur.records([("track", "i4", 1), ("X", "f4", 3)], "points")
    _finite(pts["X"].reshape(-1, 3), path, "points", at, 16)
    _unique(pts["track"], path, "points", "track", at, 16)
    at = cur.pos + 4
    mk = cur.records([("image", "i4", 1), ("track", "i4", 1), ("xy", "f4", 2)], "markers")
    _finite(mk["xy"].reshape(-1, 2), path, "markers", at, 16)
    _unique(mk["image"].astype(np.int64) * 2**32 + mk["track"].astype(np.int64) % 2**32, path, "markers",
            "image and track", at, 16)
    if cur.pos != len(data):
        raise InputError(f"{len(data) - cur.pos} unexpected bytes after the markers", path=path, field="markers")
    R = cams["R"].astype(float).reshape(-1, 3, 3).transpose(0, 2, 1)   # column-major in the file
    _rotations(R, path, at_cams, 52)
    return LibmvProblem(intrinsics=intr, image=cams["image"].astype(int), R=R, t=cams["t"].astype(float),
                        track=pts["track"].astype(int), X=pts["X"].astype(float),
                        marker_image=mk["image"].astype(int), marker_track=mk["track"].astype(int),
                        marker_xy=mk["xy"].astype(float), pixel_space=data[1:2] == b"P", path=str(path))


def marker_index(problem: LibmvProblem) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(used (k,) bool, camera index, point index)`` of the markers whose image and track exist."""
    cam_of = {int(i): k for k, i in enumerate(problem.image)}
    pt_of = {int(t): k for k, t in enumerate(problem.track)}
    used = np.array([(int(i) in cam_of) and (int(t) in pt_of)
                     for i, t in zip(problem.marker_image, problem.marker_track)], bool).reshape(-1)
    ci = np.array([cam_of[int(i)] for i in problem.marker_image[used]], int)
    pj = np.array([pt_of[int(t)] for t in problem.marker_track[used]], int)
    return used, ci, pj


def default_resolution(problem: LibmvProblem) -> tuple[int, int]:
    """Image size assumed when none is given: twice the principal point (its files put it at the centre)."""
    _, cx, cy = problem.intrinsics[:3]
    return int(round(2 * cx)), int(round(2 * cy))


def block_from_libmv(problem: LibmvProblem, *, pixel_mm: float = 0.001, sigma_px: float = 1.0,
                     resolution: tuple[int, int] | None = None, intrinsics: str = "free",
                     object_unit: str = "m") -> tuple[Block, dict]:
    """One camera (shared intrinsics) and one photo per libmv camera; markers → observations.

    Pixels use the corner convention (origin at the top-left corner of the image, as Blender's
    tracker) and ``resolution`` (default :func:`default_resolution`).  ``intrinsics="free"`` frees
    c, K1, K2 as libmv refines f, k1, k2 (principal point, K3, P1, P2 fixed); ``"fixed"`` holds all.
    Markers of unknown images or tracks are dropped (counted in ``info``).
    """
    if not problem.pixel_space:
        raise InputError("markers in normalized space ('N') are not supported; baarda needs pixel markers",
                         path=problem.path, field="marker space")
    size = tuple(resolution) if resolution else default_resolution(problem)
    if min(size) <= 0:
        raise InputError(f"the image size taken from the principal point is {size[0]} × {size[1]} pixels; give the "
                         "option resolution = [width, height]", path=problem.path, field="intrinsics")
    f, cx, cy, k1, k2, k3, p1, p2 = problem.intrinsics
    c, ap = brown_from_opencv(f, f, pixel_mm, k1=k1, k2=k2, p1=p1, p2=p2, k3=k3)
    xp, yp = mm_from_pixels([cx, cy], size, pixel_mm, "colmap")
    free = FREE if intrinsics == "free" else FIXED
    sigma_ap = np.zeros(len(BROWN))
    sigma_ap[:2] = free
    cameras = Cameras.make(["libmv"], c, xp, yp, ap_model="brown", ap=ap[None], sigma_iop=[free, FIXED, FIXED],
                           sigma_ap=sigma_ap[None], pixel_mm=pixel_mm, resolution=size,
                           format_mm=[size[0] * pixel_mm, size[1] * pixel_mm])
    poses = [pose_from_cv(nearest_rotation(R), t) for R, t in zip(problem.R, problem.t)]
    photos = Photos.make([str(i) for i in problem.image], camera=0,
                         X0=np.array([p[0] for p in poses]).reshape(-1, 3),
                         opk=np.array([p[1] for p in poses]).reshape(-1, 3))
    points = Points.make([str(j) for j in problem.track], XYZ=problem.X, role="tie")
    keep, ph, pt = marker_index(problem)
    xy = mm_from_pixels(problem.marker_xy[keep], size, pixel_mm, "colmap")
    obs = Observations.make(ph, pt, xy, sigma=sigma_px * pixel_mm)
    block = Block(cameras=cameras, photos=photos, points=points, observations=obs, object_unit=object_unit,
                  meta={"libmv": {"resolution": size, "pixel_mm": pixel_mm}},
                  source=SourceInfo(path=problem.path, format="libmv", pixel_format="libmv"))
    return block, {"dropped_markers": int((~keep).sum()), "resolution": size}


def libmv_reprojection(problem: LibmvProblem, orthonormalize: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``(residuals (k, 2) observed − predicted pixels, used (k,) bool)`` with libmv's own model.

    ``orthonormalize`` replaces each stored rotation by :func:`nearest_rotation` (as the block does).
    """
    f, cx, cy, k1, k2, k3, p1, p2 = problem.intrinsics
    used, ci, pj = marker_index(problem)
    R = np.array([nearest_rotation(M) for M in problem.R]) if orthonormalize else problem.R
    P = np.einsum("kij,kj->ki", R[ci], problem.X[pj]) + problem.t[ci]
    x, y = P[:, 0] / P[:, 2], P[:, 1] / P[:, 2]
    r2 = x * x + y * y
    rc = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    xd = x * rc + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * rc + 2 * p2 * x * y + p1 * (r2 + 2 * y * y)
    pred = np.column_stack([f * xd + cx, f * yd + cy])
    return problem.marker_xy[used] - pred, used
