"""Speed-up of a Monte Carlo on Dask: 2 local workers against 1, and the overhead per task.

Run as a script (from the repository root)::

    .venv/bin/python benchmarks/montecarlo_dask.py [--n-sim 2000] [--n 60] [--rho 8] [--repeat 2]

The Monte Carlo is RRR's critical value (:func:`baarda.pipeline.stats.rrr`, the whole procedure
simulated ``n_sim`` times) for a cubic fitted to ``n`` correlated observations (full weight
matrix: the slow, general path, a few ms per realisation), ρ suspects.  It runs

* in this process (the built-in ``map``: the baseline without Dask);
* on a ``distributed.LocalCluster`` of 1 worker process, then of 2 (127.0.0.1, one thread each),
  through :class:`baarda.pipeline.montecarlo.Engine` — the same tasks (``n_sim`` in 32 chunks);

and prints the wall times, the speed-up 1 → 2 workers, each against this process, and whether
the three critical values are identical.  Cluster start-up is timed separately (not in the
Monte Carlo's time).  The overhead per task is the wall time of ``--tasks`` empty tasks through
the 2-worker cluster divided by their number.  ``--repeat`` keeps the best of N.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def model(n: int, seed: int = 0):
    """A cubic on ``n`` points with exponentially correlated noise and one gross error."""
    from baarda.pipeline.stats import LinearModel

    g = np.random.default_rng(seed)
    t = np.linspace(-1, 1, n)
    A = np.c_[np.ones(n), t, t ** 2, t ** 3]
    S = 0.5 * np.eye(n) + 0.5 * np.exp(-np.abs(t[:, None] - t[None]) * 20)
    l = A @ [1.0, 2.0, 3.0, 4.0] + np.linalg.cholesky(S) @ g.standard_normal(n)
    l[7] += 6.0
    return LinearModel(A, l, np.linalg.inv(S))


def _noop(x):
    return x


def run(n_sim: int = 2000, n: int = 60, rho: int = 8, repeat: int = 2, tasks: int = 500) -> dict:
    from distributed import Client, LocalCluster

    from baarda.pipeline import montecarlo as mc
    from baarda.pipeline.stats import rrr

    m = model(n)

    def best(fn):
        times, out = [], None
        for _ in range(repeat):
            t0 = time.perf_counter()
            out = fn()
            times.append(time.perf_counter() - t0)
        return min(times), out

    res = {"n_sim": n_sim, "n": n, "rho": rho, "load": os.getloadavg()}
    res["here_s"], here = best(lambda: rrr(m, rho, alpha=0.01, n_sim=n_sim, rng=1))
    Hs = {"here": here.H}
    for workers in (1, 2):
        t0 = time.perf_counter()
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address="127.0.0.1:0")
        client = Client(cluster)
        client.wait_for_workers(workers)
        client.run(lambda: __import__("baarda.pipeline.stats"))          # imports are not the Monte Carlo
        res[f"start_{workers}_s"] = time.perf_counter() - t0
        try:
            with mc.Engine(client=client) as eng:
                res[f"w{workers}_s"], r = best(lambda: rrr(m, rho, alpha=0.01, n_sim=n_sim, rng=1, mapper=eng))
                res["tasks"] = eng.tasks_sent // repeat
                Hs[f"w{workers}"] = r.H
                if workers == 2:
                    t0 = time.perf_counter()
                    eng.map(_noop, range(tasks))
                    res["overhead_ms"] = (time.perf_counter() - t0) / tasks * 1e3
                    res["overhead_tasks"] = tasks
        finally:
            client.close()
            cluster.close()
    res["H"] = Hs
    res["identical"] = len(set(Hs.values())) == 1
    res["speedup"] = res["w1_s"] / res["w2_s"]
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n-sim", type=int, default=2000)
    ap.add_argument("--n", type=int, default=60)
    ap.add_argument("--rho", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--tasks", type=int, default=500)
    a = ap.parse_args(argv)
    r = run(a.n_sim, a.n, a.rho, a.repeat, a.tasks)
    print(f"RRR critical value, {r['n_sim']} realisations, n = {r['n']} correlated observations, rho = {r['rho']}, "
          f"{r['tasks']} tasks; load average before: {' '.join(f'{x:.2f}' for x in r['load'])}")
    print(f"{'':<28}{'seconds':>10}{'vs here':>10}")
    print(f"{'this process (no Dask)':<28}{r['here_s']:>10.2f}{1.0:>10.2f}")
    for w in (1, 2):
        print(f"{f'LocalCluster, {w} worker(s)':<28}{r[f'w{w}_s']:>10.2f}{r['here_s'] / r[f'w{w}_s']:>10.2f}"
              f"   (cluster start {r[f'start_{w}_s']:.1f} s, not included)")
    print(f"speed-up 2 workers vs 1: {r['speedup']:.2f}  (goal >= 1.7)")
    print(f"overhead per task (2 workers, {r['overhead_tasks']} empty tasks): {r['overhead_ms']:.2f} ms")
    print(f"critical values identical: {r['identical']}  ({', '.join(f'{k} {v:.10f}' for k, v in r['H'].items())})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
