"""One truth per number: a run's protocol summary (report.md), its results.json and its tables agree.

:func:`check_run` is called on every bundled project's run (``tests/pipeline/test_fixtures.py``):

* the lines of report.md's protocol summary and the global-test line are those that the same
  formatting functions (``protocol_lines``, ``global_test_text``) make of results.json's protocol —
  so every number printed there is results.json's value, formatted once;
* the protocol's counts and RMS are recomputed from the stage's observations table: the w-test's
  flagged count from the w columns against the printed critical value, the points whose ``decision``
  is ``flagged`` from the same w columns, the RMS of the residual columns of the coordinates in the
  adjustment.
"""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path

from baarda.pipeline.protocol import global_test_text
from baarda.plugins.bundle.protocol import protocol_lines

#: a residual column's unit suffix → its factor to the protocol's unit
_FACTORS = {("um", "µm"): 1.0, ("mm", "µm"): 1000.0, ("mm", "mm"): 1.0, ("um", "mm"): 1e-3, ("px", "px"): 1.0}


def _read(path: Path) -> tuple[list[str], list[dict]]:
    with path.open(newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        return list(reader.fieldnames or []), list(reader)


def _num(text) -> float:
    try:
        return float(text)
    except (TypeError, ValueError):
        return math.nan


def _column(names: list[str], base: str, unit: str | None) -> tuple[str | None, float | None]:
    """The column of ``base`` (``vx``, ``v``, ``wx``, …) and its factor to ``unit`` (None: unitless)."""
    alt = base[0] + "_" + base[1:] if len(base) > 1 else base
    if unit is None:
        return next(((c, 1.0) for c in (base, alt) if c in names), (None, None))
    for suffix in ("um", "mm", "px"):
        for c in (f"{base}_{suffix}", f"{alt}_{suffix}"):
            if c in names and (suffix, unit) in _FACTORS:
                return c, _FACTORS[(suffix, unit)]
    if base in names and unit in ("µm", "mm"):     # unsuffixed residuals: mm (docs/conventions.md)
        return base, _FACTORS[("mm", unit)]
    return None, None


def _rms(values: list[float]) -> float:
    return math.sqrt(sum(v * v for v in values) / len(values)) if values else math.nan


def check_run(run_dir: Path) -> int:
    """Check every stage of ``run_dir`` that has a protocol; returns how many protocols were checked."""
    run_dir = Path(run_dir)
    results = json.loads((run_dir / "results.json").read_text(encoding="utf-8"))
    report = (run_dir / "report.md").read_text(encoding="utf-8")
    checked = 0
    for st in results["stages"]:
        p = (st.get("summary") or {}).get("protocol")
        if not isinstance(p, dict) or "sigma0_hat" not in p:
            continue
        checked += 1
        sid = st["id"]
        if p.get("kind") == "bundle":
            # the summary lines are results.json's protocol through the one formatting function
            for line in protocol_lines(p):
                if line.strip():
                    assert line in report, f"{sid}: report.md lacks the protocol line {line!r}"
        g = p.get("global_test")
        if g and math.isfinite(g.get("T", math.nan)):       # T = σ̂0²/σ0², the σ̂0 the protocol reports
            assert g["T"] == pytest_approx((p["sigma0_hat"] / p["sigma0"]) ** 2, rel=1e-9), sid
        if g and g.get("p_value") is not None and math.isfinite(g.get("T", math.nan)) and st["use"] == "bundle":
            assert global_test_text(g) in report, f"{sid}: report.md lacks {global_test_text(g)!r}"
        table = run_dir / f"{sid}_observations.csv"
        if table.is_file():
            _check_table(sid, p, *_read(table))
    return checked


def _check_table(sid: str, p: dict, names: list[str], rows: list[dict]) -> None:
    t = p.get("tests") or {}
    unit = p.get("unit") or ""
    per_point = "wx" in names or "w_x" in names
    bases = (("wx", "wy"), ("vx", "vy")) if per_point else (("w",), ("v",))
    wcols = [_column(names, b, None)[0] for b in bases[0]]
    vcols = [_column(names, b, unit) for b in bases[1]]
    if None in wcols or "decision" not in names:
        return
    K = float(t["critical_w"])
    state = [r["decision"] for r in rows]
    if per_point:      # bundle: one row per image point; rejected and inactive points are not adjusted
        used = [s_ not in ("rejected", "inactive") for s_ in state]
    else:              # one row per scalar observation of the tested adjustment: its own active flag
        used = [r.get("active", "true").strip().lower() != "false" for r in rows]
    exceed = [[abs(_num(r[c])) > K for c in wcols] for r in rows]
    if per_point and {"rx", "ry"} <= set(names):
        # a point with one coordinate rejected keeps the other in the adjustment (its r > 0): that one is tested
        kept = [[s_ != "inactive" and (s_ != "rejected" or _num(r[rc]) > 0) for rc in ("rx", "ry")]
                for s_, r in zip(state, rows)]
        n_flagged = sum(e and k for ex, ks in zip(exceed, kept) for e, k in zip(ex, ks))
    else:
        n_flagged = sum(e for u, ex in zip(used, exceed) if u for e in ex)
    assert n_flagged == t["n_flagged"], (f"{sid}: the protocol counts {t['n_flagged']} coordinates with |w| > {K}, "
                                         f"the table's w columns {n_flagged}")
    if per_point:      # a point is flagged when a coordinate's |w| exceeds K and it is kept
        flagged = {i for i, s_ in enumerate(state) if s_ == "flagged"}
        expect = {i for i, (u, ex) in enumerate(zip(used, exceed)) if u and any(ex) and state[i] != "downweighted"}
        assert flagged == expect, f"{sid}: decision = flagged on {len(flagged)} points, |w| > K on {len(expect)}"
    else:              # blunder-rejection: the decisive method's decisions, as the protocol counts them
        n = sum(s_ in ("flagged", "rejected") for s_ in state)
        if "n_decided" in t or "n_rejected" in t:
            decided = int(t.get("n_decided") or 0) + int(t.get("n_rejected") or 0)
            rows_of = {r.get("observation") for r, s_ in zip(rows, state) if s_ == "rejected"}
            if not rows_of - {""} or not t.get("n_rejected"):
                assert n == decided, f"{sid}: decision marks {n} rows, the protocol {decided}"
    rms = p.get("rms") or {}
    partial = per_point and "rejected" in state      # IDS rejects one coordinate, the table marks the point
    if None not in [c for c, _ in vcols] and rms.get("all") is not None and math.isfinite(rms["all"]) and not partial:
        vals = [_num(r[c]) * f for r, u in zip(rows, used) if u for c, f in vcols]
        vals = [v for v in vals if math.isfinite(v)]
        got = _rms(vals)
        assert got == pytest_approx(rms["all"]), f"{sid}: RMS {rms['all']} {unit} in the protocol, {got} from the table"


def pytest_approx(value: float, rel: float = 2e-6):
    import pytest

    return pytest.approx(value, rel=rel, abs=1e-12)
