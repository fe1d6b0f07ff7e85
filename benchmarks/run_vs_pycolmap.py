"""Whole ``baarda run`` against pycolmap's bundle adjustment: the run at the speed of its solver.

Run as a script (from the repository root; ``make bench-run`` runs the default set)::

    .venv/bin/python benchmarks/run_vs_pycolmap.py [--sizes 2000 10000] [--no-closerange]
                                                   [--dbat-repo DIR | --dbat PROJECT.xml]
                                                   [--skip-pycolmap | --sparse-only] [--floor] [--repeat N]
                                                   [--timeout 3600] [--mem-gb 22] [--threads N]
                                                   [--workdir DIR] [--json FILE]

For every size a simulated aerial block (``scale.simulate_start``: scale.py's layout, 60/30 %
overlap, ≈ 150 points per footprint, 0.5 px noise, start perturbed as ``scale.PERTURB``) is written
as a **BAL file with a project** (``bal`` source, σ 0.5 px, intrinsics fixed; ``bundle`` with a
free network on the projection centres, covariance on — the configuration of issue 22's table), and

* ``baarda``: ``baarda run project.toml --out DIR`` in its own process, *every output written*
  (tables, results.json, report.md/html, figures, recording): wall and CPU time of the whole
  process and its peak resident set (``wait4`` of the child: it ``exec``s at once, so the
  high-water mark is its own), with the load average at its start and end;
* ``pycolmap``: the same start block (the simulated block the BAL file was written from: one
  shared camera with its resolution, intrinsics fixed, as the BAL project holds them) through the
  cross-check machinery in its own process, twice — with ``SPARSE_SCHUR`` forced
  (``max_num_images_direct_sparse_cpu_solver`` raised above the block) and with pycolmap's default
  choice (``ITERATIVE_SCHUR`` beyond 1 000 images; ``--sparse-only`` leaves it out); *solve* =
  ``adjuster.solve()`` only, with the peak resident set of that child; and a third time with
  SPARSE_SCHUR forced and pycolmap's *own* stopping rule (``sparse-own``: its defaults, as COLMAP
  runs it — the issue's first table measured that);
* ``--floor``: what any whole run of the aerial project must spend before it writes an output —
  a fresh interpreter importing the libraries, reading the BAL file, ``adjust_block`` with the
  project's bundle options (solve, precision, r, w, MDB, external reliability) — against the same
  SPARSE_SCHUR solve.

The ratios: whole run / pycolmap's SPARSE_SCHUR solve (goal ≤ 1.0 at 2 000 photos), peak memory
baarda / pycolmap (goal ≤ 2), and the same against the default solver.  The 10 000-photo goal is
absolute (whole run ≤ 3 minutes, ≤ 6 GB).  ``--repeat N`` runs every baarda run and pycolmap solve
N times and keeps the fastest (every time is in the JSON).

The close-range case (default on; goal: whole run ≤ 15 s) is **DBAT's own Roma demo**
(``data/script/romabundledemo`` of niclasborlin/dbat, BSD-style licence: 60 photos, 26 321
points, 90 561 marks = 181 122 image coordinates, self-calibration, ``set_datum depend``), taken
from a DBAT work tree or extracted with ``git show`` from a git directory (``--dbat-repo``,
``$BAARDA_DBAT_REPO``, else this workplace's mirror) and run as a ``dbat`` source project with the
covariance on.  When no DBAT repository is found, the script says so and runs the simulated
60-photo DBAT project (``closerange_block``) instead; ``--dbat`` runs any other DBAT script.
Method and numbers: ``docs/benchmarks.md`` ("Whole runs").
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PYCOLMAP_SOLVERS = ("sparse", "default", "sparse-own")
"""pycolmap's solves: ``sparse`` = SPARSE_SCHUR forced, stopping at a relative cost decrease of
``--tol-rel`` (baarda's rule: both reach the same minimum, the fair race); ``default`` = the linear
solver pycolmap picks itself (ITERATIVE_SCHUR beyond 1 000 images), the same stopping rule;
``sparse-own`` = SPARSE_SCHUR forced with pycolmap's *own* stopping rule (its
``BundleAdjustmentOptions()`` defaults: no function tolerance, gradient tolerance 1e-4, at most 100
iterations) — pycolmap as a COLMAP user runs it, and the issue's first table measured it."""


