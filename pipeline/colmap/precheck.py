"""Checks of a COLMAP model's files before and after pycolmap reads them.

pycolmap reads a model in C++: a count in a damaged binary file makes it allocate what the file
does not hold (``std::bad_alloc`` after seconds) or index past a vector (``vector::_M_range_check``),
and its messages name neither the file nor the record.  :func:`check_binary` walks the record
structure of ``cameras.bin``, ``images.bin`` and ``points3D.bin`` (COLMAP's ``ReadCamerasBinary``
… layouts) and names the file, the record and its byte offset when a count exceeds the file;
:func:`check_values` checks what pycolmap read (finite numbers, positive sizes and focal lengths).
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from baarda.pipeline.errors import InputError, quote, read_text_limited

# parameters per COLMAP camera model id (colmap/src/colmap/sensor/models.h)
MODEL_PARAMS = {0: 3, 1: 4, 2: 4, 3: 5, 4: 8, 5: 8, 6: 12, 7: 5, 8: 4, 9: 5, 10: 12, 11: 16, 12: 4, 13: 5, 14: 3,
                15: 4, 16: 6, 17: 2}


class _Reader:
    def __init__(self, path: Path):
        self.path = path
        self.data = path.read_bytes()
        self.pos = 0

    def take(self, fmt: str, what: str):
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise InputError(f"the file ends at byte {len(self.data)} inside {what} (truncated?)", path=self.path)
        out = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return out

    def skip(self, n: int, size: int, what: str, field: str):
        if n < 0 or self.pos + n * size > len(self.data):
            raise InputError(f"{what} at byte offset {self.pos} claims {n} entries of {size} bytes; the file has "
                             f"{max(len(self.data) - self.pos, 0)} bytes left (truncated?)", path=self.path, field=field)
        self.pos += n * size

    def count(self, min_size: int, what: str) -> int:
        (n,) = self.take("Q", f"the number of {what}")
        if n * min_size > len(self.data) - self.pos:
            raise InputError(f"the header claims {n} {what}; the file has room for at most "
                             f"{(len(self.data) - self.pos) // min_size}", path=self.path, field=what)
        return n

    def end(self, what: str):
        if self.pos != len(self.data):
            raise InputError(f"{len(self.data) - self.pos} bytes after the last {what}", path=self.path, field=what)


def check_binary(folder: Path) -> None:
    """Walk the three binary files; InputError naming file, record and byte offset on damage."""
    r = _Reader(folder / "cameras.bin")
    for k in range(r.count(24, "cameras")):
        at = r.pos
        _, model, width, height = r.take("iiQQ", f"camera record {k}")
        if model not in MODEL_PARAMS:
            raise InputError(f"camera record {k} (byte offset {at}): unknown camera model id {model}", path=r.path,
                             field="model")
        if width <= 0 or height <= 0 or width > 10**6 or height > 10**6:
            raise InputError(f"camera record {k} (byte offset {at}): image size {width} × {height} pixels",
                             path=r.path, field="width")
        r.skip(MODEL_PARAMS[model], 8, f"camera record {k}", "params")
    r.end("camera")
    r = _Reader(folder / "images.bin")
    for k in range(r.count(73, "images")):
        r.take("I7dI", f"image record {k}")
        nul = r.data.find(b"\0", r.pos)
        if nul < 0:
            raise InputError(f"image record {k} (byte offset {r.pos}): the image name has no end", path=r.path,
                             field="name")
        r.pos = nul + 1
        (n,) = r.take("Q", f"image record {k}")
        r.skip(n, 24, f"the 2-D points of image record {k}", "points2D")
    r.end("image")
    r = _Reader(folder / "points3D.bin")
    for k in range(r.count(51, "points")):
        r.take("Q3d3Bd", f"point record {k}")
        (n,) = r.take("Q", f"point record {k}")
        r.skip(n, 8, f"the track of point record {k}", "track")
    r.end("point")


MODEL_NAMES = {"SIMPLE_PINHOLE": 3, "PINHOLE": 4, "SIMPLE_RADIAL": 4, "RADIAL": 5, "OPENCV": 8,
               "OPENCV_FISHEYE": 8, "FULL_OPENCV": 12, "FOV": 5, "SIMPLE_RADIAL_FISHEYE": 4,
               "RADIAL_FISHEYE": 5, "THIN_PRISM_FISHEYE": 12, "RAD_TAN_THIN_PRISM_FISHEYE": 16,
               "SIMPLE_DIVISION": 4, "DIVISION": 5, "SIMPLE_FISHEYE": 3, "FISHEYE": 4, "EUCM": 6, "EQUIRECTANGULAR": 2}


def check_cameras_text(folder: Path) -> None:
    """``cameras.txt``: ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`` per line, numbers finite, sizes
    and focal length positive; InputError naming the line and the column."""
    from baarda.pipeline.errors import quote

    path = folder / "cameras.txt"
    text = read_text_limited(path, what="a COLMAP text file")
    seen: dict[str, int] = {}
    for ln, line in enumerate(text.splitlines(), start=1):
        toks = line.split()
        if not toks or toks[0].startswith("#"):
            continue
        if len(toks) < 4:
            raise InputError(f"expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]', got {len(toks)} value(s)", path=path,
                             line=ln, field="camera")
        n = MODEL_NAMES.get(toks[1])
        if n is None:
            raise InputError(f"unknown camera model {quote(toks[1])}", path=path, line=ln, field="MODEL")
        if len(toks) != 4 + n:
            raise InputError(f"a {toks[1]} camera has {n} parameters, got {len(toks) - 4}", path=path, line=ln,
                             field="PARAMS")
        for k, name in ((0, "CAMERA_ID"), (2, "WIDTH"), (3, "HEIGHT")):
            if not toks[k].isdigit() or int(toks[k]) <= 0:
                raise InputError(f"{name} must be a positive integer, got {quote(toks[k])}", path=path, line=ln,
                                 field=name)
        if toks[0] in seen:
            raise InputError(f"camera {toks[0]} given twice (first on line {seen[toks[0]]})", path=path, line=ln,
                             field="CAMERA_ID")
        seen[toks[0]] = ln
        for k, tok in enumerate(toks[4:]):
            try:
                v = float(tok)
            except ValueError:
                v = float("nan")
            if not np.isfinite(v):
                raise InputError(f"parameter {k + 1} must be a finite number, got {quote(tok)}", path=path, line=ln,
                                 field="PARAMS")


def check_values(rec, folder: Path, fmt: str) -> None:
    """What pycolmap read: finite parameters, positive sizes and focal lengths, finite poses and points."""
    ext = ".bin" if fmt == "binary" else ".txt"
    for cid, cam in rec.cameras.items():
        params = np.asarray(cam.params, float)
        if cam.width <= 0 or cam.height <= 0:
            raise InputError(f"camera {cid}: image size {cam.width} × {cam.height} pixels", path=folder / f"cameras{ext}",
                             field="width")
        if not np.isfinite(params).all():
            raise InputError(f"camera {cid}: a parameter is not a finite number", path=folder / f"cameras{ext}",
                             field="params")
        focal = [params[i] for i in cam.focal_length_idxs()]
        if min(focal, default=1.0) <= 0:
            raise InputError(f"camera {cid}: focal length {min(focal):g} px must be positive",
                             path=folder / f"cameras{ext}", field="params")
    for iid, im in rec.images.items():
        if not im.has_pose:
            continue
        m = np.asarray(im.cam_from_world().matrix(), float)
        if not np.isfinite(m).all():
            raise InputError(f"image {iid} ({im.name}): the pose is not finite", path=folder / f"images{ext}",
                             field="pose")
    for pid, p in rec.points3D.items():
        if not np.isfinite(np.asarray(p.xyz, float)).all():
            raise InputError(f"point {pid}: coordinates are not finite", path=folder / f"points3D{ext}", field="xyz")


def _int(tok: str, path: Path, ln: int, field: str, lo: int = 1) -> int:
    try:
        v = int(tok)
    except ValueError:
        raise InputError(f"{field} must be a whole number, got {quote(tok)}", path=path, line=ln, field=field) from None
    if v < lo or v > 2**63 - 1:
        raise InputError(f"{field} must be a whole number ≥ {lo}, got {v}", path=path, line=ln, field=field)
    return v


def _float(tok: str, path: Path, ln: int, field: str) -> float:
    try:
        v = float(tok)
    except ValueError:
        raise InputError(f"{field} must be a number, got {quote(tok)}", path=path, line=ln, field=field) from None
    if not np.isfinite(v):
        raise InputError(f"{field} must be a finite number, got {quote(tok)}", path=path, line=ln, field=field)
    return v


def _camera_ids_text(folder: Path) -> set[int]:
    ids = set()
    for line in read_text_limited(folder / "cameras.txt", what="a COLMAP text file").splitlines():
        toks = line.split()
        if toks and not toks[0].startswith("#") and toks[0].isdigit():
            ids.add(int(toks[0]))
    return ids


def check_images_text(folder: Path) -> dict[int, int]:
    """``images.txt``: per image a line ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` and a line of
    ``X Y POINT3D_ID`` triples; numbers finite, ids whole, the camera in ``cameras.txt``, no image
    twice.  Returns the number of 2-D points per image id.  InputError naming line and field."""
    path = folder / "images.txt"
    cameras = _camera_ids_text(folder)
    lines = read_text_limited(path, what="a COLMAP text file").splitlines()
    n2d: dict[int, int] = {}
    first: dict[int, int] = {}
    names: dict[str, int] = {}
    k = 0
    while k < len(lines):
        ln, line = k + 1, lines[k].strip()
        k += 1
        if not line or line.startswith("#"):
            continue
        toks = line.split(maxsplit=9)
        if len(toks) < 10:
            raise InputError(f"expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME', got {len(toks)} value(s)",
                             path=path, line=ln, field="image")
        iid = _int(toks[0], path, ln, "IMAGE_ID")
        for tok, name in zip(toks[1:8], ("QW", "QX", "QY", "QZ", "TX", "TY", "TZ")):
            _float(tok, path, ln, name)
        q = np.array([float(t) for t in toks[1:5]])
        if not np.linalg.norm(q) > 1e-12:
            raise InputError("the rotation quaternion QW QX QY QZ is zero", path=path, line=ln, field="QW")
        cid = _int(toks[8], path, ln, "CAMERA_ID")
        if cid not in cameras:
            raise InputError(f"camera {cid} is not in cameras.txt", path=path, line=ln, field="CAMERA_ID")
        if iid in first:
            raise InputError(f"image {iid} given twice (first on line {first[iid]})", path=path, line=ln,
                             field="IMAGE_ID")
        name = toks[9].strip()
        if name in names:
            raise InputError(f"image name {quote(name)} given twice (first on line {names[name]})", path=path,
                             line=ln, field="NAME")
        first[iid], names[name] = ln, ln
        pts = lines[k].split() if k < len(lines) else []
        pln = k + 1
        k += 1
        if len(pts) % 3:
            raise InputError(f"the 2-D points line holds {len(pts)} values, not X Y POINT3D_ID triples", path=path,
                             line=pln, field="POINTS2D")
        for j in range(0, len(pts), 3):
            _float(pts[j], path, pln, f"POINTS2D[{j // 3}].X")
            _float(pts[j + 1], path, pln, f"POINTS2D[{j // 3}].Y")
            _int(pts[j + 2], path, pln, f"POINTS2D[{j // 3}].POINT3D_ID", lo=-1)
        n2d[iid] = len(pts) // 3
    return n2d


def check_points_text(folder: Path, n2d: dict[int, int]) -> None:
    """``points3D.txt``: ``POINT3D_ID X Y Z R G B ERROR TRACK[]`` (IMAGE_ID POINT2D_IDX pairs);
    coordinates finite, colours 0–255, every track element an image of ``images.txt`` and one of
    its 2-D points, no point twice.  InputError naming line and field."""
    path = folder / "points3D.txt"
    first: dict[int, int] = {}
    for ln, line in enumerate(read_text_limited(path, what="a COLMAP text file").splitlines(), start=1):
        toks = line.split()
        if not toks or toks[0].startswith("#"):
            continue
        if len(toks) < 8:
            raise InputError(f"expected 'POINT3D_ID X Y Z R G B ERROR TRACK[]', got {len(toks)} value(s)", path=path,
                             line=ln, field="point")
        pid = _int(toks[0], path, ln, "POINT3D_ID")
        if pid in first:
            raise InputError(f"point {pid} given twice (first on line {first[pid]})", path=path, line=ln,
                             field="POINT3D_ID")
        first[pid] = ln
        for tok, name in zip(toks[1:4], "XYZ"):
            _float(tok, path, ln, name)
        for tok, name in zip(toks[4:7], "RGB"):
            v = _int(tok, path, ln, name, lo=0)
            if v > 255:
                raise InputError(f"{name} must be 0–255, got {v}", path=path, line=ln, field=name)
        _float(toks[7], path, ln, "ERROR")
        track = toks[8:]
        if len(track) % 2:
            raise InputError(f"the track holds {len(track)} values, not IMAGE_ID POINT2D_IDX pairs", path=path,
                             line=ln, field="TRACK")
        for j in range(0, len(track), 2):
            iid = _int(track[j], path, ln, f"TRACK[{j // 2}].IMAGE_ID")
            idx = _int(track[j + 1], path, ln, f"TRACK[{j // 2}].POINT2D_IDX", lo=0)
            if iid not in n2d:
                raise InputError(f"the track names image {iid}, which is not in images.txt", path=path, line=ln,
                                 field=f"TRACK[{j // 2}].IMAGE_ID")
            if idx >= n2d[iid]:
                raise InputError(f"the track names 2-D point {idx} of image {iid}, which has {n2d[iid]}", path=path,
                                 line=ln, field=f"TRACK[{j // 2}].POINT2D_IDX")


def check_text(folder: Path) -> None:
    """Every file of a text model (baarda's own reading of COLMAP's text format), before pycolmap."""
    check_cameras_text(folder)
    check_points_text(folder, check_images_text(folder))
