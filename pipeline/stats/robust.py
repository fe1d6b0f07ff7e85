"""Robust estimation by iteratively reweighted least squares (IRLS): Huber, Danish, L1.

An M-estimator replaces the least-squares sum of squares by ``Σ ρ(u_i)`` of the standardised
residuals ``u_i = v_i / s_i``; IRLS solves it as a sequence of weighted least-squares
adjustments, each observation's weight multiplied by ``ω(u_i) = ψ(u_i)/u_i`` of the previous
adjustment's residual.  Weight functions (``u`` standardised, ``c`` the tuning constant):

    huber   ω = 1 for |u| ≤ c,   c/|u| beyond            ρ = u²/2,  c|u| − c²/2
    danish  ω = 1 for |u| ≤ c,   exp(1 − (u/c)²) beyond  ρ = u²/2,  c² − (c²/2) exp(1 − (u/c)²)
    l1      ω = 1 / max(|u|, floor)                      ρ = |u|

The Danish weight is the exponential down-weighting of Krarup, Juhl & Kubik (1980), usually quoted
as ``exp(−(u/c)²)`` beyond ``c``; the factor ``e`` makes it continuous at ``|u| = c`` (without it
the weight jumps from 1 to 0.37 there and IRLS can oscillate between the two branches).  It is
redescending: a residual of 2c keeps a weight of 0.05, one of 3c 3·10⁻⁴.

**Scale.**  ``s_i`` is fixed for the whole iteration, from the first (unweighted) adjustment:

- ``standardise = "redundancy"`` (default): ``s_i = σ_l,i √r_i`` — the standard deviation of the
  least-squares residual, so ``u`` of the first iteration is Baarda's ``w``.  A gross error ∇
  shows in its residual only as ``r_i ∇``; dividing by ``σ √r_i`` makes the same ∇ produce the
  same weight in a well- and a poorly-controlled observation (as the w-test does).  Rows with
  ``r_i < r_min`` cannot be judged and keep weight 1.
- ``standardise = "apriori"``: ``s_i = σ_l,i`` — the textbook M-estimator ``min Σ ρ(v_i/σ_i)``
  (for Huber identical to ``scipy.optimize.least_squares(loss="huber")`` on ``v/σ``).
- ``standardise = "current"``: ``s_i = σ_l,i √r_i(ω)`` with the redundancy numbers of the latest
  *weighted* adjustment (``refit`` must return them, ``.r``).  A down-weighted row's redundancy
  tends to 1 and its residual to the whole error, so ``u`` tends to ``∇/σ``; with the fixed
  ``σ √r⁰`` it tends to ``∇/(σ √r⁰)``, which inflates poorly-controlled rows (more false alarms,
  docs/statistics.md).  The scale then changes with the weights: a fixed point, not the minimum
  of a fixed objective.

The fixed point minimises ``Σ (s_i/σ_i)² ρ(u_i)`` (diagonal weights): the adjustment's weights
``p_i ω(u_i)`` are its stationarity condition.  σ0 is the a-priori value (no scale estimate from
the residuals), as in the w-test.

The driver :func:`irls` takes a ``refit(weights) -> snapshot-like`` callable (anything with a
residual vector ``v``), so every adjustment can use it: :func:`weighted_linear_refit` for a
:class:`LinearModel`, :func:`scale_covariance` for the bundle (its observations' 2×2 covariances
multiplied by ``1/ω``).  Pure: arrays in, arrays out, inputs never modified.

The options are declared here once: :class:`RobustConfig` (``method``, ``c``, ``standardise``) is the
``[stage.options.robust]`` table of ``bundle``, ``helmert-screening`` and ``independent-models``;
its base :class:`RobustTuning` (``c``, ``standardise``) that of ``blunder-rejection``, whose
``method = "robust-…"`` names the weight function.

References: Huber (1981) *Robust Statistics*; Krarup, Juhl & Kubik (1980) *Götterdämmerung over
least squares adjustment*, 14th ISP Congress, Hamburg, Comm. III; Kubik, Weng & Frederiksen
(1985) *Oh, gross errors!*, Australian Journal of Geodesy, Photogrammetry and Surveying 42.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Literal

import numpy as np

from baarda.pipeline.options import check_bounds, option

from .linear import LinearModel

__all__ = ["ROBUST_METHODS", "DEFAULT_C", "robust_weights", "robust_rho", "irls", "RobustResult",
           "weighted_linear_refit", "scale_covariance", "weighted_refit", "RobustTuning", "RobustConfig"]

ROBUST_METHODS = ("huber", "danish", "l1")
#: default tuning constants (standardised residuals): Huber's 1.5 (≈ 95 % efficiency at the normal,
#: Huber 1981); Danish 2.5, so that ω < 0.5 ⇔ |u| > 2.5 √(1 + ln 2) = 3.25 ≈ the w-test's 3.29;
#: for L1 the floor of |u| (weights 1/|u| are capped at 1/floor).
DEFAULT_C = {"huber": 1.5, "danish": 2.5, "l1": 1e-3}


@dataclass(frozen=True)
class RobustTuning:
    """The tuning of an IRLS estimator (:func:`irls`'s ``c`` and ``standardise``): the
    ``[stage.options.robust]`` table of blunder-rejection, whose ``method = "robust-…"`` names the
    weight function, and the base of :class:`RobustConfig`."""

    c: float = option(0.0, "tuning constant in standardised residuals; 0 = Huber 1.5, Danish 2.5 (L1: the floor "
                           "of |u|, 0.001)", ge=0.0)
    standardise: Literal["redundancy", "apriori", "current"] = option(
        "redundancy", "residuals divided by σ √r of the first (unweighted) adjustment, by the a-priori σ, or by "
                      "σ √r of the current weighted adjustment (the bundle: a covariance computation per iteration)")

    def __post_init__(self):
        check_bounds(self)


@dataclass(frozen=True)
class RobustConfig(RobustTuning):
    """Robust estimation by IRLS: the weight function and its tuning — the ``[stage.options.robust]``
    table of ``bundle``, ``helmert-screening`` and ``independent-models`` (one declaration; each
    stage's doc of the group says what the weights act on there)."""

    method: Literal["none", "huber", "danish", "l1"] = option(
        "none", "none, or Huber, Danish or L1 weights (docs/statistics.md, Robust estimation)")


def _check(method: str, c: float | None) -> float:
    if method not in ROBUST_METHODS:
        raise ValueError(f"robust method must be one of {', '.join(ROBUST_METHODS)}, got {method!r}")
    c = DEFAULT_C[method] if c is None or c == 0 else float(c)
    if not (np.isfinite(c) and c > 0):
        raise ValueError(f"robust tuning constant c must be positive and finite, got {c}")
    return c


def robust_weights(u, method: str = "huber", c: float | None = None) -> np.ndarray:
    """IRLS weights ``ω(u) = ψ(u)/u`` of standardised residuals ``u`` (module docstring);
    ``c = None`` or 0 takes :data:`DEFAULT_C`.  For ``l1``, ``c`` is the floor of ``|u|``."""
    c = _check(method, c)
    a = np.abs(np.asarray(u, dtype=float))
    if method == "huber":
        return np.where(a <= c, 1.0, c / np.maximum(a, c))
    if method == "danish":
        return np.where(a <= c, 1.0, np.exp(1.0 - (np.maximum(a, c) / c) ** 2))
    return 1.0 / np.maximum(a, c)


def robust_rho(u, method: str = "huber", c: float | None = None) -> np.ndarray:
    """The loss ``ρ(u)`` whose ``ψ = ρ'`` gives :func:`robust_weights` (``l1``: ``|u|``)."""
    c = _check(method, c)
    u = np.asarray(u, dtype=float)
    a = np.abs(u)
    if method == "huber":
        return np.where(a <= c, 0.5 * u * u, c * a - 0.5 * c * c)
    if method == "danish":
        return np.where(a <= c, 0.5 * u * u, c * c - 0.5 * c * c * np.exp(1.0 - (np.maximum(a, c) / c) ** 2))
    return a


@dataclass(frozen=True, eq=False)
class RobustResult:
    """Outcome of :func:`irls`.

    Attributes
    ----------
    method, c, standardise : the estimator.
    weights : (n,) final robust factors ω on the a-priori weights (1 for inactive / unjudged rows).
    u : (n,) standardised residuals ``v/s`` of the final adjustment (nan where not judged).
    scale : (n,) the fixed ``s_i`` (nan where not judged).
    judged : (n,) bool, rows that were re-weighted (active, ``r ≥ r_min`` with ``redundancy``).
    fit : what ``refit`` returned for the final weights (a Snapshot, or the caller's object).
    iterations : weighted adjustments made (0: the first adjustment needed no re-weighting).
    converged : the largest weight change fell below ``tol``.
    history : per iteration ``{iteration, max_dw, n_down, objective}``.
    threshold : rows with ``weights < threshold`` count as down-weighted.
    labels : (n,) row labels.
    """

    method: str
    c: float
    standardise: str
    weights: np.ndarray
    u: np.ndarray
    scale: np.ndarray
    judged: np.ndarray
    fit: Any
    iterations: int
    converged: bool
    history: list
    threshold: float
    labels: np.ndarray = field(repr=False)

    @property
    def downweighted(self) -> np.ndarray:
        """Rows with ω < threshold, the smallest weight first."""
        idx = np.flatnonzero(self.judged & (self.weights < self.threshold))
        return idx[np.argsort(self.weights[idx], kind="stable")]

    @property
    def downweighted_labels(self) -> list[str]:
        return [str(self.labels[i]) for i in self.downweighted]

    def summary(self) -> dict:
        d = self.downweighted
        return {"method": self.method, "c": self.c, "standardise": self.standardise,
                "iterations": self.iterations, "converged": self.converged, "threshold": self.threshold,
                "n_downweighted": int(d.size),
                "downweighted": [{"row": int(i), "label": str(self.labels[i]), "weight": float(self.weights[i]),
                                  "u": float(self.u[i])} for i in d],
                "history": list(self.history)}


def irls(refit: Callable[[np.ndarray], Any], snap, method: str = "huber", c: float | None = None, *,
         standardise: Literal["redundancy", "apriori", "current"] = "redundancy", max_iter: int = 50,
         tol: float = 1e-3, w_min: float = 1e-8, r_min: float = 1e-6,
         threshold: float = 0.5) -> RobustResult:
    """Iteratively reweighted least squares from the unweighted adjustment ``snap`` (a Snapshot).

    Parameters
    ----------
    refit : ``refit(weights) -> obj`` adjusts again with each row's a-priori weight multiplied by
        ``weights`` (n,); ``obj.v`` (n,) are the new residuals (observed − computed).
    snap : :class:`Snapshot` of the adjustment with unit robust weights; supplies the scale
        (``sigma_l``, ``r``), the active rows and the labels.
    method, c : weight function and tuning constant (``None``/0: :data:`DEFAULT_C`).
    standardise : ``"redundancy"`` (``s = σ_l √r``, r of ``snap``), ``"apriori"`` (``s = σ_l``) or
        ``"current"`` (``s = σ_l √r`` with r of the latest weighted adjustment, ``refit(w).r``).
    max_iter : at most this many weighted adjustments.
    tol : converged when no weight changes by more than ``tol``.
    w_min : smallest weight handed to ``refit`` (Danish weights underflow; 0 would make the
        weight matrix singular).  Reported weights are the unclipped ω.
    r_min : with ``redundancy``, rows with ``r < r_min`` are not judged (weight 1).
    threshold : ω below this counts as down-weighted in the report.
    """
    c = _check(method, c)
    if standardise not in ("redundancy", "apriori", "current"):
        raise ValueError(f"standardise must be 'redundancy', 'apriori' or 'current', got {standardise!r}")
    if max_iter < 1 or not tol > 0 or not 0 < w_min < 1 or not 0 < threshold <= 1:
        raise ValueError("irls: need max_iter >= 1, tol > 0, 0 < w_min < 1, 0 < threshold <= 1")
    n = snap.n
    active = np.asarray(snap.active, bool)
    sig = np.asarray(snap.sigma_l, float)
    judged = active & (sig > 0) & np.isfinite(sig)
    if standardise in ("redundancy", "current"):
        r = np.asarray(snap.r, float)
        judged &= r >= r_min
        s = sig * np.sqrt(np.where(judged, r, 1.0))
    else:
        s = sig.copy()
    scale = np.where(judged, s, np.nan)
    ratio2 = np.where(judged, (np.nan_to_num(scale) / np.where(sig > 0, sig, 1.0)) ** 2, 0.0)

    def standardised(v):
        return np.where(judged, np.asarray(v, float).reshape(-1) / np.where(judged, scale, 1.0), np.nan)

    def weights_of(u):
        w = np.ones(n)
        w[judged] = robust_weights(u[judged], method, c)
        return w

    fit = snap
    u = standardised(snap.v)
    w = weights_of(u)
    history = []
    converged = bool(np.all(w == 1.0))
    it = 0
    while not converged and it < max_iter:
        it += 1
        fit = refit(np.maximum(w, w_min))
        if standardise == "current":
            rw = np.asarray(fit.r, float).reshape(-1)
            scale = np.where(judged, sig * np.sqrt(np.clip(np.where(judged, rw, 1.0), r_min, None)), np.nan)
            ratio2 = np.where(judged, (np.nan_to_num(scale) / np.where(sig > 0, sig, 1.0)) ** 2, 0.0)
        u = standardised(fit.v)
        w_new = weights_of(u)
        dw = float(np.max(np.abs(w_new - w))) if n else 0.0
        w = w_new
        obj = float(np.sum(ratio2[judged] * robust_rho(u[judged], method, c)))
        history.append({"iteration": it, "max_dw": dw, "n_down": int(np.sum(judged & (w < threshold))),
                        "objective": obj})
        converged = dw < tol
    labels = np.asarray(snap.labels, dtype=str)
    for a in (w, u, scale, judged):
        a.flags.writeable = False
    return RobustResult(method, c, standardise, w, u, scale, judged, fit, it, converged, history,
                        float(threshold), labels)


def weighted_linear_refit(model, active=None) -> Callable[[np.ndarray], Any]:
    """``refit(weights) -> Snapshot`` for a :class:`LinearModel` (or anything with ``A``, ``l``,
    ``P``, ``sigma0``, ``labels``, ``group``, ``names``): the same model with ``P`` replaced by
    ``W^½ P W^½`` (``W = diag(weights)``; for diagonal ``P`` simply ``p_i w_i``).  Rows inactive
    in ``active`` stay out."""
    act = None if active is None else np.array(active, bool)

    def refit(weights):
        w = np.asarray(weights, float).reshape(-1)
        if w.shape[0] != model.n or not np.all(w > 0):
            raise ValueError(f"weights: need {model.n} positive values")
        P = np.asarray(model.P, float)
        Pw = P * w if P.ndim == 1 else P * np.sqrt(np.outer(w, w))
        m = LinearModel(model.A, model.l, Pw, model.sigma0, model.labels, model.group, model.names)
        return m.adjust(act).snapshot

    return refit


def scale_covariance(cov, weights) -> np.ndarray:
    """Observation covariances ``(k, 2, 2)`` of image points with the robust weights of their
    scalar rows ``(2k,)`` (x, y interleaved): ``S Σ S`` with ``S = diag(1/√w_x, 1/√w_y)``, i.e. the
    weight matrix becomes ``W^½ P W^½``.  Returns a new array."""
    cov = np.asarray(cov, float)
    w = np.asarray(weights, float).reshape(-1, 2)
    if w.shape[0] != cov.shape[0] or not np.all(w > 0):
        raise ValueError(f"weights: need {2 * cov.shape[0]} positive values")
    s = 1.0 / np.sqrt(w)
    return cov * s[:, :, None] * s[:, None, :]


def weighted_refit(model, active=None, *, redundancy: bool = False):
    """``(refit(weights), how)`` for the adjustments baarda knows, or ``(None, why)``.

    - a model with ``refit_weighted(weights)`` (a third party's adjustment): that method;
    - a :class:`LinearModel` (helmert-screening, a linear user model): :func:`weighted_linear_refit`;
    - a model with ``weighted_refit(redundancy=…)`` returning ``(refit, how)`` (the bundle result
      ``adjust`` returns: adjusted again from its solution with each image point's covariance
      scaled by :func:`scale_covariance`, covariances not computed; ``refit(w).result`` is the new
      bundle result);
    - a model with ``linear_model()`` (the independent-model block): its linearisation at the
      solution, a :class:`LinearModel` with the snapshot's rows.
    ``active`` (n,) are the rows in use (default: all).  ``redundancy=True``: the bundle's refits
    compute the redundancy numbers too (``.r``, for ``standardise = "current"``; slower).
    """
    if hasattr(model, "refit_weighted"):
        return model.refit_weighted, "the adjustment's own weighted refit"
    if all(hasattr(model, k) for k in ("A", "l", "P", "adjust")):
        return weighted_linear_refit(model, active), "linear model, adjusted again"
    if hasattr(model, "weighted_refit"):
        return model.weighted_refit(redundancy=redundancy)
    if hasattr(model, "linear_model"):
        return weighted_linear_refit(model.linear_model(), active), "linearised at the solution"
    return None, f"a {type(model).__name__} offers no weighted refit (refit_weighted, A/l/P or linear_model)"
