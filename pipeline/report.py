"""Writing a run directory: ``results.json`` and the resolved project (JSON and TOML values), and
Markdown tables for the reports.  The stages' tables (CSV and Parquet) are written by
:mod:`baarda.pipeline.tables`.

Files are written as soon as a stage finishes (``report.md`` and ``results.json`` are rewritten
after every stage), so a failing stage never loses the results of the stages before it.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np


def jsonable(obj: Any) -> Any:
    """Numpy and friends → plain JSON values (nan/inf become null / strings)."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        f = float(obj)
        if math.isnan(f):
            return None
        if math.isinf(f):
            return "inf" if f > 0 else "-inf"
        return f
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_json(path: Path, data: Any) -> None:
    path.write_text(json.dumps(jsonable(data), indent=2, allow_nan=False) + "\n", encoding="utf-8")


def write_toml(path: Path, data: dict) -> None:
    """A small TOML writer for the resolved project (tables, arrays of tables, plain values)."""
    lines: list[str] = []

    def val(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (int,)) and not isinstance(v, bool):
            return str(v)
        if isinstance(v, float):
            if math.isinf(v):
                return "inf" if v > 0 else "-inf"
            if math.isnan(v):
                return "nan"
            return repr(v)
        if isinstance(v, (list, tuple)):
            if v and all(isinstance(x, dict) for x in v):
                return "[" + ", ".join(inline(x) for x in v) + "]"
            return "[" + ", ".join(val(x) for x in v) + "]"
        if isinstance(v, dict):
            return inline(v)
        if v is None:
            return '""'
        return json.dumps(str(v))

    def inline(d):
        return "{ " + ", ".join(f"{_key(k)} = {val(x)}" for k, x in d.items()) + " }"

    def table(name, d, array=False):
        lines.append(f"[[{name}]]" if array else f"[{name}]")
        subs = []
        for k, v in d.items():
            if isinstance(v, dict):
                subs.append((k, v))
            else:
                lines.append(f"{_key(k)} = {val(v)}")
        for k, v in subs:
            lines.append(f"[{name}.{_key(k)}]")
            for kk, vv in v.items():
                lines.append(f"{_key(kk)} = {val(vv)}")
        lines.append("")

    for k, v in data.items():
        if isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            for item in v:
                table(k, item, array=True)
        elif isinstance(v, dict):
            table(k, v)
        else:
            lines.append(f"{_key(k)} = {val(v)}")
    path.write_text("\n".join(lines), encoding="utf-8")


def _key(k: str) -> str:
    import re

    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else json.dumps(k)


def _cell(text: str) -> str:
    """Text of a Markdown table cell: ``|`` escaped (GFM's ``\\|``), line breaks as spaces."""
    return text.replace("\\|", "|").replace("|", "\\|").replace("\n", " ")


def markdown_table(header: list[str], rows: list[list[Any]], floatfmt: str = ".4f") -> str:
    """A Markdown table; floats formatted with ``floatfmt``.  A ``|`` inside a header or cell (e.g.
    ``|d|``) is escaped, so that it cannot split the cell and break the table."""

    def fmt(v):
        if isinstance(v, (float, np.floating)):
            return "—" if not np.isfinite(v) else format(float(v), floatfmt)
        if isinstance(v, (bool, np.bool_)):
            return "yes" if v else ""
        return _cell(str(v))

    out = ["| " + " | ".join(_cell(str(h)) for h in header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(fmt(v) for v in r) + " |" for r in rows]
    return "\n".join(out)


def count_text(n: int) -> str:
    """An integer count with thin spaces between thousands: 3 402, 1 480 000."""
    return f"{int(n):,}".replace(",", "\u2009")


def cap_text(shown: int, total: int, *, what: str = "rows", where: str = "") -> str:
    """The one wording of a capped list in every report: "12 of 3 402 flagged; all in
    bundle_observations.csv, column decision" (``where``: where the whole list is), or "all 7
    flagged" when nothing was left out."""
    head = (f"all {count_text(total)} {what}" if shown >= total
            else f"{count_text(shown)} of {count_text(total)} {what}")
    return head + (f"; all in {where}" if where and shown < total else (f"; in {where}" if where else ""))


def capped_rows(rows, most: int = 15, *, order=None) -> tuple[list, int]:
    """The first ``most`` of ``rows`` (in ``order``, e.g. largest |w| first: indices into ``rows``)
    and how many there are in all — the cap every report table goes through (issue 22: reports stay
    readable at any size; the rest is in the tables)."""
    rows = list(rows) if order is None else [rows[i] for i in order]
    return rows[:max(int(most), 0)], len(rows)


def capped_table(header: list[str], rows, *, most: int = 15, what: str = "rows", where: str = "",
                 order=None, floatfmt: str = ".4f", indent: str = "") -> list[str]:
    """A Markdown table of at most ``most`` rows with the line saying how many there are and where
    the rest is (:func:`cap_text`), as lines (``indent`` before each: a table inside a list item)."""
    shown, total = capped_rows(rows, most, order=order)
    lines = [cap_text(len(shown), total, what=what, where=where) + ":", ""] if total else []
    lines += markdown_table(header, shown, floatfmt).splitlines() if shown else []
    return [indent + x if x else x for x in lines]

