"""Run a project: stages in order, artefacts passed by name, a run directory written as we go.

The run directory holds

* ``project.resolved.toml`` — the project with every option's default filled in;
* ``report.md`` — one section per stage (rewritten after each stage);
* ``report.html`` — the same as one self-contained page: the protocol summary first, then each
  stage with its figures embedded (:mod:`baarda.pipeline.html`; rewritten after each stage);
* ``<stage>_<table>.csv`` and ``<stage>_<table>.parquet`` — the stage's tables, written by
  :mod:`baarda.pipeline.tables` (the run option ``outputs = "summary"`` skips the per-observation and
  per-point ones); ``<stage>_<figure>.png`` — its figures;
* ``<stage>.rrd`` — the stage's rerun recording; all share the run's recording id;
* ``results.json`` — a machine-readable summary per stage, pointers to its tables (file names, rows,
  the unit of each column; never the tables' values) and the list of every file of the run, written last.

The run is written into a staging directory and moved into place when it ends
(:mod:`baarda.pipeline.rundir`): a failed re-run never touches the previous complete run.  A stage
that fails leaves the files of the stages before it intact; the run stops and :func:`run_project`
returns a :class:`RunOutcome` with ``ok = False``, the message and the kind of failure
(``"input"``, ``"adjustment"``, ``"internal"`` or ``"interrupted"``).
"""

from __future__ import annotations

import datetime as _dt
import os
import re
import shutil
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from . import __version__
from .errors import AdjustmentError, BaardaError, InputError
from .options import declared_outputs
from .plugins import PluginManager
from .plausibility import check_block
from .project import Project, load_project, stage_context
from .recording import log_text, log_values, new_recording_id, open_recording
from .report import jsonable, write_json, write_toml
from .rundir import RUN_MARKER, close_run, final_place, list_files, open_run
from .stage import Finding, Progress, StageResult
from .tables import skipped_note, write_tables


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
    html_figures: list = field(default_factory=list)
    """The stage's figures for ``report.html`` (:class:`baarda.pipeline.html.HtmlFigure`)."""
    tables: dict = field(default_factory=dict)
    """``{name: {"csv", "parquet", "rows", "columns": {column: unit}}}`` of the tables written."""
    skipped: list[str] = field(default_factory=list)
    """Tables not written (marked ``detail``; the run option ``outputs = "summary"``)."""


@dataclass
class RunOutcome:
    ok: bool
    run_dir: Path
    project: Project | None
    stages: list[StageRecord]
    message: str = ""
    artefacts: dict[str, Any] = field(default_factory=dict)
    failure: str = ""
    """Why the run failed: ``"input"`` (a mistake in an input file or option), ``"adjustment"`` (an
    adjustment that cannot be solved), ``"internal"`` (a bug; traceback in ``<stage>.error.txt``),
    ``"interrupted"``; empty when ok."""
    kept: Path | None = None
    """A complete earlier run left untouched at the requested directory when this run failed."""


def default_run_dir(project_path: Path) -> Path:
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path("runs") / f"{project_path.stem}-{stamp}"


