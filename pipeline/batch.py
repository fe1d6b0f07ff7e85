"""Many runs at once: ``baarda batch`` (a list of projects, a glob, or one project with a sweep
table) through the Dask engine of :mod:`baarda.pipeline.montecarlo`.

A batch directory holds

* ``runs/<name>/`` — one run directory per run, written by the ordinary runner
  (:func:`baarda.pipeline.runner.run_project`) with its rules (staging directory, a failed
  re-run never replaces a complete one, foreign files refused);
* ``projects/<name>.toml`` — the project file of each sweep row (the base project with the row's
  options, input paths made absolute), so that every run can be repeated with ``baarda run``;
* ``summary.csv`` and ``summary.md`` — one row per run: status, failure kind and message,
  seconds, stages ok, the sweep's values and the stages' numeric summary figures
  (``<stage>.<figure>``);
* ``batch.json`` — the same rows, typed (:func:`summary_rows` reads them back, e.g. for an
  HTML report), and what ran them.

A failed run is a row with its status; it never stops the other runs.  A sweep table is a CSV
whose header names ``<stage id>.<option>`` columns (``<stage id>.<table>.<option>`` for an option
of a nested table, ``bundle.solver.max_iter``; the stage id is what the column starts with, the
rest the option's dotted path, applied as ``--set`` applies it) and optionally ``name``, one run per row,
cells read as TOML values (``0.01``, ``true``, ``"text"``, ``[1, 2]``; a bare word is a string),
or a TOML file of ``[[run]]`` tables with the same keys.  A column ``project`` names a row's own
project file (relative to the table; an empty cell: the project given), so one table may sweep
several projects: each row runs its own project, never another.  Every name and value is checked
against the stage's options of the row's project before anything runs (an InputError naming the
table, its line and the column).
"""

from __future__ import annotations

import csv
import datetime as _dt
import glob as _glob
import io
import json
import re
import time
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

from . import __version__
from .errors import BaardaError, InputError
from .html import escape, markdown_html
from .montecarlo import Engine
from .plugins import PluginManager
from .project import Overrides, load_project, path_roles, toml_value, with_overrides
from .report import markdown_table, write_toml
from .review import protocol_counts
from .runner import run_project

__all__ = ["BatchJob", "plan_batch", "read_sweep", "run_batch", "run_job", "summary_rows", "write_summary",
           "BATCH_MARKER"]

BATCH_MARKER = "batch.json"
BASE_COLUMNS = ["name", "status", "failure", "message", "seconds", "stages_ok", "stages", "run_dir", "project"]
"""The summary's first columns; then the quality columns, the sweep's ``stage.option`` values, then the
figures."""
QUALITY_COLUMNS = ["adjustment", "sigma0_hat", "dof", "global_test", "global_test_p", "n_flagged", "n_rejected",
                   "check_n", "check_rmse_x", "check_rmse_y", "check_rmse_z", "check_unit", "camera", "n_cameras"]
"""What compares runs (:func:`quality`): the protocol of the run's main adjustment (its bundle, else its
last adjustment): σ̂0 (unitless variance factor), the global test's verdict and p-value, the flagged and
rejected counts, the check-point RMSE (in ``check_unit``), then the first camera's parameters as
``camera.<name>_<unit>`` columns (c, principal point and the main APs)."""
CAMERA_PARAMETERS = ("c", "xp", "yp", "K1", "K2", "K3", "P1", "P2")
_UNIT_SUFFIX = {"mm": "mm", "px": "px", "µm": "um", "m": "m", "mm⁻²": "per_mm2", "mm⁻⁴": "per_mm4",
                "mm⁻⁶": "per_mm6", "mm⁻¹": "per_mm", "px⁻²": "per_px2", "px⁻⁴": "per_px4", "px⁻⁶": "per_px6",
                "px⁻¹": "per_px", "1": "", "": ""}


@dataclass(frozen=True)
class BatchJob:
    """One run of a batch."""

    name: str
    project: Path                 # the project file to run
    out: Path                     # its run directory
    source: str = ""              # where it came from (project file, or sweep table and line)
    overrides: dict = field(default_factory=dict)   # {"stage.option": value}


