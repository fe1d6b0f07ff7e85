"""Figures any adjustment has (matplotlib): the w-test statistics against N(0, 1), redundancy
numbers.  Part of the engine (stages' ``plots`` methods call it); the numerical libraries never
import matplotlib.  Every function returns a figure; the engine draws it with Agg."""

from __future__ import annotations

import numpy as np
from scipy import stats as sps


QQ_POINTS = 20_000
"""Order statistics drawn in the QQ plot (evenly spaced in rank; the extremes always)."""


def _plt():
    import matplotlib.pyplot as plt

    return plt


def w_distribution(w, critical: float, title: str = "w-test statistics"):
    """Histogram of w against N(0, 1) and the normal QQ plot."""
    plt = _plt()
    w = np.asarray(w, float)
    w = w[np.isfinite(w)]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8))
    lim = max(4.5, float(np.max(np.abs(w))) if w.size else 4.5)
    bins = np.linspace(-lim, lim, max(15, min(80, int(np.sqrt(max(w.size, 1))) * 2)))
    a.hist(w, bins=bins, density=True, color="#8fb3de", ec="#4a6fa0", lw=0.5, label=f"w ({w.size})")
    x = np.linspace(-lim, lim, 400)
    a.plot(x, sps.norm.pdf(x), color="k", lw=1.2, label="N(0, 1)")
    for s in (-critical, critical):
        a.axvline(s, color="#c0392b", ls="--", lw=1)
    a.set_xlabel("w")
    a.set_title(f"{title}: histogram; critical |w| = {critical:.3g}", fontsize=10)
    a.legend(fontsize=8)
    if w.size:
        k = np.unique(np.linspace(0, w.size - 1, min(w.size, QQ_POINTS)).round().astype(int))
        q = sps.norm.ppf((k + 0.5) / w.size)      # every quantile of a small sample, a thinned set of a large one
        b.plot(q, np.sort(w)[k], ".", ms=3, color="#1f4e9c")
    b.plot([-lim, lim], [-lim, lim], color="k", lw=0.8)
    b.axhline(critical, color="#c0392b", ls="--", lw=1)
    b.axhline(-critical, color="#c0392b", ls="--", lw=1)
    b.set_xlabel("N(0, 1) quantile")
    b.set_ylabel("sorted w")
    b.set_title("normal QQ plot", fontsize=10)
    fig.tight_layout()
    return fig


def redundancy_numbers(r, labels_x=None, title="Redundancy numbers r = (Qvv P)ii"):
    plt = _plt()
    r = np.asarray(r, float)
    fig, ax = plt.subplots(figsize=(6.5, 3.4))
    ax.hist(r, bins=np.linspace(0, 1, 41), color="#9bc49b", ec="#3f7a3f", lw=0.5)
    ax.axvline(np.mean(r) if r.size else 0, color="k", lw=1, label=f"mean {np.mean(r):.3f}" if r.size else "")
    ax.set_xlabel("r")
    ax.set_ylabel("rows")
    ax.set_title(f"{title}; smallest {np.min(r):.3g}" if r.size else title, fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig
