"""Writing a stage's tables: Apache Arrow columns, saved as Parquet (full precision, units in the
metadata) and as CSV, both written by :mod:`pyarrow` (docs/report.md, docs/architecture.md).

A :class:`~baarda.pipeline.stage.TableData` becomes one Arrow table (:func:`to_arrow`); no cell is
formatted by Python:

* ``<stage>_<name>.parquet`` — the machine format: every value at full precision; each field's
  metadata carries ``unit`` (``"px"``, ``"µm"``, ``"m"``, ``"deg"``, ``""`` for unitless) and
  ``description``; the schema metadata the table's ``description``, ``stage`` and ``name``;
* ``<stage>_<name>.csv`` — the same values as text (:func:`pyarrow.csv.write_csv`): floats in the
  shortest form that reads back as the same double (``0.1``, ``1.2345678901234566e-7``), a missing
  value (NaN, None) an empty cell, booleans ``true``/``false``, strings quoted.

NaN is "no value" in both files (a null in Parquet, an empty cell in CSV): a w-test that was not
computed, the check-point difference of a tie point.  :func:`write_tables` writes a stage's tables and
returns the pointers ``results.json`` keeps (``{"csv", "parquet", "rows", "columns": {col: unit}}``);
with ``outputs = "summary"`` it skips the tables marked ``detail`` and says which.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping

import csv
import io

import numpy as np
import pyarrow as pa
import pyarrow.compute as pa_compute
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq

from .stage import TableData

OUTPUTS = ("full", "summary")
"""Values of the run option ``outputs``: every table, or only the tables not marked ``detail``."""

_STRUCTURAL = r'[,"\r\n]'
"""Characters that make a CSV cell need quotes."""

POOL = pa.system_memory_pool()
"""The memory pool of every Arrow allocation here: the C library's ``malloc``, as numpy's.  Tables
are written while the stage's arrays are alive; Arrow's default pool (mimalloc) keeps the pages
its chunks freed to itself, beside the memory numpy had freed — 77 MB more at the peak of the
2 000-photo run (docs/benchmarks.md, "Whole runs")."""


def column_array(values: Any, name: str = "") -> pa.Array:
    """One column as an Arrow array, without a Python loop over its cells where the values allow.

    A numeric or boolean numpy array is taken as it is (floats as float64, NaN becomes null); a numpy string
    array becomes a string column; a list or an object array is converted by Arrow itself (None
    and NaN become null; ints and floats mixed become float64).  Only a column Arrow cannot type
    (strings mixed with numbers, nested lists) falls back to the text of each value (``str``), as
    the CSV always showed it."""
    if isinstance(values, pa.Array):                       # converted already (a slice of a chunked table)
        return values
    arr = values if isinstance(values, np.ndarray) else None
    if arr is not None and arr.ndim != 1:
        raise ValueError(f"column {name!r}: expected one dimension, got shape {arr.shape}")
    if arr is not None and arr.dtype.kind == "f":             # float16/32 as the float64 they are exactly
        return pa.array(arr.astype(np.float64, copy=False), from_pandas=True, memory_pool=POOL)
    if arr is not None and arr.dtype.kind in "biu":
        return pa.array(arr, memory_pool=POOL)
    if arr is not None and arr.dtype.kind in "US":
        return pa.array(arr.astype(str, copy=False), type=pa.string(), memory_pool=POOL)
    try:
        out = pa.array(values, from_pandas=True, memory_pool=POOL)
    except (pa.ArrowInvalid, pa.ArrowTypeError, TypeError, ValueError):
        out = None
    if out is not None and not _nested(out.type):
        if pa.types.is_null(out.type):             # only None: a text column without values
            return pa.nulls(len(out), pa.string(), memory_pool=POOL)
        if pa.types.is_floating(out.type) and out.type != pa.float64():
            return out.cast(pa.float64(), memory_pool=POOL)
        return out
    cells = values.tolist() if arr is not None else list(values)
    return pa.array([None if _missing(v) else str(v) for v in cells], type=pa.string(), memory_pool=POOL)


def _nested(tp: pa.DataType) -> bool:
    return pa.types.is_nested(tp) or pa.types.is_dictionary(tp)


def _missing(v: Any) -> bool:
    return v is None or (isinstance(v, (float, np.floating)) and np.isnan(v))


def to_arrow(table: TableData, *, stage: str = "", name: str = "") -> pa.Table:
    """The Arrow table of ``table``: its columns in order, each field with metadata ``unit``
    (from ``table.units``; ``""`` when not given) and ``description``; the schema metadata holds
    the table's description, ``stage`` and ``name``."""
    arrays, fields = [], []
    units = dict(table.units or {})
    for col, values in table.columns.items():
        a = column_array(values, col)
        arrays.append(a)
        meta = {"unit": str(units.get(col, "")), "description": _column_description(col, units.get(col, ""))}
        fields.append(pa.field(str(col), a.type, nullable=True, metadata=meta))
    meta = {"description": table.description or "", "stage": stage, "name": name}
    return pa.Table.from_arrays(arrays, schema=pa.schema(fields, metadata=meta))


