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

from baarda.pipeline.errors import InputError

# parameters per COLMAP camera model id (colmap/src/colmap/sensor/models.h)
MODEL_PARAMS = {0: 3, 1: 4, 2: 4, 3: 5, 4: 8, 5: 8, 6: 12, 7: 5, 8: 4, 9: 5, 10: 12, 11: 4}


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
               "RADIAL_FISHEYE": 5, "THIN_PRISM_FISHEYE": 12, "RAD_TAN_THIN_PRISM_FISHEYE": 16}


def check_cameras_text(folder: Path) -> None:
    """``cameras.txt``: ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`` per line, numbers finite, sizes
    and focal length positive; InputError naming the line and the column."""
    from baarda.pipeline.errors import quote

    path = folder / "cameras.txt"
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError("not a UTF-8 text file", path=path) from None
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