def run_project(project_path: str | Path, out: str | Path | None = None, *,
                plugins: PluginManager | None = None, verbose: bool = True,
                stream=None, threads: int = 1, overrides=None) -> RunOutcome:
    """Load, validate and run a project; write the run directory. Raises InputError for a bad
    project (nothing is written then) and re-raises KeyboardInterrupt after keeping what was done.
    ``overrides`` replace options of the file (``--set``; see :func:`~baarda.pipeline.project.load_project`)."""
    stream = stream or sys.stderr
    plugins = plugins or PluginManager()
    project = load_project(project_path, plugins, overrides=overrides)
    run = open_run(Path(out) if out is not None else default_run_dir(Path(project_path)))
    run_dir = run.staging
    recording_id = new_recording_id()
    started = _dt.datetime.now().isoformat(timespec="seconds")
    records = [StageRecord(s.id, s.use, s.package) for s in project.stages]
    store: dict[str, Any] = {}
    findings: list[Finding] = []
    ok, message, failure = True, "", ""
    interrupted = False
    try:
        write_toml(run_dir / "project.resolved.toml", jsonable(project.resolved()))
        n = len(project.stages)
        for k, (spec, rec) in enumerate(zip(project.stages, records)):
            if verbose:
                print(f"[{k + 1}/{n}] {spec.id} ({spec.use}) …", file=stream, flush=True)
            ctx = stage_context(project, spec, run_dir=run_dir, findings=tuple(findings), threads=threads,
                                progress=Progress(spec.id, stream=stream, enabled=verbose))
            inputs = {name.rstrip("?"): store[name.rstrip("?")] for name in spec.cls.reads
                      if name.rstrip("?") in store}
            t0 = time.perf_counter()
            result, stage = None, None
            try:
                stage = spec.cls()
                result = stage.run(inputs, spec.options, ctx)
                if not isinstance(result, StageResult):
                    raise TypeError(f"run() returned {type(result).__name__}, not StageResult")
                missing = [w for w in spec.cls.writes
                           if w.rstrip("?") not in result.artefacts and not w.endswith("?")]
                if missing:
                    raise TypeError(f"stage did not produce the artefact(s) it declares: {', '.join(missing)}")
                undeclared = undeclared_outputs(spec, [*result.tables, *result.figures])
                if undeclared:
                    raise TypeError(f"stage wrote table or figure '{undeclared[0]}', which its 'outputs' "
                                    "declaration does not name (baarda validate cannot keep writers off it)")
                if "block" in result.artefacts and "block" not in inputs:     # a source: check what it read
                    for w in check_block(result.artefacts["block"]):
                        ctx.warn(w)
            except KeyboardInterrupt:
                rec.status, rec.error, failure = "interrupted", "interrupted by the user", "interrupted"
                interrupted = True
            except BaardaError as e:
                rec.status, rec.error = "failed", str(e)
                failure = "adjustment" if isinstance(e, AdjustmentError) else "input"
            except MemoryError:
                rec.status, failure = "failed", "input"
                rec.error = "out of memory (the input is larger than this machine can hold, or claims to be)"
            except Exception as e:  # a bug in a stage: keep the traceback in the run directory
                (run_dir / f"{spec.id}.error.txt").write_text(traceback.format_exc(), encoding="utf-8")
                rec.status, failure = "failed", "internal"
                rec.error = (f"internal error {type(e).__name__}: {_first_line(e)} (a bug in stage "
                             f"'{spec.id}'; traceback in {spec.id}.error.txt)")
            rec.seconds = time.perf_counter() - t0
            rec.warnings = list(ctx.warnings)
            if rec.status != "pending":
                ok = False
                message = f"stage '{spec.id}' ({spec.use}) {rec.status}: {rec.error}"
                rec.report = f"**{rec.status.capitalize()}:** {rec.error}"
                _record_failure(run_dir, spec.id, rec, recording_id)
                _write_report(run_dir, project, records, recording_id, started, shown=run.target)
                if verbose:
                    print(f"      {rec.status} after {rec.seconds:.2f} s", file=stream, flush=True)
                break
            store.update(result.artefacts)
            rec.status, rec.summary, rec.report = "ok", jsonable(result.summary), result.report
            findings.append(Finding.of(spec.id, spec.use, result))
            _write_outputs(run_dir, spec, stage, result, ctx, rec, recording_id, outputs=project.run.outputs)
            rec.seconds = time.perf_counter() - t0      # all of the stage's work: its tables, recording, figures
            if k + 1 < n:            # after the last stage _finish writes the report (rendering it twice cost 0.2 s)
                _write_report(run_dir, project, records, recording_id, started, shown=run.target)
            if verbose:
                print(f"      done in {rec.seconds:.2f} s", file=stream, flush=True)
    except KeyboardInterrupt:       # between stages, while writing
        ok, failure, interrupted = False, "interrupted", True
        message = message or "interrupted by the user"
    final = _finish(run, project, records, recording_id, started, ok)
    if final != run.target and ok:
        message = f"the run is complete but could not be moved into place; it is in {final}"
    outcome = RunOutcome(ok=ok, run_dir=final, project=project, stages=records, message=_moved(message, run, final),
                         artefacts=store, failure=failure,
                         kept=run.target if (not ok and final != run.target and (run.target / RUN_MARKER).is_file()) else None)
    if interrupted:
        raise RunInterrupted(outcome)
    return outcome


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C during a run: what was done is kept (``outcome``) before the interrupt goes on."""

    def __init__(self, outcome: RunOutcome):
        super().__init__("interrupted")
        self.outcome = outcome


def _first_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return text[0][:200] if text else ""


def undeclared_outputs(spec, names) -> list[str]:
    """The table or figure names of ``names`` that the stage's ``outputs`` declaration does not
    name (none for a stage without the declaration: it owns every ``<id>_*``) — the run keeps to
    what ``baarda validate`` knows (:func:`~baarda.pipeline.options.stage_file_patterns`)."""
    import fnmatch

    outs = declared_outputs(spec.cls)
    if outs is None:
        return []
    return [str(n) for n in names if not any(fnmatch.fnmatchcase(str(n), o) for o in outs)]


def _write_outputs(run_dir, spec, stage, result, ctx, rec, recording_id, outputs="full") -> None:
    written = write_tables(run_dir, spec.id, result.tables, outputs=outputs, progress=ctx.progress)
    rec.tables, rec.skipped = written.tables, written.skipped
    rec.files += written.files
    note = skipped_note(spec.id, written.skipped)
    if note:
        rec.report = (rec.report.rstrip() + "\n\n" + note) if rec.report.strip() else note
    for name, png in result.figures.items():
        fname = f"{spec.id}_{name}.png"
        (run_dir / fname).write_bytes(png)
        rec.files.append(fname)
        rec.html_figures.append(_html_figure(name, fname, png))
    if hasattr(stage, "plots"):
        try:
            _write_plots(run_dir, spec, stage, result, ctx, rec)
        except Exception as e:  # a broken plot must not lose the numbers
            (run_dir / f"{spec.id}.plots-error.txt").write_text(traceback.format_exc(), encoding="utf-8")
            rec.warnings.append(f"figures incomplete: {type(e).__name__}: {_first_line(e)}")
    try:
        _write_recording(run_dir, spec, stage, result, ctx, rec, recording_id)
    except Exception as e:  # a broken log() must not lose the numbers
        (run_dir / f"{spec.id}.error.txt").write_text(traceback.format_exc(), encoding="utf-8")
        rec.warnings.append(f"recording incomplete: {type(e).__name__}: {_first_line(e)}")


def _html_figure(name, fname, png, caption=""):
    from .html import HtmlFigure

    return HtmlFigure(name, fname, png, caption)


def _write_plots(run_dir, spec, stage, result, ctx, rec) -> None:
    """The stage's ``plots(result, ctx)``: matplotlib figures (or ``(figure, caption)``) by name,
    drawn with Agg into ``<stage>_<name>.png`` and kept for ``report.html``."""
    from .html import png_of, use_agg

    use_agg()
    figs = stage.plots(result, ctx) or {}
    undeclared = undeclared_outputs(spec, figs)
    if undeclared:
        raise TypeError(f"plots() drew figure '{undeclared[0]}', which the stage's 'outputs' declaration does "
                        "not name")
    with ctx.progress.bar(len(figs), "figures", unit="fig") as bar:     # Agg renders in savefig
        for name, item in figs.items():
            fig, caption = item if isinstance(item, tuple) else (item, "")
            png = png_of(fig)
            fname = f"{spec.id}_{name}.png"
            (run_dir / fname).write_bytes(png)
            rec.files.append(fname)
            rec.html_figures.append(_html_figure(name, fname, png, caption))
            bar.update(1, last=name)


def _moved(text: str, run, final: Path) -> str:
    """Messages written while the run was in its staging directory name the final place."""
    return text.replace(str(run.staging), str(final)) if text else text


def _finish(run, project, records, recording_id, started, ok) -> Path:
    """Write ``results.json`` last and move the run into place."""
    dest = final_place(run, ok)
    for r in records:
        r.error = _moved(r.error, run, dest) if r.error else r.error
        r.report = _moved(r.report, run, dest)
        r.warnings = [_moved(w, run, dest) for w in r.warnings]
    _write_report(run.staging, project, records, recording_id, started, shown=dest)
    _write_results(run.staging, project, records, recording_id, started)
    return close_run(run, ok)


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
    with ctx.progress.bar(3, "recording", unit="step") as bar:     # summary, the stage's log, the file
        try:
            log_text(rr_stream, f"{spec.id}/summary", f"## {spec.id} ({spec.use})\n\n{result.report}")
            log_values(rr_stream, f"{spec.id}/results", result.summary)
            bar.update(1, last="summary")
            if hasattr(stage, "log"):
                stage.log(result, rr_stream, ctx)
            bar.update(1, last="log")
        finally:
            rr_stream.disconnect()
        bar.update(1, last=fname)
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
    write_json(run_dir / RUN_MARKER, {
        "baarda_version": __version__,
        "project": {"name": project.name, "file": str(project.path), "seed": project.seed},
        "started": started,
        "recording_id": recording_id,
        "ok": all(r.status == "ok" for r in records),
        "stages": [{"id": r.id, "use": r.use, "package": r.package, "status": r.status,
                    "seconds": round(r.seconds, 4), "error": r.error, "warnings": r.warnings,
                    "files": r.files, "tables": r.tables, "skipped_tables": r.skipped,
                    "summary": r.summary} for r in records],
        "files": list_files(run_dir),
    })


_ABSOLUTE = re.compile(r"(?<![\w.~/])/(?:[\w.\-]+/)+[\w.\-]*")
"""An absolute POSIX path in a report's text (at least one folder deep)."""


