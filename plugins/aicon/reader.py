"""Reader of AICON 3D Studio exports (``.ior .eor .obc .phc .scale``) — pure parsing and numerics.

File formats and the mapping to baarda: ``docs/aicon-format.md``.  In short:

* ``.ior`` — per camera five lines: ``id −999 c x0 y0 A1 A2 r0`` / ``A3`` / ``B1 B2`` / ``C1 C2`` /
  ``sensor_w sensor_h pixels_w pixels_h``.  AICON's c is negative (the image plane lies at −|c|
  in its image frame); baarda's c is the positive principal distance, ``c = −c_AICON``.
* ``.eor`` — ``image camera X0 Y0 Z0 ω φ κ flag flag flag`` (rad).  AICON's ω φ κ are baarda's:
  ``R_cam_from_world = R3(κ) R2(φ) R1(ω)`` reproduces the ``.phc`` coordinates.
* ``.obc`` — ``point X Y Z sX sY sZ rays flag flag flag`` (mm).
* ``.phc`` — ``image point x y sx sy vx vy flag active flag`` (mm); ``active = 0`` is a disabled
  measurement; ``vx vy`` are AICON's residuals, computed − observed (baarda's sign is the opposite).
* ``.scale`` — ``index "name" point_a point_b distance sigma flag`` (mm).

Every malformed line raises :class:`~baarda.pipeline.errors.InputError` naming the file, the 1-based line
and the field.
"""

from __future__ import annotations

import math
import shlex
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from baarda.pipeline.api import Block, InputError
from baarda.pipeline.errors import quote, read_limited
from baarda.pipeline.errors import finite_number as _num
from baarda.pipeline.model import (FIXED, FREE, Cameras, FrozenMap, Observations, Photos, Points, ScaleBars,
                                   SourceInfo)

SUFFIXES = ("ior", "eor", "obc", "phc", "scale")
AP_NAMES = ("A1", "A2", "A3", "B1", "B2", "C1", "C2")
VENDOR_FREE_AP = ("A1", "A2", "B1", "B2")
"""The additional parameters AICON 3D Studio estimated for this kind of export: its protocol of the
reference network (JAICOV/example/example.htm, "Innere Orientierungen") lists A1, A2, B1, B2 with a
standard deviation and A3, C1, C2 as "fest" (fixed at the exported values)."""
"""Order of AICON's parameters in ``Cameras.ap`` (the bundle's ``aicon`` model)."""


# --------------------------------------------------------------------------------------------
# parsed records


@dataclass(frozen=True)
class AiconCamera:
    """One camera of the ``.ior``; ``c`` as in the file (negative), lengths in mm."""

    id: str
    c: float
    x0: float
    y0: float
    ap: tuple[float, ...]          # A1 A2 A3 B1 B2 C1 C2
    r0: float
    sensor_mm: tuple[float, float]
    pixels: tuple[int, int]
    code: float                    # the second field (−999 in the exports seen)
    line: int


@dataclass(frozen=True)
class AiconExport:
    """Everything read from one export (``prefix.ior`` …), in the files' own conventions."""

    prefix: Path
    cameras: list[AiconCamera]
    images: dict                   # columns: id, camera, X0 (m, 3), opk (m, 3), flags (m, 3), line
    points: dict                   # columns: id, XYZ (n, 3), sigma (n, 3), rays, flags (n, 3), line
    measurements: dict             # columns: image, point, xy (k, 2), sxy, vxy, flags (k, 3), line
    scales: list[tuple]            # (name, id_a, id_b, distance, sigma, flag, line)
    files: dict = field(default_factory=dict)


# --------------------------------------------------------------------------------------------
# parsing helpers


