"""Coordinate reference systems: the user's CRS ↔ the local Cartesian frame the adjustment runs in.

A bundle adjustment needs a Cartesian object system.  Projected coordinates (UTM, …) are not one:
the grid scale factor (0.9996 … 1.0004 in UTM) changes every distance, and the map plane ignores
the earth's curvature (a point 1 km away lies 8 cm below the tangent plane).  Geographic
coordinates (lon, lat in degrees) are not even lengths.  So object coordinates given in such a
CRS are converted to a **local topocentric frame** (east, north, up; metres; origin on the
ellipsoid near the data), adjusted there, and converted back for reports and exports:

    user CRS ──pyproj──► lon, lat, h (the CRS's own datum) ──numpy──► ECEF ──numpy──► E, N, U

Heights: a 2-D CRS (e.g. ``EPSG:32722``) carries the third coordinate through as the
**ellipsoidal height** h of its datum (GNSS heights; ``docs/crs.md``).  A 3-D CRS (``EPSG:4979``,
a geocentric CRS) is transformed by pyproj with its heights.  A compound CRS whose heights are
above a geoid (``EPSG:32722+5773``, or a PROJ string with ``+geoidgrids=…``) is transformed with
PROJ's geoid grid: ``h = H + N``.  Grids are looked up where PROJ looks (its data directory, the
user-writable directory ``pyproj.datadir.get_user_data_dir()``) and in the folders named by
``PROJ_DATA`` / ``PROJ_LIB``, which :func:`use_grid_directories` adds (pyproj's wheels ignore
them otherwise).  When the grid is missing PROJ would fall back to a "ballpark" transformation
that ignores the geoid (h = H, metres wrong); baarda refuses instead, with an :class:`InputError`
naming the grid (``docs/crs.md``).  Nothing is downloaded.

pyproj is used only here (an engine module); the frame numerics (:func:`ecef_from_geodetic`,
:func:`geodetic_from_ecef`, :func:`R_enu_from_ecef`) are plain numpy.  Axes and units:
``docs/conventions.md`` (*Object system*), ``docs/crs.md``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from baarda.pipeline.errors import InputError
from baarda.pipeline.model import CrsInfo

__all__ = ["ecef_from_geodetic", "geodetic_from_ecef", "R_enu_from_ecef", "parse_crs", "LocalFrame",
           "local_frame", "frame_of_block", "use_grid_directories", "crs_label"]

WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563


# --------------------------------------------------------------------------------------------
# pure numerics (numpy only)


def ecef_from_geodetic(lon_deg, lat_deg, h, a: float = WGS84_A, f: float = WGS84_F) -> np.ndarray:
    """Earth-centred, earth-fixed X, Y, Z (n, 3) of geodetic lon, lat (degrees) and ellipsoidal h."""
    lon, lat = np.radians(np.asarray(lon_deg, float)), np.radians(np.asarray(lat_deg, float))
    h = np.asarray(h, float)
    e2 = f * (2.0 - f)
    N = a / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
    return np.stack([(N + h) * np.cos(lat) * np.cos(lon), (N + h) * np.cos(lat) * np.sin(lon),
                     (N * (1.0 - e2) + h) * np.sin(lat)], axis=-1)


def geodetic_from_ecef(xyz, a: float = WGS84_A, f: float = WGS84_F) -> np.ndarray:
    """lon, lat (degrees), h (n, 3) of ECEF coordinates (Bowring's start, then fixed-point
    iteration on the latitude to 1e-14 rad; valid everywhere except within metres of the centre)."""
    xyz = np.asarray(xyz, float)
    X, Y, Z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    e2 = f * (2.0 - f)
    b = a * (1.0 - f)
    ep2 = (a * a - b * b) / (b * b)
    p = np.hypot(X, Y)
    th = np.arctan2(Z * a, p * b)
    lat = np.arctan2(Z + ep2 * b * np.sin(th) ** 3, p - e2 * a * np.cos(th) ** 3)
    for _ in range(5):
        N = a / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
        h = np.where(np.abs(np.cos(lat)) > 1e-12, p / np.cos(lat) - N, np.abs(Z) - b)
        lat_new = np.arctan2(Z, p * (1.0 - e2 * N / (N + h)))
        if np.all(np.abs(lat_new - lat) < 1e-14):
            lat = lat_new
            break
        lat = lat_new
    N = a / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
    h = np.where(np.abs(np.cos(lat)) > 1e-12, p / np.cos(lat) - N, np.abs(Z) - b)
    return np.stack([np.degrees(np.arctan2(Y, X)), np.degrees(lat), h], axis=-1)


def R_enu_from_ecef(lon_deg: float, lat_deg: float) -> np.ndarray:
    """(3, 3) rotation of ECEF directions into east, north, up at (lon, lat)."""
    lo, la = np.radians(lon_deg), np.radians(lat_deg)
    sl, cl, sp, cp = np.sin(lo), np.cos(lo), np.sin(la), np.cos(la)
    return np.array([[-sl, cl, 0.0],
                     [-sp * cl, -sp * sl, cp],
                     [cp * cl, cp * sl, sp]])


# --------------------------------------------------------------------------------------------
# CRS parsing (pyproj)

_ODM_UTM = re.compile(r"^\s*WGS\s*-?\s*84\s+UTM\s+(\d{1,2})\s*([NS])\s*$", re.IGNORECASE)


def parse_crs(text: str, *, path=None, line: int | None = None, field: str | None = "crs"):
    """A :class:`pyproj.CRS` from what users write: ``EPSG:32722``, a PROJ string
    (``+proj=utm +zone=22 +south +datum=WGS84``), WKT, or ODM's ``WGS84 UTM 22S``.
    ``InputError`` naming ``path``, ``line`` and ``field`` when PROJ does not know it."""
    import pyproj

    s = str(text).strip()
    m = _ODM_UTM.match(s)
    if m:
        zone, hemi = int(m.group(1)), m.group(2).upper()
        if not 1 <= zone <= 60:
            raise InputError(f"UTM zone must be 1 … 60, got {zone}", path=path, line=line, field=field)
        s = f"EPSG:{32600 + zone if hemi == 'N' else 32700 + zone}"
    if not s:
        raise InputError("empty CRS (expected e.g. EPSG:32722 or a PROJ string)", path=path, line=line, field=field)
    try:
        crs = pyproj.CRS.from_user_input(s)
    except pyproj.exceptions.CRSError as e:
        short = str(e).splitlines()[0][:160]
        raise InputError(f"unknown coordinate reference system {s[:60]!r} ({short})", path=path, line=line,
                         field=field) from None
    return crs


def crs_label(text: str) -> str:
    """A CRS (any form ``parse_crs`` reads, e.g. the WKT a frame keeps) as short text that reads
    back as the same CRS: ``EPSG:32722``; a compound of two registered parts as
    ``EPSG:32722+5773``; else a PROJ string when it keeps everything (``+geoidgrids=…``), else
    one-line WKT."""
    import warnings

    crs = parse_crs(text)
    auth = crs.to_authority()
    if auth:
        return ":".join(auth)
    if crs.is_compound:
        parts = [c.to_authority() for c in crs.sub_crs_list]
        if all(parts) and len({a[0] for a in parts}) == 1:
            return f"{parts[0][0]}:" + "+".join(a[1] for a in parts)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)        # "you will likely lose …": checked below
        try:
            proj = crs.to_proj4()
        except Exception:                                   # noqa: BLE001 — no PROJ string for it
            proj = None
    if proj and parse_crs(proj).equals(crs, ignore_axis_order=True):
        return proj.replace("\n", " ").replace(" +type=crs", "")
    return crs.to_wkt()


# --------------------------------------------------------------------------------------------
# grids and transformations

_ADDED_GRID_DIRS: set[str] = set()


def use_grid_directories(*dirs) -> list[str]:
    """Let PROJ find grids (geoid models, datum shifts) in ``dirs`` and in the folders of the
    ``PROJ_DATA`` / ``PROJ_LIB`` environment variables (``os.pathsep``-separated); returns the
    folders added now.  Folders that do not exist are ignored; each is added once."""
    import os

    import pyproj

    wanted = [str(d) for d in dirs]
    for var in ("PROJ_DATA", "PROJ_LIB"):
        wanted += [d for d in os.environ.get(var, "").split(os.pathsep) if d]
    added = []
    for d in wanted:
        if d in _ADDED_GRID_DIRS or not os.path.isdir(d):
            continue
        pyproj.datadir.append_data_dir(d)
        _ADDED_GRID_DIRS.add(d)
        added.append(d)
    return added


def _missing_grids(group) -> list[str]:
    names = []
    for op in group.unavailable_operations:
        for g in getattr(op, "grids", []) or []:
            if not g.available and g.short_name not in names:
                names.append(g.short_name)
    return names


def _transformer(crs_text: str, geo_text: str):
    """pyproj's best transformation from ``crs_text`` to ``geo_text`` (x/y order), refused when PROJ
    lacks a grid the best one needs (it would use a ballpark one) or cannot build one at all."""
    import pyproj

    use_grid_directories()
    key = (crs_text, geo_text, pyproj.datadir.get_data_dir())
    if key in _TRANSFORMERS:
        return _TRANSFORMERS[key]
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)     # "best transformation is not available": said below
            group = pyproj.transformer.TransformerGroup(crs_text, geo_text, always_xy=True)
    except pyproj.exceptions.ProjError as e:
        grid = re.search(r"(\S+\.(?:gtx|tif|tiff|gsb|byn|gvb))", str(e))
        what = f"the grid {grid.group(1)}" if grid else "a grid or an operation"
        raise InputError(f"PROJ cannot transform the coordinates: {what} not found ({str(e).splitlines()[0][:120]}); "
                         "put grids where PROJ looks or in a folder named by PROJ_DATA (docs/crs.md)",
                         field="crs") from None
    missing = _missing_grids(group)
    if missing and not group.best_available:
        raise InputError(f"the heights need the grid {', '.join(missing)} (e.g. a geoid model), which PROJ "
                         "does not have here; without it PROJ would ignore the geoid. Put the grid in "
                         f"{pyproj.datadir.get_user_data_dir()} or in a folder named by PROJ_DATA (docs/crs.md; "
                         "baarda downloads nothing)", field="crs")
    if not group.transformers:
        raise InputError("PROJ has no transformation from the CRS to geographic coordinates", field="crs")
    _TRANSFORMERS[key] = group.transformers[0]
    return group.transformers[0]


_TRANSFORMERS: dict = {}


# --------------------------------------------------------------------------------------------
# the local frame


@dataclass(frozen=True)
class LocalFrame:
    """East-north-up frame (metres) with its origin at geodetic ``origin = (lon°, lat°, h)`` of
    the user's CRS's datum; ``crs`` the user's CRS as text (``None``: the coordinates already are
    a local Cartesian system and the frame is the identity)."""

    crs: str | None
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    a: float = WGS84_A
    f: float = WGS84_F

    @property
    def is_identity(self) -> bool:
        return self.crs is None

    def _transformers(self):
        import pyproj

        crs = pyproj.CRS.from_user_input(self.crs)
        if crs.is_geocentric:
            return crs, None
        geo = crs.geodetic_crs
        if geo is None:
            raise InputError(f"the CRS {self.crs[:60]!r} has no geodetic datum: give coordinates in a projected, "
                             "geographic or geocentric CRS, or none for a local system", field="crs")
        geo3 = geo.to_3d() if len(crs.axis_info) == 2 or crs.is_projected or crs.is_compound else geo
        return crs, _transformer(self.crs, geo3.to_wkt())

    def geodetic(self, xyz) -> np.ndarray:
        """lon°, lat°, h (n, 3) of coordinates in the user's CRS (h: ellipsoidal)."""
        xyz = np.atleast_2d(np.asarray(xyz, float))
        crs, fwd = self._transformers()
        if fwd is None:
            return geodetic_from_ecef(xyz, self.a, self.f)
        lon, lat, h = fwd.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2])
        out = np.column_stack([lon, lat, h])
        if not np.isfinite(out).all():
            raise InputError(f"PROJ cannot transform coordinates of {self.crs[:60]!r} to geographic ones "
                             "(outside the CRS's area, or a geoid grid PROJ does not have)", field="crs")
        return out

    def to_local(self, xyz) -> np.ndarray:
        """E, N, U (n, 3) in metres of coordinates ``xyz (n, 3)`` in the user's CRS."""
        xyz = np.atleast_2d(np.asarray(xyz, float))
        if self.is_identity:
            return xyz.copy()
        g = self.geodetic(xyz)
        ecef = ecef_from_geodetic(g[:, 0], g[:, 1], g[:, 2], self.a, self.f)
        o = ecef_from_geodetic(*self.origin, self.a, self.f)
        return (ecef - o) @ R_enu_from_ecef(self.origin[0], self.origin[1]).T

    def from_local(self, enu) -> np.ndarray:
        """Coordinates in the user's CRS of local E, N, U ``(n, 3)``."""
        enu = np.atleast_2d(np.asarray(enu, float))
        if self.is_identity:
            return enu.copy()
        o = ecef_from_geodetic(*self.origin, self.a, self.f)
        ecef = enu @ R_enu_from_ecef(self.origin[0], self.origin[1]) + o
        crs, fwd = self._transformers()
        if fwd is None:
            return ecef
        g = geodetic_from_ecef(ecef, self.a, self.f)
        x, y, z = fwd.transform(g[:, 0], g[:, 1], g[:, 2], direction="INVERSE")
        return np.column_stack([x, y, z])

    def jacobian(self, enu, step: float = 0.01) -> np.ndarray:
        """(n, 3, 3) ∂(user CRS coordinates)/∂(E, N, U) at ``enu`` by central differences (``step`` m).
        Covariances go to the user's CRS as ``J C Jᵀ``; for UTM J is the grid scale factor times the
        rotation by the meridian convergence (and 1 for the height)."""
        enu = np.atleast_2d(np.asarray(enu, float))
        J = np.zeros((len(enu), 3, 3))
        for k in range(3):
            d = np.zeros(3)
            d[k] = step
            J[:, :, k] = (self.from_local(enu + d) - self.from_local(enu - d)) / (2 * step)
        return J

    def rotation_from_local(self, enu) -> np.ndarray:
        """(n, 3, 3) the rotation of the user's CRS axes against the local ones at ``enu``: the
        orthogonal factor of :meth:`jacobian` (meridian convergence and curvature, without the scale
        factor).  An attitude turns with it: ``R_cam_from_local = R_cam_from_crs · R``.  Identity for
        an identity frame."""
        enu = np.atleast_2d(np.asarray(enu, float))
        if self.is_identity:
            return np.broadcast_to(np.eye(3), (len(enu), 3, 3)).copy()
        U, _, Vt = np.linalg.svd(self.jacobian(enu))
        return U @ Vt

    def info(self) -> CrsInfo | None:
        """The block's typed record of this frame (``Block.crs``; None for the identity)."""
        if self.is_identity:
            return None
        return CrsInfo(self.crs, tuple(self.origin), self.a, self.f)

    @classmethod
    def from_info(cls, info: CrsInfo | None) -> "LocalFrame":
        """The frame of a block's ``crs`` (the identity for None)."""
        if info is None:
            return cls(None)
        return cls(info.crs, tuple(info.origin), info.a, info.f)

    def axis_names(self) -> tuple[str, str, str]:
        """Column names of coordinates in the user's CRS (``E N h``, ``lon lat h``, ``X Y Z``)."""
        if self.is_identity:
            return ("X", "Y", "Z")
        import pyproj

        crs = pyproj.CRS.from_user_input(self.crs)
        if crs.is_geographic:
            return ("lon", "lat", "h")
        if crs.is_projected:
            return ("E", "N", "h")
        return ("X", "Y", "Z")


