"""The ``baarda`` command.

    baarda [--quiet | --verbose] COMMAND …          (``baarda`` alone prints the help)
    baarda run PROJECT.toml [--out DIR] [--set STAGE.OPTION=VALUE …] [--threads N] [--scheduler S] [--workers N]
                                                    run a project, write a run directory
    baarda batch PROJECT… [--sweep TABLE] --out DIR [--scheduler S] [--workers N]
                                                    many runs through Dask, one summary
    baarda validate PROJECT.toml [--set …] [-v]     check a project and every input file without running it;
                                                    -v: every option's value and range
    baarda stages [NAME …] [--verbose]              list installed stages; with names, each one in full
    baarda review RUN_DIR [--entities]              what was flagged, where to look; the recordings' layout
    baarda view RUN_DIR [--print]                   open the run's recordings in the viewer, in run order
                                                    (without a display: a message, exit status 4)

Exit status (:data:`EXIT_STATUS`): 0 success; 1 an adjustment cannot be solved (singular, no datum,
no convergence; earlier stages' results kept); 2 an input or project error (one line naming the
file, line and field), from ``validate`` and ``run`` alike; 3 an internal error (a bug: the
traceback is in the run directory's ``<stage>.error.txt``); 130 interrupted.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import shlex
import signal
import subprocess
import sys
import traceback
from pathlib import Path
from typing import Any

from . import __version__
from .errors import AdjustmentError, BaardaError, InputError
from .options import describe, option_value, to_plain

# The commands import the engine inside their functions, not here: it brings numpy, threadpoolctl
# and the entry-point machinery (≈ 0.17 s), which `baarda --help` and a mistyped argument do not
# need (0.03 s without them).  No import cycle is behind these.

EXIT_STATUS = {"ok": 0, "adjustment": 1, "input": 2, "internal": 3, "interrupted": 130}
"""Exit status of ``baarda`` by outcome (``RunOutcome.failure``; ``"ok"`` for success)."""

EXIT_HELP = """exit status:
  0    success
  1    an adjustment cannot be solved (singular, missing datum, no convergence);
       the earlier stages' results are kept
  2    an input or project error: one line naming the file, line and field
       (validate and run alike)
  3    an internal error (a bug): the traceback is in the run directory
  130  interrupted (what was done is kept)"""


REVIEW_EXIT_HELP = """exit status:
  0    the run directory was summarised
  2    not a run directory: missing, no recordings, or a damaged results.json or
       recording (one line naming the file)
  3    an internal error (a bug): one line; -v prints the traceback
  130  interrupted"""

VIEW_EXIT_HELP = """exit status:
  0    the viewer ran and closed (or --print printed its command)
  2    not a run directory: missing or without recordings
  4    no display to open the viewer on (DISPLAY / WAYLAND_DISPLAY unset): a
       message says what to do instead
  other  the viewer's own exit status"""


def _set_threads(n: int | None) -> int:
    """BLAS/OpenMP pools single-threaded for the whole process; returns the threads for the work
    that pays (``--threads``, default every core), which stages get as ``ctx.threads``.

    Single-threaded BLAS: the bundle's many small dense solves run slower with threaded OpenBLAS
    (measured: the AICON fixture 25.5 s threaded, 15.8 s with one thread).  The adjustment limits
    its own BLAS threads the same way (``baarda.pipeline.threads``) for any caller.  Where threads pay —
    the dense route's photo-pair products, Monte Carlo and batch workers — the code asks for them
    (``docs/benchmarks.md``, "Threads").
    """
    from .threads import limit_process                  # lazy: see the imports above

    limit_process(1)            # numpy's and scipy's BLAS, as the adjustment limits them itself
    return int(n) if n else max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                                else (os.cpu_count() or 1))


def _print_outcome(outcome) -> None:
    ok_n = sum(r.status == "ok" for r in outcome.stages)
    print(f"run directory: {outcome.run_dir}")
    print(f"stages: {ok_n}/{len(outcome.stages)} ok; report: {outcome.run_dir / 'report.md'}")
    for r in outcome.stages:
        for w in r.warnings:
            print(f"warning [{r.id}]: {w}", file=sys.stderr)
    if not outcome.ok:
        print(f"baarda: {outcome.message}", file=sys.stderr)
        if outcome.kept is not None:
            print(f"baarda: the complete earlier run in {outcome.kept} is kept unchanged", file=sys.stderr)


