"""Monte Carlo: robust estimation (Huber, Danish) against iterated data snooping on simulated blunders.

A linear model (quadratic trend at 20 uneven abscissae, unequal σ, one high-leverage end) is
simulated with normal noise and one blunder of k σ on a random row whose redundancy is at least
0.5.  Per realisation:

- IDS (α0 = 0.1 %, K = 3.29, Kok's stopping rule) *detects* when it removes the blunder row;
- Huber / Danish (IRLS, scale σ √r of the first adjustment, or of the current one: "-current") *detect* when the blunder row ends with weight < 0.5;
- every other row removed / down-weighted is a *false alarm*.

``pytest -s`` prints the rates.  Asserted is only what must hold: a 10σ blunder is detected in
more than 95 % of the realisations by each method, and without blunders the per-row false-alarm
rates stay small (IDS ≤ α0 binomially; Huber's ω < 0.5 means |u| > 3, Danish's |u| > 3.25, ≈ 0.1–0.3 %
per row for normal residuals; measured 0.5-0.9 %, see the test) — fixed seeds.  The slow variant runs more realisations and
blunder sizes.
"""

import numpy as np
import pytest

from baarda.pipeline.stats import LinearModel, irls, iterated_data_snooping, weighted_linear_refit


KEYS = ("ids", "huber", "danish", "huber-current", "danish-current")


def _design():
    t = np.array([0.0, 0.4, 0.9, 1.3, 1.8, 2.0, 2.6, 3.1, 3.3, 3.9, 4.4, 4.8, 5.5, 5.9, 6.4, 7.0, 7.3,
                  7.9, 8.5, 12.0])
    A = np.c_[np.ones_like(t), t, 0.1 * t ** 2]
    sig = np.linspace(0.5, 1.5, t.size)[np.argsort(np.sin(7 * t))]   # uneven, scrambled
    return A, sig


def simulate(N, k, seed):
    """Rates over N realisations with one blunder of k σ (k = 0: no blunder)."""
    A, sig = _design()
    n = len(sig)
    r = LinearModel(A, np.zeros(n), 1 / sig ** 2).adjust().snapshot.r
    candidates = np.flatnonzero(r >= 0.5)
    g = np.random.default_rng(seed)
    x_true = np.array([1.0, 0.5, -0.3])
    det = dict.fromkeys(KEYS, 0)
    fa = dict.fromkeys(KEYS, 0)
    for _ in range(N):
        l = A @ x_true + sig * g.standard_normal(n)
        j = int(g.choice(candidates))
        if k:
            l[j] += k * sig[j] * g.choice([-1.0, 1.0])
        m = LinearModel(A, l, 1 / sig ** 2)
        snap = m.adjust().snapshot
        ids = iterated_data_snooping(m, snap, alpha0=0.001)
        flagged = {"ids": set(ids.removed)}
        for method in ("huber", "danish"):
            for std, suffix in (("redundancy", ""), ("current", "-current")):
                res = irls(weighted_linear_refit(m), snap, method, standardise=std)
                flagged[method + suffix] = set(res.downweighted.tolist())
        for key, rows in flagged.items():
            if k:
                det[key] += j in rows
                fa[key] += len(rows - {j})
            else:
                fa[key] += len(rows)
    clean_rows = N * (n - (1 if k else 0))
    return ({m: det[m] / N for m in det} if k else None), {m: fa[m] / clean_rows for m in fa}, N * n


def _print(k, det, fa, N):
    print(f"\nblunder {k:g} σ, {N} realisations of 20 rows:")
    for m in KEYS:
        d = "" if det is None else f"detection {100 * det[m]:5.1f} %, "
        print(f"  {m:14s} {d}false alarms per clean row {100 * fa[m]:.3f} %")


def _binomial_upper(p, n, z=4.0):
    return p + z * np.sqrt(p * (1 - p) / n)


def test_ten_sigma_blunder_detected_by_all():
    det, fa, _ = simulate(150, 10.0, seed=11)
    _print(10, det, fa, 150)
    for m in KEYS:
        assert det[m] > 0.95, m


def test_false_alarms_without_blunders():
    N = 150
    _, fa, rows = simulate(N, 0.0, seed=12)
    _print(0, None, fa, N)
    # IDS at α0 = 0.1 %: the first step tests every row at α0 (and stops when the global test
    # accepts), so per row at most ≈ α0.  Huber/Danish judge the *final* residuals: a row that is
    # down-weighted takes more of its own error (its redundancy in the weighted adjustment grows
    # towards 1), so |u| > 3 is more frequent than the normal 0.27 % (measured 0.5-0.9 % here); the
    # bound only catches a wrong scale (σ instead of σ √r, or σ̂0), which gives several per cent.
    assert fa["ids"] <= _binomial_upper(0.001, rows)
    assert all(fa[m] < 0.02 for m in KEYS[1:])


@pytest.mark.slow
@pytest.mark.parametrize("k", [0.0, 3.0, 4.0, 5.0, 6.0, 10.0])
def test_rates_slow(k):
    N = 2000
    det, fa, rows = simulate(N, k, seed=100 + int(k))
    _print(k, det, fa, N)
    if k == 10.0:
        assert all(det[m] > 0.97 for m in det)
    if k == 0.0:
        assert fa["ids"] <= _binomial_upper(0.001, rows)
