"""Numbers as a person reads them: one value, its unit, 3–4 significant digits.

Every number a report, a figure title or a summary line prints goes through :func:`fmt_q`, so a
value is shown the same way wherever it appears; tables keep full precision (their column names
carry the unit, see ``docs/report.md``).

Lengths are given in metres or millimetres internally (object coordinates in the block's unit, image
coordinates in mm, see ``docs/conventions.md``); :func:`fmt_q` picks the unit a person would write
for the size of the value (``39.8 µm`` rather than ``3.98e-05 m``).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

LENGTH_UNITS = {"m": 1.0, "mm": 1e-3, "µm": 1e-6, "um": 1e-6, "nm": 1e-9, "km": 1e3}
"""Length units → metres."""

_LADDER = (("km", 1e3), ("m", 1.0), ("mm", 1e-3), ("µm", 1e-6), ("nm", 1e-9))


def as_number(x: Any) -> tuple[str | None, float]:
    """``(text, value)``: the text of what is not a float to format (``–`` for None, yes/no, an
    integer as it is, a non-number as given) and None with the float otherwise — the start of every
    number formatter (:func:`fmt_num`, ``baarda.pipeline.html.fmt``)."""
    if x is None:
        return "–", math.nan
    if isinstance(x, bool):
        return ("yes" if x else "no"), math.nan
    if isinstance(x, int):
        return str(x), math.nan
    try:
        return None, float(x)
    except (TypeError, ValueError):
        return str(x), math.nan


def fmt_num(x: Any, sig: int = 4) -> str:
    """A plain number with ``sig`` significant digits, no exponent for ordinary magnitudes;
    ``–`` for none/nan; integers as they are."""
    text, f = as_number(x)
    if text is not None:
        return text
    if math.isnan(f):
        return "–"
    if math.isinf(f):
        return "∞" if f > 0 else "−∞"
    if f == 0:
        return "0"
    mag = math.floor(math.log10(abs(f)))
    if -4 <= mag < 7:
        decimals = max(sig - 1 - mag, 0)
        return f"{f:.{decimals}f}"
    return f"{f:.{sig - 1}e}"


def best_length_unit(value_in_m: float, *, allowed=("km", "m", "mm", "µm", "nm")) -> str:
    """The unit a person would write a length of ``value_in_m`` metres in (1 ≤ value < 1000 where
    possible, among ``allowed``)."""
    v = abs(float(value_in_m))
    ladder = [(u, s) for u, s in _LADDER if u in allowed]
    if not ladder:
        raise ValueError(f"no allowed length unit among {allowed}")
    if not math.isfinite(v) or v == 0:
        return "m" if "m" in allowed else ladder[0][0]
    for u, s in ladder:
        if v >= s:
            return u
    return ladder[-1][0]


def fmt_obj(value: Any, unit: str, sig: int = 4) -> str:
    """An object-space length (coordinate, σ, check-point error) in ``unit`` as text: in m or mm by
    size, as a surveyor writes it (``0.03980 mm``, not ``39.80 µm``); model units as given."""
    return fmt_q(value, unit, sig, allowed=("km", "m", "mm"))


def fmt_q(value: Any, unit: str, sig: int = 4, *, rescale: bool = True,
          allowed=("km", "m", "mm", "µm", "nm")) -> str:
    """``value`` in ``unit`` as text with its unit, e.g. ``fmt_q(3.98e-5, "m") == "39.80 µm"``.

    Lengths (m, mm, µm, …) are re-expressed in the unit of :func:`best_length_unit` unless
    ``rescale`` is False; other units (px, deg, "", "model units", …) are printed as given. An
    empty unit gives the bare number."""
    text_unit = "µm" if unit == "um" else unit
    if value is None:
        return "–"
    try:
        f = float(value)
    except (TypeError, ValueError):
        return f"{value} {text_unit}".strip()
    if rescale and text_unit in LENGTH_UNITS and math.isfinite(f) and f != 0:
        metres = f * LENGTH_UNITS[text_unit]
        text_unit = best_length_unit(metres, allowed=allowed)
        f = metres / LENGTH_UNITS[text_unit]
    number = fmt_num(f, sig)
    return f"{number} {text_unit}" if text_unit else number


MODEL_UNITS = "model units"
"""Unit text of object coordinates of arbitrary scale (a COLMAP or BAL model without control points
or CRS): the adjustment's own length unit, not metres (docs/conventions.md)."""

_CONVENTION = {"COLMAP": "colmap", "OpenCV": "opencv", "libmv": "opencv", "BAL": "bal"}
"""Pixel source → pixel convention of its u, v (docs/conventions.md, *Pixels ↔ mm*)."""