def _engine(args):
    """The Dask engine of ``--scheduler`` / ``--workers`` (nothing starts until work needs it)."""
    from .montecarlo import Engine, Scheduler                   # lazy: see the imports above

    log = None if getattr(args, "quiet", False) else (lambda text: print(text, file=sys.stderr, flush=True))
    return Engine(Scheduler.parse(args.scheduler, args.workers), log=log)


def parse_sets(sets: list[str]) -> "Overrides | None":
    """``--set STAGE.OPTION=VALUE`` arguments (``STAGE.TABLE.OPTION`` into a nested table) as
    :class:`~baarda.pipeline.project.Overrides` (values read as TOML, a bare word as a string);
    :func:`~baarda.pipeline.project.load_project` applies and checks them — stage ids and option
    names ("did you mean …?"), types and ranges — as it checks the file.  None without ``--set``."""
    from .project import Overrides, toml_value                  # lazy: see the imports above

    values: dict[str, Any] = {}
    for item in sets:
        key, eq, value = item.partition("=")
        key = key.strip()
        sid, dot, opt = key.partition(".")
        if not eq or not dot or not sid or not opt:
            raise InputError(f"expected STAGE.OPTION=VALUE, got {item!r}", field="--set")
        values[key] = toml_value(value)
    return Overrides(values) if values else None


def _cmd_run(args) -> int:
    from .montecarlo import using                               # lazy: see the imports above
    from .runner import RunInterrupted, default_run_dir, run_project

    threads = _set_threads(args.threads)
    out = args.out if args.out is not None else default_run_dir(Path(args.project))
    overrides = parse_sets(args.set)
    with _engine(args) as engine, using(engine):
        try:
            outcome = run_project(args.project, out, verbose=not args.quiet, threads=threads, overrides=overrides)
        except RunInterrupted as e:
            _print_outcome(e.outcome)
            raise KeyboardInterrupt from None
    _print_outcome(outcome)
    return EXIT_STATUS[outcome.failure or "ok"]


def _cmd_batch(args) -> int:
    from .batch import open_batch, plan_batch, run_batch        # lazy: see the imports above

    _set_threads(args.threads)
    out = open_batch(args.out)
    jobs = plan_batch(args.projects, out, sweep=args.sweep)
    say = (lambda text: None) if args.quiet else (lambda text: print(text, file=sys.stderr, flush=True))
    with _engine(args) as engine:
        say(f"batch: {len(jobs)} run(s) on {engine.scheduler.describe()}")
        rows = run_batch(jobs, out, engine, progress=say)
    ok = sum(r["status"] == "ok" for r in rows)
    print(f"batch directory: {out}")
    print(f"runs: {ok}/{len(rows)} ok; summary: {out / 'summary.csv'}, {out / 'summary.md'}, {out / 'summary.html'}")
    return 0 if ok == len(rows) else 1


def _cmd_validate(args) -> int:
    from .plugins import PluginManager                          # lazy: see the imports above
    from .project import load_project, validate_inputs

    project = load_project(args.project, PluginManager(), overrides=parse_sets(args.set))
    warnings = validate_inputs(project)
    for w in warnings:
        print(f"warning {w}", file=sys.stderr)
    if args.verbose:               # every option as it will run, with its range
        for spec in project.stages:
            print(f"{spec.id} ({spec.use}):")
            for o in describe(spec.cls.Options):
                value = to_plain(option_value(spec.options, o["field"]))
                print(f"    {o['name']} = {value!r}" + (f"  ({o['bounds']})" if o["bounds"] else ""))
    print(f"{args.project}: valid — {len(project.stages)} stage(s): "
          + " → ".join(f"{s.id} ({s.use})" for s in project.stages)
          + (f"; with {', '.join(args.set)}" if args.set else ""))
    return 0


def _cmd_stages(args) -> int:
    from .plugins import PluginManager                          # lazy: see the imports above

    pm = PluginManager()
    if args.names:
        for k, name in enumerate(args.names):
            info = pm.get(name)            # an unknown name: InputError with "did you mean"
            _print_stage(info, first=(k == 0))
        return 0
    infos = list(pm)
    width = max((len(i.name) for i in infos), default=4)
    pwidth = max((len(i.package) for i in infos), default=7)
    for info in infos:
        print(f"{info.name:<{width}}  {info.package:<{pwidth}}  {info.summary}")
        if args.verbose:
            cls = info.cls
            print(f"{'':<{width}}  reads: {', '.join(cls.reads) or '—'}; writes: {', '.join(cls.writes) or '—'}")
            group = ""
            for o in describe(cls.Options):
                if o["group"] and o["group"] != group:
                    print(f"{'':<{width}}    {_group_line(o)}")
                group = o["group"]
                dflt = "required" if o["required"] else f"default {o['default']!r}"
                rng = f", {o['bounds']}" if o["bounds"] else ""
                print(f"{'':<{width}}    {o['name']} ({o['type']}, {dflt}{rng}): {o['doc']}")
    for name, err in sorted(pm.load_errors.items()):
        print(f"{name:<{width}}  (not loaded)  {err}", file=sys.stderr)
    return 0


