"""BAL problem-49: baarda's bundle and pycolmap's bundle adjustment from the same start.

Run as a script (from the repository root)::

    .venv/bin/python benchmarks/bal_vs_pycolmap.py [--path FILE] [--repeat N] [--datum points|centres]
                                                   [--tol-rel 1e-6] [--max-iter 200] [--threads N]
                                                   [--no-redundancy] [--compete]

or through ``make bench`` (``tests/benchmarks/test_bal_speed.py``).  Prints, for both solvers, the
final cost ½ Σ (v/px)² evaluated with *one* definition (baarda's collinearity on the same active
observations), each solver's own final cost, iterations and times, the time ratio
baarda / pycolmap, and the extra time baarda needs for the redundancy numbers of every
observation.  Both solvers get the same threads (``--threads``; -1: every core): pycolmap's Ceres
threads and baarda's ``BundleSettings.threads``.  Beside the wall-clock times the CPU times are
printed (every thread of the process counted): on a machine shared with other work they are the
steadier measure.  ``--compete`` runs the comparison twice, quiet and beside a busy-loop process,
and prints both ratios (the adjustment sets its own BLAS threads, so no ``OPENBLAS_NUM_THREADS``
is needed).  Details and the measured numbers: ``docs/benchmarks.md``.

The problem: one RADIAL camera (f, k1, k2) per photo, free network (no control).  The file has 31
observations of points behind their camera; COLMAP's cost gives them a zero residual while
baarda's collinearity fits them, so they are switched off for both solvers.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_PATH = "bal/problem-49-7776-pre.txt"


def shared_data() -> Path:
    for c in ([Path(os.environ["BAARDA_SHARED_DATA"])] if os.environ.get("BAARDA_SHARED_DATA") else []) + \
             [ROOT.parent / "shared" / "data", Path("/work/shared/data")]:
        if c.is_dir():
            return c
    raise SystemExit("shared data folder not found (set BAARDA_SHARED_DATA)")


def load_problem(path: Path):
    """The BAL file as a block (1 px = 1 µm, σ = 1 px), observations behind the camera switched off."""
    from baarda.plugins.bal.bal import behind_camera, block_from_bal, read_bal

    problem = read_bal(path)
    front = ~behind_camera(problem)            # BAL's camera looks down −Z
    block = block_from_bal(problem, pixel_mm=0.001, sigma_px=1.0)
    return block.replace(observations=block.observations.replace(active=front)), int((~front).sum())


def cost_px(block) -> float:
    """½ Σ ‖v‖² in pixels over the active observations, with baarda's collinearity (one definition)."""
    from baarda.pipeline.adjustment import project_block

    obs = block.observations
    a = obs.active
    v = (obs.xy[a] - project_block(block, obs.photo[a], obs.point[a])) / block.cameras.pixel_mm[0]
    return 0.5 * float(np.sum(v * v))


def threads_of(num_threads: int) -> int:
    """The thread count ``num_threads`` means (-1: every core)."""
    return (os.cpu_count() or 1) if num_threads < 1 else num_threads


def run_baarda(block, *, datum_on: str = "points", tol_rel: float = 1e-6, max_iter: int = 200,
               redundancy: bool = True, threads: int = 1) -> dict:
    """baarda's bundle (free network, inner constraints on ``datum_on``); times from its own split."""
    from baarda.pipeline.adjustment import BundleSettings, adjust

    settings = BundleSettings(datum="free", datum_centres=datum_on == "centres", tol_rel=tol_rel, max_iter=max_iter,
                              covariance=redundancy, threads=threads)
    c0, t0 = time.process_time(), time.perf_counter()
    res = adjust(block, settings)
    total, cpu = time.perf_counter() - t0, time.process_time() - c0
    tm = res.timings.summary()
    cov = tm.get("covariance", 0.0) if redundancy else 0.0
    return {"result": res, "iterations": res.iterations, "own_cost": res.vtpv / 2, "seconds": total - cov,
            "cpu_seconds": cpu - cov, "threads": threads, "redundancy_seconds": cov, "timings": tm,
            "cost": cost_px(res.block.replace(observations=block.observations))}