class ImageUnits(NamedTuple):
    """How a block's image measurements are shown: ``unit`` "px" for a pixel source (one pixel pitch
    for all cameras) else "µm"; ``scale`` internal mm → ``unit`` for differences (residuals, σ, MDB,
    ∇̂: 1/pitch or 1000); ``source`` the pixel source's name (None for a metric source);
    ``convention`` of its pixel coordinates ("opencv", "colmap", "bal"; None for metric).

    A tuple, so ``unit, scale, source = image_units(block)[:3]`` reads as the old triple did.
    Note y is up in mm and down in px (opencv/colmap): :meth:`diff` flips the sign of a y difference
    when ``flip_y`` is asked for (residual v_y in mm → v in px)."""

    unit: str
    scale: float
    source: str | None
    convention: str | None = None

    @classmethod
    def of(cls, block) -> "ImageUnits":
        src = block.source.pixel_format
        pitch = np.asarray(block.cameras.pixel_mm, float)
        if src and pitch.size and np.all(np.isfinite(pitch)) and np.all(pitch == pitch[0]) and pitch[0] > 0:
            return cls("px", 1.0 / float(pitch[0]), src, _CONVENTION.get(src, "opencv"))
        return cls("µm", 1000.0, None, None)

    @property
    def is_pixels(self) -> bool:
        return self.unit == "px"

    @property
    def suffix(self) -> str:
        """Column-name suffix of the unit: ``_px`` or ``_um``."""
        return "_px" if self.is_pixels else "_um"

    def diff(self, xy_mm, flip_y: bool = False) -> np.ndarray:
        """Differences (residuals, σ, MDB, ∇̂) in mm → ``unit`` (array of any shape; with
        ``flip_y`` the last axis is (x, y) and y changes sign for pixels, whose v points down)."""
        a = np.asarray(xy_mm, float) * self.scale
        if flip_y and self.is_pixels and self.convention != "bal":
            a = a.copy()
            a[..., 1] *= -1.0
        return a

    def coordinates(self, block, xy_mm, photo) -> np.ndarray:
        """Image coordinates ``(n, 2)`` in mm of photos ``photo (n,)`` → pixel coordinates (u, v) in
        the source's convention; for a metric source the mm values unchanged."""
        xy = np.asarray(xy_mm, float)
        if not self.is_pixels:
            return xy
        cam = np.asarray(block.photos.camera)[np.asarray(photo, int)]
        pitch = np.asarray(block.cameras.pixel_mm, float)[cam]
        if self.convention == "bal":
            return xy / pitch[:, None]
        from .geometry.image import pixels_from_mm
        size = np.asarray(block.cameras.resolution, float)[cam]
        return pixels_from_mm(xy, size, pitch, self.convention)


def image_units(block) -> ImageUnits:
    """:class:`ImageUnits` of ``block`` (px for a pixel source, else µm)."""
    return ImageUnits.of(block)


def object_unit_text(block) -> str:
    """Unit text of the block's object coordinates: its ``object_unit`` ("m", "mm"), or
    :data:`MODEL_UNITS` for a pixel source without control points or CRS (arbitrary scale)."""
    unit = getattr(block, "object_unit", "m") or "m"
    if block.source.pixel_format and not _has_datum(block):
        return MODEL_UNITS
    return unit


def _has_datum(block) -> bool:
    role = np.asarray(block.points.role)
    if np.isin(role, ("full", "xy", "z", "check")).any():
        return True
    return getattr(block, "crs", None) is not None


UNIT_SUFFIXES = {"px": "px", "um": "µm", "mm": "mm", "m": "m", "deg": "deg", "rad": "rad", "gon": "gon",
                 "s": "s", "cm": "cm", "mm2": "mm²", "px2": "px²", "mu": MODEL_UNITS}
"""Column-name suffix → unit text (docs/conventions.md, *Column names carry their unit*): ``x_px``,
``vx_um``, ``X_m``, ``sX_mm``, ``omega_deg``; ``_mu`` marks model units (arbitrary scale)."""


def column_unit(name: str) -> str:
    """The unit a column name's suffix says (``"vx_um"`` → ``"µm"``); "" for a name without one."""
    tail = str(name).rsplit("_", 1)
    if len(tail) == 2 and tail[0] and tail[1] in UNIT_SUFFIXES:
        return UNIT_SUFFIXES[tail[1]]
    return ""


def length_suffix(unit: str) -> str:
    """Column-name suffix of a length unit text ("m" → "_m", "µm" → "_um", model units → "_mu")."""
    inv = {v: k for k, v in UNIT_SUFFIXES.items()}
    return "_" + inv.get(unit, "um" if unit == "um" else unit)


def unit_mismatches(table) -> list[str]:
    """Where a table's ``units`` and its column names disagree (docs/conventions.md, *Column names carry
    their unit*): a column whose suffix says one unit and ``units`` another, a unit for a column without
    that suffix, a unit for a column the table lacks.  Empty when they agree."""
    out = []
    units = dict(table.units)
    for c in table.columns:
        said, given = column_unit(c), units.get(c, "")
        if said != given:
            out.append(f"{c}: name says {said or 'no unit'!r}, units says {given or 'no unit'!r}")
    out += [f"{c}: unit {u!r} for a column the table lacks" for c, u in units.items() if c not in table.columns]
    return out


