"""What every adjustment hands to the statistics library.

Any least-squares adjustment in baarda — the 2-D Helmert transformation of a stereo pair, the
bundle, the independent-model block, a user's own — reports its per-observation quantities in a
:class:`Snapshot`.  The statistics library (global test, w-test, Pope's τ, MDB, data snooping,
IDS, …) works on snapshots only, so it serves every adjustment alike.  For iterated methods an
adjustment also offers ``refit(active) -> Snapshot`` (see :class:`Refittable`).

Rows are *scalar* observations (an image point gives two rows, x and y, sharing a ``group``).
With a full weight matrix P (correlated x, y) the general formulas are used:

    w_i   = (P v)_i / (σ0 √(P Qvv P)_ii)          (standardized residual, Baarda)
    ∇̂l_i = (P v)_i / (P Qvv P)_ii               (estimated gross error)
    ∇0l_i = δ0 σ0 / √(P Qvv P)_ii                 (minimal detectable bias)
    r_i   = (Qvv P)_ii                            (redundancy number)

which reduce to ``v_i / (σ0 √(Qvv)_ii)``, ``v_i / r_i`` and ``σ_li δ0 / √r_i`` for diagonal P.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np


@dataclass(frozen=True, eq=False)
class Snapshot:
    """Per-observation statistics of one adjustment (n scalar observation rows).

    Attributes
    ----------
    v : (n,) residuals, observed minus computed (0 for inactive rows).
    Pv : (n,) ``P @ v``.
    PQvvP : (n,) diagonal of ``P Qvv P`` (0 for inactive rows).
    r : (n,) redundancy numbers ``(Qvv P)_ii`` (0 for inactive rows).
    sigma_l : (n,) a-priori standard deviation of each observation, ``σ0 √(P⁻¹)_ii``.
    vtpv : float, ``vᵀ P v`` over the active rows (including weighted constraints).
    dof : int, degrees of freedom of the adjustment (active rows + constraints − unknowns).
    sigma0 : float, a-priori standard deviation of unit weight.
    active : (n,) bool, rows used in this adjustment.
    labels : (n,) str, e.g. ``"x 5"`` / ``"photo 11 point 506 y"``.
    group : (n,) int, rows that belong to one image point share a group id (x and y), for
        the joint 2-D test; ``-1`` for rows without a partner.
    PQvvP_blocks : optional dict ``group -> (2, 2)`` block of ``P Qvv P`` for the joint test
        (rows of a group in increasing row order).
    meta : dict, free-form extras of the adjustment.
    v_pred : optional (n,) ``l − f(x̂)`` for *every* row: equal to ``v`` on active rows, the
        predicted residual (the observation against the adjustment without it) on inactive rows.
    sigma_v_pred : optional (n,) standard deviation of ``v_pred`` on inactive rows (σ0-scaled,
        ``σ0 √(Σ_ii + a_i Qxx a_iᵀ − 2 …)``); ``v_pred / sigma_v_pred`` is the w a removed
        observation would have if it were added back alone.  nan on active rows.
    """

    v: np.ndarray
    Pv: np.ndarray
    PQvvP: np.ndarray
    r: np.ndarray
    sigma_l: np.ndarray
    vtpv: float
    dof: int
    sigma0: float = 1.0
    active: np.ndarray | None = None
    labels: np.ndarray | None = None
    group: np.ndarray | None = None
    PQvvP_blocks: dict | None = None
    meta: dict = field(default_factory=dict)
    v_pred: np.ndarray | None = None
    sigma_v_pred: np.ndarray | None = None

    def __post_init__(self):
        n = np.asarray(self.v).shape[0]
        set_ = lambda k, v: object.__setattr__(self, k, v)
        for k in ("v", "Pv", "PQvvP", "r", "sigma_l"):
            a = np.array(getattr(self, k), dtype=float).reshape(-1)
            if a.shape[0] != n:
                raise ValueError(f"Snapshot.{k}: length {a.shape[0]} != {n}")
            a.flags.writeable = False
            set_(k, a)
        act = np.ones(n, bool) if self.active is None else np.array(self.active, bool).reshape(-1)
        act.flags.writeable = False
        set_("active", act)
        labels = np.array([str(i + 1) for i in range(n)] if self.labels is None else self.labels, dtype=str)
        set_("labels", labels)
        grp = np.full(n, -1, int) if self.group is None else np.array(self.group, int)
        set_("group", grp)
        for k in ("v_pred", "sigma_v_pred"):
            if getattr(self, k) is not None:
                a = np.array(getattr(self, k), dtype=float).reshape(-1)
                if a.shape[0] != n:
                    raise ValueError(f"Snapshot.{k}: length {a.shape[0]} != {n}")
                a.flags.writeable = False
                set_(k, a)

    @property
    def n(self) -> int:
        return int(self.v.shape[0])

    @property
    def sigma0_hat(self) -> float:
        """Estimated σ0 = √(vᵀPv / dof) (nan when dof = 0)."""
        return float(np.sqrt(self.vtpv / self.dof)) if self.dof > 0 else float("nan")


def group_rows(group: np.ndarray):
    """Groups (ids >= 0) of a row-group vector, vectorised.

    Returns ``(ids, starts, counts, order)``: ``order`` lists the grouped rows sorted by group id
    (stable, so rows of one group stay in increasing row order); group k occupies
    ``order[starts[k] : starts[k] + counts[k]]``.
    """
    group = np.asarray(group)
    pos = np.flatnonzero(group >= 0)
    order = pos[np.argsort(group[pos], kind="stable")]
    gs = group[order]
    starts = np.flatnonzero(np.r_[True, gs[1:] != gs[:-1]]) if gs.size else np.zeros(0, int)
    counts = np.diff(np.r_[starts, gs.size]).astype(int)
    return gs[starts], starts, counts, order


def pair_rows(group: np.ndarray):
    """Group ids with exactly two rows and their rows ``(m, 2)`` in increasing row order."""
    ids, starts, counts, order = group_rows(group)
    two = counts == 2
    rows = np.stack([order[starts[two]], order[starts[two] + 1]], axis=1) if two.any() \
        else np.zeros((0, 2), int)
    return ids[two], rows


class Refittable(Protocol):
    """An adjustment that can be recomputed with a different set of active rows."""

    def refit(self, active: np.ndarray) -> Snapshot:
        """Adjust again using only rows where ``active`` is True; return the new snapshot."""
        ...
