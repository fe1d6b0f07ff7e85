"""ODM/OpenSfM ``gcp_list.txt``: the CRS line and the pixel measurements of ground-control targets.

An engine module because two plugins read the format: the ``gcp-list`` source (a known camera,
photos resected from the targets) and the ``opensfm`` source (the targets added to a
reconstruction, option ``gcp``).  Pure parsing: text in, records out; every malformed line raises
:class:`~baarda.pipeline.errors.InputError` naming the file, the 1-based line and the field.
Format: ``docs/crs.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baarda.pipeline.errors import InputError, finite_number as _num, read_text_limited

__all__ = ["GCP_FIELDS", "GcpList", "read_gcp_list", "read_text"]

GCP_FIELDS = ("geo_x", "geo_y", "geo_z", "im_x", "im_y", "image_name", "gcp_name")


def read_text(path: Path, what: str) -> str:
    """The file as UTF-8 text (a BOM allowed), read with a size limit; bytes that are not UTF-8
    are an InputError naming the line (they used to be replaced silently)."""
    if not Path(path).exists():
        raise InputError(f"{what} not found", path=path)
    if Path(path).is_dir():
        raise InputError(f"{what} is a directory, expected a file", path=path)
    return read_text_limited(path, what=what, encoding="utf-8-sig")




@dataclass(frozen=True)
class GcpList:
    """A parsed ``gcp_list.txt``: the CRS line and one row per image measurement.

    ``geo (k, 3)`` object coordinates in the CRS; ``pixel (k, 2)`` column, row (origin at the
    centre of the top-left pixel, y down: ODM's convention); ``image``, ``name`` (k,) str (the
    name is ``geo_x,geo_y,geo_z`` as written when the line has none); ``line (k,)``.
    """

    path: Path
    crs: str
    crs_line: int
    geo: np.ndarray
    pixel: np.ndarray
    image: list
    name: list
    line: np.ndarray


def read_gcp_list(path: str | Path, skip_lines=()) -> GcpList:
    """Read an ODM/OpenSfM ground-control list.

    First non-blank line: the CRS (``EPSG:32722``, a PROJ string, ``WGS84 UTM 22S``); then one
    line per measurement ``geo_x geo_y geo_z im_x im_y image_name [gcp_name] [extra …]`` (blank
    lines and lines starting with ``#`` ignored).  The same target must have the same coordinates
    on every line, and may be measured once per image.  ``skip_lines`` are 1-based line numbers of
    measurements to leave out (a known mistake in a file one cannot edit).
    """
    path = Path(path)
    text = read_text(path, "GCP list")
    crs, crs_line = None, 0
    geo, pix, img, name, lines = [], [], [], [], []
    first_coords: dict[str, tuple[tuple[float, ...], int]] = {}
    seen: dict[tuple[str, str], int] = {}
    skip, skipped = set(int(v) for v in skip_lines), []
    for i, raw in enumerate(text.splitlines(), start=1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        if crs is None:
            crs, crs_line = s, i
            toks = s.split()
            if len(toks) >= 6 and all(_isnum(t) for t in toks[:5]):
                raise InputError("the first line must name the coordinate reference system (e.g. EPSG:32722 or "
                                 "+proj=utm …), got a measurement line", path=path, line=i, field="crs")
            continue
        if i in skip:
            skipped.append(i)
            continue
        t = s.split()
        if len(t) < 6:
            raise InputError(f"expected at least 6 fields ({' '.join(GCP_FIELDS[:6])} [gcp_name]), got {len(t)}",
                             path=path, line=i, field=GCP_FIELDS[min(len(t), 5)])
        xyz = tuple(_num(t[k], path, i, GCP_FIELDS[k]) for k in range(3))
        uv = tuple(_num(t[k], path, i, GCP_FIELDS[k]) for k in (3, 4))
        image = t[5]
        gname = t[6] if len(t) > 6 else ",".join(t[:3])
        if gname in first_coords:
            c0, l0 = first_coords[gname]
            if max(abs(a - b) for a, b in zip(c0, xyz)) > 1e-9 * max(1.0, max(abs(v) for v in xyz)):
                raise InputError(f"target {gname!r} has other coordinates than on line {l0} "
                                 f"({' '.join(f'{v:.12g}' for v in c0)})", path=path, line=i, field="geo_x")
        else:
            first_coords[gname] = (xyz, i)
        if (gname, image) in seen:
            raise InputError(f"target {gname!r} measured twice in image {image!r} (first on line "
                             f"{seen[(gname, image)]})", path=path, line=i, field="image_name")
        seen[(gname, image)] = i
        geo.append(xyz)
        pix.append(uv)
        img.append(image)
        name.append(gname)
        lines.append(i)
    if crs is None:
        raise InputError("empty GCP list: expected the CRS on the first line, then measurements", path=path)
    if not geo:
        raise InputError("no measurement lines after the CRS line", path=path, line=crs_line, field="geo_x")
    if set(skip) - set(skipped):
        ln = min(set(skip) - set(skipped))
        raise InputError(f"skip_lines: line {ln} is not a measurement line of the file", path=path, line=ln,
                         field="skip_lines")
    return GcpList(path=path, crs=crs, crs_line=crs_line, geo=np.array(geo, float), pixel=np.array(pix, float),
                   image=img, name=name, line=np.array(lines, int))


def _isnum(tok: str) -> bool:
    try:
        float(tok)
        return True
    except ValueError:
        return False