def _column_description(col: str, unit: str) -> str:
    return f"{col} ({unit})" if unit else col


def write_csv(path: str | Path, table: TableData | pa.Table) -> None:
    """``table`` as CSV text (header, one line per row), written by Arrow.

    Quotes only where a cell needs them (as Python's ``csv`` module writes): the header line by
    :mod:`csv`, the rows by Arrow, unquoted unless a string holds a comma, quote or line break
    (then Arrow quotes every string)."""
    t = table if isinstance(table, pa.Table) else to_arrow(table)
    head = io.StringIO()
    csv.writer(head, lineterminator="\n").writerow(t.column_names)
    with open(path, "wb") as fh:
        fh.write(head.getvalue().encode("utf-8"))
        if t.num_rows:
            style = "needed" if _needs_quotes(t) else "none"
            pa_csv.write_csv(t, fh, write_options=pa_csv.WriteOptions(include_header=False, quoting_style=style),
                             memory_pool=POOL)


def _needs_quotes(t: pa.Table | None) -> bool:
    """Whether a string cell of ``t`` holds a comma, a quote or a line break (vectorised)."""
    if t is None:
        return False
    for col in t.columns:
        if pa.types.is_string(col.type) or pa.types.is_large_string(col.type):
            if pa_compute.any(pa_compute.match_substring_regex(col, _STRUCTURAL, memory_pool=POOL)).as_py():
                return True
    return False


def write_parquet(path: str | Path, table: TableData | pa.Table) -> None:
    """``table`` as Parquet (full precision; units and descriptions in the metadata)."""
    t = table if isinstance(table, pa.Table) else to_arrow(table)
    # dictionary encoding only where values repeat (text: ids, kinds, decisions): Arrow tries it on
    # every column and falls back page by page on measured floats, which took half the writing time
    # (2 000-photo observations: 0.51 → 0.23 s, 63 → 56 MB; the values are the same)
    text = [f.name for f in t.schema if pa.types.is_string(f.type) or pa.types.is_large_string(f.type)
            or pa.types.is_dictionary(f.type)]
    pq.write_table(t, str(path), compression="zstd", use_dictionary=text, memory_pool=POOL)


CHUNK_ROWS = 1 << 16
"""Rows of a table converted to Arrow and written at a time (:func:`write_table`): a numeric column
that is a strided view (``r[:, 0]``) is copied by Arrow, so a whole per-observation table would be
copied at once (70 MB at 2 000 photos) while the stage's arrays are still held."""


def _chunks(table: TableData, stage: str, name: str):
    """``(schema, iterator of Arrow tables of at most CHUNK_ROWS rows)``: numeric and boolean numpy
    columns converted slice by slice, every other column (text, lists) converted once and sliced
    (so each column has one type in every chunk)."""
    n = table_rows(table)
    whole = {}
    for col, values in table.columns.items():
        if not (isinstance(values, np.ndarray) and values.ndim == 1 and values.dtype.kind in "fbiu"):
            whole[col] = column_array(values, col)
    first = _arrow_rows(table, whole, 0, min(n, CHUNK_ROWS), stage, name)

    def gen():
        yield first
        for s in range(CHUNK_ROWS, n, CHUNK_ROWS):
            yield _arrow_rows(table, whole, s, min(n, s + CHUNK_ROWS), stage, name).cast(first.schema)
    return first.schema, whole, gen()


def _arrow_rows(table, whole, s, e, stage, name) -> pa.Table:
    cols = {c: (whole[c].slice(s, e - s) if c in whole else v[s:e]) for c, v in table.columns.items()}
    units = dict(table.units or {})
    return to_arrow(TableData(cols, table.description, units={c: units.get(c, "") for c in cols}), stage=stage,
                    name=name)


