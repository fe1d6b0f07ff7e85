"""Iterated data snooping (Kok 1984; paper 000 §3).

Each iteration: w-test of all active rows; if the largest |w| exceeds K (3.29 for α0 = 0.1 %),
remove that row and adjust again; continue while the global test of the new adjustment — with
``dof − c`` degrees of freedom (c rows removed) and the B-method level α′ with
``δ(α′, β0, dof − c, ∞) = δ(α0, β0, 1, ∞)`` — still rejects.  The first snooping step does not
wait for the global test (Kok; Grün: in practice there is almost always a gross error), unless
``gate_first=True`` (Baarda's original order: global test first).

``stop="w-test"`` drops the global test as a stopping rule: rows are removed while the largest
|w| exceeds K.  That is the rule when the a-priori σ were scaled from these same residuals (a
variance component): the global test then accepts by construction and would stop with w-values
far beyond K left.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Literal

import numpy as np

from baarda.pipeline.options import check_bounds, option
from baarda.pipeline.stats.baarda import ALPHA_GLOBAL, B_METHOD, data_snooping, global_level, global_test
from baarda.pipeline.stats.critical import critical_normal
from baarda.pipeline.stats.snapshot import Refittable, Snapshot

__all__ = ["IDSStep", "IDSResult", "iterated_data_snooping", "SnoopingLevels", "SnoopingConfig"]


@dataclass(frozen=True)
class IDSStep:
    """One iteration: the adjustment with ``c`` rows removed and what was done with it."""

    iteration: int  # = c, rows removed before this adjustment
    dof: int
    T: float  # global test statistic
    critical: float  # F(1 − α′; dof, ∞) (or F(1 − α/2; dof, ∞) with a fixed alpha_global)
    alpha_prime: float  # the global test's level at this step (α′ of the B-method by default)
    global_rejected: bool  # T above the critical value
    w_max: float  # largest |w| (signed value of that row)
    row: int | None
    label: str | None
    removed: bool  # this row was removed after this step


@dataclass(frozen=True, eq=False)
class IDSResult:
    removed: list[int]
    removed_labels: list[str]
    history: list[IDSStep]
    snapshot: Snapshot  # final adjustment
    active: np.ndarray
    stop_reason: str
    critical: float  # K of the w-test

    def summary(self) -> dict:
        return {"K": self.critical, "removed": self.removed_labels, "stop": self.stop_reason,
                "history": [asdict(s) for s in self.history]}


def iterated_data_snooping(model: Refittable, snap: Snapshot, alpha0: float = 0.001,
                           beta0: float = 0.80, critical: float | None = None,
                           max_iter: int | None = None, gate_first: bool = False,
                           stop: Literal["global-test", "w-test"] = "global-test",
                           alpha_global: float | str = B_METHOD) -> IDSResult:
    """Kok's iterated data snooping starting from ``snap`` (an adjustment of ``model``); ``stop``
    is the stopping rule (module docstring).  ``alpha_global`` is the level of the global test that
    stops it: the B-method α′ (Kok, the default), or a fixed level α whose upper critical value
    F(1 − α/2; dof, ∞) it then stops below (a σ̂0 that is too *small* is no reason to remove rows)."""
    if stop not in ("global-test", "w-test"):
        raise ValueError(f"stop must be 'global-test' or 'w-test', got {stop!r}")
    K = critical_normal(alpha0) if critical is None else float(critical)
    level = global_level(alpha_global)
    active = np.array(snap.active, bool)
    current = snap
    removed: list[int] = []
    history: list[IDSStep] = []
    while True:
        c = len(removed)
        gt = global_test(current, alpha=level, alpha0=alpha0, beta0=beta0)
        ds = data_snooping(current, alpha0, beta0, K)
        i = ds.largest
        wmax = float(ds.w[i]) if i is not None else float("nan")
        go = False
        if stop == "global-test" and (c > 0 or gate_first) and not gt.too_large:
            reason = f"global test accepts (T = {gt.T:.4g} <= {gt.critical:.4g}, dof {gt.dof})"
        elif i is None or abs(wmax) <= K:
            reason = f"no |w| above K = {K:.4g}"
        elif max_iter is not None and c >= max_iter:
            reason = f"max_iter = {max_iter} reached"
        elif current.dof <= 1:
            reason = "removal would leave no redundancy"
        else:
            go, reason = True, ""
        history.append(IDSStep(c, gt.dof, gt.T, gt.critical, gt.alpha, bool(gt.too_large), wmax,
                               i, None if i is None else str(current.labels[i]), go))
        if not go:
            break
        active[i] = False
        removed.append(i)
        current = model.refit(active.copy())
    if stop == "w-test":
        reason += " (stop = 'w-test': the global test does not stop the rejections)"
    return IDSResult(removed, [str(snap.labels[i]) for i in removed], history, current,
                     active, reason, K)


@dataclass(frozen=True)
class SnoopingLevels:
    """The level and power of the w-test, declared once for every stage that tests its residuals
    (``alpha0``, ``beta0``): the base of :class:`SnoopingConfig`, and of the options of
    helmert-screening and independent-models."""

    alpha0: float = option(0.001, "significance level of the w-test, i.e. of data snooping (two-sided, per "
                                  "observation; K = Φ⁻¹(1 − α0/2))", gt=0.0, lt=1.0)
    beta0: float = option(0.80, "power β0 (δ0 for the MDBs; the B-method α′ of IDS's global test)", gt=0.0, lt=1.0)
    alpha_global: float | Literal["B-method"] = option(
        ALPHA_GLOBAL, "level of the global test of σ̂0²/σ0² reported as the verdict: two-sided χ² at this α "
                      "(default 5 %), or \"B-method\" for Baarda's one-sided α′ (from alpha0, beta0, dof)",
        gt=0.0, lt=1.0)

    def __post_init__(self):
        check_bounds(self)


@dataclass(frozen=True)
class SnoopingConfig(SnoopingLevels):
    """The levels of the w-test (:class:`SnoopingLevels`) and the limits of iterated rejection, declared
    once: the bundle's ``[bundle.tests]`` group (``StatTestsConfig`` adds ``blunders``) and
    blunder-rejection's options (which inherit them as top-level options) —
    :func:`iterated_data_snooping`'s ``alpha0``, ``beta0``, ``max_iter`` and ``stop``."""

    max_rejections: int = option(50, "iterated rejection (IDS; blunder-rejection's Pope too): at most this many "
                                     "rejected rows", ge=0)
    ids_stop: Literal["global-test", "w-test"] = option(
        "global-test", "iterated data snooping stops when the global test accepts (Kok), or goes on while "
                       "any |w| exceeds the critical value (for a-priori σ scaled from these data, where "
                       "the global test accepts by construction)")
