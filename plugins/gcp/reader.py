"""Readers: ODM/OpenSfM ``gcp_list.txt``, OpenSfM ``cameras.json``, GNSS projection-centre CSV.

Pure parsing: text in, records out; every malformed line raises
:class:`~baarda.pipeline.errors.InputError` naming the file, the 1-based line and the field.
Formats: ``docs/crs.md``.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baarda.pipeline.api import InputError
from baarda.pipeline.errors import quote
from baarda.pipeline.errors import finite_number as _num
from baarda.pipeline.gcplist import GCP_FIELDS, GcpList, read_gcp_list  # noqa: F401  (the format is shared with the opensfm source)
from baarda.pipeline.gcplist import read_text as _text


# --------------------------------------------------------------------------------------------
# OpenSfM / ODM cameras.json


@dataclass(frozen=True)
class SfmCamera:
    """One camera of an OpenSfM ``cameras.json`` in pixels: focal lengths, principal point
    (relative to the image centre, y down), radial k1 k2 of normalised coordinates."""

    id: str
    projection: str
    width: int
    height: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    k1: float
    k2: float


def read_cameras_json(path: str | Path) -> list[SfmCamera]:
    """OpenSfM's ``cameras.json``: ``{id: {projection_type, width, height, focal | focal_x focal_y,
    c_x c_y, k1 k2 …}}``; focal lengths and c_x, c_y are normalised by max(width, height).
    ``perspective`` and ``brown`` (with p1 = p2 = k3 = 0, which baarda's model does not need)
    cameras are accepted; a fisheye or spherical camera is an error."""
    path = Path(path)
    text = _text(path, "cameras.json")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(f"not valid JSON: {e.msg}", path=path, line=e.lineno, field="json") from None
    if not isinstance(data, dict) or not data:
        raise InputError("expected an object {camera id: {...}}", path=path, line=1, field="cameras")
    lines = text.splitlines()

    def line_of(key):
        return next((k + 1 for k, s in enumerate(lines) if f'"{key}"' in s), None)

    out = []
    for cid, c in data.items():
        ln = line_of(cid)
        if not isinstance(c, dict):
            raise InputError("expected an object", path=path, line=ln, field=cid)
        proj = c.get("projection_type", "perspective")
        if proj not in ("perspective", "brown"):
            raise InputError(f"projection_type {proj!r} is not supported (perspective or brown)", path=path,
                             line=ln, field="projection_type")

        def num(key, default=None, _c=c, _cid=cid):
            if key not in _c:
                if default is None:
                    raise InputError(f"camera {_cid!r} has no {key!r}", path=path, line=ln, field=key)
                return default
            v = _c[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise InputError(f"expected a number, got {quote(str(v))}", path=path, line=ln, field=key)
            return float(v)

        w, h = num("width"), num("height")
        if w <= 0 or h <= 0 or w != int(w) or h != int(h):
            raise InputError(f"width and height must be positive integers, got {w:g} × {h:g}", path=path, line=ln,
                             field="width")
        for key in ("p1", "p2", "k3"):
            if num(key, 0.0) != 0.0:
                raise InputError(f"{key} = {c[key]} is not supported (baarda maps k1, k2 only; use the bundle's "
                                 "brown model to estimate the rest)", path=path, line=ln, field=key)
        size = max(w, h)
        if proj == "perspective":
            fx = fy = num("focal") * size
            cx = cy = 0.0
        else:
            fx, fy = num("focal_x") * size, num("focal_y") * size
            cx, cy = num("c_x", 0.0) * size, num("c_y", 0.0) * size
        if fx <= 0 or fy <= 0:
            raise InputError("focal length must be positive", path=path, line=ln, field="focal")
        out.append(SfmCamera(str(cid), proj, int(w), int(h), fx, fy, cx, cy, num("k1", 0.0), num("k2", 0.0)))
    return out


# --------------------------------------------------------------------------------------------
# GNSS projection centres


@dataclass(frozen=True)
class GnssCentres:
    """GNSS antenna positions per photo: ``xyz (m, 3)`` in ``crs`` (None: the block's CRS),
    ``sigma (m, 3)`` (nan: the stage's default), ``photo`` ids, ``line`` numbers."""

    path: Path
    crs: str | None
    photo: list
    xyz: np.ndarray
    sigma: np.ndarray
    line: np.ndarray
    columns: tuple
    crs_line: int | None = None


_COORDS = (("e", "n", "h"), ("x", "y", "z"), ("lon", "lat", "h"), ("easting", "northing", "height"))


def read_gnss_csv(path: str | Path) -> GnssCentres:
    """A CSV of GNSS projection centres (``docs/crs.md``): optional ``# crs: EPSG:…`` comment
    lines, then a header with ``photo`` and one coordinate triple (``E,N,h``, ``x,y,z``,
    ``lon,lat,h``; case-insensitive) and optionally ``sigma`` (all three), ``sigma_h,sigma_v``
    (horizontal, vertical) or ``sx,sy,sz`` (metres)."""
    path = Path(path)
    text = _text(path, "GNSS file")
    crs, crs_line = None, None
    body = []
    for i, raw in enumerate(text.splitlines(), start=1):
        s = raw.strip()
        if s.startswith("#"):
            key, _, val = s[1:].partition(":")
            if key.strip().lower() == "crs" and val.strip():
                crs, crs_line = val.strip(), i
            continue
        if s:
            body.append((i, raw))
    if not body:
        raise InputError("no header line (photo,E,N,h[,sigma…])", path=path)
    hline, header = body[0]
    delim = ";" if header.count(";") > header.count(",") else ","
    names = [h.strip().lower() for h in next(csv.reader(io.StringIO(header), delimiter=delim))]
    if "photo" not in names:
        raise InputError(f"the header has no column 'photo' (columns: {', '.join(names)})", path=path, line=hline,
                         field="photo")
    triple = next((t for t in _COORDS if all(n in names for n in t)), None)
    if triple is None:
        raise InputError("the header needs one coordinate triple: E,N,h or x,y,z or lon,lat,h", path=path,
                         line=hline, field="header")
    if triple == ("lon", "lat", "h") and crs is None:
        crs = "EPSG:4979"
    sig_cols = None
    if all(n in names for n in ("sx", "sy", "sz")):
        sig_cols = ("sx", "sy", "sz")
    elif all(n in names for n in ("sigma_h", "sigma_v")):
        sig_cols = ("sigma_h", "sigma_h", "sigma_v")
    elif "sigma" in names:
        sig_cols = ("sigma",) * 3
    idx = {n: names.index(n) for n in names}
    photo, xyz, sigma, lines = [], [], [], []
    seen = {}
    for ln, raw in body[1:]:
        row = [v.strip() for v in next(csv.reader(io.StringIO(raw), delimiter=delim))]
        if len(row) < len(names):
            missing = names[len(row)]
            raise InputError(f"expected {len(names)} fields, got {len(row)}", path=path, line=ln, field=missing)
        if len(row) > len(names) and any(row[len(names):]):
            raise InputError(f"expected {len(names)} fields (the header's), got {len(row)}: an extra field",
                             path=path, line=ln, field=f"field {len(names) + 1}")
        pid = row[idx["photo"]]
        if not pid:
            raise InputError("empty photo id", path=path, line=ln, field="photo")
        if pid in seen:
            raise InputError(f"photo {pid!r} given twice (first on line {seen[pid]})", path=path, line=ln,
                             field="photo")
        seen[pid] = ln
        xyz.append([_num(row[idx[n]], path, ln, n) for n in triple])
        if sig_cols:
            s = [_num(row[idx[n]], path, ln, n) for n in sig_cols]
            for n, v in zip(sig_cols, s):
                if not v > 0:
                    raise InputError(f"sigma must be positive, got {v:g}", path=path, line=ln, field=n)
            sigma.append(s)
        else:
            sigma.append([np.nan] * 3)
        photo.append(pid)
        lines.append(ln)
    if not photo:
        raise InputError("no data line after the header", path=path, line=hline, field="photo")
    return GnssCentres(path=path, crs=crs, photo=photo, xyz=np.array(xyz, float), sigma=np.array(sigma, float),
                       line=np.array(lines, int), columns=triple, crs_line=crs_line)
