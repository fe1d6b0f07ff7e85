"""Timing of baarda's bundle on two larger networks, split into set-up, solve and covariance.

Run as a script (from the repository root)::

    .venv/bin/python benchmarks/network_timing.py [--strips 20] [--per-strip 10] [--no-pycolmap]

* the AICON close-range network of the shared data (``aicon-closerange/example``: 115 images,
  self-calibration with AICON's model, scale bars, free network);
* a simulated aerial block (:func:`baarda.pipeline.synthetic.aerial.simulate_aerial`; default 20 strips × 10
  photos = 200 photos, ≈ 9 000 points, ≈ 29 000 observations, control points fixed), with
  pycolmap's solve time of the same problem from the same start (the cross-check machinery).

The split comes from :attr:`baarda.pipeline.adjustment.BundleResult.timings`: set-up = problem set-up +
initial values; solve = linearisation + reduced systems (all iterations); covariance = cofactors,
precision and the redundancy numbers of every observation.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def split(timings) -> dict:
    """set-up / solve / covariance seconds from a BundleResult's timings.

    ``timings.setup`` does not include building the :class:`BundleProblem` (``adjust`` builds
    it before ``solve_bundle`` starts its clock), so set-up here is everything that is neither
    solve nor covariance: ``total − (linearize + solve) − covariance`` (initial values, problem
    set-up, final residuals and check points)."""
    solve = timings.linearize + timings.solve
    cov = timings.covariance
    total = timings.total
    return {"setup": total - solve - cov, "solve": solve, "covariance": cov, "total": total}


def _line(name: str, block, res, wall: float) -> str:
    s = split(res.timings)
    b = block.summary()
    return (f"{name:10s} {b['photos']:6d} {b['points']:7d} {b['active_observations']:7d} {res.iterations:5d} "
            f"{s['setup']:8.3f} {s['solve']:8.3f} {s['covariance']:8.3f} {wall:8.3f}")


HEADER = (f"{'network':10s} {'photos':>6s} {'points':>7s} {'obs':>7s} {'iter':>5s} {'set-up':>8s} {'solve':>8s} "
          f"{'cov.':>8s} {'total s':>8s}")


def time_aicon(data: Path) -> tuple:
    from baarda.plugins.aicon.reader import aicon_block, read_aicon
    from baarda.pipeline.adjustment import BundleSettings, adjust

    block = aicon_block(read_aicon(data / "aicon-closerange" / "example"))
    t0 = time.perf_counter()
    res = adjust(block, BundleSettings(datum="free"))
    return block, res, time.perf_counter() - t0


def time_aerial(n_strips: int = 20, per_strip: int = 10, seed: int = 1) -> tuple:
    from baarda.pipeline.adjustment import BundleSettings, adjust
    from baarda.pipeline.synthetic.aerial import perturb_start, simulate_aerial

    rng = np.random.default_rng(seed)
    noisy, _ = simulate_aerial(rng, n_strips=n_strips, photos_per_strip=per_strip)
    block = perturb_start(noisy, rng, position=0.5, angle=0.002, point=0.5)
    t0 = time.perf_counter()
    res = adjust(block, BundleSettings())
    return block, res, time.perf_counter() - t0


def run(data: Path | None = None, *, n_strips: int = 20, per_strip: int = 10, pycolmap: bool = True,
        stream=sys.stdout) -> dict:
    from bal_vs_pycolmap import shared_data

    data = data or shared_data()
    out = {}
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores", file=stream)
    print(HEADER, file=stream)
    block, res, wall = time_aicon(data)
    out["aicon"] = {"split": split(res.timings), "wall": wall, "iterations": res.iterations, **block.summary()}
    print(_line("AICON", block, res, wall), file=stream, flush=True)
    block, res, wall = time_aerial(n_strips, per_strip)
    out["aerial"] = {"split": split(res.timings), "wall": wall, "iterations": res.iterations, **block.summary()}
    print(_line("aerial", block, res, wall), file=stream, flush=True)
    if pycolmap:
        from baarda.plugins.crosscheck import SolverSettings, crosscheck

        cc = crosscheck(res, solver=SolverSettings(covariance=False))
        s = split(res.timings)
        out["aerial"]["pycolmap"] = dict(cc.pycolmap)
        out["aerial"]["agreement"] = {k: v["max"] for k, v in cc.quantities.items()}
        print(f"aerial, pycolmap from the same start: {cc.pycolmap['iterations']} iterations, solve "
              f"{cc.pycolmap['seconds']:.3f} s (baarda solve {s['solve']:.3f} s, "
              f"ratio {s['solve'] / cc.pycolmap['seconds']:.2f}); "
              f"points agree to {cc.quantities['points']['max']:.2g} m, residuals to "
              f"{cc.quantities['residuals']['max']:.2g} px", file=stream, flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="baarda bundle timings: AICON network and a simulated aerial block")
    ap.add_argument("--strips", type=int, default=20)
    ap.add_argument("--per-strip", type=int, default=10)
    ap.add_argument("--no-pycolmap", action="store_true", help="skip pycolmap's solve of the aerial block")
    a = ap.parse_args(argv)
    run(n_strips=a.strips, per_strip=a.per_strip, pycolmap=not a.no_pycolmap)
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(ROOT / "benchmarks"))
    raise SystemExit(main())
