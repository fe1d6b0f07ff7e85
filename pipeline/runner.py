"""Run a project: stages in order, artefacts passed by name, a run directory written as we go.

The run directory holds

* ``project.resolved.toml`` — the project with every option's default filled in;
* ``report.md`` — one section per stage (rewritten after each stage);
* ``results.json`` — a machine-readable summary per stage (rewritten after each stage);
* ``<stage>_<table>.csv`` — the stage's tables; ``<stage>_<figure>.png`` — its figures;
* ``<stage>.rrd`` — the stage's rerun recording; all share the run's recording id.

A stage that fails leaves the files of the stages before it intact; the run stops and
:func:`run_project` returns a :class:`RunOutcome` with ``ok = False`` and the message.
"""

from __future__ import annotations

import datetime as _dt
import shutil
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from . import __version__
from .errors import BaardaError, InputError
from .plugins import PluginManager
from .project import Project, load_project, stage_context
from .recording import log_text, log_values, new_recording_id, open_recording
from .report import jsonable, write_json, write_table, write_toml
from .stage import EarlierStage, Progress, StageResult

RUN_MARKER = "results.json"


@dataclass
class StageRecord:
    id: str
    use: str
    package: str
    status: str = "pending"
    seconds: float = 0.0
    summary: dict = field(default_factory=dict)
    report: str = ""
    files: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    error: str | None = None


@dataclass
class RunOutcome:
    ok: bool
    run_dir: Path
    project: Project | None
    stages: list[StageRecord]
    message: str = ""
    artefacts: dict[str, Any] = field(default_factory=dict)


def default_run_dir(project_path: Path) -> Path:
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path("runs") / f"{project_path.stem}-{stamp}"


def prepare_run_dir(run_dir: Path) -> None:
    """Create ``run_dir``; an earlier baarda run there is replaced, anything else is refused."""
    if run_dir.exists():
        if not run_dir.is_dir():
            raise InputError("run directory exists and is not a directory", path=run_dir)
        entries = list(run_dir.iterdir())
        if entries and not (run_dir / RUN_MARKER).exists():
            raise InputError("refusing to write into a non-empty directory that is not a baarda run "
                             "directory; choose another --out", path=run_dir)
        for p in entries:
            if p.is_file() and p.suffix in {".csv", ".rrd", ".png", ".json", ".md", ".toml", ".txt"}:
                p.unlink()
    run_dir.mkdir(parents=True, exist_ok=True)


def run_project(project_path: str | Path, out: str | Path | None = None, *,
                plugins: PluginManager | None = None, verbose: bool = True,
                stream=None) -> RunOutcome:
    """Load, validate and run a project; write the run directory. Raises InputError for a bad project."""
    stream = stream or sys.stderr
    plugins = plugins or PluginManager()
    project = load_project(project_path, plugins)
    run_dir = Path(out) if out is not None else default_run_dir(Path(project_path))
    prepare_run_dir(run_dir)
    recording_id = new_recording_id()
    started = _dt.datetime.now().isoformat(timespec="seconds")
    write_toml(run_dir / "project.resolved.toml", jsonable(project.resolved()))

    records = [StageRecord(s.id, s.use, s.package) for s in project.stages]
    store: dict[str, Any] = {}
    produced_by: dict[str, str] = {}
    previous: list[EarlierStage] = []
    ok, message = True, ""

    def flush():
        _write_results(run_dir, project, records, recording_id, started)
        _write_report(run_dir, project, records, recording_id, started)

    n = len(project.stages)
    for k, (spec, rec) in enumerate(zip(project.stages, records)):
        if verbose:
            print(f"[{k + 1}/{n}] {spec.id} ({spec.use}) …", file=stream, flush=True)
        ctx = stage_context(project, spec, run_dir=run_dir, previous=list(previous),
                            progress=Progress(spec.id, stream=stream, enabled=verbose))
        inputs = {}
        for name in spec.cls.reads:
            key = name.rstrip("?")
            if key in store:
                inputs[key] = store[key]
        t0 = time.perf_counter()
        try:
            stage = spec.cls()
            result = stage.run(inputs, spec.options, ctx)
            if not isinstance(result, StageResult):
                raise TypeError(f"run() returned {type(result).__name__}, not StageResult")
            missing = [w for w in spec.cls.writes if w.rstrip("?") not in result.artefacts and not w.endswith("?")]
            if missing:
                raise TypeError(f"stage did not produce the artefact(s) it declares: {', '.join(missing)}")
        except BaardaError as e:
            rec.status, rec.error = "failed", str(e)
        except Exception as e:  # a bug in a stage: keep the traceback in the run directory
            tb = traceback.format_exc()
            (run_dir / f"{spec.id}.error.txt").write_text(tb, encoding="utf-8")
            rec.status = "failed"
            rec.error = f"{type(e).__name__}: {e} (traceback in {spec.id}.error.txt)"
        rec.seconds = time.perf_counter() - t0
        rec.warnings = list(ctx.warnings)
        if rec.status == "failed":
            ok, message = False, f"stage '{spec.id}' ({spec.use}) failed: {rec.error}"
            rec.report = f"**Failed:** {rec.error}"
            _record_failure(run_dir, spec.id, rec, recording_id)
            flush()
            if verbose:
                print(f"      failed after {rec.seconds:.2f} s", file=stream, flush=True)
            break
        for name, value in result.artefacts.items():
            store[name] = value
            produced_by[name] = spec.id
        rec.status, rec.summary, rec.report = "ok", jsonable(result.summary), result.report
        previous.append(EarlierStage(spec.id, spec.use, result))
        for name, table in result.tables.items():
            fname = f"{spec.id}_{name}.csv"
            write_table(run_dir / fname, table)
            rec.files.append(fname)
        for name, png in result.figures.items():
            fname = f"{spec.id}_{name}.png"
            (run_dir / fname).write_bytes(png)
            rec.files.append(fname)
        try:
            _write_recording(run_dir, spec, stage, result, ctx, rec, recording_id)
        except Exception as e:  # a broken log() must not lose the numbers
            tb = traceback.format_exc()
            (run_dir / f"{spec.id}.error.txt").write_text(tb, encoding="utf-8")
            rec.warnings.append(f"recording incomplete: {type(e).__name__}: {e}")
        flush()
        if verbose:
            print(f"      done in {rec.seconds:.2f} s", file=stream, flush=True)
    return RunOutcome(ok=ok, run_dir=run_dir, project=project, stages=records, message=message, artefacts=store)