# ---------------------------------------------------------------------------------------- planning
def expand_projects(patterns: list[str]) -> list[Path]:
    """Project files named by paths or glob patterns, in order, each once."""
    out: list[Path] = []
    for pat in patterns:
        if _glob.has_magic(pat):
            hits = sorted(Path(p) for p in _glob.glob(pat, recursive=True))
            if not hits:
                raise InputError("no project file matches this pattern", path=pat)
        else:
            p = Path(pat)
            if not p.exists():
                raise InputError("project file not found", path=p)
            hits = sorted(p.glob("*.toml")) if p.is_dir() else [p]
            if not hits:
                raise InputError("no project file (*.toml) in this folder", path=p)
        for h in hits:
            if h.resolve() not in {q.resolve() for q in out}:
                out.append(h)
    return out


def _unique_names(names: list[str]) -> list[str]:
    seen: dict[str, int] = {}
    out = []
    for n in names:
        n = re.sub(r"[^A-Za-z0-9_.-]+", "-", n).strip("-.") or "run"
        k = seen.get(n, 0)
        seen[n] = k + 1
        out.append(n if k == 0 else f"{n}-{k + 1}")
    return out


def plan_batch(projects: list[str | Path], out: str | Path, sweep: str | Path | None = None,
               plugins=None) -> list[BatchJob]:
    """The runs of a batch: every project of ``projects`` (paths or globs), or — with ``sweep`` —
    one run per row of the sweep table applied to the one project.  Checks the projects (and the
    sweep's names and values) and writes the sweep's project files into ``out/projects``."""
    plugins = plugins or PluginManager()
    out = Path(out)
    paths = expand_projects([str(p) for p in projects])
    if sweep is None:
        names = _unique_names([p.stem for p in paths])
        return [BatchJob(name=n, project=p, out=out / "runs" / n, source=str(p)) for n, p in zip(names, paths)]
    if len(paths) != 1:
        raise InputError(f"a sweep applies to one project; {len(paths)} were given (a sweep over several projects "
                         f"names each row's project file in a column '{PROJECT_COLUMN}')", path=sweep,
                         field="--sweep")
    base = load_project(paths[0], plugins)
    rows = read_sweep(sweep, base, plugins)
    out = open_batch(out)
    names = _unique_names([r["name"] or f"{r['project'].path.stem}-{k + 1:03d}" for k, r in enumerate(rows)])
    (out / "projects").mkdir(parents=True, exist_ok=True)
    jobs = []
    for name, row in zip(names, rows):
        path = out / "projects" / f"{name}.toml"
        _write_variant(row["project"], row["overrides"], name, path, plugins)
        jobs.append(BatchJob(name=name, project=path, out=out / "runs" / name,
                             source=f"{sweep}:{row['line']}", overrides=dict(row["overrides"])))
    return jobs


PROJECT_COLUMN = "project"
"""The sweep column (CSV) or ``[[run]]`` key (TOML) naming a row's own project file (relative to the
sweep table); an empty cell: the project given on the command line."""


