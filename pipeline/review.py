"""``baarda review``: what a run found and where to look, read back from its files.

One line per stage (status, time, its headline), the warnings, then for every stage that flagged
or rejected something: how many rows of which table (``<stage>_<table>.csv``, the column that
says so, the first few ids), the recording and its views to open, and the report section.  Then
the recordings: their layout (views by kind) and whether they share one recording id.  With
``entities`` every entity of every recording is listed as well.
"""

from __future__ import annotations

import csv
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

DECISION_COLUMNS = ("decision", "flagged", "T2d_flagged", "beyond_tolerance", "rejected")
"""Columns of a stage's tables that mark rows as flagged or rejected (a word or a true value); a table
with ``decision`` is read by that column alone (the one verdict per row, docs/statistics.md)."""
FLAG_WORDS = ("flagged", "rejected", "reject", "downweighted", "true")
ID_COLUMNS = ("observation", "label", "point", "photo", "fiducial")


@dataclass
class Flagged:
    table: str
    column: str
    rows: int
    total: int
    examples: list[str] = field(default_factory=list)
    by_value: dict[str, int] = field(default_factory=dict)


def flagged_rows(path: Path, most: int = 5) -> list[Flagged]:
    """The flagged rows of one CSV table, per decision column (empty when it has none)."""
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            names = reader.fieldnames or []
            cols = ["decision"] if "decision" in names else [c for c in names if c in DECISION_COLUMNS]
            if not cols:
                return []
            idcols = [c for c in ID_COLUMNS if c in (reader.fieldnames or [])][:2]
            found = {c: Flagged(path.name, c, 0, 0) for c in cols}
            for row in reader:
                for c in cols:
                    f = found[c]
                    f.total += 1
                    v = str(row.get(c, "")).strip().lower()
                    if v in FLAG_WORDS:
                        f.rows += 1
                        f.by_value[v] = f.by_value.get(v, 0) + 1
                        if len(f.examples) < most:
                            f.examples.append("/".join(str(row[i]) for i in idcols) or f"row {f.total}")
    except (OSError, UnicodeDecodeError, csv.Error):
        return []
    return [f for f in found.values() if f.rows]


def _views(summary, stage: str) -> str:
    kinds = Counter(v.kind for v in summary.views if v.origin == f"/{stage}" or v.origin.startswith(f"/{stage}/"))
    names = {"3D": "3-D", "2D": "2-D", "TimeSeries": "time series", "TextDocument": "text", "BarChart": "bar chart"}
    parts = [f"{n} {names.get(k, k)}" for k, n in sorted(kinds.items(), key=lambda kv: -kv[1])]
    return ", ".join(parts) if parts else "no blueprint (the viewer lays it out itself)"


def _photo_views(summary, stage: str) -> list[str]:
    return [v.origin.removeprefix(f"/{stage}/") for v in summary.views
            if v.kind == "2D" and v.origin.startswith(f"/{stage}/")]


def protocol_counts(st: dict) -> dict[str, int]:
    """Flagged / rejected counts of a stage from its results.json protocol (``tests``): the numbers the
    report prints, also when the tables were not written (``outputs = "summary"``)."""
    s = st.get("summary") or {}
    t = ((s.get("protocol") or {}).get("tests") or {}) if isinstance(s, dict) else {}
    out = {"flagged": int(t.get("n_flagged") or 0) if not t.get("decided_by") else int(t.get("n_decided") or 0),
           "rejected": int(t.get("n_rejected") or 0)}
    return {k: v for k, v in out.items() if v}


def global_verdict(st: dict) -> str:
    """The stage's global test as one phrase ("accepted, p = 0.41"), "" when it has none."""
    s = st.get("summary") or {}
    g = ((s.get("protocol") or {}).get("global_test")) if isinstance(s, dict) else None
    if not g:
        return ""
    verdict = g.get("verdict") or ("rejected" if g.get("rejected") else "accepted")
    p = g.get("p_value")
    return verdict + (f", p = {float(p):.3g}" if p is not None else "")


def _finding(st: dict) -> str:
    if st.get("status") not in (None, "ok"):
        return str(st.get("error") or st.get("status"))
    s = st.get("summary") or {}
    if isinstance(s, dict) and s.get("headline"):
        return str(s["headline"])
    if isinstance(s, dict) and "photos" in s and "observations" in s:
        return (f"read {s.get('photos')} photo(s), {s.get('points', '?')} point(s), "
                f"{s.get('observations')} observation(s)")
    return ""