def local_frame(crs_text: str | None, xyz, *, path=None, line=None, field="crs") -> LocalFrame:
    """The frame for coordinates ``xyz (n, 3)`` given in ``crs_text`` (``None`` or ``"local"``: the
    identity): origin on the ellipsoid (h = 0 is *not* used: the mean height of the points, so
    the local U is close to the height above the ground of the block) at the points' centroid."""
    if crs_text is None or str(crs_text).strip().lower() in ("", "local", "none"):
        return LocalFrame(None)
    crs = parse_crs(crs_text, path=path, line=line, field=field)
    ell = crs.ellipsoid
    a = float(ell.semi_major_metre) if ell is not None else WGS84_A
    inv_f = float(ell.inverse_flattening) if ell is not None else 1.0 / WGS84_F
    f = 1.0 / inv_f if inv_f else 0.0
    text = crs.to_wkt()
    tmp = LocalFrame(text, (0.0, 0.0, 0.0), a, f)
    xyz = np.atleast_2d(np.asarray(xyz, float))
    ok = np.isfinite(xyz).all(axis=1)
    if not ok.any():
        raise InputError("no finite coordinates to place the local frame", path=path, field=field)
    try:
        g = tmp.geodetic(xyz[ok])
    except InputError as e:
        raise InputError(f"CRS {str(crs_text).strip()[:60]!r}: {e.message}", path=path, line=line, field=field) from None
    if tmp._transformers()[0].is_geographic and (np.abs(g[:, 1]) > 90).any():
        raise InputError("latitude outside ±90° (are longitude and latitude swapped?)", path=path, field=field)
    # the heights the CRS gives these coordinates: a point is on the Earth (−1 km … +100 km), or the
    # CRS is not theirs (projected E, N read as geocentric X, Y; metres read as degrees)
    h_bad = ~((g[:, 2] > -1_000.0) & (g[:, 2] < 100_000.0))
    if h_bad.any():
        k = int(np.flatnonzero(h_bad)[0])
        kind = "geocentric" if crs.is_geocentric else ("geographic" if crs.is_geographic else "projected")
        raise InputError(f"in the {kind} CRS {str(crs_text).strip()[:60]!r} these coordinates lie {g[k, 2] / 1000:.0f} km "
                         f"from the ellipsoid (point {k + 1} of {len(g)}): the coordinates are not in this CRS "
                         "(projected E, N given a geocentric CRS, or a unit mistake?)", path=path, line=line, field=field)
    origin = ecef_from_geodetic(g[:, 0], g[:, 1], g[:, 2], a, f).mean(axis=0)
    lon, lat, h = geodetic_from_ecef(origin, a, f)
    return LocalFrame(text, (float(lon), float(lat), float(np.mean(g[:, 2]))), a, f)


def frame_of_block(block) -> LocalFrame:
    """The block's frame (``block.crs``, set by source stages that read a CRS)."""
    return LocalFrame.from_info(block.crs)