def _scrubber(project, run_dir, shown):
    """Reports name no absolute path of this machine: the run directory becomes ``.``, the
    project's folder its relative name, the home folder ``~``."""
    pairs = []
    for d in {run_dir, shown}:
        if d is not None:
            pairs.append((str(Path(d).resolve()) + "/", ""))
            pairs.append((str(Path(d).resolve()), "."))
            pairs.append((str(d) + "/", ""))
    proj = Path(project.path).resolve().parent
    pairs += [(str(proj) + "/", ""), (str(proj), ".")]
    try:
        cwd = Path.cwd().resolve()
        pairs += [(str(cwd) + "/", ""), (str(cwd), ".")]
    except OSError:
        pass
    pairs.append((str(Path.home()), "~"))
    pairs.sort(key=lambda p: -len(p[0]))

    def relative(m) -> str:          # any other path of this machine: relative to the project file
        path = m.group(0)
        try:
            if Path(path).parent.exists():
                return os.path.relpath(path, proj)
        except (OSError, ValueError):
            pass
        return path

    def scrub(text: str) -> str:
        for a, b in pairs:
            if a and a not in ("/", "./"):
                text = text.replace(a, b)
        return _ABSOLUTE.sub(relative, text)

    return scrub


def _shown_viewer() -> str:
    """The rerun viewer as a path relative to the current folder (or plain ``rerun``)."""
    v = Path(viewer_command())
    try:
        return str(v.resolve().relative_to(Path.cwd().resolve()))
    except (ValueError, OSError):
        return v.name


