"""The ``adjustment`` artefact: what an adjusting stage hands to ``blunder-rejection``.

Any stage that adjusts image observations (``helmert-screening``, ``bundle``, a user's own) writes
an :class:`AdjustmentArtefact` under the artefact name ``"adjustment"``.  ``blunder-rejection``
needs nothing else: the snapshot for the one-shot tests, ``model.refit(active)`` for the iterated
ones (IDS, iterated Pope) and — for RRR only — a :class:`baarda.pipeline.stats.LinearModel` (design
matrix ``A``, observations ``l``, weights ``P``).  ``obs_rows`` ties every scalar row back to the
block, so that a decision can mark the right observation inactive.

Keep this class minimal: it is shared by several stages (the bundle produces the same class).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from baarda.pipeline.stats.snapshot import Snapshot


@dataclass(frozen=True, eq=False)
class AdjustmentArtefact:
    """An adjustment's statistics, its refittable model and the row → observation map.

    Attributes
    ----------
    name : str
        Which adjustment this is (``"helmert-screening"``, ``"bundle"``), for reports.
    snapshot : Snapshot
        The adjustment as the stage left it (rows already removed by the stage are inactive).
    model : Refittable
        ``model.refit(active) -> Snapshot``.  A :class:`baarda.pipeline.stats.LinearModel` (or a
        linearisation at the solution) also allows RRR; anything else gets data snooping, IDS
        and Pope only.
    obs_rows : (n, 2) int array
        For scalar row i: ``obs_rows[i] = (observation index in block.observations, coordinate)``
        with coordinate ``0 = x``, ``1 = y``.  Rows that are not image observations (weighted
        constraints on control points, exterior orientation, …) have ``(-1, -1)``.
    linearise : optional callable ``() -> (LinearModel, n_rows)``
        For a non-linear adjustment (the bundle): its linearisation at the solution, built only
        when a method needs the design (RRR).  Its first ``n_rows`` rows are the snapshot's rows;
        any further rows are weighted constraints, always active and tied to no observation.
    """

    name: str
    snapshot: Snapshot
    model: Any
    obs_rows: np.ndarray
    linearise: Any = None

    def __post_init__(self):
        rows = np.array(self.obs_rows, dtype=int).reshape(-1, 2)
        if rows.shape[0] != self.snapshot.n:
            raise ValueError(f"AdjustmentArtefact {self.name!r}: obs_rows has {rows.shape[0]} rows, "
                             f"the snapshot {self.snapshot.n}")
        rows.flags.writeable = False
        object.__setattr__(self, "obs_rows", rows)

    def refit(self, active) -> Snapshot:
        """Adjust again with the given active rows (delegates to ``model.refit``)."""
        return self.model.refit(active)

    @property
    def supports_rrr(self) -> bool:
        """True when the model exposes ``A``, ``l`` and ``P`` as a LinearModel does, or a
        linearisation is given."""
        return self.linearise is not None or all(hasattr(self.model, k) for k in ("A", "l", "P", "adjust"))

    def linear_model(self):
        """``(LinearModel, active rows)`` for the design-based methods: the model itself, or the
        linearisation (its extra constraint rows active); ``ValueError`` when it cannot be built
        (e.g. too large to hold densely)."""
        if self.linearise is None:
            return self.model, np.asarray(self.snapshot.active, bool)
        model, n_rows = self.linearise()
        if n_rows != self.snapshot.n:
            raise ValueError(f"the linearisation of {self.name!r} has {n_rows} observation rows, the snapshot "
                             f"{self.snapshot.n}")
        return model, np.r_[np.asarray(self.snapshot.active, bool), np.ones(model.n - n_rows, bool)]

    def observations_of(self, rows) -> np.ndarray:
        """Sorted unique block-observation indices of the given scalar rows (bool mask or indices)."""
        idx = np.flatnonzero(rows) if np.asarray(rows).dtype == bool else np.asarray(rows, int)
        idx = idx[idx < len(self.obs_rows)]           # constraint rows of a linearisation: no observation
        obs = self.obs_rows[idx, 0]
        return np.unique(obs[obs >= 0])