def run_pycolmap(block, *, max_iter: int = 200, function_tolerance: float = 1e-6, num_threads: int = -1) -> dict:
    """pycolmap's Ceres bundle adjustment from the block's values: RADIAL per camera, f and k1, k2
    refined, principal point fixed, no gauge fixing (as Ceres solves BAL problems)."""
    import pycolmap

    from baarda.plugins.crosscheck.pycolmap_ba import (SolverSettings, block_to_reconstruction, block_with_solution,
                                                read_solution, run_adjuster)

    t0 = time.perf_counter()
    obs = block.observations
    ext = np.abs(obs.xy[obs.active]).max() / block.cameras.pixel_mm[0]
    size = np.full((len(block.cameras), 2), 2 * int(np.ceil(ext)) + 2)
    rec, recmap = block_to_reconstruction(block, ["RADIAL"] * len(block.cameras), size)
    config = pycolmap.BundleAdjustmentConfig()
    for i in rec.images:
        config.add_image(i)
    t_build = time.perf_counter() - t0
    solver = SolverSettings(max_iter=max_iter, function_tolerance=function_tolerance, gradient_tolerance=1e-10,
                            parameter_tolerance=1e-8, num_threads=num_threads, covariance=False)
    c0 = time.process_time()
    out, _ = run_adjuster(rec, config, {"focal": True, "principal_point": False, "extra": True}, solver)
    cpu = time.process_time() - c0
    sol = read_solution(rec, recmap, block.cameras.pixel_mm, block)
    out.update(own_cost=out["final_cost"], build_seconds=t_build, cost=cost_px(block_with_solution(block, sol)),
               cpu_seconds=cpu)                   # (CPU of problem set-up and solve)
    return out


def run(path: Path | None = None, *, repeat: int = 1, datum_on: str = "points", tol_rel: float = 1e-6,
        max_iter: int = 200, redundancy: bool = True, num_threads: int = -1, stream=sys.stdout) -> dict:
    """Solve with both (``repeat`` times each, best time kept) and print the comparison."""
    path = Path(path) if path else shared_data() / DEFAULT_PATH
    block, behind = load_problem(path)
    start = cost_px(block)
    b = p = None
    for _ in range(repeat):
        pb = run_pycolmap(block, max_iter=max_iter, function_tolerance=tol_rel, num_threads=num_threads)
        p = pb if p is None or pb["seconds"] < p["seconds"] else p
        bb = run_baarda(block, datum_on=datum_on, tol_rel=tol_rel, max_iter=max_iter, redundancy=redundancy,
                        threads=threads_of(num_threads))
        b = bb if b is None or bb["seconds"] < b["seconds"] else b
    ratio = b["seconds"] / p["seconds"]
    cpu_ratio = b["cpu_seconds"] / p["cpu_seconds"]
    s = block.summary()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [
        f"machine: {os.cpu_count()} cores, load average {load:.2f} (other processes slow both solvers)",
        f"BAL {path.name}: {s['photos']} cameras, {s['points']} points, {s['active_observations']} observations "
        f"({behind} behind their camera switched off); start cost ½Σ(v/px)² = {start:.6g}",
        f"stopping rule for both: relative cost decrease < {tol_rel:g} (Ceres function_tolerance; baarda tol_rel), "
        f"at most {max_iter} iterations; best of {repeat}",
        "",
        f"{'':10s} {'final cost':>14s} {'own cost':>14s} {'iterations':>10s} {'threads':>7s} {'solve s':>9s} "
        f"{'CPU s':>7s}",
        f"{'baarda':10s} {b['cost']:14.6f} {b['own_cost']:14.6f} {b['iterations']:10d} {b['threads']:7d} "
        f"{b['seconds']:9.3f} {b['cpu_seconds']:7.3f}",
        f"{'pycolmap':10s} {p['cost']:14.6f} {p['own_cost']:14.6f} {p['iterations']:10d} {p['threads']:7d} "
        f"{p['seconds']:9.3f} {p['cpu_seconds']:7.3f}",
        "",
        f"time ratio baarda / pycolmap: {ratio:.2f}  (goal ≤ 1.0); CPU time ratio {cpu_ratio:.2f} (pycolmap's CPU "
        "time includes its problem set-up)",
        f"final costs differ by {abs(b['cost'] - p['cost']) / p['cost']:.2e} (relative)",
        f"baarda split: " + ", ".join(f"{k} {v:.3f} s" for k, v in b["timings"].items()),
        f"pycolmap: {p['linear_solver']}, {p['threads']} thread(s), {p['termination']} ({p['message']}); problem "
        f"set-up {p['setup_seconds']:.3f} s, reconstruction built in {p['build_seconds']:.3f} s",
    ]
    if redundancy:
        lines.append(f"redundancy numbers of every observation: +{b['redundancy_seconds']:.3f} s = "
                     f"{b['redundancy_seconds'] / b['seconds']:.2f} × one solve (goal ≤ 2)")
    print("\n".join(lines), file=stream, flush=True)
    return {"baarda": {k: v for k, v in b.items() if k != "result"}, "pycolmap": p, "ratio": ratio, "cpu_ratio": cpu_ratio,
            "start_cost": start, "behind": behind, "result": b["result"]}