def read_sweep(path: str | Path, project, plugins: PluginManager | None = None) -> list[dict]:
    """Rows of a sweep table, each ``{"name", "line", "project", "overrides": {"stage.option":
    value}}``, every row applied to its project — the one its ``project`` cell names (a path
    relative to the table), else ``project`` — by :func:`~baarda.pipeline.project.with_overrides`
    (the check of ``--set``): its columns against that project's stages and options, its values
    against their types and ranges.  A project file that does not exist or does not load is an
    InputError naming the table's line and the column ``project``."""
    plugins = plugins or PluginManager()
    path = Path(path)
    if not path.is_file():
        raise InputError("sweep table not found" if not path.exists() else "not a file", path=path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as e:
        raise InputError(f"not a UTF-8 text file (byte offset {e.start})", path=path) from None
    rows: list[dict] = []
    if path.suffix.lower() == ".toml":
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            m = re.search(r"line (\d+)", str(e))
            raise InputError(f"not valid TOML: {e}", path=path, line=int(m.group(1)) if m else None) from None
        bad = sorted(set(data) - {"run"})
        if bad:
            raise InputError(f"unknown table '{bad[0]}' (a sweep file holds [[run]] tables)", path=path, field=bad[0])
        runs = data.get("run", [])
        if not isinstance(runs, list) or not all(isinstance(r, dict) for r in runs):
            raise InputError("a sweep file holds [[run]] tables", path=path, field="run")
        starts = [i + 1 for i, ln in enumerate(text.splitlines()) if re.match(r"\s*\[\[\s*run\s*\]\]", ln)]
        for k, r in enumerate(runs):
            line = starts[k] if k < len(starts) else None
            name = r.get("name", "")
            if not isinstance(name, str):
                raise InputError("name must be a string", path=path, line=line, field="name")
            proj = r.get(PROJECT_COLUMN, "")
            if not isinstance(proj, str):
                raise InputError("project must be a string (a project file)", path=path, line=line,
                                 field=PROJECT_COLUMN)
            rows.append({"name": name, "line": line, "project": proj.strip(),
                         "overrides": {c: v for c, v in r.items() if c not in ("name", PROJECT_COLUMN)}})
    else:
        reader = csv.reader(io.StringIO(text))
        try:
            header = next(reader)
        except StopIteration:
            raise InputError("the sweep table is empty (expected a header of stage.option columns)", path=path) from None
        header = [h.strip() for h in header]
        for c in header:
            if not c:
                raise InputError("an empty column name in the header", path=path, line=1)
        dup = [c for c in header if header.count(c) > 1]
        if dup:
            raise InputError(f"column '{dup[0]}' appears twice", path=path, line=1, field=dup[0])
        for cells in reader:
            line = reader.line_num
            if not any(c.strip() for c in cells):
                continue
            if len(cells) != len(header):
                raise InputError(f"{len(cells)} cells for {len(header)} columns", path=path, line=line)
            row = dict(zip(header, cells))
            name = row.pop("name", "").strip()
            proj = row.pop(PROJECT_COLUMN, "").strip()
            rows.append({"name": name, "line": line, "project": proj,
                         "overrides": {c: toml_value(v) for c, v in row.items() if v.strip() != ""}})
    if not rows:
        raise InputError("the sweep table has no runs", path=path)
    named: dict[str, int] = {}       # explicit names, as their folders will be named: each once
    for row in rows:
        if not row["name"]:
            continue
        folder = _unique_names([row["name"]])[0]
        if folder in named:
            raise InputError(f"run name {row['name']!r} (folder runs/{folder}) given twice (first on line "
                             f"{named[folder]}); each row needs its own name", path=path, line=row["line"],
                             field="name")
        named[folder] = row["line"]
    is_toml = path.suffix.lower() == ".toml"
    loaded: dict[Path, Any] = {Path(project.path).resolve(): project}
    for row in rows:       # each row's project: its own, or the one given
        row["project"] = _row_project(row, path, loaded, project, plugins)
    for row in rows:       # names, types and ranges as --set checks them: the table, its line, the column
        with_overrides(row["project"], Overrides(row["overrides"], source=path, line=row["line"],
                                                 name_line=row["line"] if is_toml else 1), plugins)
    return rows


def _row_project(row: dict, table: Path, loaded: dict, default, plugins):
    """The loaded project of a sweep row: its ``project`` cell (relative to the sweep table), or
    ``default``.  A file that is missing, not a file, or does not load is an InputError on the
    row's line and the column ``project`` (a project's own mistake names that project's file)."""
    text = row["project"]
    if not text:
        return default
    p = Path(text).expanduser()
    p = (p if p.is_absolute() else table.parent / p).resolve()
    if p in loaded:
        return loaded[p]
    if not p.is_file():
        raise InputError(f"project file {'not found' if not p.exists() else 'is not a file'}: {p}", path=table,
                         line=row["line"], field=PROJECT_COLUMN)
    try:
        loaded[p] = load_project(p, plugins)
    except InputError as e:
        if e.path is not None and Path(str(e.path)).resolve() == p:    # its own mistake: its file, line, field
            raise InputError(f"{e.message} (the project of {table.name}:{row['line']})", e.path, e.line,
                             e.field) from None
        raise InputError(f"project {p.name}: {e}", path=table, line=row["line"], field=PROJECT_COLUMN) from None
    return loaded[p]


def _write_variant(project, overrides: dict, name: str, path: Path, plugins=None) -> None:
    """The project file of one sweep row: the base project's TOML with the row's options applied
    by :func:`~baarda.pipeline.project.with_overrides` (as ``--set`` applies them: the column
    ``bundle.solver.max_iter`` is the stage ``bundle``'s option ``solver.max_iter``), input paths
    made absolute (the file lives in the batch directory)."""
    variant = with_overrides(project, overrides, plugins)
    data = {k: v for k, v in project.data.items() if k != "stage"}
    by_id = {s.id: s for s in variant.stages}
    stages = []
    for st in project.data.get("stage", []):
        sid = st.get("id", st.get("use"))
        spec = by_id.get(sid) if st.get("enabled", True) else None
        if spec is None:                    # a disabled stage: left as it is
            stages.append(st)
            continue
        opts = dict(spec.raw_options)       # the file's option table with the row's values
        for opt, role in path_roles(spec.cls).items():
            if role == "output" or opt not in opts:
                continue
            opts[opt] = _absolute(opts[opt], project.directory)
        stages.append({**st, "options": opts})
    data["stage"] = stages
    proj = dict(data.get("project", {}))
    proj["name"] = f"{proj.get('name', project.path.stem)} [{name}]"
    proj["description"] = (str(proj.get("description", "")) + f" (batch sweep of {project.path})").strip()
    data["project"] = proj
    write_toml(path, data)


def _absolute(value: Any, base: Path) -> Any:
    if isinstance(value, list):
        return [_absolute(v, base) for v in value]
    if not isinstance(value, str) or not value or value == ".":
        return value
    p = Path(value).expanduser()
    return str(p if p.is_absolute() else (base / p).resolve())


# ---------------------------------------------------------------------------------------- running
def open_batch(out: str | Path) -> Path:
    """Check the batch directory: new, empty, or an earlier batch's (``batch.json``)."""
    out = Path(out).expanduser().absolute()
    if out.exists():
        if not out.is_dir():
            raise InputError("the batch directory exists and is not a directory; choose another --out", path=out)
        if any(out.iterdir()) and not (out / BATCH_MARKER).is_file():
            raise InputError("refusing to write a batch into a non-empty directory that is not a baarda batch "
                             "directory; choose another --out", path=out)
    try:
        (out / "runs").mkdir(parents=True, exist_ok=True)
        if not (out / BATCH_MARKER).is_file():      # marks the directory as a batch's from the start
            write_summary(out, [], total=0)
    except OSError as e:
        raise InputError(f"cannot write the batch directory: {e.strerror or e}", path=out) from None
    return out


def run_job(job: BatchJob) -> dict:
    """Run one project of a batch (on a worker); never raises for a failed run: returns its row."""
    row = {"name": job.name, "status": "failed", "failure": "", "message": "", "seconds": 0.0, "stages_ok": 0,
           "stages": 0, "run_dir": str(job.out), "project": str(job.project), "source": job.source,
           "overrides": dict(job.overrides), "figures": {}}
    t0 = time.perf_counter()
    try:
        outcome = run_project(job.project, job.out, verbose=False)
    except BaardaError as e:
        row.update(failure="input", message=str(e))
    except KeyboardInterrupt:
        row.update(failure="interrupted", message="interrupted")
    except Exception as e:     # noqa: BLE001 - a bug in a stage: reported, the batch goes on
        row.update(failure="internal", message=f"{type(e).__name__}: {str(e).splitlines()[0][:200] if str(e) else ''}")
    else:
        row.update(status="ok" if outcome.ok else "failed", failure=outcome.failure,
                   message=outcome.message.splitlines()[0][:300] if outcome.message else "",
                   stages_ok=sum(r.status == "ok" for r in outcome.stages), stages=len(outcome.stages),
                   run_dir=str(outcome.run_dir), figures=_figures(outcome.stages),
                   quality=quality([{"id": r.id, "summary": r.summary} for r in outcome.stages]))
    row["seconds"] = round(time.perf_counter() - t0, 3)
    return row


def _lost(job: BatchJob, error: BaseException) -> dict:
    """The row of a run whose task did not come back (its worker died, or it could not be sent)."""
    text = str(error).splitlines()[0][:300] if str(error) else ""
    return {"name": job.name, "status": "failed", "failure": "internal",
            "message": f"the task did not complete: {type(error).__name__}: {text}", "seconds": 0.0,
            "stages_ok": 0, "stages": 0, "run_dir": str(job.out), "project": str(job.project), "source": job.source,
            "overrides": dict(job.overrides), "figures": {}}


def _figures(records) -> dict:
    """``{"stage.key": number}`` of every stage's numeric top-level summary values."""
    out = {}
    for r in records:
        for k, v in (r.summary or {}).items():
            if isinstance(v, bool):
                out[f"{r.id}.{k}"] = v
            elif isinstance(v, (int, float)):
                out[f"{r.id}.{k}"] = v
    return out


def main_protocol(stages: list[dict]) -> tuple[str, dict] | None:
    """``(stage id, protocol)`` of a run's main adjustment: its last bundle, else its last adjustment
    with a protocol (``summary["protocol"]``); None when no stage adjusted anything."""
    found = [(s["id"], (s.get("summary") or {}).get("protocol")) for s in stages]
    found = [(sid, p) for sid, p in found if isinstance(p, dict) and "sigma0_hat" in p]
    bundles = [f for f in found if f[1].get("kind") == "bundle"]
    return (bundles or found or [None])[-1]


def quality(stages: list[dict]) -> dict:
    """The quality columns of one run (:data:`QUALITY_COLUMNS`) from its stages' summaries (dicts with
    ``id`` and ``summary``, as results.json holds them): the same numbers as each run's report."""
    found = main_protocol(stages)
    if found is None:
        return {}
    sid, p = found
    g = p.get("global_test") or {}
    t = p.get("tests") or {}
    out: dict[str, Any] = {"adjustment": sid, "sigma0_hat": p.get("sigma0_hat"), "dof": p.get("dof"),
                           "global_test": g.get("verdict") or ("" if not g else ("rejected" if g.get("rejected")
                                                                                  else "accepted")),
                           "global_test_p": g.get("p_value"),
                           "n_flagged": 0, "n_rejected": 0}
    out.update({f"n_{k}": n for k, n in protocol_counts({"summary": {"protocol": p}}).items()})
    ch = p.get("check")
    if ch:
        out.update(check_n=ch.get("n"), check_rmse_x=ch.get("Sx"), check_rmse_y=ch.get("Sy"),
                   check_rmse_z=ch.get("Sz"), check_unit=ch.get("unit", ""))
    cams = p.get("cameras") or []
    if cams:
        cam = cams[0]
        out.update(camera=str(cam.get("camera", "")), n_cameras=len(cams))
        for par in cam.get("parameters") or []:
            if par.get("name") in CAMERA_PARAMETERS:
                suffix = _UNIT_SUFFIX.get(par.get("unit", ""), "")
                out[f"camera.{par['name']}" + (f"_{suffix}" if suffix else "")] = par.get("value")
    out.update(congruence_columns(stages))
    return out


def congruence_columns(stages: list[dict]) -> dict:
    """A monitoring run's congruence result for the batch summary (one row per run, so that a batch of
    epochs reads as one congruence summary): the last comparison of its ``congruence`` stage —
    reference and epoch, the global test's T, p and verdict, the points found moved (count and ids)."""
    for st in reversed(stages):
        comps = (st.get("summary") or {}).get("comparisons")
        if not comps:
            continue
        c = comps[-1]
        g = c.get("global_test") or {}
        moved = [str(m) for m in c.get("moved") or []]
        return {"congruence.reference": c.get("reference"), "congruence.epoch": c.get("epoch"),
                "congruence.T": g.get("T"), "congruence.p": g.get("p"),
                "congruence": "congruent" if g.get("accepted") else "moved",
                "congruence.n_moved": len(moved), "congruence.moved": " ".join(moved[:20])}
    return {}


def run_batch(jobs: list[BatchJob], out: str | Path, engine=None,
              progress: Callable[[str], None] | None = None) -> list[dict]:
    """Run every job on ``engine`` (a :class:`~baarda.pipeline.montecarlo.Engine`; default: the
    local scheduler), write the summary as each run ends, return the rows in job order."""
    out = open_batch(out)
    started = _dt.datetime.now().isoformat(timespec="seconds")
    own = engine is None
    engine = engine or Engine()
    rows: list[dict | None] = [None] * len(jobs)
    t0 = time.perf_counter()
    try:
        for n_done, (k, row) in enumerate(engine.as_completed(run_job, jobs, errors="return"), start=1):
            if isinstance(row, BaseException):      # the worker died (or the task could not run)
                row = _lost(jobs[k], row)
            rows[k] = row
            if progress:
                tail = f" — {row['failure']}: {row['message']}" if row["status"] != "ok" else ""
                progress(f"[{n_done}/{len(jobs)}] {row['name']}: {row['status']} ({row['seconds']:.1f} s){tail}")
            write_summary(out, [r for r in rows if r is not None], started=started,
                          scheduler=engine.scheduler.describe(), seconds=time.perf_counter() - t0,
                          total=len(jobs))
    finally:
        if own:
            engine.close()
    done = [r for r in rows if r is not None]
    write_summary(out, done, started=started, scheduler=engine.scheduler.describe(),
                  seconds=time.perf_counter() - t0, total=len(jobs))
    return done


# ---------------------------------------------------------------------------------------- summary
def _columns(rows: list[dict]) -> tuple[list[str], list[str]]:
    sweep = sorted({c for r in rows for c in r.get("overrides", {})})
    figs = sorted({c for r in rows for c in r.get("figures", {})})
    return sweep, figs


def _quality_columns(rows: list[dict]) -> list[str]:
    have = {c for r in rows for c in (r.get("quality") or {})}
    cams = [f"camera.{n}" for n in CAMERA_PARAMETERS]
    extra = sorted((c for c in have if c not in QUALITY_COLUMNS),
                   key=lambda c: next((k for k, pre in enumerate(cams) if c == pre or c.startswith(pre + "_")), 99))
    return [c for c in QUALITY_COLUMNS if c in have] + extra


def flat_rows(rows: list[dict]) -> list[dict]:
    """Rows with the sweep's values and the figures as columns of their own (CSV, tables)."""
    sweep, figs = _columns(rows)
    qual = _quality_columns(rows)
    out = []
    for r in rows:
        d = {c: r.get(c, "") for c in BASE_COLUMNS}
        d.update({c: _blank((r.get("quality") or {}).get(c)) for c in qual})
        d.update({c: r.get("overrides", {}).get(c, "") for c in sweep})
        d.update({c: r.get("figures", {}).get(c, "") for c in figs})
        out.append(d)
    return out


def write_summary(out: Path, rows: list[dict], *, started: str = "", scheduler: str = "",
                  seconds: float = 0.0, total: int | None = None) -> None:
    """``batch.json``, ``summary.csv`` and ``summary.md`` of ``rows`` (rewritten as runs end)."""
    out = Path(out)
    flat = flat_rows(rows)
    cols = list(flat[0]) if flat else list(BASE_COLUMNS)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, lineterminator="\n")
    w.writeheader()
    for d in flat:
        w.writerow({k: json.dumps(v) if isinstance(v, (list, dict)) else v for k, v in d.items()})
    _atomic(out / "summary.csv", buf.getvalue())
    svg = _figure_files(out, rows) if rows else ""
    _atomic(out / "summary.md", _markdown(rows, started, scheduler, seconds, total, plot=bool(svg)))
    _atomic(out / "summary.html", _html(rows, started, scheduler, seconds, total, svg=svg))
    _atomic(out / BATCH_MARKER, json.dumps({
        "baarda_version": __version__, "kind": "batch", "started": started, "scheduler": scheduler,
        "seconds": round(seconds, 3), "runs": total if total is not None else len(rows),
        "done": len(rows), "ok": sum(r["status"] == "ok" for r in rows), "rows": rows},
        indent=1, default=str))


