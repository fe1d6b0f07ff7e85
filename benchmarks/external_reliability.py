"""External reliability of every image row at scale: :func:`own_effects` beside the precision it
builds on, on simulated aerial blocks (the scale benchmark's simulator).

    .venv/bin/python benchmarks/external_reliability.py [--sizes 300 2000] [--seed 7]

Per size: the block is adjusted with the covariance (``solver = "auto"``: dense below ≈ 330 photos,
sparse above); the baseline is the adjustment's own precision time (``timings.covariance``:
selected inversion / cofactors, redundancy numbers); then ``own_effects`` (the MDB of every row on
its own point and photo) is timed and the ratio printed, with the peak resident memory before and
after.  As a check, the full effect vectors of three rows (``effect_vectors``: one solve of the
whole system each) must agree with ``own_effects`` on the own point and photo.  Numbers in
``docs/statistics.md`` ("External reliability, error ellipses and covariances of the bundle").
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))


def _hwm_gb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024 ** 2
    return float("nan")


def run(n_photos: int, seed: int) -> dict:
    import numpy as np

    from baarda.pipeline.adjustment import adjust, effect_vectors, own_effects
    from baarda.pipeline.synthetic.aerial import simulate_aerial
    from scale import layout

    strips, per = layout(n_photos)
    block, _ = simulate_aerial(np.random.default_rng(seed), n_strips=strips, photos_per_strip=per)
    t0 = time.perf_counter()
    res = adjust(block)
    t_adj = time.perf_counter() - t0
    hwm0 = _hwm_gb()
    t0 = time.perf_counter()
    eff = own_effects(res)
    t_eff = time.perf_counter() - t0
    hwm1 = _hwm_gb()
    oi = np.flatnonzero(res.obs_active)
    rows = 2 * oi[[0, len(oi) // 2, len(oi) - 1]] + np.array([0, 1, 0])
    t0 = time.perf_counter()
    ev = effect_vectors(res, rows)
    t_full = time.perf_counter() - t0
    obs = res.block_in.observations
    worst = 0.0
    for j, row in enumerate(rows):
        k, c = divmod(int(row), 2)
        ref = np.r_[ev.points[j, obs.point[k]], ev.eo[j, obs.photo[k]]]
        got = np.r_[eff.point[k, c], eff.eo[k, c]]
        worst = max(worst, float(np.abs(got - ref).max() / np.abs(ref).max()))
    return {"photos": n_photos, "rows": int(res.row_active.sum()), "route": res.solver_route,
            "adjust_s": t_adj, "precision_s": res.timings.covariance, "own_effects_s": t_eff,
            "ratio": t_eff / res.timings.covariance, "full_3_rows_s": t_full, "agreement": worst,
            "hwm_before_gb": hwm0, "hwm_after_gb": hwm1,
            "largest_point_sigma": float(np.nanmax(eff.point_in_sigma))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[300, 2000])
    ap.add_argument("--seed", type=int, default=7)
    a = ap.parse_args(argv)
    print("| photos | rows | route | adjust s | precision s (baseline) | own_effects s | ratio | 3 full rows s "
          "| own vs full | peak GB before → after | largest on a point (σ) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for n in a.sizes:
        r = run(n, a.seed)
        print(f"| {r['photos']} | {r['rows']} | {r['route']} | {r['adjust_s']:.1f} | {r['precision_s']:.2f} | "
              f"{r['own_effects_s']:.2f} | {r['ratio']:.2f} | {r['full_3_rows_s']:.2f} | {r['agreement']:.1e} | "
              f"{r['hwm_before_gb']:.2f} → {r['hwm_after_gb']:.2f} | {r['largest_point_sigma']:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
