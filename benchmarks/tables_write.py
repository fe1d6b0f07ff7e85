"""Writing a stage's tables: pyarrow (CSV + Parquet, :mod:`baarda.pipeline.tables`) against the
cell-by-cell Python CSV writer it replaced (``report.write_table`` before issue 22, kept below as
the reference), in process, on a synthetic table of the 2 000-photo case's size.

    .venv/bin/python benchmarks/tables_write.py [--rows 600000] [--columns 20] [--seed 1]

The table looks like ``bundle_observations``: two id columns (lists of str, as the stage builds
them), float64 columns (NaN in a few cells), one bool and one text decision column.  Prints the
seconds of each writer, the file sizes and the ratio old / new; then checks that the CSVs read back
(Python's csv module) as the same numbers — the old writer's shortened small values (7 digits
below 1e-4) to its precision, the new one's bit for bit.  A benchmark, not a test: the numbers go
to docs/benchmarks.md ("Writing tables").
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from baarda.pipeline.stage import TableData
from baarda.pipeline.tables import write_table


def _old_cell(v: Any) -> Any:
    """``report._cell`` before issue 22 (the reference)."""
    if isinstance(v, (np.bool_, bool)):
        return "true" if v else "false"
    if isinstance(v, (float, np.floating)):
        f = float(v)
        if math.isnan(f):
            return ""
        return repr(f) if abs(f) >= 1e-4 or f == 0 else f"{f:.6e}"
    if isinstance(v, np.integer):
        return int(v)
    return v


def old_write_table(path: Path, table: TableData) -> None:
    """``report.write_table`` before issue 22: every cell through Python."""
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(list(table.columns))
        for row in table.rows():
            w.writerow([_old_cell(v) for v in row.values()])


def synthetic(rows: int, columns: int, seed: int) -> TableData:
    rng = np.random.default_rng(seed)
    photo = rng.integers(0, 2000, rows).astype(str).tolist()
    point = rng.integers(0, 150_000, rows).astype(str).tolist()
    cols: dict[str, Any] = {"photo": photo, "point": point}
    n_float = max(columns - 4, 1)
    for k in range(n_float):
        x = rng.normal(size=rows) * 10.0 ** rng.integers(-6, 4)
        x[rng.random(rows) < 0.01] = np.nan
        cols[f"f{k}_px"] = x
    cols["active"] = rng.random(rows) > 0.01
    cols["decision"] = np.where(rng.random(rows) < 0.001, "flagged", "ok").tolist()
    return TableData(cols, "synthetic per-observation table", units={f"f{k}_px": "px" for k in range(n_float)},
                     detail=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=600_000)
    ap.add_argument("--columns", type=int, default=20)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args(argv)
    table = synthetic(a.rows, a.columns, a.seed)
    print(f"table: {a.rows} rows × {len(table.columns)} columns", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        t0 = time.perf_counter()
        write_table(d, "new", table)
        t_new = time.perf_counter() - t0
        t0 = time.perf_counter()
        old_write_table(d / "old.csv", table)
        t_old = time.perf_counter() - t0
        mb = {p.name: p.stat().st_size / 1e6 for p in d.iterdir()}
        print(f"old write_table (csv, Python cells): {t_old:8.2f} s  old.csv {mb['old.csv']:.0f} MB")
        print(f"pyarrow (csv + parquet):             {t_new:8.2f} s  new.csv {mb['new.csv']:.0f} MB, "
              f"new.parquet {mb['new.parquet']:.0f} MB")
        print(f"ratio old / new: {t_old / t_new:.1f}", flush=True)
        # the same numbers: every float column read back from both CSVs
        with open(d / "old.csv", newline="") as fo, open(d / "new.csv", newline="") as fn:
            ro, rn = csv.reader(fo), csv.reader(fn)
            head = next(ro)
            assert next(rn) == head, "headers differ"
            fcols = [i for i, h in enumerate(head) if h.startswith("f")]
            worst = 0.0
            for k, (a_row, b_row) in enumerate(zip(ro, rn)):
                for i in fcols:
                    x, y = a_row[i], b_row[i]
                    if x == "" or y == "":
                        assert x == y, (k, head[i], x, y)
                        continue
                    truth = float(table.columns[head[i]][k])
                    assert float(y) == truth, (k, head[i], y, truth)
                    worst = max(worst, abs(float(x) - truth) / abs(truth) if truth else 0.0)
        print(f"new CSV: every float bit for bit; old CSV: largest relative rounding {worst:.1e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
