"""The photogrammetric data model: arrays with index arrays, never object graphs.

A :class:`Block` holds five tables — cameras, photos, object points, image observations and
stereo pairs — and, optionally, GNSS antenna observations of the photos (:class:`Gnss`), each a frozen dataclass of equally long numpy arrays.  Arrays are made read-only
when a table is built, so a stage cannot modify its input by accident; a stage that changes
something builds a new table with :meth:`Table.replace` (or :func:`dataclasses.replace`).

Units and signs follow ``docs/conventions.md``: image coordinates in mm, object coordinates in
the block's ``object_unit``, angles in radians, ``R_cam_from_world = R3(κ) R2(φ) R1(ω)``.

A-priori standard deviations use three kinds of value: a positive number (observed with that
sigma: a weighted constraint), ``0`` (fixed, not estimated) and ``inf`` (free, unknown).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, ClassVar, Iterator, Mapping

import numpy as np

ROLES = ("full", "xy", "z", "check", "tie")
"""Object-point roles: full XYZ control, planimetric control, height control, check, tie."""

FREE = np.inf
FIXED = 0.0


def _frozen(a, dtype=None) -> np.ndarray:
    arr = np.array(a, dtype=dtype, copy=True)
    arr.flags.writeable = False
    return arr


class Table:
    """Common behaviour of the column tables: validation, length, ``replace`` and selection."""

    _columns: ClassVar[dict[str, tuple[Any, tuple[int, ...]]]] = {}

    def __post_init__(self):
        n = None
        for name, (dtype, tail) in self._columns.items():
            arr = _frozen(getattr(self, name), dtype)
            if arr.ndim == 0 or arr.shape[1:] != tail:
                if arr.size == 0:
                    arr = _frozen(np.zeros((0,) + tail), dtype)
                else:
                    raise ValueError(
                        f"{type(self).__name__}.{name}: expected shape (n, {', '.join(map(str, tail))}) "
                        f"got {arr.shape}".replace(", )", ")"))
            object.__setattr__(self, name, arr)
            if n is None:
                n = arr.shape[0]
            elif arr.shape[0] != n:
                raise ValueError(f"{type(self).__name__}.{name}: length {arr.shape[0]} != {n}")

    def __len__(self) -> int:
        first = next(iter(self._columns))
        return int(getattr(self, first).shape[0])

    def replace(self, **changes):
        """A copy with some columns replaced (validated and frozen again)."""
        return dataclasses.replace(self, **changes)

    def take(self, index) -> "Table":
        """Rows ``index`` (bool mask or integer array) as a new table of the same kind."""
        return dataclasses.replace(self, **{k: getattr(self, k)[index] for k in self._columns})

    def index_of(self, ids) -> np.ndarray:
        """Row indices of the given ids (``KeyError`` naming the first unknown id)."""
        lookup = {v: i for i, v in enumerate(self.ids)}
        out = []
        for v in np.atleast_1d(ids):
            try:
                out.append(lookup[str(v)])
            except KeyError:
                raise KeyError(f"unknown id {v!r} in {type(self).__name__}") from None
        return np.array(out, dtype=int)


@dataclass(frozen=True, eq=False)
class Cameras(Table):
    """Interior orientation and additional-parameter model of each camera.

    ids (k,) str; c, xp, yp (k,) mm; ap_model (k,) name of a registered AP model (``"none"``,
    ``"ebner12"``, ``"brown"``, ``"aicon"``); ap (k, p) parameter values, ``p`` the largest
    parameter count in use (unused columns 0); sigma_iop (k, 3) a-priori sigmas of c, xp, yp;
    sigma_ap (k, p); format_mm (k, 2) width and height of the format; pixel_mm (k,) pixel
    pitch for digital cameras (nan for film); resolution (k, 2) pixels (0 for film).
    """

    ids: np.ndarray
    c: np.ndarray
    xp: np.ndarray
    yp: np.ndarray
    ap_model: np.ndarray
    ap: np.ndarray
    sigma_iop: np.ndarray
    sigma_ap: np.ndarray
    format_mm: np.ndarray
    pixel_mm: np.ndarray
    resolution: np.ndarray

    _columns: ClassVar = {
        "ids": (str, ()), "c": (float, ()), "xp": (float, ()), "yp": (float, ()),
        "ap_model": (str, ()), "sigma_iop": (float, (3,)),
        "format_mm": (float, (2,)), "pixel_mm": (float, ()), "resolution": (int, (2,)),
    }

    def __post_init__(self):
        super().__post_init__()
        n = len(self.ids)
        for name in ("ap", "sigma_ap"):
            arr = np.array(getattr(self, name), dtype=float)
            if arr.size == 0:
                arr = np.zeros((n, 0))
            if arr.ndim != 2 or arr.shape[0] != n:
                raise ValueError(f"Cameras.{name}: expected shape ({n}, p), got {arr.shape}")
            object.__setattr__(self, name, _frozen(arr))
        if self.sigma_ap.shape != self.ap.shape:
            raise ValueError("Cameras.sigma_ap must have the shape of Cameras.ap")

    def take(self, index):
        # every column in one replace: the table is validated once, with ap and sigma_ap cut too
        cols = {k: getattr(self, k)[index] for k in self._columns}
        return dataclasses.replace(self, **cols, ap=self.ap[index], sigma_ap=self.sigma_ap[index])

    @classmethod
    def make(cls, ids, c, xp=None, yp=None, *, ap_model=None, ap=None, sigma_iop=None,
             sigma_ap=None, format_mm=None, pixel_mm=None, resolution=None) -> "Cameras":
        """Build with defaults: no APs, IOP fixed (sigma 0), format unknown (nan)."""
        ids = [str(i) for i in np.atleast_1d(ids)]
        k = len(ids)
        full = lambda v, d, shape=(): np.broadcast_to(np.asarray(d if v is None else v, float), (k,) + shape)
        return cls(
            ids=np.array(ids, dtype=str),
            c=full(c, 0.0), xp=full(xp, 0.0), yp=full(yp, 0.0),
            ap_model=np.array(["none"] * k if ap_model is None
                              else np.broadcast_to(np.asarray(ap_model, dtype=object), (k,)), dtype=str),
            ap=np.zeros((k, 0)) if ap is None else np.atleast_2d(ap),
            sigma_iop=full(sigma_iop, FIXED, (3,)),
            sigma_ap=(np.zeros((k, 0)) if ap is None else np.zeros_like(np.atleast_2d(ap)))
            if sigma_ap is None else np.atleast_2d(sigma_ap),
            format_mm=full(format_mm, np.nan, (2,)), pixel_mm=full(pixel_mm, np.nan),
            resolution=np.broadcast_to(np.asarray(0 if resolution is None else resolution, int), (k, 2)),
        )


@dataclass(frozen=True, eq=False)
class Photos(Table):
    """Exterior orientation of each photo.

    ids (m,) str; camera (m,) index into :class:`Cameras`; X0 (m, 3) projection centre (nan when
    unknown); opk (m, 3) ω, φ, κ radians (nan when unknown); sigma_eo (m, 6) a-priori sigmas of
    X0, Y0, Z0, ω, φ, κ (``inf`` free, ``0`` fixed, else a weighted constraint); image_path (m,)
    the image file of the photo as the source found it (``""`` when unknown or not found), for
    figures drawn over the photo.
    """

    ids: np.ndarray
    camera: np.ndarray
    X0: np.ndarray
    opk: np.ndarray
    sigma_eo: np.ndarray
    image_path: np.ndarray = None  # type: ignore[assignment]   # None: "" for every photo

    _columns: ClassVar = {
        "ids": (str, ()), "camera": (int, ()), "X0": (float, (3,)), "opk": (float, (3,)),
        "sigma_eo": (float, (6,)), "image_path": (str, ()),
    }

    def __post_init__(self):
        paths = self.image_path
        if paths is None:
            paths = [""] * len(np.atleast_1d(self.ids))
        paths = np.array(["" if p is None else str(p) for p in np.asarray(paths, dtype=object).reshape(-1)],
                         dtype=str)
        object.__setattr__(self, "image_path", paths)
        super().__post_init__()

    @classmethod
    def make(cls, ids, camera=0, X0=None, opk=None, sigma_eo=None, image_path=None) -> "Photos":
        ids = [str(i) for i in np.atleast_1d(ids)]
        m = len(ids)
        return cls(
            ids=np.array(ids, dtype=str),
            camera=np.broadcast_to(np.asarray(camera, int), (m,)),
            X0=np.broadcast_to(np.asarray(np.nan if X0 is None else X0, float), (m, 3)),
            opk=np.broadcast_to(np.asarray(np.nan if opk is None else opk, float), (m, 3)),
            sigma_eo=np.broadcast_to(np.asarray(FREE if sigma_eo is None else sigma_eo, float), (m, 6)),
            image_path=image_path,
        )

    def images(self) -> dict[str, str]:
        """Photo id → image file, for the photos whose file is known."""
        return {str(i): str(p) for i, p in zip(self.ids.tolist(), self.image_path.tolist()) if p}

    @property
    def has_orientation(self) -> np.ndarray:
        """(m,) bool: both X0 and ω φ κ are known."""
        return np.isfinite(self.X0).all(axis=1) & np.isfinite(self.opk).all(axis=1)


@dataclass(frozen=True, eq=False)
class Points(Table):
    """Object points.

    ids (n,) str; XYZ (n, 3) coordinates (surveyed for control/check, approximate or nan for tie);
    role (n,) one of :data:`ROLES`; sigma (n, 3) a-priori sigmas of X, Y, Z as they enter the
    adjustment (``0`` fixed control, positive weighted control, ``inf`` unknown).
    """

    ids: np.ndarray
    XYZ: np.ndarray
    role: np.ndarray
    sigma: np.ndarray

    _columns: ClassVar = {
        "ids": (str, ()), "XYZ": (float, (3,)), "role": (str, ()), "sigma": (float, (3,)),
    }

    def __post_init__(self):
        super().__post_init__()
        bad = sorted(set(self.role.tolist()) - set(ROLES))
        if bad:
            raise ValueError(f"Points.role: unknown role(s) {bad}; expected one of {ROLES}")

    @classmethod
    def make(cls, ids, XYZ=None, role="tie", sigma=None) -> "Points":
        ids = [str(i) for i in np.atleast_1d(ids)]
        n = len(ids)
        role_arr = np.array(np.broadcast_to(np.asarray(role, dtype=object), (n,)), dtype=str)
        if sigma is None:
            sigma = np.full((n, 3), FREE)
            sigma[role_arr == "full"] = FIXED
            sigma[role_arr == "xy", :2] = FIXED
            sigma[role_arr == "z", 2] = FIXED
        return cls(ids=np.array(ids, dtype=str),
                   XYZ=np.broadcast_to(np.asarray(np.nan if XYZ is None else XYZ, float), (n, 3)),
                   role=role_arr, sigma=np.broadcast_to(np.asarray(sigma, float), (n, 3)))


@dataclass(frozen=True, eq=False)
class Observations(Table):
    """Image observations: one row per measured point in a photo.

    photo (k,) index into photos; point (k,) index into points; xy (k, 2) image coordinates mm;
    cov (k, 2, 2) a-priori covariance mm² (x, y may be correlated); active (k,) bool — inactive
    rows are kept (so decisions are reported) but not used.
    """

    photo: np.ndarray
    point: np.ndarray
    xy: np.ndarray
    cov: np.ndarray
    active: np.ndarray

    _columns: ClassVar = {
        "photo": (int, ()), "point": (int, ()), "xy": (float, (2,)), "cov": (float, (2, 2)),
        "active": (bool, ()),
    }

    @classmethod
    def make(cls, photo, point, xy, sigma=None, cov=None, active=True) -> "Observations":
        """Build from indices and coordinates; ``sigma`` (scalar or (k,) or (k, 2)) gives a diagonal cov."""
        photo = np.asarray(photo, int).reshape(-1)
        k = photo.shape[0]
        if cov is None:
            s = np.broadcast_to(np.asarray(1.0 if sigma is None else sigma, float), (k,) if np.ndim(sigma) <= 1 else (k, 2))
            s2 = np.column_stack([s, s]) if s.ndim == 1 else s
            cov = np.zeros((k, 2, 2))
            cov[:, 0, 0] = s2[:, 0] ** 2
            cov[:, 1, 1] = s2[:, 1] ** 2
        return cls(photo=photo, point=np.asarray(point, int).reshape(-1),
                   xy=np.asarray(xy, float).reshape(-1, 2), cov=cov,
                   active=np.broadcast_to(np.asarray(active, bool), (k,)))


@dataclass(frozen=True, eq=False)
class Pairs(Table):
    """Stereo pairs: left and right photo indices."""

    left: np.ndarray
    right: np.ndarray

    _columns: ClassVar = {"left": (int, ()), "right": (int, ())}


@dataclass(frozen=True, eq=False)
class Gnss(Table):
    """GNSS antenna observations: one row per photo with an observed antenna position.

    photo (g,) index into photos (each photo at most once); XYZ (g, 3) the antenna position in the
    object system and unit (the block's local Cartesian frame); cov (g, 3, 3) its a-priori covariance
    (object unit², may be full); lever_arm (g, 3) the antenna in the **camera frame** of the photo's
    camera (x right, y up, z back out of the lens; object unit; ``docs/conventions.md``).  The
    bundle adjusts the observation equation ``XYZ + v = X0 + R_cam_from_worldᵀ · lever_arm``
    (``docs/bundle.md``).  The lever arm is a camera's, repeated on its photos' rows (:meth:`make`
    takes it per camera).
    """

    photo: np.ndarray
    XYZ: np.ndarray
    cov: np.ndarray
    lever_arm: np.ndarray

    _columns: ClassVar = {"photo": (int, ()), "XYZ": (float, (3,)), "cov": (float, (3, 3)),
                          "lever_arm": (float, (3,))}

    @classmethod
    def make(cls, photo, XYZ, sigma=None, cov=None, lever_arm=None) -> "Gnss":
        """From photo indices, antenna positions and ``sigma`` (scalar, (g,) or (g, 3); a diagonal
        covariance) or ``cov`` (g, 3, 3); ``lever_arm`` (3,) for every row or (g, 3)."""
        photo = np.asarray(photo, int).reshape(-1)
        g = photo.shape[0]
        if cov is None:
            s = np.asarray(1.0 if sigma is None else sigma, float)
            s = np.broadcast_to(s[:, None] if s.ndim == 1 else s, (g, 3))
            cov = np.zeros((g, 3, 3))
            cov[:, [0, 1, 2], [0, 1, 2]] = s ** 2
        arm = np.broadcast_to(np.asarray(0.0 if lever_arm is None else lever_arm, float), (g, 3))
        return cls(photo=photo, XYZ=np.asarray(XYZ, float).reshape(-1, 3), cov=cov, lever_arm=arm)

    @classmethod
    def empty(cls) -> "Gnss":
        return cls.make(np.zeros(0, int), np.zeros((0, 3)))

    @property
    def sigma(self) -> np.ndarray:
        """(g, 3) standard deviations (the covariance's diagonal)."""
        return np.sqrt(np.einsum("gii->gi", self.cov))


@dataclass(frozen=True, eq=False)
class ScaleBars(Table):
    """Scale bars (measured distances between two object points): one row per bar.

    a, b (s,) point ids of the ends; distance (s,) in the block's object unit; sigma (s,) its
    a-priori standard deviation (same unit).  The bundle adjusts them as observations of the
    distance (``docs/bundle.md``)."""

    a: np.ndarray
    b: np.ndarray
    distance: np.ndarray
    sigma: np.ndarray

    _columns: ClassVar = {"a": (str, ()), "b": (str, ()), "distance": (float, ()), "sigma": (float, ())}

    @classmethod
    def make(cls, rows=()) -> "ScaleBars":
        """From ``(id_a, id_b, distance, sigma)`` tuples."""
        rows = [tuple(r)[:4] for r in rows]
        return cls(a=np.array([str(r[0]) for r in rows], dtype=str), b=np.array([str(r[1]) for r in rows], dtype=str),
                   distance=np.array([float(r[2]) for r in rows]), sigma=np.array([float(r[3]) for r in rows]))

    def rows(self) -> list[tuple[str, str, float, float]]:
        """``(id_a, id_b, distance, sigma)`` per bar."""
        return list(zip(self.a.tolist(), self.b.tolist(), self.distance.tolist(), self.sigma.tolist()))


@dataclass(frozen=True, eq=False)
class CircleTargets(Table):
    """Circular targets of known size: one row per object point that is a circle (``docs/targets.md``).

    ids (t,) point ids; diameter (t,) in the block's object unit; normal (t, 3) the normal of the
    target's plane in the object system (any length, any sign; NaN: estimated from the best-fitting
    plane of the point's neighbours).  Image observations of these points are ellipse centres; the
    bundle corrects them for the perspective eccentricity (``BundleConfig.eccentricity``)."""

    ids: np.ndarray
    diameter: np.ndarray
    normal: np.ndarray

    _columns: ClassVar = {"ids": (str, ()), "diameter": (float, ()), "normal": (float, (3,))}

    def __post_init__(self):
        super().__post_init__()
        if np.any(~(self.diameter > 0)):
            raise ValueError("CircleTargets.diameter: every diameter must be > 0")
        given = np.isfinite(self.normal).all(axis=1)
        if np.any(np.linalg.norm(np.where(given[:, None], self.normal, 1.0), axis=1) == 0):
            raise ValueError("CircleTargets.normal: a given normal must not be zero")

    @classmethod
    def make(cls, ids, diameter, normal=None) -> "CircleTargets":
        """From point ids, a diameter (scalar or per target) and a normal ((3,) common, (t, 3), or None:
        estimate from the neighbours)."""
        ids = [str(i) for i in np.atleast_1d(ids)]
        t = len(ids)
        return cls(ids=np.array(ids, dtype=str), diameter=np.broadcast_to(np.asarray(diameter, float), (t,)),
                   normal=np.broadcast_to(np.asarray(np.nan if normal is None else normal, float), (t, 3)))


@dataclass(frozen=True, eq=False)
class RigSensors(Table):
    """The sensors (cameras) of camera rigs: one row per (rig, camera) (``docs/rigs.md``).

    rig (s,) rig id; camera (s,) index into :class:`Cameras` (a camera belongs to at most one rig);
    reference (s,) bool, the rig's reference sensor (exactly one per rig: its image-space frame is the
    rig frame, its pose is the identity); centre (s, 3) the sensor's projection centre in the rig frame
    (object unit; x right, y up, z back out of the reference lens, ``docs/conventions.md``); opk (s, 3)
    ω, φ, κ radians of ``R_sensor_from_rig`` (nan: unknown, estimated from the photos' orientations);
    sigma (s, 6) a-priori σ of the six (``0`` fixed, ``inf`` estimated, else weighted); prior_sigma
    (s, 6) σ of the given pose as a calibration of the rig (for the stability test of an estimated
    rig; ``nan`` none); ref_centre, ref_opk (s, 3) a reference solution to compare with (e.g.
    ``cv2.stereoCalibrate``; nan none); line (s,) the row's line in its file (0 unknown).
    """

    rig: np.ndarray
    camera: np.ndarray
    reference: np.ndarray
    centre: np.ndarray
    opk: np.ndarray
    sigma: np.ndarray
    prior_sigma: np.ndarray = None  # type: ignore[assignment]
    ref_centre: np.ndarray = None  # type: ignore[assignment]
    ref_opk: np.ndarray = None  # type: ignore[assignment]
    line: np.ndarray = None  # type: ignore[assignment]

    _columns: ClassVar = {
        "rig": (str, ()), "camera": (int, ()), "reference": (bool, ()), "centre": (float, (3,)),
        "opk": (float, (3,)), "sigma": (float, (6,)), "prior_sigma": (float, (6,)), "ref_centre": (float, (3,)),
        "ref_opk": (float, (3,)), "line": (int, ()),
    }

    def __post_init__(self):
        s = len(np.atleast_1d(self.rig))
        for name, tail, fill in (("prior_sigma", (6,), np.nan), ("ref_centre", (3,), np.nan),
                                 ("ref_opk", (3,), np.nan), ("line", (), 0)):
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.full((s,) + tail, fill))
        super().__post_init__()

    @classmethod
    def make(cls, rig, camera, reference, centre=None, opk=None, sigma=None, **extra) -> "RigSensors":
        """From columns; ``centre``/``opk`` default to unknown (nan), ``sigma`` to estimated (inf);
        the reference sensor's pose is set to the identity and fixed."""
        rig = np.array([str(r) for r in np.atleast_1d(rig)], dtype=str)
        s = len(rig)
        ref = np.broadcast_to(np.asarray(reference, bool), (s,)).copy()
        c = np.array(np.broadcast_to(np.asarray(np.nan if centre is None else centre, float), (s, 3)))
        o = np.array(np.broadcast_to(np.asarray(np.nan if opk is None else opk, float), (s, 3)))
        sg = np.array(np.broadcast_to(np.asarray(FREE if sigma is None else sigma, float), (s, 6)))
        c[ref], o[ref], sg[ref] = 0.0, 0.0, FIXED
        return cls(rig=rig, camera=np.broadcast_to(np.asarray(camera, int), (s,)), reference=ref, centre=c, opk=o,
                   sigma=sg, **extra)


@dataclass(frozen=True, eq=False)
class FrameMembers(Table):
    """Photos grouped into frames (one pose of a rig per frame): one row per photo of a frame.

    frame (f,) frame id; photo (f,) index into :class:`Photos` (each photo in at most one frame);
    line (f,) the row's line in its file (0 unknown).  The frame's rig is the rig of its photos'
    cameras (:class:`RigSensors`)."""

    frame: np.ndarray
    photo: np.ndarray
    line: np.ndarray = None  # type: ignore[assignment]

    _columns: ClassVar = {"frame": (str, ()), "photo": (int, ()), "line": (int, ())}

    def __post_init__(self):
        if self.line is None:
            object.__setattr__(self, "line", np.zeros(len(np.atleast_1d(self.frame)), int))
        super().__post_init__()


@dataclass(frozen=True, eq=False)
class Rigs:
    """Camera rigs of a block (``docs/rigs.md``): ``sensors`` (:class:`RigSensors`) and ``frames``
    (:class:`FrameMembers`); ``path``/``frames_path`` the files they were read from (for messages)
    and ``reference_name`` what the sensors' ``ref_*`` columns are (e.g. ``"cv2.stereoCalibrate"``).
    Empty when the block has no rig: every photo is then its own frame (the bundle as before)."""

    sensors: RigSensors = field(default_factory=lambda: RigSensors.make([], [], []))
    frames: FrameMembers = field(default_factory=lambda: FrameMembers(frame=np.zeros(0, str),
                                                                      photo=np.zeros(0, int)))
    path: str | None = None
    frames_path: str | None = None
    reference_name: str = ""

    def __bool__(self) -> bool:
        return len(self.frames) > 0

    def replace(self, **changes) -> "Rigs":
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True)
class CrsInfo:
    """The user's coordinate reference system of a block whose coordinates were read in one and
    turned into a local east-north-up frame (``docs/crs.md``): ``crs`` the CRS as WKT, ``origin``
    (longitude °, latitude °, height) of the frame's origin on the CRS's ellipsoid (semi-major
    axis ``a`` m, flattening ``f``).  ``baarda.pipeline.crs.frame_of_block`` turns it into the
    frame that transforms coordinates."""

    crs: str
    origin: tuple[float, float, float]
    a: float
    f: float

    def __post_init__(self):
        object.__setattr__(self, "origin", tuple(float(v) for v in self.origin))
        object.__setattr__(self, "a", float(self.a))
        object.__setattr__(self, "f", float(self.f))