def resolve_prefix(path: str | Path) -> Path:
    """The common prefix of an export: ``dir/example`` for ``dir/example.ior`` …

    ``path`` may be the prefix itself, any one of the files, or a directory holding exactly one
    ``.ior``.  Raises ``InputError`` when nothing (or more than one export) is found.
    """
    p = Path(path)
    if p.is_dir():
        iors = sorted(p.glob("*.ior"))
        if len(iors) != 1:
            found = ", ".join(i.name for i in iors) or "none"
            raise InputError(f"expected exactly one .ior file in the directory, found {found}; "
                             "give the prefix (e.g. .../example)", path=p)
        return iors[0].with_suffix("")
    if p.suffix.lstrip(".") in SUFFIXES:
        return p.with_suffix("")
    return p


def _path(prefix: Path, suffix: str) -> Path:
    return prefix.parent / f"{prefix.name}.{suffix}"


def _lines(path: Path) -> list[tuple[int, list[str]]]:
    """Non-blank lines as (1-based line number, tokens); ``InputError`` if the file is missing."""
    if not path.exists():
        raise InputError("file not found (an AICON export needs .ior, .eor, .obc and .phc; "
                         ".scale is optional)", path=path)
    text = read_limited(path, what="an AICON file").decode("utf-8", errors="replace")
    out = []
    for i, line in enumerate(text.splitlines(), start=1):
        if line.strip() and not line.lstrip().startswith("#"):
            out.append((i, line.split()))
    return out




def _int(tok: str, path: Path, line: int, name: str) -> int:
    v = _num(tok, path, line, name)
    if v != int(v):
        raise InputError(f"expected an integer, got {quote(tok)}", path=path, line=line, field=name)
    return int(v)


def _ident(tok: str, path: Path, line: int, name: str) -> str:
    """An id as written; must be a (whole) number in AICON's exports."""
    _int(tok, path, line, name)
    return tok


def _columns(path: Path, names: tuple[str, ...], min_cols: int):
    """Parse a whitespace table with at least ``min_cols`` columns; rows of tokens + lines."""
    rows = []
    for ln, toks in _lines(path):
        if len(toks) < min_cols:
            raise InputError(f"expected {min_cols} columns ({' '.join(names[:min_cols])}), got {len(toks)}",
                             path=path, line=ln, field=names[min(len(toks), len(names) - 1)])
        rows.append((ln, toks))
    return rows


# --------------------------------------------------------------------------------------------
# the five files


def read_ior(path: Path) -> list[AiconCamera]:
    """Cameras of an ``.ior`` file (records of five lines; see the module docstring)."""
    lines = _lines(path)
    cams = []
    k = 0
    while k < len(lines):
        ln, t = lines[k]
        if len(t) != 8:
            raise InputError(f"camera record must start with 8 values (id −999 c x0 y0 A1 A2 r0), got {len(t)}",
                             path=path, line=ln, field="camera")
        if k + 4 >= len(lines):
            raise InputError("incomplete camera record: expected 4 more lines (A3 / B1 B2 / C1 C2 / sensor)",
                             path=path, line=ln, field="camera")
        cid = _ident(t[0], path, ln, "camera")
        code = _num(t[1], path, ln, "code")
        c, x0, y0, a1, a2, r0 = (_num(v, path, ln, n) for v, n in zip(t[2:], ("c", "x0", "y0", "A1", "A2", "r0")))
        expect = [(1, ("A3",)), (2, ("B1", "B2")), (2, ("C1", "C2")), (4, ("sensor_width", "sensor_height",
                                                                             "pixels_x", "pixels_y"))]
        vals = []
        for j, (n, names) in enumerate(expect, start=1):
            lnj, tj = lines[k + j]
            if len(tj) != n:
                raise InputError(f"expected {n} value(s) ({' '.join(names)}), got {len(tj)}", path=path,
                                 line=lnj, field=names[0])
            vals.append([_num(v, path, lnj, nm) for v, nm in zip(tj, names)])
        (a3,), (b1, b2), (c1, c2), (sw, sh, pw, ph) = vals
        if c == 0:
            raise InputError("principal distance c is 0", path=path, line=ln, field="c")
        if c > 0:
            raise InputError(f"AICON writes the principal distance negative (c = -{c:g} for a {c:g} mm lens); "
                             f"got c = +{c:g}", path=path, line=ln, field="c")
        lns = lines[k + 4][0]
        for v, nm in ((sw, "sensor_width"), (sh, "sensor_height")):
            if not v > 0:
                raise InputError(f"the sensor size must be positive (mm), got {v:g}", path=path, line=lns, field=nm)
        for v, nm in ((pw, "pixels_x"), (ph, "pixels_y")):
            if not (v >= 1 and float(v).is_integer() and v <= 1_000_000):
                raise InputError(f"the pixel count must be a whole number from 1 to 1000000, got {v:g}", path=path,
                                 line=lns, field=nm)
        if any(cm.id == cid for cm in cams):
            raise InputError(f"duplicate camera {cid}", path=path, line=ln, field="camera")
        cams.append(AiconCamera(id=cid, c=c, x0=x0, y0=y0, ap=(a1, a2, a3, b1, b2, c1, c2), r0=r0,
                                sensor_mm=(sw, sh), pixels=(int(pw), int(ph)), code=code, line=ln))
        k += 5
    if not cams:
        raise InputError("no camera in file", path=path)
    return cams


