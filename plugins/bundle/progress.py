"""The bundle stage's progress: a bar over the Levenberg–Marquardt iterations of every adjustment
the stage runs (the first one, AP selection, variance components, robust re-weighting, each IDS
re-adjustment) and over the long phases besides them (initial values, precision, external
reliability: :data:`baarda.pipeline.adjustment.PHASE_CALLBACK`), and with ``baarda --verbose``
one Ceres-style line per iteration.

The iteration reports through :data:`baarda.pipeline.adjustment.ITERATION_CALLBACK`, an observer
that never changes the numbers.  The ETA is an upper bound: ``max_iter`` iterations at the mean
rate so far (an adjustment usually stops long before).
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field

from baarda.pipeline.adjustment import ITERATION_CALLBACK, PHASE_CALLBACK, IterationEvent, PhaseEvent

HEADER = "adj iter        vtpv   vtpv_change  max_step/σ      lambda   time(s)"


@dataclass
class Work:
    """What the stage has done so far: adjustments, iterations, wall-clock time since it started."""

    t0: float = field(default_factory=time.perf_counter)
    adjustments: int = 0
    iterations: int = 0
    last_vtpv: float | None = None

    @property
    def seconds(self) -> float:
        return time.perf_counter() - self.t0


CURRENT: ContextVar[Work | None] = ContextVar("bundle_work", default=None)


def current_work() -> Work | None:
    """The :class:`Work` of the running bundle stage (None outside :func:`iteration_progress`)."""
    return CURRENT.get()


def iteration_line(adjustment: int, event: IterationEvent, previous: float | None) -> str:
    s = event.step
    change = "" if previous is None else f"{previous - s.vtpv:13.6e}"
    return (f"{adjustment:3d} {s.iteration:4d} {s.vtpv:11.6e} {change:>13} "
            f"{s.max_step_sigma:11.3e} {s.lam:11.3e} {event.seconds:9.3f}")


@contextmanager
def iteration_progress(ctx, max_iter: int):
    work = Work()
    bar = ctx.progress.bar(max_iter, "adjustment 1, iteration")
    detail = ctx.progress.detail

    phase = [None]           # the long phase the bar shows now (None: the iterations)

    def on_iteration(event: IterationEvent) -> None:
        s = event.step
        if s.iteration == 1:                            # a new adjustment starts
            work.adjustments += 1
            work.last_vtpv = None
            if work.adjustments > 1 or phase[0] is not None:
                bar.reset(event.max_iter, f"adjustment {work.adjustments}, iteration")
                phase[0] = None
            if detail:
                bar.line(HEADER)
        work.iterations += 1
        if detail:
            bar.line(iteration_line(work.adjustments, event, work.last_vtpv))
        work.last_vtpv = s.vtpv
        bar.update(1, vtpv=f"{s.vtpv:.6g}")

    def on_phase(event: PhaseEvent) -> None:
        """Initial values, precision, external reliability: the bar counts their steps (ETA)."""
        if event.phase != phase[0]:
            phase[0] = event.phase
            bar.reset(event.total, event.phase)
            bar.postfix = {}
        if event.done > bar.n:
            bar.update(event.done - bar.n)

    token_cb = ITERATION_CALLBACK.set(on_iteration)
    token_phase = PHASE_CALLBACK.set(on_phase)
    token_work = CURRENT.set(work)
    try:
        yield work
    finally:
        ITERATION_CALLBACK.reset(token_cb)
        PHASE_CALLBACK.reset(token_phase)
        CURRENT.reset(token_work)
        bar.close()
