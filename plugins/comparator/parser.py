"""Parse a baarda comparator file (docs/comparator-format.md) into plain records.

This module reads text and checks it; it computes nothing.  Every mistake raises
:class:`baarda.pipeline.errors.InputError` naming the file, the 1-based line and the field.  The
records keep their line numbers so that later checks (interior orientation, screening) can point
at the line a user has to fix.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from baarda.pipeline.api import InputError
from baarda.pipeline.errors import quote
from baarda.pipeline.model import ROLES

from .interior import KINDS

UNITS = {"mm": 1.0, "um": 1e-3, "µm": 1e-3, "μm": 1e-3}
"""Comparator units accepted by the ``unit`` line and their size in mm."""

MODES = ("fiducial", "photo")
MAX_COORD_MM = 1.0e4
"""A measured coordinate (fiducial or point, converted to mm) beyond ±10 m is an input error: no
comparator stage or image is that large."""
OBJECT_UNITS = ("m", "mm")
HEADER_KEYS = ("unit", "mode", "transform", "sigma", "object_unit")
KEYWORDS = HEADER_KEYS + ("camera", "fiducial", "photo", "fid", "pt", "pair", "point")


@dataclass
class Mark:
    """A measured or calibrated 2-D position with the line it came from.

    ``sigma`` is (sx, sy) in the unit of the line's coordinates, or None for the default.
    """

    id: str
    x: float
    y: float
    line: int
    sigma: tuple[float, float] | None = None


@dataclass
class CameraRecord:
    id: str
    line: int
    c: float
    xp: float = 0.0
    yp: float = 0.0
    format_mm: tuple[float, float] = (math.nan, math.nan)
    fiducials: dict[str, Mark] = field(default_factory=dict)


@dataclass
class PhotoRecord:
    id: str
    line: int
    camera: str | None
    fids: dict[str, Mark] = field(default_factory=dict)
    pts: dict[str, Mark] = field(default_factory=dict)


@dataclass
class PointRecord:
    id: str
    role: str
    XYZ: tuple[float, float, float]
    sigma: tuple[float, float, float] | None
    line: int


@dataclass
class PairRecord:
    left: str
    right: str
    line: int


@dataclass
class ComparatorFile:
    """Everything a comparator file declares, in file order, with line numbers.

    ``header`` maps each header keyword to ``(value, line)``; defaults are filled in by
    :func:`parse_comparator` (``unit mm``, ``mode fiducial``, ``transform affine``,
    ``sigma 0.005 mm``, ``object_unit m``).
    """

    path: Path
    unit: str = "mm"
    mode: str = "fiducial"
    transform: str = "affine"
    sigma: tuple[float, float] | None = None
    object_unit: str = "m"
    header_lines: dict[str, int] = field(default_factory=dict)
    cameras: dict[str, CameraRecord] = field(default_factory=dict)
    photos: dict[str, PhotoRecord] = field(default_factory=dict)
    points: dict[str, PointRecord] = field(default_factory=dict)
    pairs: list[PairRecord] = field(default_factory=list)

    @property
    def unit_mm(self) -> float:
        """Size of one comparator unit in mm."""
        return UNITS[self.unit]


class _Reader:
    def __init__(self, path: Path):
        self.path = path
        self.out = ComparatorFile(path=path)
        self.camera: CameraRecord | None = None  # open camera section
        self.photo: PhotoRecord | None = None    # open photo section

    # -- helpers ---------------------------------------------------------------------------
    def error(self, msg: str, line: int | None, fld: str | None = None):
        return InputError(msg, self.path, line, fld)

    def number(self, tok: str, line: int, fld: str) -> float:
        try:
            val = float(tok)
        except ValueError:
            raise self.error(f"expected a number for {fld}, got {quote(tok)}", line, fld) from None
        if not math.isfinite(val):
            raise self.error(f"{fld} must be a finite number, got {quote(tok)}", line, fld)
        return val

    def count(self, toks: list[str], line: int, allowed: tuple[int, ...], usage: str):
        if len(toks) not in allowed:
            raise self.error(f"expected '{usage}', got {len(toks) - 1} value(s)",
                             line, toks[0])

    # -- keywords --------------------------------------------------------------------------
    def header(self, toks, line):
        key = toks[0]
        if key in self.out.header_lines:
            raise self.error(f"'{key}' given twice (first at line {self.out.header_lines[key]})", line, key)
        if key == "sigma":
            self.count(toks, line, (2, 3), "sigma <s> [<sy>]")
            vals = [self.number(t, line, "sigma") for t in toks[1:]]
            if min(vals) <= 0:
                raise self.error(f"sigma must be positive, got {' '.join(toks[1:])}", line, "sigma")
            self.out.sigma = (vals[0], vals[-1])
        else:
            self.count(toks, line, (2,), f"{key} <value>")
            choices = {"unit": tuple(UNITS), "mode": MODES, "transform": tuple(KINDS),
                       "object_unit": OBJECT_UNITS}[key]
            if toks[1] not in choices:
                raise self.error(f"{key} must be one of {', '.join(choices)}, got {quote(toks[1])}", line, key)
            setattr(self.out, key, toks[1])
        self.out.header_lines[key] = line

    def camera_line(self, toks, line):
        if len(toks) < 2:
            raise self.error("expected 'camera <id> c <mm> [format <w> <h>] [xp <mm>] [yp <mm>]'",
                             line, "camera")
        cid = toks[1]
        if cid in self.out.cameras:
            raise self.error(f"camera {quote(cid)} declared twice (first at line {self.out.cameras[cid].line})",
                             line, "camera")
        values: dict[str, tuple] = {}
        i = 2
        sizes = {"c": 1, "xp": 1, "yp": 1, "format": 2}
        while i < len(toks):
            key = toks[i]
            if key not in sizes:
                raise self.error(f"unknown camera field {quote(key)}; expected c, xp, yp, format", line, key)
            if key in values:
                raise self.error(f"camera field {quote(key)} given twice", line, key)
            k = sizes[key]
            if len(toks[i + 1:i + 1 + k]) < k:
                raise self.error(f"camera field {quote(key)} needs {k} number(s)", line, key)
            values[key] = tuple(self.number(t, line, key) for t in toks[i + 1:i + 1 + k])
            i += 1 + k
        if "c" not in values:
            raise self.error(f"camera {quote(cid)} has no principal distance (add 'c <mm>')", line, "c")
        if values["c"][0] <= 0:
            raise self.error(f"principal distance c must be positive, got {values['c'][0]}", line, "c")
        fmt = values.get("format", (math.nan, math.nan))
        if "format" in values and min(fmt) <= 0:
            raise self.error(f"format must be positive, got {fmt[0]} × {fmt[1]}", line, "format")
        cam = CameraRecord(id=cid, line=line, c=values["c"][0], xp=values.get("xp", (0.0,))[0],
                           yp=values.get("yp", (0.0,))[0], format_mm=fmt)
        self.out.cameras[cid] = cam
        self.camera, self.photo = cam, None

    def fiducial_line(self, toks, line):
        if self.camera is None:
            raise self.error("'fiducial' (calibrated fiducial coordinates) must follow a 'camera' line",
                             line, "fiducial")
        self.count(toks, line, (4,), "fiducial <id> <x_mm> <y_mm>")
        fid = toks[1]
        if fid in self.camera.fiducials:
            raise self.error(f"fiducial {quote(fid)} of camera {quote(self.camera.id)} given twice "
                             f"(first at line {self.camera.fiducials[fid].line})", line, "fiducial")
        self.camera.fiducials[fid] = Mark(fid, self.number(toks[2], line, "x"),
                                          self.number(toks[3], line, "y"), line)

    def photo_line(self, toks, line):
        if len(toks) not in (2, 4) or (len(toks) == 4 and toks[2] != "camera"):
            raise self.error("expected 'photo <id> [camera <camera id>]'", line, "photo")
        pid = toks[1]
        if pid in self.out.photos:
            raise self.error(f"photo {quote(pid)} declared twice (first at line {self.out.photos[pid].line})",
                             line, "photo")
        rec = PhotoRecord(id=pid, line=line, camera=toks[3] if len(toks) == 4 else None)
        self.out.photos[pid] = rec
        self.photo, self.camera = rec, None

    def mark_line(self, toks, line):
        key = toks[0]
        if self.photo is None:
            raise self.error(f"'{key}' must be inside a photo section (after a 'photo' line)", line, key)
        if key == "fid":
            self.count(toks, line, (4,), "fid <id> <X> <Y>")
            table, what = self.photo.fids, "fiducial"
        else:
            self.count(toks, line, (4, 6), "pt <id> <x> <y> [<sx> <sy>]")
            table, what = self.photo.pts, "point"
        mid = toks[1]
        if mid in table:
            raise self.error(f"{what} {quote(mid)} measured twice in photo {quote(self.photo.id)} "
                             f"(first at line {table[mid].line})", line, key)
        x = self.number(toks[2], line, "x")
        y = self.number(toks[3], line, "y")
        sigma = None
        if len(toks) == 6:
            sigma = (self.number(toks[4], line, "sx"), self.number(toks[5], line, "sy"))
            if min(sigma) <= 0:
                raise self.error(f"sx, sy must be positive, got {toks[4]} {toks[5]}", line, "sx")
        table[mid] = Mark(mid, x, y, line, sigma)

    def pair_line(self, toks, line):
        self.count(toks, line, (3,), "pair <left photo> <right photo>")
        if toks[1] == toks[2]:
            raise self.error(f"pair names photo {quote(toks[1])} twice", line, "pair")
        for p in self.out.pairs:
            if (p.left, p.right) == (toks[1], toks[2]):
                raise self.error(f"pair {toks[1]} {toks[2]} declared twice (first at line {p.line})", line, "pair")
        self.out.pairs.append(PairRecord(toks[1], toks[2], line))
        self.camera = self.photo = None

    def point_line(self, toks, line):
        if len(toks) not in (3, 6, 9):
            raise self.error("expected 'point <id> <role> [<X> <Y> <Z> [<sX> <sY> <sZ>]]'", line, "point")
        pid, role = toks[1], toks[2]
        if pid in self.out.points:
            raise self.error(f"object point {quote(pid)} declared twice (first at line {self.out.points[pid].line})",
                             line, "point")
        if role not in ROLES:
            raise self.error(f"role must be one of {', '.join(ROLES)}, got {quote(role)}", line, "role")
        if len(toks) == 3:
            if role != "tie":
                raise self.error(f"a {quote(role)} point needs coordinates X Y Z", line, "XYZ")
            xyz = (math.nan,) * 3
        else:
            xyz = tuple(self.number(t, line, f) for t, f in zip(toks[3:6], "XYZ"))
        sig = None
        if len(toks) == 9:
            sig = tuple(self.number(t, line, f) for t, f in zip(toks[6:9], ("sX", "sY", "sZ")))
            if min(sig) < 0:
                raise self.error("a-priori sigmas must not be negative", line, "sX")
        self.out.points[pid] = PointRecord(pid, role, xyz, sig, line)
        self.camera = self.photo = None

    # -- driver ----------------------------------------------------------------------------
    def feed(self, text: str) -> ComparatorFile:
        handlers = {"camera": self.camera_line, "fiducial": self.fiducial_line, "photo": self.photo_line,
                    "fid": self.mark_line, "pt": self.mark_line, "pair": self.pair_line,
                    "point": self.point_line}
        for key in HEADER_KEYS:
            handlers[key] = self.header
        for i, raw in enumerate(text.splitlines(), start=1):
            toks = raw.split("#", 1)[0].split()
            if not toks:
                continue
            handler = handlers.get(toks[0])
            if handler is None:
                raise self.error(f"unknown keyword {quote(toks[0])}; expected one of {', '.join(KEYWORDS)}",
                                 i, "keyword")
            handler(toks, i)
        self.check()
        return self.out

    def check(self):
        out = self.out
        if not out.photos:
            raise self.error("no 'photo' section in the file", None, "photo")
        if out.mode == "fiducial" and not out.cameras:
            raise self.error("mode fiducial needs a 'camera' line with its calibrated fiducials "
                             "(or write 'mode photo' for coordinates already in mm)",
                             out.header_lines.get("mode"), "camera")
        for ph in out.photos.values():
            if ph.camera is None:
                if len(out.cameras) > 1:
                    raise self.error(f"photo {quote(ph.id)} does not name its camera and the file declares "
                                     f"{len(out.cameras)} cameras ({', '.join(out.cameras)})", ph.line, "camera")
            elif ph.camera not in out.cameras:
                known = ", ".join(out.cameras) or "(none)"
                raise self.error(f"photo {quote(ph.id)} names camera {quote(ph.camera)}, which is not declared "
                                 f"(cameras: {known})", ph.line, "camera")
            if out.mode == "photo" and ph.fids:
                first = min(m.line for m in ph.fids.values())
                raise self.error("'fid' lines need 'mode fiducial'; this file is in mode photo",
                                 first, "fid")
            if out.mode == "fiducial":
                cam = out.cameras[ph.camera] if ph.camera else next(iter(out.cameras.values()))
                for m in ph.fids.values():
                    if m.id not in cam.fiducials:
                        known = ", ".join(cam.fiducials) or "(none)"
                        raise self.error(f"fiducial {quote(m.id)} of photo {quote(ph.id)} is not calibrated for "
                                         f"camera {quote(cam.id)} (calibrated: {known})", m.line, "fid")
            for m in (*ph.fids.values(), *ph.pts.values()):
                for fld, val in (("x", m.x), ("y", m.y)):
                    if abs(val) * out.unit_mm > MAX_COORD_MM:
                        raise self.error(f"{fld} = {val:g} {out.unit} of {quote(m.id)} in photo {quote(ph.id)} lies "
                                         f"beyond {MAX_COORD_MM:g} mm from the origin: no comparator or image reaches "
                                         "that far (a unit or decimal-point mistake?)", m.line, fld)
        for p in out.pairs:
            for side, pid in (("left", p.left), ("right", p.right)):
                if pid not in out.photos:
                    raise self.error(f"pair {p.left} {p.right}: {side} photo {quote(pid)} is not in this file "
                                     f"(photos: {', '.join(out.photos)})", p.line, "pair")


def parse_comparator(path: str | Path) -> ComparatorFile:
    """Read and check a comparator file; raise :class:`InputError` on the first mistake."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError("comparator file not found", path, None, "path") from None
    except IsADirectoryError:
        raise InputError("expected a comparator file, got a directory", path, None, "path") from None
    except UnicodeDecodeError as e:
        line = e.object[:e.start].count(b"\n") + 1
        raise InputError("not a UTF-8 text file", path, line, None) from None
    except OSError as e:
        raise InputError(f"cannot read the comparator file: {e.strerror}", path, None, "path") from None
    return _Reader(path).feed(text)


def parse_comparator_text(text: str, path: str | Path = "<text>") -> ComparatorFile:
    """Parse text already in memory (tests, notebooks); ``path`` is used in messages."""
    return _Reader(Path(path)).feed(text)