_EOR = ("image", "camera", "X0", "Y0", "Z0", "omega", "phi", "kappa", "flag1", "flag2", "flag3")
_OBC = ("point", "X", "Y", "Z", "sX", "sY", "sZ", "rays", "flag1", "flag2", "flag3")
_PHC = ("image", "point", "x", "y", "sx", "sy", "vx", "vy", "flag1", "active", "flag3")


def _table(path: Path, names: tuple[str, ...], min_cols: int, id_cols: int):
    """Rows → (ids per id column, float matrix of the rest, line numbers)."""
    rows = _columns(path, names, min_cols)
    ids = [[] for _ in range(id_cols)]
    vals = np.full((len(rows), len(names) - id_cols), np.nan)
    lines = np.zeros(len(rows), int)
    for r, (ln, t) in enumerate(rows):
        for j in range(id_cols):
            ids[j].append(_ident(t[j], path, ln, names[j]))
        for j in range(id_cols, min(len(t), len(names))):
            vals[r, j - id_cols] = _num(t[j], path, ln, names[j])
        lines[r] = ln
    return ids, vals, lines


def read_eor(path: Path) -> dict:
    """Images of an ``.eor``: id, camera, X0 (m, 3), opk (m, 3) rad, flags (m, 3), line."""
    (img, cam), v, lines = _table(path, _EOR, 8, 2)
    seen = {}
    for i, ln in zip(img, lines):
        if i in seen:
            raise InputError(f"duplicate image {i} (first on line {seen[i]})", path=path, line=int(ln), field="image")
        seen[i] = int(ln)
    return {"id": img, "camera": cam, "X0": v[:, 0:3], "opk": v[:, 3:6], "flags": v[:, 6:9], "line": lines}


def read_obc(path: Path) -> dict:
    """Object points of an ``.obc``: id, XYZ (n, 3), sigma (n, 3), rays, flags (n, 3), line."""
    (pid,), v, lines = _table(path, _OBC, 4, 1)
    if not pid:
        raise InputError("no object point in the file (an AICON .obc lists point, X, Y, Z …)", path=path)
    seen = {}
    for i, ln in zip(pid, lines):
        if i in seen:
            raise InputError(f"duplicate point {i} (first on line {seen[i]})", path=path, line=int(ln), field="point")
        seen[i] = int(ln)
    bad = np.argwhere(v[:, 3:6] < 0)
    if bad.size:
        r, j = bad[0]
        raise InputError(f"a standard deviation must not be negative, got {v[r, 3 + j]:g}", path=path,
                         line=int(lines[r]), field=_OBC[4 + j])
    return {"id": pid, "XYZ": v[:, 0:3], "sigma": v[:, 3:6], "rays": v[:, 6], "flags": v[:, 7:10], "line": lines}