# -- the projects -----------------------------------------------------------------------------------
def write_aerial_project(folder: Path, n_photos: int, seed: int = 1) -> dict:
    """The simulated aerial block of ``n_photos`` (scale.py's layout and start) as ``block.txt``
    (BAL) with ``project.toml``; ``start.npz`` the start block as baarda reads it back."""
    from baarda.plugins.bal.writer import bal_from_block, write_bal
    from scale import save_block, simulate_start

    folder.mkdir(parents=True, exist_ok=True)
    start, strips, per = simulate_start(n_photos, seed)
    pitch = float(start.cameras.pixel_mm[0])
    problem, info = bal_from_block(start, pixel_mm=pitch)
    write_bal(problem, folder / "block.txt")
    (folder / "project.toml").write_text(f"""# written by benchmarks/run_vs_pycolmap.py
[project]
name = "simulated aerial block, {n_photos} photos ({strips} strips × {per}), BAL"
object_unit = "m"

[[stage]]
use = "bal"
id = "source"
[stage.options]
path = "block.txt"
pixel_mm = {pitch!r}
sigma_px = 0.5
intrinsics = "fixed"

[[stage]]
use = "bundle"
[stage.options]
datum = "free"
datum_on = "centres"
solver.covariance = true
""")
    save_block(folder / "start.npz", start)      # pycolmap's start: the block the BAL file holds
    return {"project": str(folder / "project.toml"), "photos": info["cameras"], "points": info["points"],
            "observations": info["observations"], "layout": f"{strips} × {per}", "kind": "aerial (BAL)"}


def closerange_block(rng, *, n_photos: int = 60, n_points: int = 26321, n_control: int = 30,
                     mean_rays: float = 3.44, noise_px: float = 0.3, zero_ap: bool = False, truth: bool = False):
    """A convergent close-range block: ``n_photos`` on a cap around a 2 × 1.6 × 0.8 m point cloud
    (half rolled by 90°), one 6000 × 4000 px camera (6 µm, c = 25 mm, ``brown-backward`` with
    small distortion, self-calibrating), every point seen by 2–5 of the photos that see it
    (mean ``mean_rays``), the first ``n_control`` points fixed control seen by every photo; tie
    points without coordinates (to be intersected), orientations perturbed by 5 mm / 0.002 rad."""
    import numpy as np

    from baarda.pipeline.adjustment import project_observations
    from baarda.pipeline.geometry import opk_from_rotation
    from baarda.pipeline.model import FREE, Block, Cameras, Observations, Photos, Points
    from baarda.pipeline.synthetic.closerange import look_at

    pitch, W, H, c = 0.006, 6000, 4000, 25.0
    ap = np.zeros(7) if zero_ap else np.array([-2.0e-5, 1.0e-8, 0.0, 2.0e-6, -1.5e-6, 0.0, 0.0])
    XYZ = np.column_stack([rng.uniform(-1, 1, n_points), rng.uniform(-0.8, 0.8, n_points),
                           rng.uniform(-0.4, 0.4, n_points)])
    X0, opk = [], []
    for i in range(n_photos):
        az = 2 * np.pi * i / n_photos
        ring = 1.0 + 0.6 * (i % 3)
        C = np.array([ring * np.sin(az), 0.7 * ring * np.cos(az), 3.2 + 0.2 * (i % 4)])
        R = look_at(C, np.array([0.1 * np.cos(3 * az), 0.1 * np.sin(2 * az), 0.0]),
                    roll=(np.pi / 2) * (i % 2) + 0.05 * i)
        X0.append(C)
        opk.append(opk_from_rotation(R))
    X0, opk = np.array(X0), np.array(opk)
    cam = np.r_[c, 0.05, -0.03, ap]
    ph = np.repeat(np.arange(n_photos), n_points)
    pt = np.tile(np.arange(n_points), n_photos)
    pr = project_observations(ph, pt, XYZ, X0, opk, np.zeros(n_photos, int), cam[None], ["brown-backward"], [{}],
                              jacobians=False)
    half = np.array([W, H]) * pitch / 2 - 0.1
    seen = (pr.W < 0) & (np.abs(pr.xy) < half).all(axis=1)
    # rays per point: 2 + binomial(3, p) with mean mean_rays, at most the photos that see it
    want = 2 + rng.binomial(3, (mean_rays - 2) / 3, n_points)
    key = rng.random(len(ph)) + np.where(seen, 0.0, 2.0)          # unseen pairs sort last
    order = np.lexsort((key, pt))                                  # per point, seen pairs in random order
    rank = np.empty(len(ph), int)
    starts = np.searchsorted(pt[order], np.arange(n_points))
    rank[order] = np.arange(len(ph)) - np.repeat(starts, np.diff(np.r_[starts, len(ph)]))
    keep = seen & ((rank < want[pt]) | (pt < n_control))
    xy = pr.xy[keep] + noise_px * pitch * rng.standard_normal((int(keep.sum()), 2))
    if truth:
        cams = Cameras.make(["cam"], c, 0.05, -0.03, ap_model="brown-backward", ap=ap[None],
                            format_mm=(W * pitch, H * pitch), pixel_mm=pitch, resolution=(W, H))
        role = np.array(["full"] * n_points, dtype=object)
        return Block(cams, Photos.make([f"{i + 1}" for i in range(n_photos)], 0, X0, opk),
                     Points.make([str(1000 + j) for j in range(n_points)], XYZ, role),
                     Observations.make(ph[keep], pt[keep], xy, sigma=noise_px * pitch))
    cams = Cameras.make(["cam"], c + 0.1, 0.0, 0.0, ap_model="brown-backward", ap=np.zeros((1, 7)),
                        sigma_iop=np.full(3, FREE), sigma_ap=np.r_[FREE, FREE, 0, FREE, FREE, 0, 0][None],
                        format_mm=(W * pitch, H * pitch), pixel_mm=pitch, resolution=(W, H))
    photos = Photos.make([f"{i + 1}" for i in range(n_photos)], 0, X0 + 0.005 * rng.standard_normal(X0.shape),
                         opk + 0.002 * rng.standard_normal(opk.shape))
    role = np.array(["tie"] * n_points, dtype=object)
    role[:n_control] = "full"
    start = XYZ.copy()
    start[n_control:] = np.nan
    points = Points.make([str(1000 + j) for j in range(n_points)], start, role)
    obs = Observations.make(ph[keep], pt[keep], xy, sigma=noise_px * pitch)
    return Block(cams, photos, points, obs)