def _write_report(run_dir, project, records, recording_id, started, shown=None):
    scrub = _scrubber(project, run_dir, shown)
    lines = [f"# {project.name}", ""]
    if project.description:
        lines += [project.description, ""]
    lines += [f"- project file: `{Path(project.path).name}`", f"- started: {started}, baarda {__version__}",
              f"- recording id: `{recording_id}` (open the recordings in run order with `baarda view .`, in the "
              f"run directory; or `{_shown_viewer()} *.rrd`); the same report with figures: "
              "[report.html](report.html)", "",
              "| stage | uses | status | time (s) |", "|---|---|---|---|"]
    lines += [f"| {r.id} | {r.use} | {r.status} | {r.seconds:.2f} |" for r in records]
    lines.append("")
    for r in records:
        if r.status == "pending":
            continue
        lines += [f"## {r.id} ({r.use})", ""]
        if r.warnings:
            lines += ["Warnings:", ""] + [f"- {scrub(w)}" for w in r.warnings] + [""]
        lines += [scrub(r.report.strip()), ""]
        if r.files:
            lines += ["Files: " + ", ".join(f"[{f}]({f})" for f in r.files), ""]
    (run_dir / "report.md").write_text("\n".join(lines), encoding="utf-8")
    try:
        _write_html(run_dir, project, records, recording_id, started, scrub)
    except Exception:  # a broken page must not lose the run: report.md and results.json stand
        (run_dir / "report.html.error.txt").write_text(traceback.format_exc(), encoding="utf-8")


def _write_html(run_dir, project, records, recording_id, started, scrub) -> None:
    from .html import HtmlStage, render_report

    stages = [HtmlStage(r.id, r.use, r.status, r.seconds, scrub(r.report), [scrub(w) for w in r.warnings],
                        list(r.files), list(r.html_figures),
                        r.summary.get("protocol") if isinstance(r.summary, dict) else None,
                        bool(r.summary.get("conclusion")) if isinstance(r.summary, dict) else False)
              for r in records]
    page = render_report(title=project.name, description=(project.description or "").strip(),
                         project_file=Path(project.path).name, started=started, version=__version__,
                         recording_id=recording_id, stages=stages)
    (run_dir / "report.html").write_text(page, encoding="utf-8")
