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
from typing import Any

LENGTH_UNITS = {"m": 1.0, "mm": 1e-3, "µm": 1e-6, "um": 1e-6, "nm": 1e-9, "km": 1e3}
"""Length units → metres."""

_LADDER = (("km", 1e3), ("m", 1.0), ("mm", 1e-3), ("µm", 1e-6), ("nm", 1e-9))


def fmt_num(x: Any, sig: int = 4) -> str:
    """A plain number with ``sig`` significant digits, no exponent for ordinary magnitudes;
    ``–`` for none/nan; integers as they are."""
    if x is None:
        return "–"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int):
        return str(x)
    try:
        f = float(x)
    except (TypeError, ValueError):
        return str(x)
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


def fmt_q(value: Any, unit: str, sig: int = 4, *, rescale: bool = True) -> str:
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
        text_unit = best_length_unit(metres)
        f = metres / LENGTH_UNITS[text_unit]
    number = fmt_num(f, sig)
    return f"{number} {text_unit}" if text_unit else number