def write_closerange_project(folder: Path, seed: int = 2) -> dict:
    """The close-range block as a DBAT script project (``dbat-export``'s writer) and its toml."""
    import numpy as np

    from baarda.plugins.dbat.writer import write_dbat

    folder.mkdir(parents=True, exist_ok=True)
    block = closerange_block(np.random.default_rng(seed))
    info = write_dbat(block, folder / "dbat", name="closerange")
    return {**_dbat_toml(folder, folder / "dbat" / "closerange.xml", "simulated close-range block, DBAT"),
            "photos": len(block.photos), "points": len(block.points), "observations": info["marks"]}


def _dbat_toml(folder: Path, xml: Path, name: str) -> dict:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "project.toml").write_text(f"""# written by benchmarks/run_vs_pycolmap.py
[project]
name = "{name}"
object_unit = "m"

[[stage]]
use = "dbat"
id = "source"
[stage.options]
path = {json.dumps(str(xml))}

[[stage]]
use = "bundle"
[stage.options]
datum = "control"
solver.covariance = true
""")
    return {"project": str(folder / "project.toml"), "kind": name, "layout": "–"}


# -- children ----------------------------------------------------------------------------------------
ROMA = "data/script/romabundledemo"
"""DBAT's Roma demo in the DBAT repository (niclasborlin/dbat, BSD-style licence): 60 photos of a
Roman relief, 26 321 points, 181 122 image coordinates, self-calibration, dependent relative
orientation (``set_datum depend``)."""
DBAT_REPOS = (os.environ.get("BAARDA_DBAT_REPO", ""), "/work/.mirror/niclasborlin+dbat/repo",
              "/work/.mirror/niclasborlin+dbat")
"""Where the DBAT repository is looked for: ``$BAARDA_DBAT_REPO``, then this workplace's mirror; a
work tree or a bare git directory."""


