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

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np


class GroupBlocks(Mapping):
    """``group id -> (2, 2)`` blocks of ``P Qvv P`` held in two arrays instead of a dict.

    A mapping like the dict it replaces (``blocks[g]``, ``g in blocks``, ``items()``), but one
    (m,) id array and one (m, 2, 2) array: a dict of a million image points costs ≈ 250 bytes per
    entry (a key, a view object, a hash slot) against 40 here, and :meth:`take` gathers many blocks
    at once.  Read-only."""

    def __init__(self, ids, blocks):
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        blocks = np.asarray(blocks, dtype=float).reshape(-1, 2, 2)
        if ids.shape[0] != blocks.shape[0]:
            raise ValueError(f"GroupBlocks: {ids.shape[0]} ids for {blocks.shape[0]} blocks")
        order = np.argsort(ids, kind="stable")
        self.ids, self.blocks = ids[order], blocks[order]
        if ids.size and (np.diff(self.ids) == 0).any():
            raise ValueError("GroupBlocks: a group id is repeated")
        self.ids.flags.writeable = False
        self.blocks.flags.writeable = False

    @classmethod
    def of(cls, blocks) -> "GroupBlocks":
        """``blocks`` as GroupBlocks (a dict ``group -> (2, 2)``, or GroupBlocks as it is)."""
        if isinstance(blocks, GroupBlocks):
            return blocks
        blocks = dict(blocks or {})
        return cls(list(blocks), [blocks[g] for g in blocks] if blocks else np.zeros((0, 2, 2)))

    def _index(self, groups) -> tuple[np.ndarray, np.ndarray]:
        g = np.asarray(groups, dtype=np.int64).reshape(-1)
        i = np.minimum(np.searchsorted(self.ids, g), max(self.ids.size - 1, 0))
        found = (self.ids[i] == g) if self.ids.size else np.zeros(g.shape, bool)
        return i, found

    def has(self, groups) -> np.ndarray:
        """(k,) bool: which of ``groups`` have a block."""
        return self._index(groups)[1]

    def take(self, groups) -> np.ndarray:
        """(k, 2, 2) blocks of ``groups``; KeyError naming the first missing ones."""
        i, found = self._index(groups)
        if not found.all():
            raise KeyError([int(x) for x in np.asarray(groups).reshape(-1)[~found][:5]])
        return self.blocks[i]

    def __getitem__(self, g):
        i, found = self._index([g])
        if not found[0]:
            raise KeyError(g)
        return self.blocks[i[0]]

    def __iter__(self):
        return (int(g) for g in self.ids)

    def __len__(self) -> int:
        return int(self.ids.size)

    def __contains__(self, g) -> bool:
        try:
            return bool(self._index([g])[1][0])
        except (TypeError, ValueError, OverflowError):
            return False

    def __repr__(self) -> str:
        return f"GroupBlocks({len(self)} groups)"


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
    PQvvP_blocks : optional mapping ``group -> (2, 2)`` block of ``P Qvv P`` for the joint test
        (rows of a group in increasing row order): a dict, or :class:`GroupBlocks` (arrays; what
        the bundle gives, a million image points need no million-entry dict).
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
    PQvvP_blocks: Mapping | None = None
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
        if isinstance(self.labels, np.ndarray) and self.labels.dtype.kind == "U" and self.labels.ndim == 1:
            labels = self.labels              # already strings: shared, not copied (a million rows: 0.3 GB)
        else:
            labels = np.array([str(i + 1) for i in range(n)] if self.labels is None else self.labels, dtype=str)
        if labels.shape[0] != n:
            raise ValueError(f"Snapshot.labels: length {labels.shape[0]} != {n}")
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
