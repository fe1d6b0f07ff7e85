"""Pope's τ test (σ0 unknown) and its iterated form (Pope 1976; paper 000 eq. 7).

    τ_i = (Pv)_i / (σ̂0 √(PQvvP)_ii),   σ̂0² = vᵀPv / dof,   τ_i ~ τ(dof) under H0.

:func:`pope_iterated` removes the row with the largest |τ| above the critical value, adjusts
again, recomputes σ̂0, the degrees of freedom and the critical value, and repeats until no |τ|
exceeds it.  ``alpha`` is the two-sided level *per residual* (the paper's 0.05 % / 0.1 %);
``familywise=True`` instead spreads ``alpha`` over the tested rows (Šidák).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from baarda.pipeline.stats import tau_distribution
from baarda.pipeline.stats.baarda import RowTestResult, controlled, w_test
from baarda.pipeline.stats.snapshot import Refittable, Snapshot

__all__ = ["PopeResult", "PopeStep", "PopeIteratedResult", "pope_test", "pope_iterated"]


@dataclass(frozen=True, eq=False)
class PopeResult(RowTestResult):
    tau: np.ndarray  # (n,) 0 on inactive/uncontrolled rows
    critical: float
    flagged: np.ndarray
    alpha: float  # level used per residual
    dof: int
    sigma0_hat: float
    largest: int | None
    labels: np.ndarray = field(repr=False)

    def summary(self) -> dict:
        return {"critical": self.critical, "alpha": self.alpha, "dof": self.dof,
                "sigma0_hat": self.sigma0_hat, "flagged": self.flagged_labels,
                "largest": self._largest("tau", self.tau)}


def pope_test(snap: Snapshot, alpha: float = 0.001, familywise: bool = False) -> PopeResult:
    """Pope's τ test of every active row (needs ``dof >= 2``).

    ``alpha`` is per residual (two-sided) unless ``familywise`` (then Šidák over the tested rows).
    """
    ok = controlled(snap)
    dof = int(snap.dof)
    s0h = snap.sigma0_hat
    if dof < 2 or not ok.any() or not s0h > 0:
        return PopeResult(np.zeros(snap.n), float("nan"), np.zeros(snap.n, bool), float(alpha),
                          dof, s0h, None, snap.labels)
    tau = w_test(snap) * (snap.sigma0 / s0h)
    if familywise:
        a = float(-np.expm1(np.log1p(-alpha) / int(ok.sum())))
    else:
        a = float(alpha)
    crit = tau_distribution.critical(a, dof)
    largest = int(np.argmax(np.where(ok, np.abs(tau), -1.0)))
    return PopeResult(tau, crit, ok & (np.abs(tau) > crit), a, dof, s0h, largest, snap.labels)


@dataclass(frozen=True)
class PopeStep:
    iteration: int
    dof: int
    sigma0_hat: float
    critical: float
    tau_max: float
    row: int | None
    label: str | None
    removed: bool


@dataclass(frozen=True, eq=False)
class PopeIteratedResult:
    removed: list[int]
    removed_labels: list[str]
    history: list[PopeStep]
    snapshot: Snapshot  # final adjustment
    stop_reason: str
    alpha: float

    def summary(self) -> dict:
        return {"alpha": self.alpha, "removed": self.removed_labels, "stop": self.stop_reason,
                "history": [s.__dict__ for s in self.history]}


def pope_iterated(model: Refittable, snap: Snapshot, alpha: float = 0.001,
                  max_iter: int | None = None, familywise: bool = False) -> PopeIteratedResult:
    """Iterated Pope test: remove the largest |τ| above τ_c, refit, repeat.

    Stops when no |τ| exceeds the critical value, when ``max_iter`` rows were removed, or when a
    removal would leave fewer than 2 degrees of freedom.
    """
    active = np.array(snap.active, bool)
    current = snap
    removed: list[int] = []
    history: list[PopeStep] = []
    it = 0
    while True:
        res = pope_test(current, alpha, familywise)
        i = res.largest
        tmax = float(abs(res.tau[i])) if i is not None else float("nan")
        exceed = i is not None and tmax > res.critical
        if not exceed:
            reason = "no |tau| above the critical value" if i is not None else "nothing testable"
        elif max_iter is not None and it >= max_iter:
            reason, exceed = f"max_iter = {max_iter} reached", False
        elif current.dof - 1 < 2:
            reason, exceed = "removal would leave fewer than 2 degrees of freedom", False
        history.append(PopeStep(it, res.dof, res.sigma0_hat, res.critical, tmax, i,
                                None if i is None else str(current.labels[i]), bool(exceed)))
        if not exceed:
            break
        active[i] = False
        removed.append(i)
        current = model.refit(active.copy())
        it += 1
    return PopeIteratedResult(removed, [str(snap.labels[i]) for i in removed], history, current,
                              reason, float(alpha))