def _blank(v: Any) -> Any:
    return "" if v is None or (isinstance(v, float) and v != v) else v


def quality_figure(rows: list[dict]):
    """σ̂0 with its global-test verdict and the flagged / rejected counts across the runs (matplotlib
    figure; None when no run has an adjustment)."""
    q = [(r["name"], r.get("quality") or {}) for r in rows if r.get("status") == "ok" and r.get("quality")]
    q = [(n, d) for n, d in q if d.get("sigma0_hat") is not None]
    if not q:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = list(range(len(q)))
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(max(5.0, 0.6 * len(q) + 2), 5.0), sharex=True)
    s0 = [float(d["sigma0_hat"]) for _, d in q]
    bad = [str(d.get("global_test", "")).startswith("rejected") for _, d in q]
    from matplotlib.ticker import MaxNLocator

    a1.axhline(1.0, color="#888", lw=0.8)
    for flag, colour, marker, label in ((False, "#1f4e9c", "o", "global test accepted"),
                                        (True, "#c0392b", "s", "global test rejected")):
        pick = [i for i, b in zip(x, bad) if b == flag]
        if pick:
            a1.scatter(pick, [s0[i] for i in pick], color=colour, marker=marker, label=label, zorder=3)
    a1.set_ylabel(r"$\hat\sigma_0$ (a priori 1)")
    a1.legend(fontsize=8, loc="best")
    a1.set_title(r"$\hat\sigma_0$ and the global test per run", fontsize=10)
    w = 0.4
    a2.bar([i - w / 2 for i in x], [int(d.get("n_flagged") or 0) for _, d in q], w, label="flagged", color="#e69f00")
    a2.bar([i + w / 2 for i in x], [int(d.get("n_rejected") or 0) for _, d in q], w, label="rejected", color="#c0392b")
    a2.set_ylabel("observations")
    a2.yaxis.set_major_locator(MaxNLocator(integer=True))
    a2.legend(fontsize=8, loc="best")
    a2.set_xticks(x, [n for n, _ in q], rotation=30, ha="right", fontsize=8)
    fig.tight_layout()
    return fig


