"""The adjustment at scale: simulated aerial blocks of 500 … 10 000 photos, baarda beside pycolmap.

Run as a script (from the repository root; ``make bench-scale`` runs the full set)::

    .venv/bin/python benchmarks/scale.py [--sizes 500 1000 2000 5000 10000] [--skip-pycolmap] [--bal]
                                         [--timeout 3600] [--mem-gb 22] [--tol-rel 1e-6] [--repeat N]
                                         [--threads N] [--workdir DIR] [--json FILE]

For every size the block is simulated once (:func:`baarda.pipeline.synthetic.aerial.simulate_aerial`:
60/30 % overlap, ≈ 150 points per footprint, control points fixed, 0.5 px noise), disturbed with
:func:`~baarda.pipeline.synthetic.aerial.perturb_start` and saved; then each solver runs in its
*own* child process on that file:

* ``baarda``: :func:`baarda.pipeline.adjustment.adjust` with the covariance on — solve time
  (``timings`` linearize + solve), precision + redundancy time (``timings`` covariance), peak
  memory, and a check that the redundancy numbers of all observations sum to the redundancy;
* ``pycolmap``: the same start through the cross-check machinery
  (:mod:`baarda.plugins.crosscheck.pycolmap_ba`: ``block_to_reconstruction``, ``run_adjuster``,
  ``read_solution``), control points constant, intrinsics fixed — solve time (``adjuster.solve()``)
  and peak memory.

Both stop when the cost decreases by less than ``--tol-rel`` (relative), and both final costs are
evaluated with one definition (``bal_vs_pycolmap.cost_px``: ½ Σ ‖v‖² in pixels, baarda's
collinearity), so one sees that they reached the same minimum.  Peak memory is the child's own
high-water mark (``VmHWM`` of ``/proc/self/status``): ``ru_maxrss`` of a child also counts its
parent's resident set at the fork, so it is only the fallback when a child dies.  Every child runs
under ``RLIMIT_AS = --mem-gb`` and ``--timeout`` seconds; a size that fails prints "out of
memory", "timeout" or the error in its row instead of stopping the script.  ``--bal`` adds BAL
problem-49 (``bal_vs_pycolmap.run``, in a child too).  Method and numbers: ``docs/benchmarks.md``
("Scale").
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GB = 1024 ** 3

# perturbation of the start (object unit m, angles rad), as benchmarks/network_timing.py
PERTURB = {"position": 0.5, "angle": 0.002, "point": 0.5}


def layout(n_photos: int) -> tuple[int, int]:
    """``(strips, photos per strip)`` with exactly ``n_photos`` photos and the block as square on
    the ground as the divisors allow (a strip advances 0.4 × 66.7 m per photo, strips are 70 m
    apart, so a square block has ≈ 2.6 photos per strip for every strip)."""
    if n_photos < 4:
        raise ValueError(f"a block needs at least 4 photos, got {n_photos}")
    aspect = (0.7 * 100.0) / (0.4 * 100.0 * 16 / 24)
    best = None
    for s in range(2, n_photos // 2 + 1):
        if n_photos % s:
            continue
        p = n_photos // s
        if p < 2:
            continue
        score = abs(math.log(p / (s * aspect)))
        if best is None or score < best[0]:
            best = (score, s, p)
    if best is None:
        raise ValueError(f"{n_photos} photos cannot be laid out in strips of at least 2 photos")
    return best[1], best[2]


# -- the block on disk (npz, no pickle) ----------------------------------------------------------
def save_block(path: Path, block) -> None:
    """Every column of the block's tables (``<table>.<column>``), object unit and meta (JSON)."""
    import dataclasses

    import numpy as np

    arrays = {}
    for name in ("cameras", "photos", "points", "observations", "pairs"):
        table = getattr(block, name)
        for f in dataclasses.fields(table):
            arrays[f"{name}.{f.name}"] = np.asarray(getattr(table, f.name))
    arrays["object_unit"] = np.array(block.object_unit)
    arrays["meta"] = np.array(json.dumps(block.meta))
    np.savez(path, **arrays)