def busy_loop():
    """A competing process: one core busy in a Python loop until it is stopped (``--compete``)."""
    import subprocess

    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


def run_quiet_and_competing(path=None, *, stream=sys.stdout, **kw) -> dict:
    """:func:`run` on a quiet machine, then again beside :func:`busy_loop`; both ratios printed.

    The library path is what is measured: no ``OPENBLAS_NUM_THREADS`` is needed (the adjustment
    limits its own BLAS threads); a caller's threaded BLAS used to make baarda 4.3–4.7 × pycolmap's
    time with other work on the machine (``docs/benchmarks.md``, "Threads")."""
    blas = os.environ.get("OPENBLAS_NUM_THREADS", "unset")
    print(f"-- quiet (OPENBLAS_NUM_THREADS {blas})", file=stream, flush=True)
    quiet = run(path, stream=stream, **kw)
    print("\n-- with a competing process (a busy loop on one core)", file=stream, flush=True)
    proc = busy_loop()
    try:
        time.sleep(0.5)
        busy = run(path, stream=stream, **kw)
    finally:
        proc.kill()
        proc.wait()
    print(f"\ntime ratio baarda / pycolmap: quiet {quiet['ratio']:.2f}, competing {busy['ratio']:.2f} "
          f"(CPU ratio {quiet['cpu_ratio']:.2f}, {busy['cpu_ratio']:.2f})", file=stream, flush=True)
    return {"quiet": quiet, "competing": busy}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--path", type=Path, default=None, help=f"BAL file (default: <shared data>/{DEFAULT_PATH})")
    ap.add_argument("--repeat", type=int, default=1, help="runs per solver; the fastest is reported")
    ap.add_argument("--datum", choices=("points", "centres"), default="points",
                    help="baarda's inner constraints on the points or the projection centres")
    ap.add_argument("--tol-rel", type=float, default=1e-6, help="relative cost decrease that stops both solvers")
    ap.add_argument("--max-iter", type=int, default=200)
    ap.add_argument("--threads", type=int, default=-1, help="threads of both solvers (-1: all cores)")
    ap.add_argument("--no-redundancy", action="store_true", help="skip baarda's redundancy numbers")
    ap.add_argument("--compete", action="store_true",
                    help="run quiet, then again beside a busy-loop process, and print both ratios")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    kw = dict(repeat=a.repeat, datum_on=a.datum, tol_rel=a.tol_rel, max_iter=a.max_iter,
              redundancy=not a.no_redundancy, num_threads=a.threads)
    if a.compete:
        run_quiet_and_competing(a.path, **kw)
    else:
        run(a.path, **kw)
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    raise SystemExit(main())