def read_phc(path: Path) -> dict:
    """Image measurements of a ``.phc``: image, point, xy (k, 2), sxy, vxy (k, 2), flags (k, 3), line."""
    (img, pid), v, lines = _table(path, _PHC, 4, 2)
    if not img:
        raise InputError("no image measurement in the file (an AICON .phc lists image, point, x, y …)", path=path)
    bad = np.argwhere(v[:, 2:4] < 0)
    if bad.size:
        r, j = bad[0]
        raise InputError(f"a standard deviation must not be negative, got {v[r, 2 + j]:g}", path=path,
                         line=int(lines[r]), field=_PHC[4 + j])
    first: dict = {}
    for r, key in enumerate(zip(img, pid)):
        if v[r, 7] == 0:                  # an inactive repeat is AICON's own record of a rejected measurement
            continue
        if key in first:
            raise InputError(f"point {key[1]} measured twice (both active) in image {key[0]} (first on line "
                             f"{first[key]})",
                             path=path, line=int(lines[r]), field="point")
        first[key] = int(lines[r])
    for r in np.flatnonzero(v[:, 7] == v[:, 7]):  # active column present
        if v[r, 7] not in (0.0, 1.0):
            raise InputError(f"expected 0 or 1, got {v[r, 7]:g}", path=path, line=int(lines[r]), field="active")
    return {"image": img, "point": pid, "xy": v[:, 0:2], "sxy": v[:, 2:4], "vxy": v[:, 4:6],
            "flags": v[:, 6:9], "line": lines}


def read_scale(path: Path) -> list[tuple]:
    """Scale bars of a ``.scale``: (name, point_a, point_b, distance, sigma, flag, line)."""
    out = []
    lines = _lines(path)
    raw_lines = read_limited(path, what="an AICON file").decode("utf-8", errors="replace").splitlines()
    for ln, _ in lines:
        raw = raw_lines[ln - 1]
        try:
            t = shlex.split(raw)
        except ValueError as e:
            raise InputError(f"cannot split the line: {e}", path=path, line=ln, field="name") from None
        if len(t) < 6:
            raise InputError(f"expected 7 columns (index name point_a point_b distance sigma flag), got {len(t)}",
                             path=path, line=ln, field="distance" if len(t) >= 4 else "point_a")
        a = _ident(t[2], path, ln, "point_a")
        b = _ident(t[3], path, ln, "point_b")
        d = _num(t[4], path, ln, "distance")
        s = _num(t[5], path, ln, "sigma")
        flag = _num(t[6], path, ln, "flag") if len(t) > 6 else 1.0
        if d <= 0:
            raise InputError(f"distance must be positive, got {d:g}", path=path, line=ln, field="distance")
        if s <= 0:
            raise InputError(f"sigma must be positive, got {s:g} (a scale bar enters the adjustment weighted "
                             "by its σ)", path=path, line=ln, field="sigma")
        out.append((t[1], a, b, d, s, flag, ln))
    return out


def read_aicon(path: str | Path) -> AiconExport:
    """Read an export given its prefix, one of its files or its directory."""
    prefix = resolve_prefix(path)
    files = {s: _path(prefix, s) for s in SUFFIXES}
    cams = read_ior(files["ior"])
    images = read_eor(files["eor"])
    points = read_obc(files["obc"])
    meas = read_phc(files["phc"])
    scales = read_scale(files["scale"]) if files["scale"].exists() else []
    cam_ids = {c.id for c in cams}
    for cid, ln in zip(images["camera"], images["line"]):
        if cid not in cam_ids:
            raise InputError(f"unknown camera {cid} (cameras in {files['ior'].name}: {', '.join(sorted(cam_ids))})",
                             path=files["eor"], line=int(ln), field="camera")
    img_ids = set(images["id"])
    for iid, ln in zip(meas["image"], meas["line"]):
        if iid not in img_ids:
            raise InputError(f"unknown image {iid} (not in {files['eor'].name})", path=files["phc"],
                             line=int(ln), field="image")
    seen = {}
    active = meas["flags"][:, 1] != 0.0
    for iid, pid, ln, a in zip(meas["image"], meas["point"], meas["line"], active):
        if not a:
            continue   # AICON keeps disabled duplicates of a measurement (seen in real exports)
        key = (iid, pid)
        if key in seen:
            raise InputError(f"point {pid} measured twice (both active) in image {iid} (first on line "
                             f"{seen[key]})", path=files["phc"], line=int(ln), field="point")
        seen[key] = int(ln)
    return AiconExport(prefix=prefix, cameras=cams, images=images, points=points, measurements=meas,
                       scales=scales, files={k: str(v) for k, v in files.items()})