AP_UNIT_POWER = {
    "none": (),
    "brown": (2, 4, 6, 1, 1, 0, 0),
    "aicon": (2, 4, 6, 1, 1, 0, 0),
    "brown-backward": (2, 4, 6, 1, 1, 0, 0),
    "ebner12": (0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3),
}
"""Per AP model, the power k of each additional parameter's unit (mm⁻ᵏ or px⁻ᵏ): K1 of ``x̄ r²`` k = 2,
P1 k = 1, B1 dimensionless … — also the bundle's ``AP_PIXEL_POWER`` (plugins/bundle/protocol.py, which
converts the parameters to px)."""

_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def camera_parameter_units(ap_model: str, n_ap: int, base: str = "mm") -> list[str]:
    """Units of a camera's parameters c, xp, yp and its ``n_ap`` additional parameters of AP model
    ``ap_model``, in image unit ``base`` ("mm" or "px"): ``["mm", "mm", "mm", "mm⁻²", …]``; a model not
    in :data:`AP_UNIT_POWER` (a third-party one) gives "model units (mm)" for its APs."""
    powers = AP_UNIT_POWER.get(str(ap_model))
    if powers is None or len(powers) != n_ap:
        return [base] * 3 + ["model units (mm)"] * n_ap
    return [base] * 3 + [("1" if k == 0 else f"{base}⁻{str(k).translate(_SUPERSCRIPT)}") for k in powers]


UNITLESS_NAMES = frozenset({
    "w", "r", "tau", "p", "T", "rho", "T2d", "T2d_critical", "dof", "lambda", "vtpv", "rcond", "global_T",
    "max_abs_w", "sigma0_hat", "max_step_sigma", "scale", "s_scale",
    "n", "rays", "active_rays", "points", "marks", "measurements", "targets", "models", "realisations", "failed",
    "iteration", "iterations", "repetition", "row", "line", "case", "kept", "active", "photos", "cameras",
    "camera", "photo", "point", "model", "id", "mark_point",
})
"""Column names a reader knows as unitless (docs/conventions.md, *Column names carry their unit*): test
statistics and redundancy numbers, correlations, σ̂0 and vᵀPv (in units of σ), counts, indices and
identifiers (a numeric camera, photo or point id)."""

_UNITLESS_FAMILIES = (
    r"(w|r|tau)_?[xyzENU]",                # w-test and redundancy per coordinate: wx, w_x, rE
    r"n_\w+|\w+_count",                    # counts
    r"\w*_in_sigma(_[xyz])?",              # an effect in σ of the parameter
    r"bar_delta0(_[xy])?",                 # δ̄0
    r"(\w+_)?ratio(_\w+)?|\w+_pct|(\w+_)?share(_\w+)?|\w*mahalanobis2",     # ratios, percentages, shares, …
    r"ellipsoid_axis\d_[xyz]",             # direction cosines
)


def known_unitless(name: str) -> bool:
    """Whether a column without a unit suffix is unitless by the conventional names
    (:data:`UNITLESS_NAMES` and their families: ``wx``, ``n_flagged``, ``…_in_sigma``, ``…_ratio``,
    ``…_pct`` …).  Any other numeric column without a suffix must be declared unitless by its table
    (``units={"col": ""}``) or sit in a table with a per-row ``unit`` column."""
    import re

    return name in UNITLESS_NAMES or any(re.fullmatch(f, name) for f in _UNITLESS_FAMILIES)


_AXIS_UNIT_SUFFIX = {"metre": "_m", "meter": "_m", "degree": "_deg", "foot": "_ft", "US survey foot": "_ftUS"}
"""pyproj's unit name of a CRS axis → column-name suffix."""


def crs_axis_suffixes(frame) -> list[str]:
    """Column-name unit suffixes of coordinates in the user's CRS of a ``baarda.pipeline.crs.LocalFrame``
    (its ``axis_names()`` order): E, N in the projection's unit (``_m``), lon/lat in degrees (``_deg``),
    heights in m; a frame without a CRS: three empty suffixes (the caller's object unit applies)."""
    if frame.is_identity:
        return ["", "", ""]
    import pyproj

    axes = list(pyproj.CRS.from_user_input(frame.crs).axis_info)
    out = [_AXIS_UNIT_SUFFIX.get(a.unit_name, "_" + a.unit_name.replace(" ", "")) for a in axes[:3]]
    if len(out) == 3 or len(out) < 2:
        return (out + ["_m"] * 3)[:3]
    return out + ["_m"]                    # a 2-D CRS: ellipsoidal heights in m
