"""Timing benchmarks of the bundle (not tests: ``pytest -m benchmark tests/bundle -s``).

Prints set-up / linearise / solve / covariance times for the AICON network, a simulated
200-photo aerial block and BAL problem-49 (49 cameras, 7 776 points, 31 843 observations).
Set ``OPENBLAS_NUM_THREADS=1`` on a loaded machine: multi-threaded OpenBLAS on small dense
factorisations is orders of magnitude slower under contention.
"""

import time

import numpy as np
import pytest

from baarda.pipeline.adjustment import BundleSettings, adjust

pytestmark = pytest.mark.benchmark


def _print(name, res, wall):
    t = res.timings
    print(f"\n{name}: {len(res.block_in.photos)} photos, {int(res.problem.point_used.sum())} points, "
          f"{int(res.obs_active.sum())} obs; {res.iterations} iterations; total {wall:.2f} s "
          f"(initial {t.initial_values:.2f}, linearise {t.linearize:.2f}, solve {t.solve:.2f}, "
          f"covariance {t.covariance:.2f}); sigma0_hat {res.sigma0_hat:.4f}; mode {res.problem.normals.gram_mode}")


def test_benchmark_aicon(shared_data):
    from baarda.plugins.aicon.reader import aicon_block, perturb_initial_values, read_aicon

    blk = aicon_block(read_aicon(shared_data / "aicon-closerange" / "example"))
    start = perturb_initial_values(blk, np.random.default_rng(1), sigma_position=50.0, sigma_angle_deg=1.0,
                                   sigma_c=0.2, zero_distortion=True)
    t0 = time.perf_counter()
    res = adjust(start, BundleSettings(datum="free"))
    _print("AICON (free network, self-calibration, perturbed start)", res, time.perf_counter() - t0)


def test_benchmark_aerial_200():
    from baarda.pipeline.synthetic.aerial import simulate_aerial, perturb_start

    noisy, exact = simulate_aerial(np.random.default_rng(3), n_strips=20, photos_per_strip=10)
    start = perturb_start(noisy, np.random.default_rng(4), position=1.0, angle=0.002, point=1.0)
    t0 = time.perf_counter()
    res = adjust(start)
    _print("aerial 20 × 10", res, time.perf_counter() - t0)


def test_benchmark_bal49(shared_data):
    from baarda.plugins.bal.bal import block_from_bal, read_bal

    blk = block_from_bal(read_bal(shared_data / "bal" / "problem-49-7776-pre.txt"))
    settings = BundleSettings(datum="free", datum_centres=True, max_iter=100, tol_rel=1e-6)
    t0 = time.perf_counter()
    res = adjust(blk, settings, covariance=False)
    _print("BAL problem-49 (Ceres-like function tolerance 1e-6, no covariance)", res, time.perf_counter() - t0)