# --------------------------------------------------------------------------------------------
# to a block



def _id_order(point_id: str):
    """Point ids in number order where they are integers (AICON's), any other text after them."""
    return (0, int(point_id), "") if point_id.isdigit() else (1, 0, point_id)

def aicon_block(export: AiconExport, *, sigma_image_um: float | None = None, self_calibration: bool = True,
                keep_unused: bool = False, free_ap: tuple[str, ...] | list[str] | None = VENDOR_FREE_AP) -> Block:
    """The export as a :class:`~baarda.pipeline.model.Block` (object unit mm).

    * camera: ``c = −c_AICON`` (positive), ``xp, yp = x0, y0``, ``ap_model = "aicon"`` with
      ``ap = (A1, A2, A3, B1, B2, C1, C2)``; ``r0`` in ``meta["aicon"].r0[camera]`` and
      ``Block.ap_meta[camera]["r0"]``.  With ``self_calibration`` c, xp, yp and the APs named in
      ``free_ap`` are free (default :data:`VENDOR_FREE_AP`: A1 A2 B1 B2, as AICON ran it; A3, C1, C2
      stay fixed at the exported values); ``free_ap = None`` frees every AP that is not exactly 0 in
      the file.  Without ``self_calibration`` everything is fixed.
    * photos: ω φ κ as exported, all free.  Points: role ``tie``, XYZ from the ``.obc``.
    * observations: cov ``diag(sx², sy²)`` from the file, or ``sigma_image_um`` for all;
      ``active = False`` for disabled measurements.
    * ``Block.scale_bars``: the active scale bars (ids of the ends, distance and σ in mm).

    Unless ``keep_unused``, points without coordinates in the ``.obc`` and points with fewer than
    two active measurements are left out with their measurements (listed in
    ``meta["aicon"].dropped_without_coordinates`` and ``.dropped_few_rays``); with it,
    coordinate-less points become tie points with unknown (nan) XYZ.
    """
    ph, pt, ms = export.images, export.points, export.measurements
    cam_index = {c.id: k for k, c in enumerate(export.cameras)}
    cams = export.cameras
    ap = np.array([c.ap for c in cams], float)
    free = FREE if self_calibration else FIXED
    if free_ap is None:
        sigma_ap = np.where(ap != 0.0, free, FIXED)
    else:
        unknown = [n for n in free_ap if n not in AP_NAMES]
        if unknown:
            raise ValueError(f"free_ap: {unknown[0]!r} is not an AICON parameter ({', '.join(AP_NAMES)})")
        sigma_ap = np.where(np.isin(AP_NAMES, list(free_ap))[None, :], free, FIXED) * np.ones_like(ap)
    cameras = Cameras.make(
        [c.id for c in cams], [-c.c for c in cams], [c.x0 for c in cams], [c.y0 for c in cams],
        ap_model="aicon", ap=ap, sigma_ap=sigma_ap, sigma_iop=free,
        format_mm=[c.sensor_mm for c in cams], pixel_mm=[c.sensor_mm[0] / c.pixels[0] for c in cams],
        resolution=[c.pixels for c in cams])
    photos = Photos.make(ph["id"], [cam_index[c] for c in ph["camera"]], ph["X0"], ph["opk"], FREE)

    active = ms["flags"][:, 1] != 0.0
    active[np.isnan(ms["flags"][:, 1])] = True
    has_coords = set(pt["id"])
    n_active = {}
    for p, a in zip(ms["point"], active):
        n_active[p] = n_active.get(p, 0) + int(a)
    without_coords = sorted({p for p in ms["point"] if p not in has_coords}, key=_id_order)
    few_rays = sorted((p for p in pt["id"] if n_active.get(p, 0) < 2), key=_id_order)
    if keep_unused:
        drop = set()
        ids = list(pt["id"]) + without_coords
        XYZ = np.vstack([pt["XYZ"], np.full((len(without_coords), 3), np.nan)])
    else:
        drop = set(without_coords) | set(few_rays)
        keep = [k for k, p in enumerate(pt["id"]) if p not in drop]
        ids = [pt["id"][k] for k in keep]
        XYZ = pt["XYZ"][keep]
    points = Points.make(ids, XYZ, "tie")

    pidx = {p: k for k, p in enumerate(ids)}
    iidx = {p: k for k, p in enumerate(ph["id"])}
    rows = np.array([k for k, p in enumerate(ms["point"]) if p not in drop], int)
    sxy = ms["sxy"][rows]
    if sigma_image_um is not None:
        sxy = np.full_like(sxy, sigma_image_um * 1e-3)
    elif not (np.isfinite(sxy).all() and (sxy > 0).all()):
        bad = rows[np.flatnonzero(~(np.isfinite(sxy) & (sxy > 0)).all(axis=1))[0]]
        raise InputError("sx, sy must be positive (or set the option sigma_image_um)",
                         path=export.files["phc"], line=int(ms["line"][bad]), field="sx")
    obs = Observations.make([iidx[ms["image"][k]] for k in rows], [pidx[ms["point"][k]] for k in rows],
                            ms["xy"][rows], sigma=sxy, active=active[rows])
    distances = [(a, b, d, s) for (_, a, b, d, s, flag, _) in export.scales if flag != 0]
    for a, b, _, _ in distances:
        for q in (a, b):
            if q not in pidx:
                ln = next(s[-1] for s in export.scales if q in (s[1], s[2]))
                raise InputError(f"scale bar point {q} is not an object point of the export",
                                 path=Path(export.files["scale"]), line=ln, field="point_a" if q == a else "point_b")
    phc_file = export.files["phc"]
    info = AiconInfo(
        prefix=str(export.prefix), files=export.files, r0={c.id: c.r0 for c in cams},
        c_file={c.id: c.c for c in cams}, ap_names=AP_NAMES,
        residuals_file=-ms["vxy"][rows],   # AICON's v (computed − observed), baarda's sign
        dropped_without_coordinates=without_coords,
        dropped_few_rays=[] if keep_unused else few_rays,
        dropped_measurements=int(len(ms["point"]) - len(rows)),
        disabled_measurements=int((~active[rows]).sum()),
        point_sigma_file=pt["sigma"][[k for k, p in enumerate(pt["id"]) if p in pidx]])
    meta = {"aicon": info}
    source = SourceInfo(path=str(phc_file), format="AICON 3D Studio",
                        lines={(int(o), int(q)): (phc_file, int(ms["line"][k]))
                               for o, q, k in zip(obs.photo, obs.point, rows)})
    return Block(cameras=cameras, photos=photos, points=points, observations=obs, object_unit="mm", meta=meta,
                 scale_bars=ScaleBars.make(distances), ap_meta={c.id: {"r0": c.r0} for c in cams}, source=source)