def _print_stage(info, first: bool = True) -> None:
    cls = info.cls
    if not first:
        print()
    print(f"{info.name}  ({info.package})")
    print(f"  {info.summary}")
    doc = inspect.getdoc(cls)
    if doc and doc.strip() != str(info.summary).strip():
        print("\n".join("  " + ln for ln in doc.splitlines()))
    print(f"  reads: {', '.join(cls.reads) or '—'}; writes: {', '.join(cls.writes) or '—'}")
    formerly = getattr(cls, "formerly", ())
    if formerly:
        print(f"  formerly: {', '.join(formerly)}")
    opts = describe(cls.Options)
    print("  options:" if opts else "  options: none")
    group = ""
    for o in opts:
        if o["group"] and o["group"] != group:
            print(f"    {_group_line(o)}")
        group = o["group"]
        dflt = "required" if o["required"] else f"default {o['default']!r}"
        rng = f", {o['bounds']}" if o["bounds"] else ""
        print(f"    {o['name']} ({o['type']}, {dflt}{rng})")
        print(f"        {o['doc']}")


def _group_line(o: dict) -> str:
    """The line before the options of a nested table: ``solver.*  (a [stage.options.solver] table): doc``."""
    return f"{o['group']}.*  (a [stage.options.{o['group']}] table): {o['group_doc']}"


def _cmd_review(args) -> int:
    from .recording import read_recording                       # lazy: see the imports above
    from .review import print_review

    run_dir = Path(args.run_dir)
    if not run_dir.is_dir():
        raise InputError("run directory not found", path=run_dir)
    results = {}
    if (run_dir / "results.json").exists():
        try:
            results = json.loads((run_dir / "results.json").read_text(encoding="utf-8"))
            if not isinstance(results, dict):
                raise ValueError("not a JSON object")
        except (ValueError, UnicodeDecodeError) as e:
            raise InputError(f"not a baarda results file ({_one_line(e)})", path=run_dir / "results.json") from None
    files = run_order(run_dir)
    recordings = {}
    for f in files:
        try:
            recordings[f.stem] = read_recording(f)
        except Exception as e:  # rerun's reader on a damaged file
            raise InputError(f"cannot read the recording ({_one_line(e)})", path=f) from None
    print_review(run_dir, results, recordings, entities=args.entities)
    return 0


def run_order(run_dir: Path) -> list[Path]:
    """The run's recordings in the order its stages ran (``results.json``; files it does not list
    last, by name).  The last stage's file carries the layout of the whole run, and the viewer
    keeps the layout of the file it loads last."""
    files = sorted(Path(run_dir).glob("*.rrd"))
    if not files:
        raise InputError("no .rrd recordings in this directory (is it a baarda run directory?)", path=run_dir)
    order: dict[str, int] = {}
    try:
        results = json.loads((Path(run_dir) / "results.json").read_text(encoding="utf-8"))
        order = {st["id"]: k for k, st in enumerate(results.get("stages", []))}
    except (OSError, ValueError, AttributeError, KeyError, TypeError):
        pass
    return sorted(files, key=lambda f: (order.get(f.stem, len(order)), f.name))


def _cmd_view(args) -> int:
    from .runner import viewer_command                          # lazy: see the imports above

    run_dir = Path(args.run_dir)
    if not run_dir.is_dir():
        raise InputError("run directory not found", path=run_dir)
    cmd = [viewer_command(), *map(str, run_order(run_dir))]
    if args.print:
        print(shlex.join(cmd))
        return 0
    if not has_display():
        print(NO_DISPLAY.format(run_dir=shlex.quote(str(run_dir))), file=sys.stderr)
        return VIEW_NO_DISPLAY
    return subprocess.call(cmd)


VIEW_NO_DISPLAY = 4
"""Exit status of ``baarda view`` when there is no display to open the viewer on."""