def print_review(run_dir: Path, results: dict, recordings: dict, *, entities: bool = False, out=None) -> None:
    """Print the review of ``run_dir`` (``results.json`` as a dict, recordings by stage id)."""
    import sys

    out = out or sys.stdout

    def say(text: str = "") -> None:
        print(text, file=out)

    stages = list(results.get("stages", []))
    known = {s["id"] for s in stages}
    stages += [{"id": sid, "use": "?", "status": "?"} for sid in recordings if sid not in known]
    if results:
        ok = sum(s.get("status") == "ok" for s in stages)
        verdict = "every stage ok" if ok == len(stages) else f"{ok} of {len(stages)} stages ok"
        say(f"project: {results['project']['name']}  (baarda {results.get('baarda_version')}, "
            f"started {results.get('started')}) — {verdict}")
    say()
    w = max((len(s["id"]) for s in stages), default=5)
    say(f"  {'stage':<{w}}  {'status':<11} {'time (s)':>8}  finding")
    for s in stages:
        finding = _finding(s)
        say(f"  {s['id']:<{w}}  {str(s.get('status')):<11} {float(s.get('seconds') or 0):>8.2f}  "
            f"{finding[:150]}{' …' if len(finding) > 150 else ''}")

    warnings = [(s["id"], wt) for s in stages for wt in s.get("warnings") or []]
    if warnings:
        say(f"\nWarnings ({len(warnings)}):")
        for sid, wt in warnings[:20]:
            say(f"  [{sid}] {wt}")
        if len(warnings) > 20:
            say(f"  … {len(warnings) - 20} more in report.md")

    say("\nFlagged or rejected — where to look:")
    any_flag = False
    for s in stages:
        sid = s["id"]
        found = [f for t in sorted(run_dir.glob(f"{sid}_*.csv")) for f in flagged_rows(t)]
        counts = protocol_counts(s)
        if not found and counts:     # flagged, but no table says so (outputs = "summary")
            any_flag = True
            say(f"  {sid}: " + ", ".join(f"{n} {k}" for k, n in counts.items())
                + " (results.json; no table with a decision column was written)")
            say(f"    report.md, section '{sid}'")
            continue
        if not found:
            continue
        any_flag = True
        gv = global_verdict(s)
        say(f"  {sid}:" + (f" global test {gv}" if gv else ""))
        for f in found:
            vals = ", ".join(f"{n} {v}" for v, n in sorted(f.by_value.items()))
            ex = ", ".join(f.examples) + (" …" if f.rows > len(f.examples) else "")
            say(f"    {f.table}, column {f.column}: {f.rows} of {f.total} rows ({vals}): {ex}")
        rec = recordings.get(sid)
        if rec is not None:
            photos = _photo_views(rec, sid)
            where = f"{sid}.rrd" + (f": the 2-D views {', '.join(photos[:6])}{' …' if len(photos) > 6 else ''}"
                                    if photos else "")
            say(f"    recording {where}")
        say(f"    report.md, section '{sid}'")
    if not any_flag:
        say("  nothing: no stage's table marks a row as flagged or rejected")

    say(f"\nRecordings ({len(recordings)}), each laid out by its blueprint:")
    ids = set()
    for sid, rec in recordings.items():
        ids.add(rec.recording_id)
        say(f"  {sid}.rrd: {len(rec.entities)} entities under /{sid}; views: {_views(rec, sid)}")
        if entities:
            for e in rec.entities:
                tl = f" over {', '.join(e.timelines)}" if e.timelines else (" static" if e.static else "")
                cols = ", ".join(c for c in e.columns[:6])
                more = f" (+{len(e.columns) - 6})" if len(e.columns) > 6 else ""
                say(f"    {e.path}  rows={e.rows}{tl}  [{cols}{more}]")
    if len(ids) == 1:
        say(f"They share recording id {ids.pop()}: opened together they are one recording.")
    else:
        say(f"warning: the recordings carry {len(ids)} different recording ids")
    if not entities:
        say("Every entity: baarda review --entities " + str(run_dir))
    say(f"Open them (in run order: the last stage's file holds the whole run's layout):  baarda view {run_dir}")