class FrozenMap(Mapping):
    """A read-only mapping (a copy of the one given) that pickles, unlike ``MappingProxyType``:
    blocks travel to worker processes (``pipeline/montecarlo.py``, ``baarda batch``)."""

    __slots__ = ("_data",)

    def __init__(self, data=()):
        object.__setattr__(self, "_data", dict(data))

    def __getitem__(self, key):
        return self._data[key]

    def __iter__(self) -> Iterator:
        return iter(self._data)

    def __len__(self) -> int:
        return len(self._data)

    def __setattr__(self, name, value):
        raise AttributeError("FrozenMap is read-only")

    def __reduce__(self):
        return (FrozenMap, (self._data,))

    def __repr__(self) -> str:
        return f"FrozenMap({self._data!r})"


def _frozen_mapping(m) -> Mapping:
    return FrozenMap(m or {})


@dataclass(frozen=True)
class SourceInfo:
    """Where a block was read from, for messages and reports.

    ``path`` the main file read (None for a simulated block); ``format`` the reader's name of it;
    ``pixel_format`` the name of a source whose image measurements are pixels (``"COLMAP"``,
    ``"BAL"``, ``"libmv"``, ``"OpenCV"``; None for sources measured in mm); ``lines``
    ``(photo index, point index)`` of an observation → ``(file, line)`` where a reader knows it
    (may be empty); ``pair_lines`` ``(file, line)`` of each stereo pair."""

    path: str | None = None
    format: str | None = None
    pixel_format: str | None = None
    lines: Mapping = field(default_factory=dict)
    pair_lines: tuple = ()

    def __post_init__(self):
        object.__setattr__(self, "path", None if self.path is None else str(self.path))
        object.__setattr__(self, "lines", _frozen_mapping(self.lines))
        object.__setattr__(self, "pair_lines", tuple(tuple(p) for p in self.pair_lines))


