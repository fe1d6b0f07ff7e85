"""Baarda's testing theory on a :class:`~baarda.pipeline.stats.snapshot.Snapshot` (O(n), vectorised).

References: Baarda (1968) *A testing procedure for use in geodetic networks*; Förstner (1985)
*The reliability of block triangulation*; paper 000 eqs. (1)–(6).

    global test   T = vᵀPv / (dof σ0²)  ~ F(dof, ∞) = χ²(dof)/dof        two-sided at α (5 %): reject if
                  T < F(α/2; dof, ∞) or T > F(1−α/2; dof, ∞); B-method: T > F(1−α′; dof, ∞)
    w-test        w_i  = (Pv)_i / (σ0 √(PQvvP)_ii)  ~ N(0, 1)             (diag P: v_i / (σ0 √(Qvv)_ii))
    gross error   ∇̂l_i = (Pv)_i / (PQvvP)_ii                            (diag P: v_i / r_i)
    MDB           ∇0l_i = δ0 σ0 / √(PQvvP)_ii                              (diag P: σ_li δ0 / √r_i)
    external      ∇0x_i = N⁻¹ Aᵀ P e_i ∇0l_i,  δ̄0_i = √(∇0x_iᵀ N ∇0x_i) / σ0  (diag P: √((1−r_i)/r_i) δ0)

Rows that are inactive, or whose residual is not controlled (``r_i ≈ 0``), get ``w = 0``,
``∇̂l = 0`` and ``∇0l = inf`` (inactive: nan).  With ``include_inactive=True`` the w-test and the
estimated errors of removed rows are taken from the predicted residuals (``Snapshot.v_pred``):
the value the row would have if it were put back alone.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy import stats

from baarda.pipeline.stats.critical import alpha_prime, critical_normal
from baarda.pipeline.stats.critical import delta0 as _delta0
from baarda.pipeline.stats.snapshot import Snapshot

__all__ = [
    "RowTestResult", "GlobalTestResult", "B_METHOD", "ALPHA_GLOBAL", "global_level", "global_critical", "DataSnoopingResult", "ExternalReliability",
    "global_test", "w_test", "estimated_errors", "mdb", "data_snooping", "external_reliability",
    "controlled",
]

#: redundancy below which a residual counts as uncontrolled (no test possible)
R_MIN = 1e-10


def controlled(snap: Snapshot) -> np.ndarray:
    """(n,) bool: active rows whose residual is controlled by the others (r_i > 1e-10).

    Uses the dimensionless ``(PQvvP)_ii σ_li² / σ0²`` (= r_i for diagonal P).
    """
    rel = snap.PQvvP * (snap.sigma_l / snap.sigma0) ** 2
    return snap.active & (rel > R_MIN)


class RowTestResult:
    """Shared helpers of row-wise test results (needs ``labels``, ``flagged``, ``largest``)."""

    @property
    def flagged_labels(self) -> list[str]:
        return [str(s) for s in self.labels[self.flagged]]

    def _largest(self, name: str, values: np.ndarray) -> dict | None:
        i = self.largest
        return None if i is None else {"row": i, "label": str(self.labels[i]), name: float(values[i])}


#: the option value that selects Baarda's B-method level α′ for the global test (one-sided)
B_METHOD = "B-method"
#: the global test's conventional default level (two-sided χ² test of σ̂0²/σ0²)
ALPHA_GLOBAL = 0.05


@dataclass(frozen=True)
class GlobalTestResult:
    """Global (overall model) test of H0: E(σ̂0²) = σ0², paper 000 eq. (1).

    ``method`` is ``"two-sided"`` (default: χ² test at level α, H0 rejected when σ̂0 is too large
    *or* too small) or ``"B-method"`` (one-sided, level α′ from the B-method).  ``interval`` is the
    (1 − α) acceptance interval of σ̂0 under H0 (in the unit of σ0): H0 is rejected exactly when
    σ̂0 lies outside it.
    """

    T: float  # vᵀPv / (dof σ0²) = σ̂0² / σ0²
    critical: float  # upper critical value F(1 − α/2; dof, ∞) (two-sided) or F(1 − α′; dof, ∞)
    p_value: float  # two-sided: 2 min(P(F < T), P(F > T)); B-method: P(F > T)
    rejected: bool
    alpha: float
    dof: int
    vtpv: float
    sigma0: float
    sigma0_hat: float
    critical_lower: float = 0.0  # F(α/2; dof, ∞) (two-sided); 0 for the one-sided B-method
    method: str = "two-sided"
    interval: tuple[float, float] = (float("nan"), float("nan"))  # σ̂0 acceptance interval

    @property
    def too_large(self) -> bool:
        """σ̂0 above the upper bound (the model does not explain the residuals)."""
        return bool(self.T > self.critical)

    @property
    def too_small(self) -> bool:
        """σ̂0 below the lower bound (the a-priori σ are pessimistic); never for the B-method."""
        return bool(self.T < self.critical_lower)

    @property
    def verdict(self) -> str:
        """``"accepted"``, ``"rejected (σ̂0 too large)"``, ``"rejected (σ̂0 too small)"`` or
        ``"not testable (dof 0)"``."""
        if not np.isfinite(self.T):
            return f"not testable (dof {self.dof})"
        if self.too_large:
            return "rejected (σ̂0 too large)"
        if self.too_small:
            return "rejected (σ̂0 too small)"
        return "accepted"

    @property
    def level_text(self) -> str:
        """How the level was chosen: "two-sided χ², α = 5 %" or "B-method, α′ = 0.694"."""
        if self.method == B_METHOD:
            return f"B-method (one-sided), α′ = {self.alpha:.3g}"
        return f"two-sided χ², α = {100 * self.alpha:.3g} %"

    def summary(self) -> dict:
        out = {k: getattr(self, k) for k in self.__dataclass_fields__}
        out["interval"] = [float(x) for x in self.interval]
        out["verdict"] = self.verdict
        return out


def global_level(alpha: float | str | None) -> float | str:
    """Check a global-test level: a probability in (0, 1) or ``"B-method"`` (None = B-method, as
    before the option existed)."""
    if alpha is None or alpha == B_METHOD:
        return B_METHOD
    if isinstance(alpha, str):
        raise ValueError(f"alpha_global must be a probability or {B_METHOD!r}, got {alpha!r}")
    a = float(alpha)
    if not 0.0 < a < 1.0:
        raise ValueError(f"alpha_global must lie strictly between 0 and 1, got {a}")
    return a


def global_critical(alpha: float, dof: int) -> tuple[float, float]:
    """Two-sided critical values of ``T = σ̂0²/σ0² ~ χ²(dof)/dof`` at level α:
    ``(χ²(α/2; dof)/dof, χ²(1 − α/2; dof)/dof)``."""
    return (float(stats.chi2.ppf(alpha / 2.0, dof) / dof), float(stats.chi2.isf(alpha / 2.0, dof) / dof))


def global_test(snap: Snapshot, alpha: float | str | None = ALPHA_GLOBAL, alpha0: float = 0.001,
                beta0: float = 0.80) -> GlobalTestResult:
    """Global test of ``T = vᵀPv/(dof σ0²) = σ̂0²/σ0²``.

    Default: two-sided χ² test at ``alpha`` (5 %): reject if ``T < χ²(α/2; dof)/dof`` or
    ``T > χ²(1 − α/2; dof)/dof``; the p-value is two-sided.  ``alpha="B-method"`` (or None) uses
    Baarda's level ``α′ = alpha_prime(alpha0, beta0, dof)`` one-sided (reject if
    ``T > F(1 − α′; dof, ∞)``), the level iterated data snooping stops on (Kok 1984).
    With ``dof = 0`` nothing can be tested: T and the p-value are nan and ``rejected`` is False.
    """
    level = global_level(alpha)
    method = B_METHOD if level == B_METHOD else "two-sided"
    dof = int(snap.dof)
    if dof <= 0:
        nan = float("nan")
        return GlobalTestResult(nan, nan, nan, False, nan if level == B_METHOD else float(level), dof,
                                float(snap.vtpv), snap.sigma0, nan, nan, method, (nan, nan))
    T = float(snap.vtpv) / (dof * snap.sigma0 ** 2)
    if level == B_METHOD:
        a = alpha_prime(alpha0, beta0, dof)
        lo, hi = 0.0, float(stats.chi2.isf(a, dof) / dof)
        p = float(stats.chi2.sf(T * dof, dof))
    else:
        a = float(level)
        lo, hi = global_critical(a, dof)
        p = float(min(1.0, 2.0 * min(stats.chi2.cdf(T * dof, dof), stats.chi2.sf(T * dof, dof))))
    s0 = float(snap.sigma0)
    return GlobalTestResult(T, hi, p, bool(T > hi or T < lo), a, dof, float(snap.vtpv), s0,
                            snap.sigma0_hat, lo, method, (s0 * float(np.sqrt(lo)), s0 * float(np.sqrt(hi))))


def _ratio(num: np.ndarray, den: np.ndarray, mask: np.ndarray, fill: float) -> np.ndarray:
    out = np.full(num.shape, fill, dtype=float)
    np.divide(num, den, out=out, where=mask)
    return out


def _predicted(snap: Snapshot, w: np.ndarray, kind: str) -> np.ndarray:
    if snap.v_pred is None:
        return w
    out_rows = ~snap.active
    if kind == "w":
        if snap.sigma_v_pred is None:
            return w
        ok = out_rows & (snap.sigma_v_pred > 0) & np.isfinite(snap.sigma_v_pred)
        return np.where(ok, _ratio(snap.v_pred, snap.sigma_v_pred, ok, 0.0), w)
    return np.where(out_rows, snap.v_pred, w)


def w_test(snap: Snapshot, include_inactive: bool = False) -> np.ndarray:
    """(n,) standardized residuals ``w_i = (Pv)_i / (σ0 √(PQvvP)_ii)`` (Baarda), ~N(0,1) under H0.

    0 on inactive/uncontrolled rows unless ``include_inactive`` (then removed rows get
    ``v_pred / sigma_v_pred``).
    """
    ok = controlled(snap)
    w = _ratio(snap.Pv, snap.sigma0 * np.sqrt(np.where(ok, snap.PQvvP, 1.0)), ok, 0.0)
    return _predicted(snap, w, "w") if include_inactive else w


def estimated_errors(snap: Snapshot, include_inactive: bool = False) -> np.ndarray:
    """(n,) estimated gross errors ``∇̂l_i = (Pv)_i / (PQvvP)_ii`` (= v_i / r_i for diagonal P).

    This is the predicted residual of row i (the observation minus its prediction from all the
    others); removed rows get their predicted residual ``v_pred`` if ``include_inactive``.
    """
    ok = controlled(snap)
    e = _ratio(snap.Pv, snap.PQvvP, ok, 0.0)
    return _predicted(snap, e, "e") if include_inactive else e


def mdb(snap: Snapshot, delta0: float | None = None) -> np.ndarray:
    """(n,) minimal detectable biases ``∇0l_i = δ0 σ0 / √(PQvvP)_ii`` (internal reliability).

    ``delta0`` defaults to δ0(0.1 %, 80 %) = 4.13.  inf for uncontrolled rows, nan for inactive.
    """
    d0 = _delta0() if delta0 is None else float(delta0)
    ok = controlled(snap)
    out = _ratio(np.full(snap.n, d0 * snap.sigma0), np.sqrt(np.where(ok, snap.PQvvP, 1.0)), ok,
                 np.inf)
    out[~snap.active] = np.nan
    return out


@dataclass(frozen=True, eq=False)
class DataSnoopingResult(RowTestResult):
    """Data snooping (Baarda): all rows tested with the w-test at one critical value."""

    w: np.ndarray
    critical: float
    flagged: np.ndarray  # |w| > critical
    nabla_hat: np.ndarray
    mdb: np.ndarray
    r: np.ndarray
    largest: int | None  # row index of the largest |w| among controlled rows (None if none)
    alpha0: float
    beta0: float
    delta0: float
    labels: np.ndarray = field(repr=False)

    def summary(self) -> dict:
        return {
            "critical": self.critical, "alpha0": self.alpha0, "beta0": self.beta0,
            "delta0": self.delta0, "n_flagged": int(self.flagged.sum()),
            "flagged": self.flagged_labels, "largest": self._largest("w", self.w),
        }


def data_snooping(snap: Snapshot, alpha0: float = 0.001, beta0: float = 0.80,
                  critical: float | None = None) -> DataSnoopingResult:
    """w-test of every row; ``critical`` defaults to ``Φ⁻¹(1 − α0/2)`` (3.29 for 0.1 %).

    The MDBs use ``δ0(alpha0, beta0)``.  Pass ``critical=delta0()``-style values (4.13) to use
    Baarda's B-method value as the paper mentions.
    """
    k = critical_normal(alpha0) if critical is None else float(critical)
    d0 = _delta0(alpha0, beta0)
    w = w_test(snap)
    ok = controlled(snap)
    largest = int(np.argmax(np.where(ok, np.abs(w), -1.0))) if ok.any() else None
    return DataSnoopingResult(
        w=w, critical=k, flagged=ok & (np.abs(w) > k), nabla_hat=estimated_errors(snap),
        mdb=mdb(snap, d0), r=np.array(snap.r), largest=largest, alpha0=float(alpha0),
        beta0=float(beta0), delta0=d0, labels=snap.labels)


class ExternalReliability(NamedTuple):
    """Effect of each undetected MDB on the unknowns (external reliability); unpacks as
    ``dx, bar_delta0 = external_reliability(...)``."""

    dx: np.ndarray  # (n, u): ∇0x for a bias ∇0l_i in row i (zero rows for inactive rows)
    bar_delta0: np.ndarray  # (n,): δ̄0_i = √(∇0x_iᵀ N ∇0x_i) / σ0

    def on(self, F) -> np.ndarray:
        """(n, k) effect on derived quantities ``F x`` (F: (k, u), e.g. object coordinates)."""
        return self.dx @ np.asarray(F, dtype=float).T


def external_reliability(model, adjustment, mdb) -> ExternalReliability:
    """External reliability of a :class:`~baarda.pipeline.stats.linear.LinearModel` adjustment.

    ``∇0x_i = N⁻¹ Aᵀ P e_i ∇0l_i`` for every active row i (Baarda 1968, Förstner 1985) and
    Baarda's scalar summary ``δ̄0_i = √(∇0x_iᵀ N ∇0x_i)/σ0`` which equals ``√((1−r_i)/r_i) δ0``
    for uncorrelated observations; ``σ0 δ̄0_i`` bounds the effect on any function f of the unknowns
    in units of its standard deviation, ``|∇0 f| ≤ δ̄0_i σ_f``.  ``mdb`` is the (n,) output of
    :func:`mdb` (or any vector of biases).  ``result.on(F)`` maps the effects to derived
    quantities ``F x`` (e.g. object coordinates).  Rows with an infinite MDB get nan.
    """
    act = np.asarray(adjustment.active, bool)
    B = model.weighted_design(act)  # (n, u), P_a A_a scattered
    bias = np.array(mdb, dtype=float).reshape(-1)
    if bias.shape[0] != B.shape[0]:
        raise ValueError(f"mdb has {bias.shape[0]} entries, model has {B.shape[0]} rows")
    scale = np.where(act, bias, 0.0)
    bad = act & ~np.isfinite(scale)
    scale = np.where(bad, np.nan, np.nan_to_num(scale, nan=0.0, posinf=0.0))
    BQ = B @ adjustment.Qxx
    dx = BQ * scale[:, None]
    q = np.einsum("ij,ij->i", BQ, B)  # b_i Qxx b_iᵀ ;  ∇xᵀ N ∇x = bias² q
    bar = np.abs(scale) * np.sqrt(np.maximum(q, 0.0)) / adjustment.snapshot.sigma0
    bar[~act] = np.nan
    return ExternalReliability(dx=dx, bar_delta0=bar)
