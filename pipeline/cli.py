"""The ``baarda`` command.

    baarda run PROJECT.toml [--out DIR] [--quiet] [--threads N] [--scheduler S] [--workers N]
                                                    run a project, write a run directory
    baarda batch PROJECT… [--sweep TABLE] --out DIR [--scheduler S] [--workers N]
                                                    many runs through Dask, one summary
    baarda validate PROJECT.toml                    check a project and every input file without running it
    baarda stages [--verbose]                       list installed stages (and their options)
    baarda review RUN_DIR                           what each recording holds, read back from the files

Exit status (:data:`EXIT_STATUS`): 0 success; 1 an adjustment cannot be solved (singular, no datum,
no convergence; earlier stages' results kept); 2 an input or project error (one line naming the
file, line and field), from ``validate`` and ``run`` alike; 3 an internal error (a bug: the
traceback is in the run directory's ``<stage>.error.txt``); 130 interrupted.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from . import __version__
from .errors import AdjustmentError, BaardaError, InputError

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


def _set_threads(n: int | None) -> int:
    """BLAS/OpenMP pools single-threaded for the whole process; returns the threads for the work
    that pays (``--threads``, default every core), which stages get as ``ctx.threads``.

    Single-threaded BLAS: the bundle's many small dense solves run slower with threaded OpenBLAS
    (measured: the AICON fixture 25.5 s threaded, 15.8 s with one thread).  Where threads pay —
    the sparse route's independent subtrees and its large fronts — the code asks for them.
    """
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1)
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
    from .montecarlo import Engine, Scheduler

    log = None if getattr(args, "quiet", False) else (lambda text: print(text, file=sys.stderr, flush=True))
    return Engine(Scheduler.parse(args.scheduler, args.workers), log=log)


def _cmd_run(args) -> int:
    from .montecarlo import using
    from .runner import RunInterrupted, run_project

    threads = _set_threads(args.threads)
    with _engine(args) as engine, using(engine):
        try:
            outcome = run_project(args.project, args.out, verbose=not args.quiet, threads=threads)
        except RunInterrupted as e:
            _print_outcome(e.outcome)
            raise KeyboardInterrupt from None
    _print_outcome(outcome)
    return EXIT_STATUS[outcome.failure or "ok"]


def _cmd_batch(args) -> int:
    from .batch import open_batch, plan_batch, run_batch

    _set_threads(args.threads)
    out = open_batch(args.out)
    jobs = plan_batch(args.projects, out, sweep=args.sweep)
    say = (lambda text: None) if args.quiet else (lambda text: print(text, file=sys.stderr, flush=True))
    with _engine(args) as engine:
        say(f"batch: {len(jobs)} run(s) on {engine.scheduler.describe()}")
        rows = run_batch(jobs, out, engine, progress=say)
    ok = sum(r["status"] == "ok" for r in rows)
    print(f"batch directory: {out}")
    print(f"runs: {ok}/{len(rows)} ok; summary: {out / 'summary.csv'}, {out / 'summary.md'}")
    return 0 if ok == len(rows) else 1


def _cmd_validate(args) -> int:
    from .plugins import PluginManager
    from .project import load_project, validate_inputs

    project = load_project(args.project, PluginManager())
    for w in validate_inputs(project):
        print(f"warning {w}", file=sys.stderr)
    print(f"{args.project}: valid — {len(project.stages)} stage(s): "
          + " → ".join(f"{s.id} ({s.use})" for s in project.stages))
    return 0


def _cmd_stages(args) -> int:
    from .options import describe
    from .plugins import PluginManager

    pm = PluginManager()
    infos = list(pm)
    width = max((len(i.name) for i in infos), default=4)
    pwidth = max((len(i.package) for i in infos), default=7)
    for info in infos:
        print(f"{info.name:<{width}}  {info.package:<{pwidth}}  {info.summary}")
        if args.verbose:
            cls = info.cls
            print(f"{'':<{width}}  reads: {', '.join(cls.reads) or '—'}; writes: {', '.join(cls.writes) or '—'}")
            for o in describe(cls.Options):
                dflt = "required" if o["required"] else f"default {o['default']!r}"
                print(f"{'':<{width}}    {o['name']} ({o['type']}, {dflt}): {o['doc']}")
    for name, err in sorted(pm.load_errors.items()):
        print(f"{name:<{width}}  (not loaded)  {err}", file=sys.stderr)
    return 0


def _cmd_review(args) -> int:
    from .recording import read_recording
    from .runner import viewer_command

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
    files = sorted(run_dir.glob("*.rrd"))
    if not files:
        raise InputError("no .rrd recordings in this directory (is it a baarda run directory?)", path=run_dir)
    order = {s["id"]: k for k, s in enumerate(results.get("stages", []))}
    files.sort(key=lambda p: order.get(p.stem, len(order)))
    status = {s["id"]: s for s in results.get("stages", [])}
    ids = set()
    if results:
        print(f"project: {results['project']['name']}  (baarda {results.get('baarda_version')}, "
              f"started {results.get('started')})")
    for f in files:
        try:
            s = read_recording(f)
        except Exception as e:  # rerun's reader on a damaged file
            raise InputError(f"cannot read the recording ({_one_line(e)})", path=f) from None
        ids.add(s.recording_id)
        st = status.get(f.stem, {})
        head = f"{f.name}: stage '{f.stem}'"
        if st:
            head += f" ({st.get('use')}, {st.get('status')}, {st.get('seconds', 0):.2f} s)"
        print("\n" + head)
        print(f"  recording id {s.recording_id}; archetypes: {', '.join(s.archetypes) or '—'}")
        for e in s.entities:
            tl = f" over {', '.join(e.timelines)}" if e.timelines else (" static" if e.static else "")
            cols = ", ".join(c.split(":")[0] + ":" + c.split(":")[1] if ":" in c else c for c in e.columns[:6])
            more = f" (+{len(e.columns) - 6})" if len(e.columns) > 6 else ""
            print(f"  {e.path}  rows={e.rows}{tl}  [{cols}{more}]")
        if s.summary_text:
            first = [ln for ln in s.summary_text.splitlines() if ln.strip() and not ln.startswith("#")]
            if first:
                print(f"  summary: {first[0][:160]}")
    print()
    if len(ids) == 1:
        print(f"All {len(files)} recordings share recording id {ids.pop()}; they open as one recording.")
    else:
        print(f"warning: recordings carry {len(ids)} different recording ids")
    print(f"Open them in the viewer:  {viewer_command()} {run_dir}/*.rrd")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="baarda", description=(
        "Photogrammetric adjustment with statistical testing: screening, blunder rejection, "
        "self-calibrating bundle, independent models."), epilog=EXIT_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"baarda {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run a project and write a run directory", epilog=EXIT_HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter, description=(
                           "Run a project. The run is written to a staging directory and moved to --out when it "
                           "ends; an earlier complete run there is replaced only by a complete one (a failed "
                           "re-run goes to <out>.failed). A non-empty directory that is not a baarda run is "
                           "refused."))
    r.add_argument("project", help="project file (TOML)")
    r.add_argument("--out", help="run directory (default: runs/<project>-<timestamp>)")
    r.add_argument("--quiet", action="store_true", help="no progress output")
    r.add_argument("--threads", type=_positive_int, default=None, metavar="N",
                   help="threads for the work that pays, e.g. the bundle's sparse route (default: every core; "
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
    b.add_argument("--quiet", action="store_true", help="no progress output")
    b.add_argument("--threads", type=_positive_int, default=None, metavar="N",
                   help="BLAS/OpenMP threads of this process (workers use 1)")
    _scheduler_args(b)
    b.set_defaults(func=_cmd_batch)
    v = sub.add_parser("validate", help="check a project and its input files without running it",
                       epilog=EXIT_HELP, formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="Check the project, every option, and every input file with the "
                                   "checks and messages of `run`, without adjusting anything.")
    v.add_argument("project")
    v.set_defaults(func=_cmd_validate)
    s = sub.add_parser("stages", help="list installed stages")
    s.add_argument("--verbose", "-v", action="store_true", help="also show reads/writes and options")
    s.set_defaults(func=_cmd_stages)
    rv = sub.add_parser("review", help="summarise the recordings of a run directory")
    rv.add_argument("run_dir")
    rv.set_defaults(func=_cmd_review)
    return p


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
    import signal

    args = build_parser().parse_args(argv)
    try:   # a kill (SIGTERM) ends a run as Ctrl-C does: what was done is kept and marked
        before = signal.signal(signal.SIGTERM, signal.default_int_handler)
    except ValueError:          # not the main thread (called from a test harness)
        before = None
    try:
        return _dispatch(args)
    finally:
        if before is not None:
            signal.signal(signal.SIGTERM, before)


def _dispatch(args) -> int:
    try:
        return args.func(args)
    except AdjustmentError as e:
        print(f"baarda: error: {e}", file=sys.stderr)
        return EXIT_STATUS["adjustment"]
    except BaardaError as e:
        print(f"baarda: error: {e}", file=sys.stderr)
        return EXIT_STATUS["input"]
    except BrokenPipeError:  # output piped into e.g. `head`: not an error
        import os

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
        import os
        import traceback

        if os.environ.get("BAARDA_TRACEBACK"):
            traceback.print_exc()
        print(f"baarda: internal error {type(e).__name__}: {_one_line(e)} (a bug; set BAARDA_TRACEBACK=1 "
              "to see the traceback)", file=sys.stderr)
        return EXIT_STATUS["internal"]


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
