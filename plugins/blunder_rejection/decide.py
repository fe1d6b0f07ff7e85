"""Run the configured blunder-rejection methods on an adjustment (no I/O, no logging).

Each method comes from :mod:`baarda.pipeline.stats`; this module only calls them with the settings,
collects one :class:`Decision` per rejected row (with the statistic that decided it) and
a per-method history for the recording.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar, Literal

import numpy as np

from baarda.pipeline import montecarlo
from baarda.pipeline.api import AdjustmentArtefact, option
from baarda.pipeline.options import check_bounds
from baarda.pipeline.stats import (RobustTuning, SnoopingConfig, data_snooping, estimated_errors, irls,
                                   iterated_data_snooping, mdb, pope_iterated, pope_test, rrr, w_test,
                                   weighted_refit)
from baarda.pipeline.stats.critical import delta0 as _delta0


METHODS = ("data-snooping", "ids", "pope", "rrr")
#: robust estimators (IRLS, baarda.pipeline.stats.robust): run on request, not by method = "all"
ROBUST_METHODS = ("robust-huber", "robust-danish", "robust-l1")


@dataclass(frozen=True)
class BlunderOptions(SnoopingConfig):
    """The options of ``blunder-rejection`` and the settings of every function here (one schema).

    ``alpha0``, ``beta0``, ``max_rejections`` and ``ids_stop`` are the statistics library's
    :class:`~baarda.pipeline.stats.SnoopingConfig` (the bundle's ``tests`` group declares them there
    too); the ``robust`` table is its :class:`~baarda.pipeline.stats.RobustTuning` — the IRLS's ``c`` and
    ``standardise``, with the weight function named by ``method = "robust-…"`` (a robust method is
    one of this stage's methods, side by side with the others, so it is no option of its own).
    Ranges are declared on the fields (:func:`~baarda.pipeline.options.check_bounds`)."""

    RENAMED: ClassVar[dict[str, str]] = {"max_iter": "max_rejections"}
    MOVED: ClassVar[dict[str, str]] = {"robust_c": "robust.c", "robust_standardise": "robust.standardise"}
    method: Literal["data-snooping", "ids", "pope", "rrr", "all", "robust-huber", "robust-danish", "robust-l1"] = option(
        "all", "method: data-snooping (one pass, σ0 a priori), ids (Kok's iterated data snooping), "
               "pope (iterated τ test, σ̂0), rrr (recursive residual rejection), or all of them side by side; "
               "robust-huber / robust-danish / robust-l1: robust estimation by IRLS, the rows ending with a "
               "weight below 0.5 are rejected (docs/statistics.md)")
    decide_by: Literal["data-snooping", "ids", "pope", "rrr"] = option(
        "rrr", "with method = all: the method whose rejections act on the block")
    action: Literal["flag", "remove"] = option(
        "flag", "flag: report only; remove: mark the rejected observations inactive in the block")
    critical_w: float = option(0.0, "data snooping / IDS: critical value K; 0 = from alpha0 (3.29), "
                                    "4.13 = Baarda's B-method value", ge=0.0)
    alpha_pope: float = option(0.001, "Pope: two-sided level per residual (τ critical value, dof of each step)",
                               gt=0.0, lt=1.0)
    alpha_rrr: float = option(0.001, "RRR: probability that the whole procedure rejects anything in clean data",
                              gt=0.0, lt=1.0)
    rho: int = option(0, "RRR: number of suspects; 0 = ⌈0.20 (n − u)⌉, which rounds Benciolini et al.'s "
                         "0.15 < ρ/(n − u) < 0.20 up and can leave that range (3 for n − u = 14). "
                         "Give at least one more than the gross errors you expect: an error left among "
                         "the non-suspects masks the others (paper 000's Data 1 needs ρ = 4)", ge=0)
    n_sim: int = option(20000, "RRR: Monte Carlo repetitions of the whole procedure for the critical value H", ge=0)
    rrr_critical: float = option(0.0, "RRR: use this critical value H instead of the Monte Carlo one (0 = simulate)",
                                 ge=0.0)
    robust: RobustTuning = option(RobustTuning(), "robust-* methods: the IRLS's tuning (its weight function is the "
                                                  "method's: robust-huber → Huber …); the first adjustment is the "
                                                  "one given")

    def __post_init__(self):
        check_bounds(self)
        if self.n_sim == 0 and not self.rrr_critical > 0 and self.method in ("rrr", "all"):
            raise ValueError("n_sim = 0 needs an explicit rrr_critical")


@dataclass(frozen=True)
class Decision:
    """One rejected row: which method, at which step, with which statistic and critical value."""

    method: str
    row: int
    label: str
    statistic: str      # "w", "tau", "H_exp"
    value: float
    critical: float
    step: int           # iteration (IDS, Pope) or suspect number (RRR); 0 for one-shot data snooping


@dataclass(frozen=True, eq=False)
class MethodResult:
    method: str
    rejected: list[int]
    decisions: list[Decision]
    history: list[dict]
    summary: dict
    raw: object = field(repr=False, default=None)
    skipped: str | None = None   # reason when the method could not run

    @property
    def rejected_labels(self) -> list[str]:
        return [d.label for d in self.decisions]


def auto_rho(dof: int) -> int:
    """Benciolini–Mussio–Sansò's photogrammetric rule 0.15 < ρ/(n − u) < 0.20: ρ = ⌈0.20 (n − u)⌉."""
    return max(1, math.ceil(0.20 * dof - 1e-9))


def run_data_snooping(art: AdjustmentArtefact, s: BlunderOptions) -> MethodResult:
    snap = art.snapshot
    ds = data_snooping(snap, s.alpha0, s.beta0, s.critical_w or None)
    rows = np.flatnonzero(ds.flagged)
    dec = [Decision("data-snooping", int(i), str(snap.labels[i]), "w", float(ds.w[i]), ds.critical, 0)
           for i in rows[np.argsort(-np.abs(ds.w[rows]))]]
    return MethodResult("data-snooping", [d.row for d in dec], dec, [], ds.summary(), ds)


def run_ids(art: AdjustmentArtefact, s: BlunderOptions) -> MethodResult:
    res = iterated_data_snooping(art.model, art.snapshot, s.alpha0, s.beta0, s.critical_w or None, s.max_rejections,
                                 stop=s.ids_stop)
    dec = [Decision("ids", h.row, h.label, "w", h.w_max, res.critical, h.iteration)
           for h in res.history if h.removed]
    hist = [{"iteration": h.iteration, "dof": h.dof, "T": h.T, "F_critical": h.critical,
             "alpha_prime": h.alpha_prime, "w_max": h.w_max, "label": h.label, "removed": h.removed}
            for h in res.history]
    return MethodResult("ids", [d.row for d in dec], dec, hist, res.summary(), res)


def run_pope(art: AdjustmentArtefact, s: BlunderOptions) -> MethodResult:
    res = pope_iterated(art.model, art.snapshot, s.alpha_pope, s.max_rejections)
    dec = [Decision("pope", h.row, h.label, "tau", _signed_tau(art, res, h), h.critical, h.iteration)
           for h in res.history if h.removed]
    hist = [{"iteration": h.iteration, "dof": h.dof, "sigma0_hat": h.sigma0_hat, "tau_critical": h.critical,
             "tau_max": h.tau_max, "label": h.label, "removed": h.removed} for h in res.history]
    return MethodResult("pope", [d.row for d in dec], dec, hist, res.summary(), res)


def _signed_tau(art, res, step) -> float:
    """|τ|max of a Pope step with the sign of that row's residual at that step."""
    if step.iteration == 0:
        sign = np.sign(art.snapshot.v[step.row]) or 1.0
    else:
        active = np.array(art.snapshot.active, bool)
        active[res.removed[:step.iteration]] = False
        sign = np.sign(art.model.refit(active).v[step.row]) or 1.0
    return float(sign * step.tau_max)


def run_rrr(art: AdjustmentArtefact, s: BlunderOptions, rng, progress=None) -> MethodResult:
    """RRR; ``progress`` (a :class:`~baarda.pipeline.stage.Progress`) shows a bar over the Monte Carlo's tasks."""
    if not art.supports_rrr:
        return MethodResult("rrr", [], [], [], {}, None,
                            skipped=f"the adjustment '{art.name}' offers no linear model (A, l, P)")
    snap = art.snapshot
    try:
        model, active = art.linear_model()
    except ValueError as e:
        return MethodResult("rrr", [], [], [], {}, None, skipped=str(e))
    rho = s.rho or auto_rho(snap.dof)
    mapper = montecarlo.mapper()                           # realisations as tasks on the run's Dask engine
    if progress is not None:
        mapper = progress.mapper(mapper, "RRR Monte Carlo task")
    res = rrr(model, rho, s.alpha_rrr, s.n_sim, rng=rng, active=active, critical=s.rrr_critical or None,
              mapper=mapper)
    dec = [Decision("rrr", row, lab, "H_exp", float(h), res.H, j)
           for j, (row, lab, h, rej) in enumerate(zip(res.suspects, res.suspect_labels, res.H_exp, res.rejected))
           if rej]
    hist = [{"suspect": j, **{k: v for k, v in h.items() if k != "recursive_residuals"}}
            for j, h in enumerate(res.history)]
    summary = res.summary()
    summary["rho"] = rho
    return MethodResult("rrr", [d.row for d in dec], dec, hist, summary, res)


def run_robust(art: AdjustmentArtefact, method: str, s: BlunderOptions) -> MethodResult:
    """IRLS with the weight function of ``method`` (``robust-huber`` …); the rows ending with a weight
    below 0.5 are its rejections (statistic ``weight``, critical value 0.5, step = IRLS iterations)."""
    snap = art.snapshot
    refit, how = weighted_refit(art.model, snap.active, redundancy=s.robust.standardise == "current")
    if refit is None:
        return MethodResult(method, [], [], [], {}, None, skipped=how)
    res = irls(refit, snap, method.split("-", 1)[1], s.robust.c or None, standardise=s.robust.standardise)
    dec = [Decision(method, int(i), str(snap.labels[i]), "weight", float(res.weights[i]), res.threshold,
                    res.iterations) for i in res.downweighted]
    return MethodResult(method, [d.row for d in dec], dec, list(res.history), {"how": how, **res.summary()}, res)


def run_methods(art: AdjustmentArtefact, methods, s: BlunderOptions, rng, progress=None) -> dict[str, MethodResult]:
    """Run each method in ``methods`` (names from :data:`METHODS`) on the adjustment."""
    out = {}
    for m in methods:
        if m == "data-snooping":
            out[m] = run_data_snooping(art, s)
        elif m == "ids":
            out[m] = run_ids(art, s)
        elif m == "pope":
            out[m] = run_pope(art, s)
        elif m == "rrr":
            out[m] = run_rrr(art, s, rng, progress)
        elif m in ROBUST_METHODS:
            out[m] = run_robust(art, m, s)
        else:
            raise ValueError(f"unknown method {m!r}; expected one of {METHODS + ROBUST_METHODS}")
    return out


def row_statistics(art: AdjustmentArtefact, s: BlunderOptions) -> dict[str, np.ndarray]:
    """Per-row statistics of the adjustment as given: v, r, w, τ, ∇̂, MDB."""
    snap = art.snapshot
    return {"v": np.asarray(snap.v), "r": np.asarray(snap.r), "w": w_test(snap),
            "tau": pope_test(snap, s.alpha_pope).tau, "nabla_hat": estimated_errors(snap),
            "mdb": mdb(snap, _delta0(s.alpha0, s.beta0))}