def load_block(path: Path):
    import numpy as np

    from baarda.pipeline import model

    kinds = {"cameras": model.Cameras, "photos": model.Photos, "points": model.Points,
             "observations": model.Observations, "pairs": model.Pairs}
    with np.load(path, allow_pickle=False) as z:
        cols = {}
        for key in z.files:
            if "." in key:
                table, col = key.split(".", 1)
                cols.setdefault(table, {})[col] = z[key]
        tables = {name: cls(**cols[name]) for name, cls in kinds.items()}
        return model.Block(**tables, object_unit=str(z["object_unit"]), meta=json.loads(str(z["meta"])))


# -- children -------------------------------------------------------------------------------------
def _peak_kb() -> int:
    """This process's high-water resident set (kB), not counting its parent's pages."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
    except OSError:
        pass
    import resource

    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)


def _cost_px(block) -> float:
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bal_vs_pycolmap import cost_px

    return cost_px(block)


def simulate_start(n_photos: int = 0, seed: int = 1, *, strips: int = 0, per_strip: int = 0):
    """The simulated aerial block of ``n_photos`` (laid out by :func:`layout`, or ``strips`` ×
    ``per_strip``) and its start disturbed as ``PERTURB``: ``(start, strips, per_strip)``.  The one
    generator of this benchmark and of ``run_vs_pycolmap.py``."""
    import numpy as np

    from baarda.pipeline.synthetic.aerial import perturb_start, simulate_aerial

    if not strips:
        strips, per_strip = layout(n_photos)
    rng = np.random.default_rng(seed)
    noisy, _ = simulate_aerial(rng, n_strips=strips, photos_per_strip=per_strip)
    return perturb_start(noisy, rng, **PERTURB), strips, per_strip


def child_simulate(a) -> dict:
    import numpy as np

    t0 = time.perf_counter()
    start, _, _ = simulate_start(seed=a.seed, strips=a.strips, per_strip=a.per_strip)
    seconds = time.perf_counter() - t0
    save_block(Path(a.block), start)
    s = start.summary()
    per_photo = np.bincount(start.observations.photo, minlength=len(start.photos))
    return {"photos": s["photos"], "points": s["points"], "observations": s["active_observations"],
            "control": s["roles"]["full"], "strips": a.strips, "per_strip": a.per_strip,
            "points_per_photo": float(np.median(per_photo)), "simulate_seconds": seconds,
            "start_cost": _cost_px(start)}


def child_baarda(a) -> dict:
    import numpy as np

    from baarda.pipeline.adjustment import BundleSettings, adjust

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bal_vs_pycolmap import threads_of

    block = load_block(Path(a.block))
    settings = BundleSettings(tol_rel=a.tol_rel, max_iter=a.max_iter, covariance=True,
                              threads=threads_of(a.threads))
    best = None
    for _ in range(max(1, a.repeat)):          # the fastest of --repeat solves
        t0 = time.perf_counter()
        res = adjust(block, settings)
        wall = time.perf_counter() - t0
        tm = res.timings.summary()
        solve = tm.get("linearize", 0.0) + tm.get("solve", 0.0)
        if best is None or solve < best["solve_seconds"]:
            r = np.asarray(res.redundancy)[np.asarray(res.obs_active)]
            best = {"solve_seconds": solve, "redundancy_seconds": tm.get("covariance", float("nan")),
                    "wall_seconds": wall, "timings": tm, "iterations": int(res.iterations), "threads": settings.threads,
                    "own_cost": float(res.vtpv) / 2, "sigma0_hat": float(res.sigma0_hat), "dof": int(res.dof),
                    "redundancy_finite": int(np.isfinite(r).all(axis=1).sum()), "redundancy_rows": int(r.shape[0]),
                    "redundancy_sum": float(np.sum(r)),
                    "cost": _cost_px(res.block.replace(observations=block.observations))}
        del res
    return best


def child_pycolmap(a) -> dict:
    import pycolmap

    from baarda.plugins.crosscheck.pycolmap_ba import (SolverSettings, block_to_reconstruction, block_with_solution,
                                                       read_solution, run_adjuster)

    block = load_block(Path(a.block))
    cams, pts = block.cameras, block.points
    refine = {"focal": bool((cams.sigma_iop[:, 0] != 0).any()),
              "principal_point": bool((cams.sigma_iop[:, 1:] != 0).any()),
              "extra": bool((cams.sigma_ap != 0).any())}
    solver = SolverSettings(max_iter=a.max_iter, function_tolerance=a.tol_rel, gradient_tolerance=1e-10,
                            parameter_tolerance=1e-8, num_threads=a.threads, covariance=False)
    best = None
    for _ in range(max(1, a.repeat)):          # the fastest of --repeat solves, each from the start
        t0 = time.perf_counter()
        rec, recmap = block_to_reconstruction(block, [None] * len(cams))
        config = pycolmap.BundleAdjustmentConfig()
        for i in recmap.image_id[recmap.image_id > 0]:
            config.add_image(int(i))
        for j in ((pts.sigma == 0).all(axis=1) & (recmap.point3D_id > 0)).nonzero()[0]:
            config.add_constant_point(int(recmap.point3D_id[j]))
        build = time.perf_counter() - t0
        out, _ = run_adjuster(rec, config, refine, solver)
        if best is None or out["seconds"] < best["solve_seconds"]:
            sol = read_solution(rec, recmap, cams.pixel_mm, block)
            best = {"solve_seconds": out["seconds"], "setup_seconds": out["setup_seconds"], "build_seconds": build,
                    "iterations": out["iterations"], "own_cost": out["final_cost"],
                    "termination": out["termination"], "linear_solver": out["linear_solver"],
                    "threads": out["threads"], "cost": _cost_px(block_with_solution(block, sol)),
                    "pycolmap": pycolmap.__version__}
        del rec, recmap, config
    return best


def child_bal(a) -> dict:
    import io

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bal_vs_pycolmap import run

    buf = io.StringIO()
    out = run(datum_on="centres", tol_rel=a.tol_rel, num_threads=a.threads, repeat=max(1, a.repeat), stream=buf)
    b, p = out["baarda"], out["pycolmap"]
    return {"lines": buf.getvalue().splitlines(), "ratio": out["ratio"], "baarda_seconds": b["seconds"],
            "pycolmap_seconds": p["seconds"], "redundancy_seconds": b["redundancy_seconds"],
            "baarda_cost": b["cost"], "pycolmap_cost": p["cost"], "baarda_iterations": b["iterations"],
            "pycolmap_iterations": p["iterations"]}


def child_warm(a) -> dict:
    """Compile (or load from numba's cache) every kernel the solvers use, dense and sparse route, on
    a small block, so that no timed child pays for compilation (the first process after kernels.py
    changed compiles for ≈ 2–3 s)."""
    from baarda.pipeline.adjustment import BundleSettings, adjust

    t0 = time.perf_counter()
    start, _, _ = simulate_start(seed=0, strips=3, per_strip=8)
    for solver in ("dense", "sparse"):
        adjust(start, BundleSettings(covariance=True, solver=solver))
    return {"seconds": time.perf_counter() - t0}


CHILDREN = {"simulate": child_simulate, "baarda": child_baarda, "pycolmap": child_pycolmap, "bal": child_bal,
            "warm": child_warm}


def child_main(a, children=None) -> int:
    """Run one child (``children[a.child]``, default this script's): memory limit first, then the
    job; the result (or why it failed) as JSON in ``a.out``, with ``child_seconds`` and ``peak_kb``."""
    import resource

    if a.mem_gb > 0:
        lim = int(a.mem_gb * GB)
        resource.setrlimit(resource.RLIMIT_AS, (lim, lim))
    t0 = time.perf_counter()
    try:
        out = (children or CHILDREN)[a.child](a)
        out["status"] = "ok"
        code = 0
    except MemoryError:
        out, code = {"status": "out of memory"}, 3
    except Exception as exc:                     # reported in the row; the traceback goes to stderr
        import traceback

        traceback.print_exc()
        out, code = {"status": f"error: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"}, 4
    out["child_seconds"] = time.perf_counter() - t0
    out["peak_kb"] = _peak_kb()
    Path(a.out).write_text(json.dumps(out))
    return code


# -- the parent (no numpy here: a child's ru_maxrss includes the parent's resident set) ------------
def run_process(cmd: list[str], stdout: Path, stderr: Path, *, timeout: float, env=None, cwd=None) -> dict:
    """Run ``cmd`` to completion or ``timeout`` (then killed): ``rc``, ``timed_out``, wall and CPU
    seconds (``wait4``'s rusage of the child) and ``ru_maxrss_kb``, the child's high-water resident
    set as the kernel counts it (for a child that ``exec``s at once, its own)."""
    with open(stdout, "w") as so, open(stderr, "w") as se:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=so, stderr=se, env=env, cwd=cwd or str(ROOT))
        deadline = time.monotonic() + timeout
        timed_out = False
        while True:
            pid, status, ru = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.monotonic() > deadline:
                os.kill(proc.pid, signal.SIGKILL)
                pid, status, ru = os.wait4(proc.pid, 0)
                timed_out = True
                break
            time.sleep(0.05)
        wall = time.perf_counter() - t0
    return {"rc": os.waitstatus_to_exitcode(status), "timed_out": timed_out, "wall_seconds": wall,
            "cpu_seconds": ru.ru_utime + ru.ru_stime, "ru_maxrss_kb": int(ru.ru_maxrss)}


def failure_status(w: dict, stderr: Path, timeout: float) -> str:
    """Why a child gave no result: timeout, killed (out of memory?), or its last line of stderr."""
    rc = w["rc"]
    if w["timed_out"]:
        return f"timeout ({timeout:.0f} s)"
    if rc == -signal.SIGKILL:
        return "killed (out of memory?)"
    if rc < 0:
        return f"killed by signal {-rc}"
    tail = stderr.read_text(errors="replace").strip().splitlines() if stderr.exists() else []
    last = tail[-1][:120] if tail else "no message"
    oom = any(w in last.lower() for w in ("memory", "bad_alloc"))
    return f"{'out of memory' if oom else 'failed'} (exit {rc}): {last}"


def run_child(kind: str, workdir: Path, tag: str, args: list[str], *, timeout: float, mem_gb: float,
              script: Path | None = None) -> dict:
    """Run one child of ``script`` (default this one: ``--child kind``) to completion, timeout or
    death; its JSON result plus ``status``, ``peak_kb`` and the ``run_process`` numbers."""
    out = workdir / f"{tag}-{kind}.json"
    out.unlink(missing_ok=True)
    env = dict(os.environ)
    for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(k, "1")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT / "benchmarks"), env.get("PYTHONPATH")]))
    cmd = [sys.executable, str(Path(script or __file__).resolve()), "--child", kind, "--out", str(out),
           "--mem-gb", str(mem_gb), *args]
    stderr = workdir / f"{tag}-{kind}.stderr"
    w = run_process(cmd, workdir / f"{tag}-{kind}.stdout", stderr, timeout=timeout, env=env)
    result = {}
    if out.exists():
        try:
            result = json.loads(out.read_text())
        except ValueError:
            result = {}
    if w["timed_out"] or not result.get("status"):
        result["status"] = failure_status(w, stderr, timeout)
    result.setdefault("peak_kb", w["ru_maxrss_kb"])
    return result


def _gb(kb) -> str:
    return f"{kb / 1024 ** 2:.2f}" if kb else "–"


def _num(v, fmt="{:.2f}") -> str:
    return fmt.format(v) if isinstance(v, (int, float)) else "–"


def _status(d: dict | None) -> str:
    return "–" if d is None else ("" if d.get("status") == "ok" else d.get("status", "?"))


TABLE_HEADER = ("| photos | strips × photos | points | observations | baarda iter. | baarda solve s | "
                "precision + redundancy s | baarda peak GB | pycolmap iter. | pycolmap solve s | pycolmap peak GB "
                "| solve ratio | memory ratio | baarda final cost | pycolmap final cost | Δcost rel. | notes |")


def table_row(size: int, r: dict) -> str:
    sim, b, p = r.get("simulate"), r.get("baarda"), r.get("pycolmap")
    ok = lambda d: d is not None and d.get("status") == "ok"
    s = sim if ok(sim) else {}
    bs = b if ok(b) else {}
    ps = p if ok(p) else {}
    ratio = bs["solve_seconds"] / ps["solve_seconds"] if bs and ps else None
    mem = b["peak_kb"] / p["peak_kb"] if bs and ps else None
    dcost = abs(bs["cost"] - ps["cost"]) / ps["cost"] if bs and ps else None
    notes = "; ".join(f"{k}: {_status(d)}" for k, d in (("simulate", sim), ("baarda", b), ("pycolmap", p))
                      if d is not None and d.get("status") != "ok")
    if bs and bs["redundancy_finite"] != bs["redundancy_rows"]:
        notes = "; ".join(filter(None, [notes, f"redundancy numbers finite for {bs['redundancy_finite']} of "
                                               f"{bs['redundancy_rows']} observations"]))
    cells = [str(size), f"{s['strips']} × {s['per_strip']}" if s else "–",
             f"{s['points']:,}" if s else "–", f"{s['observations']:,}" if s else "–",
             _num(bs.get("iterations"), "{:d}"), _num(bs.get("solve_seconds")), _num(bs.get("redundancy_seconds")),
             _gb(b.get("peak_kb")) if b else "–", _num(ps.get("iterations"), "{:d}"), _num(ps.get("solve_seconds")),
             _gb(p.get("peak_kb")) if p else "–", f"**{ratio:.2f}**" if ratio is not None else "–",
             f"**{mem:.2f}**" if mem is not None else "–", _num(bs.get("cost"), "{:.6g}"),
             _num(ps.get("cost"), "{:.6g}"), _num(dcost, "{:.1e}"), notes]
    return "| " + " | ".join(c.replace(",", " ") for c in cells) + " |"


def _machine() -> str:
    mem = "?"
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemTotal:"):
                    mem = f"{int(line.split()[1]) / 1024 ** 2:.1f} GB"
    except OSError:
        pass
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return f"machine: {os.cpu_count()} cores, {mem} memory, load average {load:.2f}; Python {sys.version.split()[0]}"


def run(sizes=(500, 1000, 2000, 5000, 10000), *, pycolmap: bool = True, bal: bool = False, timeout: float = 3600.0,
        mem_gb: float = 22.0, tol_rel: float = 1e-6, max_iter: int = 200, seed: int = 1, threads: int = -1,
        repeat: int = 1, workdir: Path | None = None, stream=sys.stdout) -> dict:
    """Simulate each size once, solve it with baarda and pycolmap in their own processes, print
    the table; returns ``{"bal": …, "sizes": {size: {"simulate", "baarda", "pycolmap"}}}``."""
    say = lambda *a: print(*a, file=stream, flush=True)
    tmp = None
    if workdir is None:
        tmp = tempfile.TemporaryDirectory(prefix="baarda-scale-")
        workdir = Path(tmp.name)
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    common = ["--tol-rel", repr(tol_rel), "--max-iter", str(max_iter), "--threads", str(threads),
              "--repeat", str(repeat)]
    kw = {"timeout": timeout, "mem_gb": mem_gb}
    results = {"sizes": {}, "bal": None, "machine": _machine(), "date": time.strftime("%Y-%m-%d %H:%M UTC",
                                                                                       time.gmtime())}
    say(results["machine"])
    say(f"each child: at most {timeout:.0f} s and {mem_gb:g} GB address space; stopping rule for both solvers: "
        f"relative cost decrease < {tol_rel:g}, at most {max_iter} iterations; best of {repeat}; threads of both solvers {threads}; "
        f"BLAS threads {os.environ.get('OPENBLAS_NUM_THREADS', '1')}")
    try:
        w = run_child("warm", workdir, "warm", [], **kw)
        say(f"kernels compiled or loaded from the cache in {w.get('seconds', float('nan')):.1f} s (not timed)"
            if w.get("status") == "ok" else f"warm-up: {w.get('status')}")
        if bal:
            r = run_child("bal", workdir, "bal", common, **kw)
            results["bal"] = r
            if r.get("status") == "ok":
                say("\nBAL problem-49:\n" + "\n".join("  " + line for line in r["lines"]))
            else:
                say(f"\nBAL problem-49: {r.get('status')}")
        for size in sizes:
            strips, per = layout(size)
            tag = f"n{size}"
            block = workdir / f"{tag}.npz"
            r = {"simulate": run_child("simulate", workdir, tag,
                                       ["--block", str(block), "--strips", str(strips), "--per-strip", str(per),
                                        "--seed", str(seed)], **kw)}
            sim = r["simulate"]
            if sim.get("status") == "ok":
                say(f"\n{size} photos ({strips} strips × {per}): {sim['points']} points, {sim['observations']} "
                    f"observations, {sim['control']} control points, median {sim['points_per_photo']:.0f} points "
                    f"per photo; simulated in {sim['simulate_seconds']:.1f} s, peak {_gb(sim['peak_kb'])} GB; "
                    f"start cost {sim['start_cost']:.6g}")
                r["baarda"] = run_child("baarda", workdir, tag, ["--block", str(block), *common], **kw)
                b = r["baarda"]
                if b.get("status") == "ok":
                    say(f"  baarda:   {b['iterations']} iterations, {b['threads']} threads, solve {b['solve_seconds']:.2f} s, precision + "
                        f"redundancy {b['redundancy_seconds']:.2f} s, wall {b['wall_seconds']:.2f} s, peak "
                        f"{_gb(b['peak_kb'])} GB, final cost {b['cost']:.6g}; Σr = {b['redundancy_sum']:.1f} for "
                        f"redundancy {b['dof']} ({b['redundancy_finite']} of {b['redundancy_rows']} observations "
                        f"with finite r)")
                else:
                    say(f"  baarda:   {b['status']} (peak {_gb(b.get('peak_kb'))} GB)")
                if pycolmap:
                    r["pycolmap"] = run_child("pycolmap", workdir, tag, ["--block", str(block), *common], **kw)
                    p = r["pycolmap"]
                    if p.get("status") == "ok":
                        say(f"  pycolmap: {p['iterations']} iterations, solve {p['solve_seconds']:.2f} s "
                            f"({p['linear_solver']}, {p['threads']} threads, {p['termination']}), reconstruction "
                            f"built in {p['build_seconds']:.1f} s, peak {_gb(p['peak_kb'])} GB, final cost "
                            f"{p['cost']:.6g}")
                    else:
                        say(f"  pycolmap: {p['status']} (peak {_gb(p.get('peak_kb'))} GB)")
            else:
                say(f"\n{size} photos: simulation {sim['status']}")
            block.unlink(missing_ok=True)
            results["sizes"][size] = r
    finally:
        if tmp is not None:
            tmp.cleanup()
    say("\n" + TABLE_HEADER)
    say("|" + "---|" * (TABLE_HEADER.count("|") - 1))
    for size, r in results["sizes"].items():
        say(table_row(size, r))
    say("\nsolve ratio = baarda solve / pycolmap solve (goal ≤ 1.0 at 2 000 photos); memory ratio = baarda peak / "
        "pycolmap peak (goal ≤ 2); final costs: ½ Σ (v/px)² with baarda's collinearity for both solutions")
    if results["bal"] and results["bal"].get("status") == "ok":
        say(f"BAL problem-49: solve ratio baarda / pycolmap **{results['bal']['ratio']:.2f}** (goal ≤ 1.0)")
    return results


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[500, 1000, 2000, 5000, 10000],
                    help="photos per block (each laid out as strips × photos per strip)")
    ap.add_argument("--skip-pycolmap", action="store_true", help="baarda only")
    ap.add_argument("--bal", action="store_true", help="also BAL problem-49 (benchmarks/bal_vs_pycolmap.py)")
    ap.add_argument("--timeout", type=float, default=3600.0, help="seconds per child before it is killed")
    ap.add_argument("--mem-gb", type=float, default=22.0, help="address-space limit per child (0: none)")
    ap.add_argument("--tol-rel", type=float, default=1e-6, help="relative cost decrease that stops both solvers")
    ap.add_argument("--max-iter", type=int, default=200)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=1, help="solves per child; the fastest is reported")
    ap.add_argument("--threads", type=int, default=-1,
                    help="threads of both solvers: Ceres' and baarda's BundleSettings.threads (-1: all cores)")
    ap.add_argument("--workdir", type=Path, default=None, help="keep the children's files here (default: temporary)")
    ap.add_argument("--json", type=Path, default=None, help="write every number to this file")
    # the child side (internal)
    ap.add_argument("--child", choices=sorted(CHILDREN), help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    ap.add_argument("--block", help=argparse.SUPPRESS)
    ap.add_argument("--strips", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--per-strip", type=int, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        return child_main(a)
    for size in a.sizes:
        try:
            layout(size)
        except ValueError as exc:
            ap.error(f"--sizes: {exc}")
    res = run(a.sizes, pycolmap=not a.skip_pycolmap, bal=a.bal, timeout=a.timeout, mem_gb=a.mem_gb,
              tol_rel=a.tol_rel, max_iter=a.max_iter, seed=a.seed, threads=a.threads, repeat=a.repeat,
              workdir=a.workdir)
    if a.json:
        a.json.write_text(json.dumps(res, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    raise SystemExit(main())
