"""Monte Carlo of the congruence test on a real network's precision (issue 24, docs/monitoring.md).

One epoch of a bundled monitoring project is adjusted once and its points' joint cofactor matrix Q
(σ0² Q) taken as the precision of one epoch:

* ``--network testfield`` (default): the simulated test field of paper 001,
  fixtures/monitoring/testfield-epochs.toml (10 photos, 21 targets, weighted control of case 5,
  σ 4 µm, self-calibrating); the mover is target 13;
* ``--network panel``: the planned panel of fixtures/monitoring/panel-epochs.toml (free
  self-calibrating network, σ 0.05 px); the mover is T08.

Epoch pairs are then drawn from N(X, σ0² Q) — exactly the distribution the test assumes — and
tested:

* nothing moved: the global congruence test's false-alarm rate must equal α (within its MC error);
* one target moved by its MDD in its worst direction (datum: the other targets declared stable):
  the target's 3-D test must detect it with the power β0 (within MC error);
* one target moved by 3 MDDs, no datum declared: localisation must name exactly that target.

Prints each rate with its Monte Carlo standard error and the ratio to the expected value.

    python benchmarks/congruence_mc.py [--n 1000] [--seed 1] [--network testfield|panel]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


NETWORKS = {"testfield": ("testfield-epochs.toml", "13"), "panel": ("panel-epochs.toml", "T08")}
"""Project of each network and the target the Monte Carlo moves."""


def first_epoch(network: str = "testfield"):
    """The first epoch (``Epoch``) of the network's monitoring project, adjusted by ``baarda run``."""
    from baarda.pipeline.runner import run_project

    text = (ROOT / "fixtures" / "monitoring" / NETWORKS[network][0]).read_text()
    head = text.split('[[stage]]\nuse = "epoch"\nid = "epoch-1"')[0]
    head = head.replace('"../design/', f'"{ROOT}/fixtures/design/').replace(
        '"panel-targets-1.csv"', f'"{ROOT}/fixtures/monitoring/panel-targets-1.csv"')
    head += '[[stage]]\nuse = "epoch"\nid = "epoch-1"\n'
    import tempfile

    tmp = Path(tempfile.mkdtemp(prefix="baarda-cmc-"))
    (tmp / "p.toml").write_text(head)
    out = run_project(tmp / "p.toml", tmp / "run", verbose=False)
    assert out.ok, out.message
    return out.artefacts["epochs"][0]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=1000, help="simulations per case")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--network", choices=sorted(NETWORKS), default="testfield")
    a = ap.parse_args(argv)
    from baarda.pipeline.stats.congruence import congruence

    ep = first_epoch(a.network)
    X, Q, s0 = ep.XYZ, ep.Q, 1.0
    n = len(ep.ids)
    w, V = np.linalg.eigh((Q + Q.T) / 2)
    L = V * np.sqrt(np.clip(w, 0, None))           # Q = L Lᵀ (singular along the datum directions)
    rng = np.random.default_rng(a.seed)
    draw = lambda: X + (L @ rng.normal(size=3 * n)).reshape(n, 3) * s0  # noqa: E731
    alpha, alpha_p, beta0 = 0.05, 0.001, 0.80
    target = ep.ids.index(NETWORKS[a.network][1])
    datum = [i for i in range(n) if i != target]
    base = congruence(X, Q, X, Q, sigma0=s0, datum_points=datum, alpha=alpha, alpha_point=alpha_p,
                      beta0=beta0, localise=False)
    pt = base.points[target]
    wv, Vv = np.linalg.eigh(np.linalg.inv(pt.Q))
    worst = Vv[:, 0] * pt.mdd
    print(f"network {a.network}: {n} points, MDD of {ep.ids[target]} {pt.mdd * 1e6:.1f} µm (α {alpha_p}, β0 {beta0})")
    t0 = time.perf_counter()
    fa = det = loc = 0
    for _ in range(a.n):
        fa += not congruence(draw(), Q, draw(), Q, sigma0=s0, alpha=alpha, localise=False).accepted0
        X2 = draw()
        X2[target] += worst
        det += congruence(draw(), Q, X2, Q, sigma0=s0, datum_points=datum, alpha=alpha, alpha_point=alpha_p,
                          beta0=beta0, localise=False).points[target].p < alpha_p
        X3 = draw()
        X3[target] += 3 * worst
        loc += congruence(draw(), Q, X3, Q, sigma0=s0, alpha=alpha, alpha_point=alpha_p).moved == (target,)
    se = lambda p: np.sqrt(p * (1 - p) / a.n)  # noqa: E731
    for name, k, expect in (("false alarms, nothing moved", fa, alpha), ("detection at one MDD", det, beta0)):
        p = k / a.n
        print(f"{name:34s} {p:.4f} ± {se(p):.4f} (expected {expect}; ratio {p / expect:.3f}, "
              f"{abs(p - expect) / se(expect):.1f} MC σ)")
    print(f"{'localisation names only the mover at 3 MDD':34s} {loc / a.n:.4f} ± {se(loc / a.n):.4f}")
    print(f"{3 * a.n} congruence tests in {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
