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
    """The iterations of an adjustment, iteration 0 (the start) first: a sequence of
    :class:`Iteration` with one read-only column per quantity (``iteration``, ``vtpv``, ``lam``,
    ``max_step_sigma``, ``exact_similarity``)."""

    steps: tuple[Iteration, ...]

    def __len__(self) -> int:
        return len(self.steps)

    def __iter__(self):
        return iter(self.steps)

    def __getitem__(self, i):
        return self.steps[i]

    def _column(self, name: str, dtype) -> np.ndarray:
        out = np.array([getattr(s, name) for s in self.steps], dtype)
        out.flags.writeable = False
        return out

    @property
    def iteration(self) -> np.ndarray:
        return self._column("iteration", int)

    @property
    def vtpv(self) -> np.ndarray:
        return self._column("vtpv", float)

    @property
    def lam(self) -> np.ndarray:
        return self._column("lam", float)

    @property
    def max_step_sigma(self) -> np.ndarray:
        return self._column("max_step_sigma", float)

    @property
    def exact_similarity(self) -> np.ndarray:
        return self._column("exact_similarity", bool)


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
