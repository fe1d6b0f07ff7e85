"""Compare two sets of run directories number by number (a refactoring must not change results).

    python tests/regression/compare_runs.py BEFORE AFTER [--rtol 1e-9]

BEFORE and AFTER each hold one run directory per bundled project (as written by
``tests/regression/run_fixtures.sh``).  For every project present in both, ``results.json`` and every
``*.csv`` are compared: numbers to ``rtol`` relative (``atol`` absolute near zero), text exactly.
Wall-clock fields (``seconds``, ``started``, timings), the recording id and absolute paths are
ignored.  Prints one line per difference and a summary; exit 1 when anything differs.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path

IGNORED_KEYS = {"seconds", "started", "recording_id", "file", "prefix", "timings", "time_s", "elapsed",
                "setup_s", "solve_s", "covariance_s", "baarda_version"}


def _num(x):
    if isinstance(x, bool):
        return None
    if isinstance(x, (int, float)):
        return float(x)
    if isinstance(x, str):
        try:
            return float(x)
        except ValueError:
            return None
    return None


def _close(a: float, b: float, rtol: float, atol: float) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return a == b or abs(a - b) <= max(atol, rtol * max(abs(a), abs(b)))


def compare_values(a, b, where: str, rtol: float, atol: float, out: list[str]) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k in IGNORED_KEYS or k.endswith(("_seconds", "_s")):
                continue
            if k not in a or k not in b:
                out.append(f"{where}/{k}: only in {'after' if k not in a else 'before'}")
                continue
            compare_values(a[k], b[k], f"{where}/{k}", rtol, atol, out)
        return
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out.append(f"{where}: length {len(a)} → {len(b)}")
        for i, (x, y) in enumerate(zip(a, b)):
            compare_values(x, y, f"{where}[{i}]", rtol, atol, out)
        return
    na, nb = _num(a), _num(b)
    if na is not None and nb is not None:
        if not _close(na, nb, rtol, atol):
            out.append(f"{where}: {a!r} → {b!r}")
    elif a != b and not (isinstance(a, str) and isinstance(b, str) and ("/" in a or "\\" in a)):
        out.append(f"{where}: {a!r} → {b!r}")


def compare_csv(pa: Path, pb: Path, rtol: float, atol: float, out: list[str]) -> None:
    ra = list(csv.reader(pa.open()))
    rb = list(csv.reader(pb.open()))
    if len(ra) != len(rb):
        out.append(f"{pa.name}: {len(ra)} rows → {len(rb)}")
    for i, (x, y) in enumerate(zip(ra, rb)):
        if i == 0 and x != y:
            out.append(f"{pa.name}: header {x} → {y}")
            continue
        compare_values(x, y, f"{pa.name}:{i + 1}", rtol, atol, out)


def compare_run(before: Path, after: Path, rtol: float, atol: float) -> list[str]:
    out: list[str] = []
    ja, jb = before / "results.json", after / "results.json"
    if ja.is_file() and jb.is_file():
        compare_values(json.loads(ja.read_text()), json.loads(jb.read_text()), "results.json", rtol, atol, out)
    elif ja.is_file() != jb.is_file():
        out.append(f"results.json only {'before' if ja.is_file() else 'after'}")
    names_a = {p.name for p in before.glob("*.csv")}
    names_b = {p.name for p in after.glob("*.csv")}
    for n in sorted(names_a ^ names_b):
        out.append(f"{n}: only {'before' if n in names_a else 'after'}")
    for n in sorted(names_a & names_b):
        compare_csv(before / n, after / n, rtol, atol, out)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", type=Path)
    ap.add_argument("after", type=Path)
    ap.add_argument("--rtol", type=float, default=1e-9)
    ap.add_argument("--atol", type=float, default=1e-12)
    ap.add_argument("--max-lines", type=int, default=20, help="differences printed per project")
    a = ap.parse_args(argv)
    total = 0
    for run in sorted(p for p in a.before.iterdir() if p.is_dir()):
        other = a.after / run.name
        if not other.is_dir():
            print(f"{run.name}: missing after")
            total += 1
            continue
        diffs = compare_run(run, other, a.rtol, a.atol)
        total += len(diffs)
        print(f"{run.name}: {'same' if not diffs else f'{len(diffs)} differences'}")
        for d in diffs[: a.max_lines]:
            print(f"    {d}")
    print(f"{total} differences in all")
    return 1 if total else 0


if __name__ == "__main__":
    sys.exit(main())
