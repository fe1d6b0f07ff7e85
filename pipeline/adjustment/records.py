"""Typed records the iteration hands on: one :class:`Iteration` per step, the :class:`Convergence`
of an adjustment (its iterations, one read-only column per quantity), the :class:`IterationEvent`
an observer of the iteration receives, and the :class:`Timings` of an adjustment.  All frozen."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

__all__ = ["Iteration", "Convergence", "IterationEvent", "Timings"]


@dataclass(frozen=True, slots=True)
class Iteration:
    """One step of the Levenberg–Marquardt iteration (``iteration`` 0: the start): vᵀPv after it,
    the damping ``lam`` (λ, 0 for a Gauss–Newton step), the largest change of an observation the
    linear model predicted, in σ of that observation (``max_step_sigma``, nan at the start), and
    whether the step's similarity part was applied exactly (``exact_similarity``)."""

    iteration: int
    vtpv: float
    lam: float
    max_step_sigma: float
    exact_similarity: bool = False


@dataclass(frozen=True, eq=False)
class Convergence:
    """The iterations of an adjustment, iteration 0 (the start) first, as a column table: one
    read-only array per quantity of :class:`Iteration` (``iteration``, ``vtpv``, ``lam``,
    ``max_step_sigma``, ``exact_similarity``).  ``conv[i]`` is the :class:`Iteration` ``i`` (a
    slice gives a tuple of them); built with :meth:`of`."""

    iteration: np.ndarray
    vtpv: np.ndarray
    lam: np.ndarray
    max_step_sigma: np.ndarray
    exact_similarity: np.ndarray

    @classmethod
    def of(cls, steps) -> Convergence:
        """From a sequence of :class:`Iteration`."""
        cols = {}
        for f in dataclasses.fields(Iteration):
            col = np.array([getattr(s, f.name) for s in steps], _DTYPES[f.name])
            col.flags.writeable = False
            cols[f.name] = col
        return cls(**cols)

    def __len__(self) -> int:
        return len(self.iteration)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return tuple(self[j] for j in range(len(self))[i])
        return Iteration(int(self.iteration[i]), float(self.vtpv[i]), float(self.lam[i]),
                         float(self.max_step_sigma[i]), bool(self.exact_similarity[i]))

    def __iter__(self):
        return (self[j] for j in range(len(self)))


_DTYPES = {"iteration": int, "vtpv": float, "lam": float, "max_step_sigma": float, "exact_similarity": bool}


@dataclass(frozen=True, slots=True)
class IterationEvent:
    """What an observer of the iteration (:data:`~.lm.ITERATION_CALLBACK`) receives after each
    accepted step: the ``step``, the adjustment's ``max_iter`` and the ``seconds`` since its start."""

    step: Iteration
    max_iter: int
    seconds: float


@dataclass(frozen=True, slots=True)
class Timings:
    """Seconds an adjustment spent: ``setup`` (the problem), ``linearize``, ``solve`` (the reduced
    systems), ``residuals`` (trial steps), ``initial_values``, ``covariance`` (the precision) and
    ``total``.  :meth:`summary` gives them as a mapping (results.json)."""

    setup: float = 0.0
    linearize: float = 0.0
    solve: float = 0.0
    residuals: float = 0.0
    initial_values: float = 0.0
    covariance: float = 0.0
    total: float = 0.0

    def summary(self) -> dict:
        return dataclasses.asdict(self)