def viewer_command() -> str:
    """The rerun viewer that matches the SDK that wrote the recordings: the ``rerun`` beside this
    Python (``.venv/bin/rerun`` in baarda's virtual environment, which is not on PATH unless the
    environment is activated), else ``rerun`` from PATH."""
    beside = Path(sys.executable).with_name("rerun")
    if beside.exists():
        return str(beside)
    return shutil.which("rerun") or "rerun"


def _write_recording(run_dir, spec, stage, result, ctx, rec, recording_id):
    fname = f"{spec.id}.rrd"
    rr_stream = open_recording(run_dir / fname, recording_id)
    try:
        log_text(rr_stream, f"{spec.id}/summary", f"## {spec.id} ({spec.use})\n\n{result.report}")
        log_values(rr_stream, f"{spec.id}/results", result.summary)
        if hasattr(stage, "log"):
            stage.log(result, rr_stream, ctx)
    finally:
        rr_stream.disconnect()
    rec.files.append(fname)


def _record_failure(run_dir, stage_id, rec, recording_id):
    try:
        rr_stream = open_recording(run_dir / f"{stage_id}.rrd", recording_id)
        log_text(rr_stream, f"{stage_id}/summary", f"## {stage_id} failed\n\n{rec.error}")
        rr_stream.disconnect()
        rec.files.append(f"{stage_id}.rrd")
    except Exception:
        pass


def _write_results(run_dir, project, records, recording_id, started):
    write_json(run_dir / "results.json", {
        "baarda_version": __version__,
        "project": {"name": project.name, "file": str(project.path), "seed": project.seed},
        "started": started,
        "recording_id": recording_id,
        "ok": all(r.status == "ok" for r in records),
        "stages": [{"id": r.id, "use": r.use, "package": r.package, "status": r.status,
                    "seconds": round(r.seconds, 4), "error": r.error, "warnings": r.warnings,
                    "files": r.files, "summary": r.summary} for r in records],
    })


def _write_report(run_dir, project, records, recording_id, started):
    lines = [f"# {project.name}", ""]
    if project.description:
        lines += [project.description, ""]
    lines += [f"- project file: `{project.path}`", f"- started: {started}, baarda {__version__}",
              f"- recording id: `{recording_id}` (open all recordings: `{viewer_command()} {run_dir}/*.rrd`)", "",
              "| stage | uses | status | time (s) |", "|---|---|---|---|"]
    lines += [f"| {r.id} | {r.use} | {r.status} | {r.seconds:.2f} |" for r in records]
    lines.append("")
    for r in records:
        if r.status == "pending":
            continue
        lines += [f"## {r.id} ({r.use})", ""]
        if r.warnings:
            lines += ["Warnings:", ""] + [f"- {w}" for w in r.warnings] + [""]
        lines += [r.report.strip(), ""]
        if r.files:
            lines += ["Files: " + ", ".join(f"[{f}]({f})" for f in r.files), ""]
    (run_dir / "report.md").write_text("\n".join(lines), encoding="utf-8")