def find_roma(workdir: Path, repo: str | None = None) -> tuple[Path | None, str]:
    """``(romabundledemo.xml, where it came from)``: from a DBAT work tree, or extracted with
    ``git show`` from a bare git directory into ``workdir/romabundledemo``; ``(None, why)`` when
    neither is there."""
    tried = []
    for cand in ([repo] if repo else DBAT_REPOS):
        if not cand:
            continue
        root = Path(cand)
        tried.append(str(root))
        xml = root / ROMA / "romabundledemo.xml"
        if xml.is_file():
            return xml, f"{root} (work tree)"
        if not (root / "HEAD").is_file():
            continue
        git = ["git", f"--git-dir={root}"]
        ls = subprocess.run([*git, "ls-tree", "-r", "--name-only", "HEAD", ROMA], capture_output=True, text=True)
        names = ls.stdout.split()
        if ls.returncode or not any(n.endswith("romabundledemo.xml") for n in names):
            continue
        for name in names:
            dest = workdir / "romabundledemo" / Path(name).relative_to(ROMA)
            dest.parent.mkdir(parents=True, exist_ok=True)
            with open(dest, "wb") as f:
                subprocess.run([*git, "show", f"HEAD:{name}"], stdout=f, check=True)
        rev = subprocess.run([*git, "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
        return workdir / "romabundledemo" / "romabundledemo.xml", f"{root} (git, commit {rev})"
    return None, "no DBAT repository with " + ROMA + (f" in {', '.join(tried)}" if tried else "")


def child_prepare(a) -> dict:
    folder = Path(a.folder)
    if a.kind == "aerial":
        return write_aerial_project(folder, a.size, seed=a.seed)
    if a.kind == "dbat":
        from baarda.plugins.dbat.reader import dbat_block, read_dbat

        xml = Path(a.dbat).resolve()
        block = dbat_block(read_dbat(xml))
        return {**_dbat_toml(folder, xml, f"DBAT project {xml.stem}"), "photos": len(block.photos),
                "points": len(block.points), "observations": int(len(block.observations))}
    return write_closerange_project(folder, seed=a.seed)


def child_pycolmap(a) -> dict:
    """pycolmap's solve of the start block with SPARSE_SCHUR forced or its default choice."""
    import pycolmap

    from baarda.plugins.crosscheck.pycolmap_ba import (SolverSettings, ba_options, block_to_reconstruction)
    from scale import load_block

    block = load_block(Path(a.block))
    t0 = time.perf_counter()
    rec, recmap = block_to_reconstruction(block, [None] * len(block.cameras))
    config = pycolmap.BundleAdjustmentConfig()
    for i in recmap.image_id[recmap.image_id > 0]:
        config.add_image(int(i))
    build = time.perf_counter() - t0
    solver = SolverSettings(max_iter=200, function_tolerance=a.tol_rel, gradient_tolerance=1e-10,
                            parameter_tolerance=1e-8, num_threads=a.threads, covariance=False)
    pycolmap.logging.minloglevel = 2
    opts = ba_options({"focal": False, "principal_point": False, "extra": False}, solver)
    if a.solver in ("sparse", "sparse-own"):
        opts.ceres.max_num_images_direct_sparse_cpu_solver = 10 ** 9
    if a.solver == "sparse-own":                 # pycolmap's own stopping rule, read from its defaults
        own, so = pycolmap.BundleAdjustmentOptions().ceres.solver_options, opts.ceres.solver_options
        for name in ("function_tolerance", "gradient_tolerance", "parameter_tolerance", "max_num_iterations"):
            setattr(so, name, getattr(own, name))
    t1 = time.perf_counter()
    adjuster = pycolmap.create_default_ceres_bundle_adjuster(opts, config, rec)
    t2 = time.perf_counter()
    summary = adjuster.solve()
    t3 = time.perf_counter()
    cs = summary.ceres_summary
    return {"solve_seconds": t3 - t2, "setup_seconds": t2 - t1, "build_seconds": build,
            "iterations": int(cs.num_successful_steps + cs.num_unsuccessful_steps),
            "linear_solver": str(cs.linear_solver_type_used).split(".")[-1], "threads": int(cs.num_threads_used),
            "termination": str(cs.termination_type).split(".")[-1], "final_cost": float(cs.final_cost),
            "pycolmap": pycolmap.__version__}


FLOOR_IMPORTS = ("import numpy, scipy.sparse, scipy.linalg, scipy.stats, pyarrow, pyarrow.parquet, matplotlib; "
                 "matplotlib.use('Agg'); import matplotlib.pyplot, rerun, baarda.pipeline.adjustment")


def child_floor(a) -> dict:
    """The floor of any whole run of the project (``--floor``): what it must spend before it writes
    an output — a fresh interpreter importing the libraries a run needs (best of 3, its own
    process), reading the BAL file, and ``adjust_block`` with the project's bundle options (the
    solve, the precision, r, w and MDB of every observation, external reliability): no tables,
    figures, recording or reports.  Wall and CPU seconds."""
    import tomllib

    from baarda.pipeline.adjustment.workflow import BundleConfig, adjust_block
    from baarda.pipeline.options import parse_options
    from baarda.plugins.bal.bal import block_from_bal, read_bal

    cpu = lambda: sum(os.times()[:2])
    starts = []
    for _ in range(3):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", FLOOR_IMPORTS], check=True)
        starts.append(time.perf_counter() - t0)
    project = Path(a.folder) / "project.toml"
    stages = tomllib.loads(project.read_text())["stage"]
    src = stages[0]["options"]
    config = parse_options(BundleConfig, stages[1]["options"])
    t0, c0 = time.perf_counter(), cpu()
    block = block_from_bal(read_bal(project.parent / src["path"]), pixel_mm=src["pixel_mm"], sigma_px=src["sigma_px"],
                           intrinsics=src["intrinsics"])
    t1, c1 = time.perf_counter(), cpu()
    rep = adjust_block(block, config)
    t2, c2 = time.perf_counter(), cpu()
    snap = rep.result.snapshot
    return {"sum_r": float(snap.r[snap.active].sum()), "dof": int(snap.dof),
            "external_reliability": rep.external is not None,
            "imports_seconds": min(starts), "read_seconds": t1 - t0, "read_cpu": c1 - c0,
            "adjust_seconds": t2 - t1, "adjust_cpu": c2 - c1,
            "floor_seconds": min(starts) + (t2 - t0), "adjust_timings": {k: getattr(rep.result.timings, k) for k in
                                                                        ("setup", "linearize", "solve", "covariance", "total")}}


CHILDREN = {"prepare": child_prepare, "pycolmap": child_pycolmap, "floor": child_floor}


# -- the parent (imports no numpy; the children's machinery is scale.py's) ----------------------------
def run_child(kind: str, workdir: Path, tag: str, args: list[str], *, timeout: float, mem_gb: float) -> dict:
    from scale import run_child as scale_run_child

    return scale_run_child(kind, workdir, tag, args, timeout=timeout, mem_gb=mem_gb, script=Path(__file__))


def run_baarda(project: str, workdir: Path, tag: str, *, threads: int, timeout: float) -> dict:
    """``baarda run`` as a user runs it (its own process, every output), timed from outside."""
    baarda = Path(sys.executable).with_name("baarda")
    cmd = [str(baarda)] if baarda.exists() else [sys.executable, "-m", "baarda.pipeline.cli"]
    out = workdir / f"{tag}-run"
    cmd += ["run", project, "--out", str(out)] + (["--threads", str(threads)] if threads > 0 else [])
    from scale import failure_status, run_process

    load0 = os.getloadavg()[0]
    stdout, stderr = workdir / f"{tag}-baarda.stdout", workdir / f"{tag}-baarda.stderr"
    w = run_process(cmd, stdout, stderr, timeout=timeout)
    w["peak_kb"] = w.pop("ru_maxrss_kb")          # baarda exec's at once: the kernel's count is its own
    w["status"] = "ok" if w["rc"] == 0 and not w["timed_out"] else failure_status(w, stderr, timeout)
    w["load"] = (load0, os.getloadavg()[0])
    size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file()) if out.exists() else 0
    w["output_mb"] = size / 1e6
    w["stages"] = {**_stage_seconds(stderr), **_stage_seconds(stdout)}
    return w


def _stage_seconds(log: Path) -> dict:
    """``{stage: seconds}`` from the runner's ``done in … s`` lines."""
    out, stage = {}, None
    for line in log.read_text(errors="replace").splitlines() if log.exists() else []:
        s = line.strip()
        if s.startswith("[") and "] " in s and s.endswith("…"):
            stage = s.split("] ", 1)[1].split(" ", 1)[0]
        elif s.startswith("done in ") and stage:
            try:
                out[stage] = float(s.split()[2])
            except (IndexError, ValueError):
                pass
    return out


def _gb(kb) -> str:
    return f"{kb / 1024 ** 2:.2f}" if kb else "–"


def _machine() -> str:
    load = os.getloadavg()
    return (f"{os.cpu_count()} cores, load average {load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f}; "
            f"Python {sys.version.split()[0]}; BLAS threads in the pycolmap children "
            f"{os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}")


_LABEL = {"sparse": "SPARSE_SCHUR", "default": "default", "sparse-own": "SPARSE_SCHUR, own stop"}
HEADER = ("| case | photos | points | image points | whole run s (CPU s) | load | run peak GB | output MB | "
          "pycolmap SPARSE_SCHUR solve s (iter.) | peak GB | pycolmap default solve s (solver, iter.) | peak GB | "
          "pycolmap SPARSE_SCHUR, own stopping rule, solve s (iter.) | peak GB | "
          + " | ".join(f"run / {_LABEL[s]} | memory / {_LABEL[s]}" for s in PYCOLMAP_SOLVERS) + " |")


def row(name: str, r: dict) -> str:
    p, b = r.get("prepare", {}), r.get("baarda", {})
    cells = [name, str(p.get("photos", "–")), f"{p.get('points', 0):,}".replace(",", " "),
             f"{p.get('observations', 0):,}".replace(",", " "),
             f"{b['wall_seconds']:.1f} ({b['cpu_seconds']:.1f})" if b.get("status") == "ok" else b.get("status", "–"),
             "{:.1f} → {:.1f}".format(*b["load"]) if b.get("load") else "–",
             _gb(b.get("peak_kb")), f"{b.get('output_mb', 0):.0f}"]
    for s in PYCOLMAP_SOLVERS:
        q = r.get(s)
        if q and q.get("status") == "ok":
            cells += [f"{q['solve_seconds']:.1f} ({q['iterations']})" if s != "default"
                      else f"{q['solve_seconds']:.1f} ({q['linear_solver']}, {q['iterations']})", _gb(q["peak_kb"])]
        else:
            cells += [q.get("status", "–") if q else "–", "–"]
    for s in PYCOLMAP_SOLVERS:
        q = r.get(s)
        if q and q.get("status") == "ok" and b.get("status") == "ok":
            cells += [f"**{b['wall_seconds'] / q['solve_seconds']:.2f}**", f"**{b['peak_kb'] / q['peak_kb']:.2f}**"]
        else:
            cells += ["–", "–"]
    return "| " + " | ".join(cells) + " |"


def _best(runs: list[dict], key: str) -> dict:
    """The fastest of repeated runs that succeeded (else the last), with every time in ``repeats``."""
    ok = [r for r in runs if r.get("status") == "ok"]
    best = dict(min(ok, key=lambda r: r[key]) if ok else runs[-1])
    best["repeats"] = [round(r.get(key, float("nan")), 2) for r in runs]
    return best


def run(sizes=(2000, 10000), *, closerange: bool = True, dbat: str | None = None, dbat_repo: str | None = None,
        pycolmap: bool = True, solvers=PYCOLMAP_SOLVERS, repeat: int = 1, timeout: float = 3600.0,
        mem_gb: float = 22.0, threads: int = -1, tol_rel: float = 1e-6, seed: int = 1,
        workdir: Path | None = None, floor: bool = False, stream=sys.stdout) -> dict:
    say = lambda *a: print(*a, file=stream, flush=True)
    tmp = None
    if workdir is None:
        tmp = tempfile.TemporaryDirectory(prefix="baarda-run-")
        workdir = Path(tmp.name)
    workdir.mkdir(parents=True, exist_ok=True)
    kw = {"timeout": timeout, "mem_gb": mem_gb}
    results = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "machine": _machine(), "cases": {},
               "repeat": repeat}
    say(f"machine: {results['machine']}")
    say(f"best of {repeat} for every baarda run and pycolmap solve" if repeat > 1 else "one run each (--repeat N: best of N)")
    cases = [(f"aerial {n}", ["--kind", "aerial", "--size", str(n)], True) for n in sizes]
    try:
        if not dbat and closerange:
            xml, where = find_roma(workdir, dbat_repo)
            if xml is not None:
                dbat = str(xml)
                results["roma"] = where
                say(f"close-range project: DBAT's romabundledemo from {where}")
            else:
                say(f"close-range project: {where}; the simulated 60-photo DBAT project instead "
                    "(--dbat-repo DIR or $BAARDA_DBAT_REPO: a DBAT work tree or git directory)")
        if dbat:
            cases.append(("DBAT " + Path(dbat).stem, ["--kind", "dbat", "--dbat", dbat], False))
        elif closerange:
            cases.append(("close-range 60 (simulated)", ["--kind", "closerange"], False))
        for name, args, with_pycolmap in cases:
            tag = name.split(" (")[0].replace(" ", "-")
            folder = workdir / tag
            r = {"prepare": run_child("prepare", workdir, f"{tag}-prepare",
                                      ["--folder", str(folder), "--seed", str(seed), *args], **kw)}
            results["cases"][name] = r
            if r["prepare"].get("status") != "ok":
                say(f"\n{name}: preparing failed: {r['prepare'].get('status')}")
                continue
            p = r["prepare"]
            say(f"\n{name}: {p.get('photos')} photos, {p.get('points')} points, {p.get('observations')} image points "
                f"({p['project']})")
            runs = []
            for k in range(max(1, repeat)):
                b = run_baarda(p["project"], workdir, f"{tag}-{k}", threads=threads, timeout=timeout)
                runs.append(b)
                say(f"  baarda run: {b['status']}, {b['wall_seconds']:.1f} s wall, {b['cpu_seconds']:.1f} s CPU, peak "
                    f"{_gb(b['peak_kb'])} GB, outputs {b['output_mb']:.0f} MB, load average {b['load'][0]:.1f} → "
                    f"{b['load'][1]:.1f}; stages " + ", ".join(f"{k} {v:.1f} s" for k, v in b["stages"].items()))
                if b["status"] != "ok":
                    break
            r["baarda"] = _best(runs, "wall_seconds")
            if floor and with_pycolmap:
                f = run_child("floor", workdir, f"{tag}-floor", ["--folder", str(folder)], **kw)
                r["floor"] = f
                if f.get("status") == "ok":
                    say(f"  floor (no output written): interpreter + imports {f['imports_seconds']:.1f} s, reading "
                        f"{f['read_seconds']:.1f} s, adjust_block {f['adjust_seconds']:.1f} s ({f['adjust_cpu']:.1f} s "
                        f"CPU; Σr {f['sum_r']:.1f} for {f['dof']} dof, external reliability "
                        f"{'on' if f['external_reliability'] else 'off'}) = {f['floor_seconds']:.1f} s")
                else:
                    say(f"  floor: {f.get('status')}")
            if pycolmap and with_pycolmap:
                for s in solvers:
                    qs = []
                    for k in range(max(1, repeat)):
                        load0 = os.getloadavg()[0]
                        q = run_child("pycolmap", workdir, f"{tag}-pycolmap-{s}-{k}",
                                      ["--block", str(folder / "start.npz"), "--solver", s, "--threads",
                                       str(threads), "--tol-rel", repr(tol_rel)], **kw)
                        q["load"] = (load0, os.getloadavg()[0])
                        qs.append(q)
                        if q.get("status") == "ok":
                            say(f"  pycolmap ({s}): {q['linear_solver']}, {q['threads']} threads, {q['iterations']} "
                                f"iterations, solve {q['solve_seconds']:.1f} s (set-up {q['setup_seconds']:.1f} s, "
                                f"reconstruction built in {q['build_seconds']:.1f} s), peak {_gb(q['peak_kb'])} GB, "
                                f"{q['termination']}, load average {q['load'][0]:.1f} → {q['load'][1]:.1f}")
                        else:
                            say(f"  pycolmap ({s}): {q.get('status')}")
                            break
                    r[s] = _best(qs, "solve_seconds")
    finally:
        if tmp is not None:
            tmp.cleanup()
    say("\n" + HEADER)
    say("|" + "---|" * (HEADER.count("|") - 1))
    for name, r in results["cases"].items():
        say(row(name, r))
    floors = [(name, r["floor"], r.get("sparse")) for name, r in results["cases"].items()
              if r.get("floor", {}).get("status") == "ok"]
    if floors:
        say("\n| case | floor s: imports + reading + adjust_block | of it adjust_block s (CPU) | pycolmap SPARSE_SCHUR "
            "solve s | floor / SPARSE_SCHUR |\n|---|---|---|---|---|")
        for name, f, q in floors:
            ok = q and q.get("status") == "ok"
            say(f"| {name} | {f['floor_seconds']:.1f} | {f['adjust_seconds']:.1f} ({f['adjust_cpu']:.1f}) | "
                + (f"{q['solve_seconds']:.1f} | **{f['floor_seconds'] / q['solve_seconds']:.2f}** |" if ok else "– | – |"))
    say("\nwhole run = `baarda run` wall time, every output written; load = the 1-minute load average at the start "
        "and end of the baarda run (2 cores: above 2, the run waited for a core); goals: aerial 2 000 run / "
        "SPARSE_SCHUR ≤ 1.0 and memory ≤ 2; aerial 10 000 ≤ 180 s and ≤ 6 GB; close-range 60 photos ≤ 15 s")
    return results


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="*", default=[2000, 10000], help="aerial blocks, photos each")
    ap.add_argument("--no-closerange", dest="closerange", action="store_false",
                    help="leave out the 60-photo close-range project")
    ap.add_argument("--dbat", default=None, help="a real DBAT script (.xml) instead of the simulated close-range one")
    ap.add_argument("--dbat-repo", default=None,
                    help="the DBAT repository (work tree or git directory) with data/script/romabundledemo "
                         "(default: $BAARDA_DBAT_REPO, then /work/.mirror/niclasborlin+dbat)")
    ap.add_argument("--skip-pycolmap", action="store_true")
    ap.add_argument("--floor", action="store_true",
                    help="also time the floor of the aerial runs: imports, reading and adjust_block, no output")
    ap.add_argument("--sparse-only", action="store_true", help="pycolmap only with SPARSE_SCHUR forced (both stopping rules), not its default linear solver")
    ap.add_argument("--repeat", type=int, default=1, help="baarda runs and pycolmap solves per case; the fastest counts")
    ap.add_argument("--timeout", type=float, default=3600.0, help="seconds per child before it is killed")
    ap.add_argument("--mem-gb", type=float, default=22.0, help="address-space limit of the helper children")
    ap.add_argument("--threads", type=int, default=-1, help="baarda --threads and Ceres threads (-1: all cores)")
    ap.add_argument("--tol-rel", type=float, default=1e-6, help="pycolmap's function tolerance (the sparse and default solves; sparse-own keeps pycolmap's own)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workdir", type=Path, default=None, help="keep every file here (default: temporary)")
    ap.add_argument("--json", type=Path, default=None, help="write every number to this file")
    # the child side (internal)
    ap.add_argument("--child", choices=sorted(CHILDREN), help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    ap.add_argument("--folder", help=argparse.SUPPRESS)
    ap.add_argument("--kind", help=argparse.SUPPRESS)
    ap.add_argument("--size", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--block", help=argparse.SUPPRESS)
    ap.add_argument("--solver", choices=PYCOLMAP_SOLVERS, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        from scale import child_main

        return child_main(a, CHILDREN)
    res = run(a.sizes, closerange=a.closerange, dbat=a.dbat, dbat_repo=a.dbat_repo, pycolmap=not a.skip_pycolmap,
              solvers=("sparse", "sparse-own") if a.sparse_only else PYCOLMAP_SOLVERS, repeat=a.repeat, timeout=a.timeout,
              mem_gb=a.mem_gb, threads=a.threads, tol_rel=a.tol_rel, seed=a.seed, workdir=a.workdir,
              floor=a.floor)
    if a.json:
        a.json.write_text(json.dumps(res, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT / "benchmarks"))
    raise SystemExit(main())
