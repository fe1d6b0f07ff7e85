"""2-D Helmert (4-parameter similarity) transformation left → right, as a linear model.

Pure numerics: arrays in, :class:`baarda.pipeline.stats.LinearModel` / small results out.

Observation equations (paper 000; right coordinates observed, left coordinates fixed)::

    xR = a xL − b yL + tx
    yR = b xL + a yL + ty

Unknowns ``(a, b, tx, ty)``; scalar rows are ordered ``x1, y1, x2, y2, …``.  Residuals are
observed minus computed, ``v = l − A x̂`` (docs/conventions.md), the sign of the paper's
Table 3.  The residuals do not depend on how the rotation is signed (``b`` ↔ ``−b``) nor on the
origin of either photo's coordinates (the shifts are absorbed by ``tx, ty``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from baarda.pipeline.geometry.transforms import helmert_design
from baarda.pipeline.stats import LinearModel, w_test

UNKNOWNS = ("a", "b", "tx", "ty")


def row_labels(point_ids, prefix: str = "") -> list[str]:
    """Scalar-row labels ``X5``, ``Y5`` (the paper's notation), optionally prefixed (``"L-R "``)."""
    return [f"{prefix}{c}{p}" for p in point_ids for c in "XY"]


def helmert_model(xy_left, xy_right, *, sigma0: float = 1.0, P=None, labels=None, group=None,
                  prefix: str = "") -> LinearModel:
    """The linear model of one pair: right coordinates (n, 2) observed, left (n, 2) fixed.

    ``P`` is None (all 2n right coordinates equally weighted, as in the paper) or a (2n,) / (2n, 2n)
    weight matrix in row order.  ``group`` defaults to one group per point (x and y together).
    """
    xy_right = np.asarray(xy_right, float).reshape(-1, 2)
    n = xy_right.shape[0]
    A = helmert_design(xy_left)
    if labels is None:
        labels = row_labels([str(i + 1) for i in range(n)], prefix)
    if group is None:
        group = np.repeat(np.arange(n), 2)
    return LinearModel(A, xy_right.reshape(-1), P=P, sigma0=sigma0, labels=labels, group=group,
                       names=[f"{prefix}{u}" for u in UNKNOWNS])


def stack_models(models: list[LinearModel]) -> LinearModel:
    """One block-diagonal model from independent pair models (4 unknowns each).

    All models must share σ0.  Groups are renumbered so that they stay unique.
    """
    if len(models) == 1:
        return models[0]
    sigma0 = models[0].sigma0
    if any(m.sigma0 != sigma0 for m in models):
        raise ValueError("stack_models: all pair models must share sigma0")
    A = sp.block_diag([m.A for m in models], format="csr")
    l = np.concatenate([m.l for m in models])
    if all(m.kind == "identity" for m in models):
        P = None
    elif all(m.kind != "full" for m in models):
        P = np.concatenate([m.P for m in models])
    else:
        P = sp.block_diag([np.diag(m.P) if m.kind != "full" else m.P for m in models]).toarray()
    groups, offset = [], 0
    for m in models:
        g = np.where(m.group >= 0, m.group + offset, -1)
        offset = max(offset, int(g.max()) + 1) if g.size else offset
        groups.append(g)
    return LinearModel(A, l, P=P, sigma0=sigma0, labels=np.concatenate([m.labels for m in models]),
                       group=np.concatenate(groups), names=sum((m.names for m in models), []))


def outside_format(xy: np.ndarray, format_mm, margin_mm: float = 0.0) -> np.ndarray:
    """(n,) bool: a coordinate pair lies outside the format ``(w, h)`` centred on the origin.

    A format with nan (unknown) gives all False.
    """
    xy = np.asarray(xy, float).reshape(-1, 2)
    w, h = np.asarray(format_mm, float)
    if not (np.isfinite(w) and np.isfinite(h)):
        return np.zeros(xy.shape[0], bool)
    return (np.abs(xy[:, 0]) > w / 2 + margin_mm) | (np.abs(xy[:, 1]) > h / 2 + margin_mm)


@dataclass(frozen=True)
class SwapCandidate:
    """Exchanging the right coordinates of points ``i`` and ``j`` (indices into the pair's points)."""

    i: int
    j: int
    vtpv_before: float
    vtpv_after: float
    w_after: tuple[float, float, float, float]
    """standardized residuals (x_i, y_i, x_j, y_j) after the exchange."""


def swap_trials(xy_left, xy_right, candidates, *, sigma0: float, critical: float, P=None,
                min_gain: float = 2.0) -> list[SwapCandidate]:
    """Swapped point numbers: exchanges of right coordinates that make the misfit vanish.

    For every candidate ``i`` (index of a flagged point) and every other point ``j`` the right
    coordinates of ``i`` and ``j`` are exchanged and the transformation adjusted again.  An
    exchange is kept when afterwards all four standardized residuals of ``i`` and ``j`` pass the
    w-test (``|w| ≤ critical`` with the a-priori ``sigma0``) and ``vᵀPv`` drops by at least the
    factor ``min_gain``.  For each ``i`` only the best ``j`` (smallest ``vᵀPv``) is returned;
    a pair found from both ends is returned once.  Uses the same weights for the exchanged rows.
    """
    xy_left = np.asarray(xy_left, float).reshape(-1, 2)
    xy_right = np.asarray(xy_right, float).reshape(-1, 2)
    n = xy_left.shape[0]
    if n < 4:  # 3 points leave 2 redundant coordinates: an exchange cannot be told from a blunder
        return []
    base = helmert_model(xy_left, xy_right, sigma0=sigma0, P=P).adjust().snapshot.vtpv
    found: dict[frozenset, SwapCandidate] = {}
    for i in sorted(set(int(c) for c in candidates)):
        best = None
        for j in range(n):
            if j == i:
                continue
            xr = xy_right.copy()
            xr[[i, j]] = xr[[j, i]]
            snap = helmert_model(xy_left, xr, sigma0=sigma0, P=P).adjust().snapshot
            w = w_test(snap)[[2 * i, 2 * i + 1, 2 * j, 2 * j + 1]]
            if np.all(np.abs(w) <= critical) and snap.vtpv * min_gain <= base:
                if best is None or snap.vtpv < best.vtpv_after:
                    best = SwapCandidate(i, j, float(base), float(snap.vtpv), tuple(float(x) for x in w))
        if best is not None:
            key = frozenset((best.i, best.j))
            if key not in found or best.vtpv_after < found[key].vtpv_after:
                found[key] = best
    return sorted(found.values(), key=lambda s: s.vtpv_after)
