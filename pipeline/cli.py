"""The ``baarda`` command.

    baarda run PROJECT.toml [--out DIR] [--quiet]   run a project, write a run directory
    baarda validate PROJECT.toml                    check a project and its input files without running it
    baarda stages [--verbose]                       list installed stages (and their options)
    baarda review RUN_DIR                           what each recording holds, read back from the files

Exit status: 0 success, 1 a stage failed (earlier results kept), 2 bad input (one-line message
naming file, line and field), 130 interrupted.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from . import __version__
from .errors import BaardaError, InputError


def _cmd_run(args) -> int:
    from .runner import run_project

    outcome = run_project(args.project, args.out, verbose=not args.quiet)
    ok_n = sum(r.status == "ok" for r in outcome.stages)
    print(f"run directory: {outcome.run_dir}")
    print(f"stages: {ok_n}/{len(outcome.stages)} ok; report: {outcome.run_dir / 'report.md'}")
    for r in outcome.stages:
        for w in r.warnings:
            print(f"warning [{r.id}]: {w}", file=sys.stderr)
    if not outcome.ok:
        print(f"baarda: {outcome.message}", file=sys.stderr)
        return 1
    return 0


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
        results = json.loads((run_dir / "results.json").read_text())
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
        s = read_recording(f)
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
        "self-calibrating bundle, independent models."))
    p.add_argument("--version", action="version", version=f"baarda {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run a project and write a run directory")
    r.add_argument("project", help="project file (TOML)")
    r.add_argument("--out", help="run directory (default: runs/<project>-<timestamp>)")
    r.add_argument("--quiet", action="store_true", help="no progress output")
    r.set_defaults(func=_cmd_run)
    v = sub.add_parser("validate", help="check a project and its input files without running it")
    v.add_argument("project")
    v.set_defaults(func=_cmd_validate)
    s = sub.add_parser("stages", help="list installed stages")
    s.add_argument("--verbose", "-v", action="store_true", help="also show reads/writes and options")
    s.set_defaults(func=_cmd_stages)
    rv = sub.add_parser("review", help="summarise the recordings of a run directory")
    rv.add_argument("run_dir")
    rv.set_defaults(func=_cmd_review)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except BaardaError as e:
        print(f"baarda: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("baarda: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into e.g. `head`: not an error
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