def _figure_files(out: Path, rows: list[dict]) -> str:
    """Write ``summary.png`` (the plot across runs) and return it as inline SVG for summary.html."""
    fig = quality_figure(rows)
    if fig is None:
        (out / "summary.png").unlink(missing_ok=True)
        return ""
    import matplotlib.pyplot as plt

    try:
        fig.savefig(out / "summary.png", dpi=110)
        buf = io.StringIO()
        fig.savefig(buf, format="svg")
    finally:
        plt.close(fig)
    svg = buf.getvalue()
    return svg[svg.index("<svg"):]


def _atomic(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)


def _html(rows: list[dict], started: str, scheduler: str, seconds: float, total: int | None, svg: str = "") -> str:
    """The summary as one self-contained page: the same tables, each run's name a link to its own
    ``report.html`` (relative, inside the batch directory), and the plot across runs (inline SVG)."""
    body = markdown_html(_markdown(rows, started, scheduler, seconds, total, links=True))
    if svg:
        body += "\n<figure>" + svg + "<figcaption>σ̂0 with the global test's verdict, and the flagged and rejected " \
                "observations, per run (summary.png)</figcaption></figure>"
    return ("<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>baarda batch summary</title>"
            "<style>body{font-family:system-ui,sans-serif;margin:2em;max-width:110em}"
            "table{border-collapse:collapse;font-size:90%}th,td{border:1px solid #bbb;padding:.25em .5em;"
            "text-align:left}th{background:#eee}</style></head><body>\n" + body +
            f"\n<p>baarda {escape(__version__)}; every figure of every run: summary.csv.</p></body></html>\n")


