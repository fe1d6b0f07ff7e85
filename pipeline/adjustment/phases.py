"""Progress of the adjustment's long phases besides the iterations (initial values, precision,
external reliability), for a progress bar with an ETA.

:data:`PHASE_CALLBACK` is an observer like :data:`~.lm.ITERATION_CALLBACK`: the bundle stage sets
it (``plugins/bundle/progress.py``), the numerics call :func:`phase_step` as they go; it never
changes a number and costs one context-variable lookup per call when nobody listens.
"""

from __future__ import annotations

import contextvars
from dataclasses import dataclass

__all__ = ["PHASE_CALLBACK", "PhaseEvent", "phase_step"]

PHASE_CALLBACK = contextvars.ContextVar("phase_callback", default=None)


@dataclass(frozen=True, slots=True)
class PhaseEvent:
    """``done`` of ``total`` steps of the phase ``phase`` (e.g. "precision", supernodes)."""

    phase: str
    done: int
    total: int
    unit: str = "it"


def phase_step(phase: str, done: int, total: int, unit: str = "it") -> None:
    """Tell the observer (if any) that ``done`` of ``total`` steps of ``phase`` are done."""
    cb = PHASE_CALLBACK.get()
    if cb is not None:
        cb(PhaseEvent(phase, int(done), int(total), unit))