NO_DISPLAY = """baarda view: no display to open the rerun viewer on (neither DISPLAY nor WAYLAND_DISPLAY is set:
  a remote shell, a container or a CI job). Instead:
  - open the run on a machine with a screen: copy {run_dir} there and run `baarda view` (or the
    command `baarda view {run_dir} --print` prints), or use `ssh -X` for a forwarded display;
  - read it here: `baarda review {run_dir}` summarises every recording, and the tables, report.md
    and report.html hold every number;
  - take a screenshot headlessly (Xvfb): see docs/recordings.md, "Seen in the viewer"."""


def has_display(environ=None) -> bool:
    """Whether the viewer can open a window: always on macOS and Windows; elsewhere (X11, Wayland) only
    with ``DISPLAY``, ``WAYLAND_DISPLAY`` or ``WAYLAND_SOCKET`` set — without, winit stops with a raw error."""
    env = os.environ if environ is None else environ
    if sys.platform in ("darwin", "win32", "cygwin"):
        return True
    return any(env.get(k) for k in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"))


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="baarda", description=(
        "Photogrammetric adjustment with statistical testing: screening, blunder rejection, "
        "self-calibrating bundle, independent models."), epilog=EXIT_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"baarda {__version__}")
    _noise_args(p, top=True)
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    r = sub.add_parser("run", help="run a project and write a run directory", epilog=EXIT_HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter, description=(
                           "Run a project. The run is written to a staging directory and moved to --out when it "
                           "ends; an earlier complete run there is replaced only by a complete one (a failed "
                           "re-run goes to <out>.failed). A non-empty directory that is not a baarda run is "
                           "refused."))
    r.add_argument("project", help="project file (TOML)")
    r.add_argument("--out", help="run directory (default: runs/<project>-<timestamp>)")
    _noise_args(r)
    _set_arg(r)
    r.add_argument("--threads", type=_positive_int, default=None, metavar="N",
                   help="threads for the work that pays, e.g. the bundle's photo-pair products (default: every core; "
                        "BLAS itself stays single-threaded, faster for the many small dense solves)")
    _scheduler_args(r)
    r.set_defaults(func=_cmd_run)
    b = sub.add_parser("batch", help="run many projects (a list, a glob, or a sweep of one) through Dask",
                       formatter_class=argparse.RawDescriptionHelpFormatter, epilog=BATCH_HELP, description=(
                           "Run many projects, each into its own run directory under OUT/runs, through Dask: "
                           "worker processes on this machine by default, or an existing Dask cluster. A failed "
                           "run is reported in the summary (OUT/summary.csv, OUT/summary.md) and does not stop "
                           "the others. See docs/batch.md."))
    b.add_argument("projects", nargs="+", metavar="PROJECT",
                   help="project files, folders of them, or glob patterns (quote them: 'projects/*.toml')")
    b.add_argument("--sweep", metavar="TABLE",
                   help="a CSV (or TOML [[run]] tables) whose columns are stage_id.option values: one run "
                        "of the one PROJECT per row")
    b.add_argument("--out", required=True, help="batch directory (new, empty, or an earlier batch's)")
    _noise_args(b)
    b.add_argument("--threads", type=_positive_int, default=None, metavar="N",
                   help="BLAS/OpenMP threads of this process (workers use 1)")
    _scheduler_args(b)
    b.set_defaults(func=_cmd_batch)
    v = sub.add_parser("validate", help="check a project and its input files without running it",
                       epilog=EXIT_HELP, formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="Check the project, every option, and every input file with the "
                                   "checks and messages of `run`, without adjusting anything.")
    v.add_argument("project")
    _set_arg(v)
    _noise_args(v)
    v.set_defaults(func=_cmd_validate)
    s = sub.add_parser("stages", help="list installed stages, or describe the named ones",
                       epilog=EXIT_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    s.add_argument("names", nargs="*", metavar="NAME",
                   help="stages to describe in full (what they read and write, every option)")
    _noise_args(s, verbose_help="with no NAME: also show reads/writes and options of every stage")
    s.set_defaults(func=_cmd_stages)
    rv = sub.add_parser("review", help="what a run flagged and where to look; the recordings' layout",
                        epilog=REVIEW_EXIT_HELP, formatter_class=argparse.RawDescriptionHelpFormatter,
                        description="Summarise a run directory: each stage's status, time and finding, "
                                    "its warnings, what was flagged or rejected and in which file and view "
                                    "to look, and what each recording shows (read back from the files).")
    rv.add_argument("run_dir")
    rv.add_argument("--entities", action="store_true", help="also list every entity of every recording")
    _noise_args(rv)
    rv.set_defaults(func=_cmd_review)
    vw = sub.add_parser("view", help="open a run's recordings in the rerun viewer, in run order",
                        epilog=VIEW_EXIT_HELP, formatter_class=argparse.RawDescriptionHelpFormatter,
                        description="Open every recording of a run directory in the rerun viewer that matches "
                                    "this SDK, in the order the stages ran: the files merge into one recording "
                                    "and the last stage's layout (one tab per stage) is the one shown. Needs a "
                                    "display (see docs/recordings.md for a headless screenshot).")
    vw.add_argument("run_dir")
    vw.add_argument("--print", action="store_true", help="print the viewer command instead of running it")
    vw.set_defaults(func=_cmd_view)
    return p


def _noise_args(p: argparse.ArgumentParser, top: bool = False, verbose_help: str | None = None) -> None:
    """``--quiet`` / ``--verbose``, before the command (``baarda -v run …``) or after it."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--quiet", "-q", action="store_true", dest="top_quiet" if top else "quiet",
                   help="no progress output (results and errors only)")
    g.add_argument("--verbose", "-v", action="store_true", dest="top_verbose" if top else "verbose",
                   help=verbose_help or "more detail: every bundle iteration as a line (Ceres-style)")


def _set_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--set", action="append", default=[], metavar="STAGE.OPTION=VALUE",
                   help="override an option of the project for this run, e.g. --set bundle.solver.max_iter=50 "
                        "(repeatable; the value is TOML: 0.5, true, \"text\", [1, 2]; checked as in the file)")


BATCH_HELP = """exit status:
  0    every run succeeded
  1    at least one run failed (see the summary: status, failure, message)
  2    an input error before anything ran (a project, the sweep table, --out, --scheduler)"""


def _scheduler_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scheduler", default="local", metavar="S",
                   help="where Monte Carlo tasks and batch runs go: local (default: a Dask cluster of "
                        "worker processes on 127.0.0.1, started when the work needs it), processes "
                        "(dask's multiprocessing scheduler), sync (this process) or the address of a "
                        "running Dask scheduler, e.g. tcp://10.0.0.5:8786 (docs/batch.md)")
    p.add_argument("--workers", type=_positive_int, default=None, metavar="N",
                   help="worker processes of local/processes (default: the CPUs of this machine)")


def _positive_int(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {n}")
    return n


def _one_line(e: BaseException) -> str:
    lines = str(e).strip().splitlines()
    return (lines[0][:200] if lines else type(e).__name__)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:          # `baarda` alone: the help
        parser.print_help()
        return 0
    try:   # a kill (SIGTERM) ends a run as Ctrl-C does: what was done is kept and marked
        before = signal.signal(signal.SIGTERM, signal.default_int_handler)
    except ValueError:          # not the main thread (called from a test harness)
        before = None
    try:
        return _dispatch(args)
    finally:
        if before is not None:
            signal.signal(signal.SIGTERM, before)


def _merge_noise(args) -> None:
    """``--quiet``/``--verbose`` given before the command count as given after it."""
    for name in ("quiet", "verbose"):
        top = getattr(args, f"top_{name}", None)
        if top:
            setattr(args, name, True)
    if getattr(args, "quiet", False) and getattr(args, "verbose", False):
        raise InputError("--quiet and --verbose exclude each other", field="--quiet")


def _dispatch(args) -> int:
    from .stage import set_verbose                              # lazy: see the imports above

    try:
        _merge_noise(args)
        set_verbose(bool(getattr(args, "verbose", False)) and not getattr(args, "quiet", False))
        return args.func(args)
    except AdjustmentError as e:
        print(f"baarda: error: {e}", file=sys.stderr)
        return EXIT_STATUS["adjustment"]
    except BaardaError as e:
        print(f"baarda: error: {e}", file=sys.stderr)
        return EXIT_STATUS["input"]
    except BrokenPipeError:  # output piped into e.g. `head`: not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as e:       # a file the user named cannot be read or written
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        print(f"baarda: error: {where}{e.strerror or _one_line(e)}", file=sys.stderr)
        return EXIT_STATUS["input"]
    except MemoryError:
        print("baarda: error: out of memory", file=sys.stderr)
        return EXIT_STATUS["input"]
    except KeyboardInterrupt:
        print("baarda: interrupted", file=sys.stderr)
        return 130
    except Exception as e:   # a bug: one line here, the traceback on request
        if os.environ.get("BAARDA_TRACEBACK"):
            traceback.print_exc()
        print(f"baarda: internal error {type(e).__name__}: {_one_line(e)} (a bug; set BAARDA_TRACEBACK=1 "
              "to see the traceback)", file=sys.stderr)
        return EXIT_STATUS["internal"]


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