def _markdown(rows: list[dict], started: str, scheduler: str, seconds: float, total: int | None,
              links: bool = False, plot: bool = False) -> str:
    ok = sum(r["status"] == "ok" for r in rows)
    n = total if total is not None else len(rows)
    sweep, figs = _columns(rows)
    # the figures that differ between the successful runs tell a sweep's story: at most eight
    varying = [c for c in figs if len({json.dumps(r["figures"].get(c)) for r in rows if r["status"] == "ok"}) > 1][:8]
    lines = [f"# Batch summary", "",
             f"{len(rows)} of {n} run(s) done, {ok} ok, {len(rows) - ok} failed; started {started}; "
             f"{seconds:.1f} s on {scheduler or 'this machine'}.", ""]
    head = ["run", "status", "seconds", "stages ok", *sweep, *varying, "message"]
    body = []
    for r in rows:
        name = f"[{_cell(r['name'])}](runs/{r['name']}/report.html)" if links and r["status"] == "ok" else r["name"]
        body.append([name, r["status"] + (f" ({r['failure']})" if r["failure"] else ""), f"{r['seconds']:.1f}",
                     f"{r['stages_ok']}/{r['stages']}", *(_cell(r["overrides"].get(c, "")) for c in sweep),
                     *(_cell(r["figures"].get(c, "")) for c in varying), _cell(r["message"])])
    lines += [markdown_table(head, body), ""]
    lines += _quality_lines(rows, links)
    if plot and not links:
        lines += ["![σ̂0, global test, flagged and rejected per run](summary.png)", ""]
    if figs:
        lines += [f"Every stage's numeric summary figures are columns of summary.csv ({len(figs)} of them)"
                  + ("; those that differ between the runs are shown above." if varying else "."), ""]
    return "\n".join(lines)