def write_table(directory: str | Path, stem: str, table: TableData, *, stage: str = "",
                name: str = "") -> dict:
    """Write ``<stem>.csv`` and ``<stem>.parquet`` into ``directory``; returns the pointer entry
    of ``results.json``: ``{"csv", "parquet", "rows", "columns": {column: unit}}``.  A table of more
    than :data:`CHUNK_ROWS` rows is converted and written that many rows at a time (the Parquet
    file then has one row group per chunk; the values and the CSV text are the same)."""
    directory = Path(directory)
    units = dict(table.units or {})
    n = table_rows(table)
    if n <= CHUNK_ROWS:
        t = to_arrow(table, stage=stage, name=name or stem)
        write_csv(directory / f"{stem}.csv", t)
        write_parquet(directory / f"{stem}.parquet", t)
        rows = t.num_rows
    else:
        rows = _write_chunked(directory, stem, table, stage, name or stem)
    return {"csv": f"{stem}.csv", "parquet": f"{stem}.parquet", "rows": rows,
            "columns": {c: str(units.get(c, "")) for c in table.columns}}


def _write_chunked(directory: Path, stem: str, table: TableData, stage: str, name: str) -> int:
    schema, whole, chunks = _chunks(table, stage, name)
    style = "needed" if _needs_quotes(pa.table(list(whole.values()), names=list(whole)) if whole else None) else "none"
    head = io.StringIO()
    csv.writer(head, lineterminator="\n").writerow(schema.names)
    text = [f.name for f in schema if pa.types.is_string(f.type) or pa.types.is_large_string(f.type)
            or pa.types.is_dictionary(f.type)]
    rows = 0
    with open(directory / f"{stem}.csv", "wb") as fh, \
            pq.ParquetWriter(str(directory / f"{stem}.parquet"), schema, compression="zstd", use_dictionary=text,
                             memory_pool=POOL) as pw:
        fh.write(head.getvalue().encode("utf-8"))
        for t in chunks:
            if t.num_rows:
                pa_csv.write_csv(t, fh, write_options=pa_csv.WriteOptions(include_header=False, quoting_style=style),
                             memory_pool=POOL)
            pw.write_table(t)
            rows += t.num_rows
    return rows


@dataclass
class Written:
    """What :func:`write_tables` did: the pointers by table name, the files, the skipped tables."""

    tables: dict[str, dict] = field(default_factory=dict)
    files: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    """Names of tables marked ``detail`` not written (``outputs = "summary"``)."""


def table_rows(table: TableData) -> int:
    """Rows of a table (its longest column), without converting it."""
    return max((len(v) for v in table.columns.values() if hasattr(v, "__len__")), default=0)


def write_tables(directory: str | Path, stage_id: str, tables: Mapping[str, TableData], *,
                 outputs: str = "full", progress=None) -> Written:
    """Write a stage's tables as ``<stage id>_<name>.csv`` / ``.parquet``; with ``outputs =
    "summary"`` the tables marked ``detail`` are skipped (their names in ``skipped``).
    ``progress`` (a :class:`~baarda.pipeline.stage.Progress`) shows a bar over the rows written."""
    if outputs not in OUTPUTS:
        raise ValueError(f"outputs must be one of {', '.join(OUTPUTS)}, got {outputs!r}")
    done = Written()
    todo = {}
    for name, table in tables.items():
        if outputs == "summary" and table.detail:
            done.skipped.append(name)
        else:
            todo[name] = table
    rows = {name: max(1, table_rows(t)) for name, t in todo.items()}
    bar = progress.bar(sum(rows.values()), "tables", unit="rows") if progress is not None and todo else None
    try:
        for name, table in todo.items():
            entry = write_table(directory, f"{stage_id}_{name}", table, stage=stage_id, name=name)
            done.tables[name] = entry
            done.files += [entry["csv"], entry["parquet"]]
            if bar is not None:
                bar.update(rows[name], last=name)
    finally:
        if bar is not None:
            bar.close()
    return done


def skipped_note(stage_id: str, skipped: Iterable[str]) -> str:
    """The report's line for tables left out by ``outputs = "summary"`` (empty when none)."""
    names = [f"{stage_id}_{n}" for n in skipped]
    if not names:
        return ""
    return ("Not written (run option outputs = \"summary\"; outputs = \"full\" writes them): "
            + ", ".join(f"`{n}.csv`/`.parquet`" for n in names) + ".")


def read_table(path: str | Path) -> pa.Table:
    """A table written by :func:`write_table` (``.parquet`` or ``.csv``) as an Arrow table."""
    path = Path(path)
    if path.suffix == ".parquet":
        return pq.read_table(path)
    return pa_csv.read_csv(path)


def units_of(path: str | Path) -> dict[str, str]:
    """``{column: unit}`` from a Parquet file's field metadata."""
    schema = pq.read_schema(path)
    return {f.name: (f.metadata or {}).get(b"unit", b"").decode() for f in schema}