def _read_only(a) -> np.ndarray:
    arr = np.array(a, dtype=float, copy=True)
    arr.flags.writeable = False
    return arr


class _Frozen:
    """Pickles through the constructor, so arrays come back read-only (an unpickled array is writable)."""

    def __reduce__(self):
        return (type(self), tuple(getattr(self, f.name) for f in fields(self)))


@dataclass(frozen=True, eq=False)
class AiconExported(_Frozen):
    """The export's initial values, kept when the ``aicon`` source perturbs them (read-only arrays):
    projection centres ``X0`` (n, 3) mm, ``opk`` (n, 3) rad, per camera ``c`` (mm) and ``ap`` (m, 7),
    object points ``XYZ`` (p, 3) mm."""

    X0: np.ndarray
    opk: np.ndarray
    c: np.ndarray
    ap: np.ndarray
    XYZ: np.ndarray

    def __post_init__(self):
        for f in fields(self):
            object.__setattr__(self, f.name, _read_only(getattr(self, f.name)))


@dataclass(frozen=True, eq=False)
class AiconInfo(_Frozen):
    """What the ``aicon`` source keeps of an export beside the block (``Block.meta["aicon"]``, private
    to this plugin).  Immutable and picklable: arrays read-only, mappings :class:`FrozenMap`.

    ``prefix`` the export's common prefix, ``files`` kind (``ior``, ``eor``, ``obc``, ``phc``,
    ``scale``) → file; per camera id ``r0`` (mm) and ``c_file`` (AICON's c, negative); ``ap_names``
    the seven APs; ``residuals_file`` (k, 2) mm the export's residual of each measurement read, in
    baarda's sign (computed − observed); points left out: ``dropped_without_coordinates`` (no .obc
    coordinates) and ``dropped_few_rays`` (fewer than two active rays), with
    ``dropped_measurements``; ``disabled_measurements`` those read inactive;
    ``point_sigma_file`` (p, 3) mm the .obc σ of each point read; ``perturbation`` the source's
    perturbation options and ``exported`` the export's own initial values when it perturbed them
    (else None)."""

    prefix: str
    files: Mapping[str, str]
    r0: Mapping[str, float]
    c_file: Mapping[str, float]
    ap_names: tuple[str, ...]
    residuals_file: np.ndarray
    dropped_without_coordinates: tuple[str, ...]
    dropped_few_rays: tuple[str, ...]
    dropped_measurements: int
    disabled_measurements: int
    point_sigma_file: np.ndarray
    perturbation: object | None = None
    exported: AiconExported | None = None

    def __post_init__(self):
        for name in ("files", "r0", "c_file"):
            object.__setattr__(self, name, FrozenMap(getattr(self, name)))
        for name in ("ap_names", "dropped_without_coordinates", "dropped_few_rays"):
            object.__setattr__(self, name, tuple(str(v) for v in getattr(self, name)))
        for name in ("residuals_file", "point_sigma_file"):
            object.__setattr__(self, name, _read_only(getattr(self, name)))
        object.__setattr__(self, "dropped_measurements", int(self.dropped_measurements))
        object.__setattr__(self, "disabled_measurements", int(self.disabled_measurements))

    @property
    def dropped_points(self) -> int:
        """How many points were left out."""
        return len(self.dropped_without_coordinates) + len(self.dropped_few_rays)