def _quality_lines(rows: list[dict], links: bool) -> list[str]:
    """The runs compared: each run's main adjustment, σ̂0, global test (p), flagged / rejected, check-point
    RMSE and camera, printed through :func:`~baarda.pipeline.units.fmt_q` as in each run's report."""
    from .units import fmt_num, fmt_q

    q = [(r, r.get("quality") or {}) for r in rows if r.get("quality")]
    if not q:
        return []
    head = ["run", "adjustment", "σ̂0", "global test", "p", "flagged", "rejected", "check-point RMSE X / Y / Z",
            "camera"]
    body = []
    for r, d in q:
        name = f"[{_cell(r['name'])}](runs/{r['name']}/report.html)" if links and r["status"] == "ok" else r["name"]
        unit = d.get("check_unit") or ""
        check = (" / ".join(fmt_q(d.get(k), unit) if unit else fmt_num(d.get(k))
                            for k in ("check_rmse_x", "check_rmse_y", "check_rmse_z"))
                 + f" ({d.get('check_n')})") if d.get("check_rmse_x") is not None else "–"
        cam = []
        units = {v: k for k, v in _UNIT_SUFFIX.items() if v}
        for k, v in d.items():
            if k.startswith("camera.") and v is not None:
                name_, _, suf = k[len("camera."):].partition("_")
                if name_ != "c" and not v:        # parameters held at 0 (every value is in summary.csv)
                    continue
                unit_ = units.get(suf, "")
                cam.append(f"{name_} {fmt_q(v, unit_)}" if unit_ in ("mm", "px", "µm", "m")
                           else f"{name_} {fmt_num(v)} {unit_}".rstrip())
        camtxt = (f"{d.get('camera')}" + (f" (1 of {d.get('n_cameras')})" if (d.get("n_cameras") or 1) > 1 else "")
                  + (": " + ", ".join(cam) if cam else "")) if d.get("camera") else "–"
        body.append([name, _cell(d.get("adjustment", "")), fmt_num(d.get("sigma0_hat")), _cell(d.get("global_test", "")),
                     fmt_num(d.get("global_test_p"), 3), str(d.get("n_flagged", "")), str(d.get("n_rejected", "")),
                     check, _cell(camtxt)])
    return ["## Runs compared", "", markdown_table(head, body), "",
            "σ̂0 is the variance factor of each run's main adjustment (its bundle, else its last adjustment); flagged: a "
            "test exceeded its critical value, the observation kept; rejected: removed from the adjustment "
            "(docs/statistics.md). Every value is a column of summary.csv.", ""]


def _cell(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v).replace("|", "\\|").replace("\n", " ")


def summary_rows(batch_dir: str | Path) -> list[dict]:
    """The rows of a batch (as :func:`run_job` returns them: name, status, failure, message,
    seconds, stages_ok, stages, run_dir, project, source, overrides, figures), read back from
    its ``batch.json`` — for a report that shows the batch."""
    path = Path(batch_dir) / BATCH_MARKER
    if not path.is_file():
        raise InputError("not a batch directory (no batch.json)", path=batch_dir)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        rows = data["rows"]
        if not isinstance(rows, list):
            raise ValueError("rows is not a list")
    except (ValueError, KeyError, TypeError, UnicodeDecodeError) as e:
        raise InputError(f"not a baarda batch file ({e})", path=path) from None
    return rows


def jobs_as_dicts(jobs: list[BatchJob]) -> list[dict]:
    return [{**asdict(j), "project": str(j.project), "out": str(j.out)} for j in jobs]
