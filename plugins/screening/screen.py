"""Screening of one stereo pair by the 2-D Helmert transformation (pure numerics).

:func:`screen_pair` adjusts the transformation left → right (:mod:`.helmert`), runs the
statistics library on it (global test, data snooping with the a-priori σ0, Pope's τ with σ̂0)
and adds the checks a comparator operator needs before any adjustment: residuals beyond a
threshold, coordinates outside the format and swapped point numbers.  Nothing here reads files
or logs; the stage turns the result into tables, a report and a recording.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from baarda.pipeline.stats import (DataSnoopingResult, GlobalTestResult, LinearAdjustment, LinearModel,
                            PopeResult, data_snooping, global_test, pope_test)

from .helmert import SwapCandidate, helmert_model, outside_format, row_labels, swap_trials

FLAG_METHODS = ("data-snooping", "pope", "threshold", "format", "swap")
"""Checks that can mark an observation as flagged (option ``flag_by``)."""


@dataclass(frozen=True)
class ScreeningSettings:
    sigma0: float = 0.2          # mm, a-priori σ of one right coordinate about the transformation
    alpha0: float = 0.001        # data snooping (two-sided, per residual)
    beta0: float = 0.80
    alpha_pope: float = 0.001    # Pope τ (two-sided, per residual)
    threshold_mm: float = 2.0
    format_margin_mm: float = 0.0
    detect_swaps: bool = True
    flag_by: tuple[str, ...] = ("pope", "threshold", "format", "swap")
    alpha_global: float | str = 0.05   # global test: two-sided χ² at this α, or "B-method"


@dataclass(frozen=True, eq=False)
class PairScreening:
    """Result of :func:`screen_pair` for one pair with m common points (2m scalar rows x1, y1, …)."""

    point_ids: list[str]
    labels: np.ndarray                 # (2m,) "X5", "Y5" (prefixed for multi-pair blocks)
    xy_left: np.ndarray                # (m, 2)
    xy_right: np.ndarray               # (m, 2)
    model: LinearModel
    adjustment: LinearAdjustment
    global_: GlobalTestResult
    snooping: DataSnoopingResult
    pope: PopeResult
    beyond: np.ndarray                 # (2m,) |v| > threshold
    outside_left: np.ndarray           # (m,) left point outside the format
    outside_right: np.ndarray          # (m,)
    swaps: list[SwapCandidate]
    flagged: np.ndarray                # (2m,) flagged by any method in settings.flag_by
    settings: ScreeningSettings
    notes: list[str] = field(default_factory=list)

    @property
    def swap_partner(self) -> list[str]:
        """(m,) id of the point each point's right coordinates seem swapped with ('' if none)."""
        out = [""] * len(self.point_ids)
        for s in self.swaps:
            out[s.i], out[s.j] = self.point_ids[s.j], self.point_ids[s.i]
        return out

    @property
    def most_suspicious(self) -> int | None:
        """Row with the largest |w| (equivalently |τ|): where the screening points first."""
        return self.snooping.largest

    def method_flags(self) -> dict[str, np.ndarray]:
        """(2m,) bool per check, point-level checks spread to both rows of the point."""
        swapped = np.zeros(len(self.point_ids), bool)
        for s in self.swaps:
            swapped[[s.i, s.j]] = True
        return {
            "data-snooping": np.asarray(self.snooping.flagged, bool),
            "pope": np.asarray(self.pope.flagged, bool),
            "threshold": self.beyond,
            "format": np.repeat(self.outside_left | self.outside_right, 2),
            "swap": np.repeat(swapped, 2),
        }


def screen_pair(xy_left, xy_right, point_ids, settings: ScreeningSettings, *,
                format_left=(np.nan, np.nan), format_right=(np.nan, np.nan),
                prefix: str = "") -> PairScreening:
    """Screen one pair.  ``xy_left``/``xy_right`` (m, 2) mm of the m common points, m ≥ 3."""
    xy_left = np.asarray(xy_left, float).reshape(-1, 2)
    xy_right = np.asarray(xy_right, float).reshape(-1, 2)
    m = xy_left.shape[0]
    if m < 3:
        raise ValueError(f"the Helmert screening needs at least 3 common points, got {m}")
    ids = [str(p) for p in point_ids]
    labels = np.array(row_labels(ids, prefix))
    model = helmert_model(xy_left, xy_right, sigma0=settings.sigma0, labels=labels)
    adj = model.adjust()
    snap = adj.snapshot
    gt = global_test(snap, alpha=settings.alpha_global, alpha0=settings.alpha0, beta0=settings.beta0)
    ds = data_snooping(snap, settings.alpha0, settings.beta0)
    pt = pope_test(snap, settings.alpha_pope)
    notes = []
    if snap.dof < 2:
        notes.append(f"{m} common points leave {snap.dof} degree(s) of freedom: Pope's τ needs 2, "
                     "the screening is weak")
    beyond = np.abs(adj.v) > settings.threshold_mm
    out_l = outside_format(xy_left, format_left, settings.format_margin_mm)
    out_r = outside_format(xy_right, format_right, settings.format_margin_mm)
    if not np.isfinite(np.asarray(format_left, float)).all() or \
            not np.isfinite(np.asarray(format_right, float)).all():
        notes.append("camera format unknown: coordinates not checked against the format")
    swaps: list[SwapCandidate] = []
    if settings.detect_swaps:
        cand_rows = ds.flagged | pt.flagged | beyond
        candidates = np.unique(np.flatnonzero(cand_rows) // 2)
        if candidates.size:
            swaps = swap_trials(xy_left, xy_right, candidates, sigma0=settings.sigma0,
                                critical=ds.critical)
    res = PairScreening(ids, labels, xy_left, xy_right, model, adj, gt, ds, pt, beyond, out_l, out_r,
                        swaps, np.zeros(2 * m, bool), settings, notes)
    flags = res.method_flags()
    flagged = np.zeros(2 * m, bool)
    for name in settings.flag_by:
        flagged |= flags[name]
    object.__setattr__(res, "flagged", flagged)
    return res