@dataclass(frozen=True, eq=False)
class Block:
    """Everything one adjustment needs, plus provenance.

    Typed fields carry what more than one stage uses: ``crs`` the user's CRS the coordinates were
    read in (:class:`CrsInfo`, None for a local system), ``scale_bars`` (:class:`ScaleBars`),
    ``source`` (:class:`SourceInfo`: the file read, its format, the line of each observation),
    ``ap_meta`` camera id → the AP model's constants (``r0`` of the AICON model, ``b`` of Ebner's),
    the image file of each photo (``photos.image_path``), ``circles`` (:class:`CircleTargets`:
    points that are circular targets of known diameter, or None) and ``rigs`` the camera rigs and the
    frames their photos are grouped in (:class:`Rigs`; empty: no rig).

    ``meta`` is a namespace private to the plugin that wrote the block: a key is read only by the
    plugin that writes it (``tests/pipeline/test_contracts_typed.py`` checks this), never used to
    hand data to another plugin.
    """

    cameras: Cameras
    photos: Photos
    points: Points
    observations: Observations
    pairs: Pairs = field(default_factory=lambda: Pairs(left=np.zeros(0, int), right=np.zeros(0, int)))
    object_unit: str = "m"
    meta: dict = field(default_factory=dict)
    gnss: Gnss = field(default_factory=lambda: Gnss.empty())
    crs: CrsInfo | None = None
    scale_bars: ScaleBars = field(default_factory=lambda: ScaleBars.make())
    source: SourceInfo = field(default_factory=SourceInfo)
    ap_meta: Mapping = field(default_factory=dict)
    circles: CircleTargets | None = None
    rigs: Rigs = field(default_factory=Rigs)

    def __post_init__(self):
        object.__setattr__(self, "ap_meta", FrozenMap({str(k): _frozen_mapping(v)
                                                       for k, v in dict(self.ap_meta or {}).items()}))
        g = self.gnss.photo
        if len(g):
            if g.min() < 0 or g.max() >= len(self.photos):
                raise ValueError("Gnss.photo index out of range")
            if len(np.unique(g)) != len(g):
                raise ValueError("Gnss.photo: a photo has two antenna observations")
        obs = self.observations
        if len(obs):
            if obs.photo.min() < 0 or obs.photo.max() >= len(self.photos):
                raise ValueError("Observations.photo index out of range")
            if obs.point.min() < 0 or obs.point.max() >= len(self.points):
                raise ValueError("Observations.point index out of range")
        if len(self.photos) and (self.photos.camera.min() < 0 or self.photos.camera.max() >= len(self.cameras)):
            raise ValueError("Photos.camera index out of range")
        for name in ("left", "right"):
            idx = getattr(self.pairs, name)
            if len(idx) and (idx.min() < 0 or idx.max() >= len(self.photos)):
                raise ValueError(f"Pairs.{name} index out of range")
        rs, fm = self.rigs.sensors, self.rigs.frames
        if len(rs) and (rs.camera.min() < 0 or rs.camera.max() >= len(self.cameras)):
            raise ValueError("RigSensors.camera index out of range")
        if len(fm) and (fm.photo.min() < 0 or fm.photo.max() >= len(self.photos)):
            raise ValueError("FrameMembers.photo index out of range")

    def replace(self, **changes) -> "Block":
        return dataclasses.replace(self, **changes)

    def observation_ids(self) -> list[tuple[str, str]]:
        """(photo id, point id) of each observation row."""
        return list(zip(self.photos.ids[self.observations.photo].tolist(),
                        self.points.ids[self.observations.point].tolist()))

    def summary(self) -> dict:
        """Counts for reports."""
        roles = {r: int((self.points.role == r).sum()) for r in ROLES}
        return {
            "cameras": len(self.cameras), "photos": len(self.photos), "points": len(self.points),
            "observations": len(self.observations),
            "active_observations": int(self.observations.active.sum()),
            "pairs": len(self.pairs), "roles": roles, "object_unit": self.object_unit,
            **({"gnss_antennas": len(self.gnss)} if len(self.gnss) else {}),
        }