def perturb_initial_values(block: Block, rng: np.random.Generator, *, sigma_position: float = 0.0,
                           sigma_angle_deg: float = 0.0, sigma_c: float = 0.0, sigma_point: float = 0.0,
                           zero_distortion: bool = False) -> Block:
    """A copy of ``block`` with its initial values disturbed (normal draws from ``rng``):
    projection centres by ``sigma_position`` (object unit), ω φ κ by ``sigma_angle_deg``, c by
    ``sigma_c`` (mm), point coordinates by ``sigma_point``; ``zero_distortion`` sets every free
    additional parameter to 0 (a fixed one keeps its value: it is not estimated, so a start at 0
    would change the model).  The input is not modified."""
    ph, cam, pts = block.photos, block.cameras, block.points
    X0 = ph.X0 + rng.normal(0.0, sigma_position, ph.X0.shape) if sigma_position else ph.X0
    opk = ph.opk + np.deg2rad(rng.normal(0.0, sigma_angle_deg, ph.opk.shape)) if sigma_angle_deg else ph.opk
    c = cam.c + rng.normal(0.0, sigma_c, cam.c.shape) if sigma_c else cam.c
    XYZ = pts.XYZ + rng.normal(0.0, sigma_point, pts.XYZ.shape) if sigma_point else pts.XYZ
    ap = np.where(cam.sigma_ap != 0, 0.0, cam.ap) if zero_distortion else cam.ap
    return replace(block, photos=ph.replace(X0=X0, opk=opk), cameras=cam.replace(c=c, ap=ap),
                   points=pts.replace(XYZ=XYZ))
