"""Pope's τ distribution (Pope 1976, *The statistics of residuals and the detection of outliers*).

With σ0 unknown, the studentized residual ``τ_i = v_i / (σ̂0 √(Qvv)_ii)``, ``σ̂0² = vᵀPv/r``, uses
σ̂0 from the *same* residuals, so it is not Student-distributed.  Under H0, with ``r`` degrees of
freedom,

    τ = √r · t / √(r − 1 + t²),   t ~ Student(r − 1),      |τ| ≤ √r,

equivalently ``τ²/r ~ Beta(1/2, (r−1)/2)``.  The CDF follows from the monotone map to t:

    F_τ(τ) = F_t(τ √(r−1) / √(r − τ²)).

``r`` must be at least 2 (with r = 1, |τ| = 1 always).  Critical values are two-sided.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

__all__ = ["tau_from_t", "t_from_tau", "cdf", "sf", "pdf", "ppf", "rvs", "critical",
           "critical_max", "tau_critical"]


def _dof(dof) -> int:
    dof = int(dof)
    if dof < 2:
        raise ValueError(f"Pope's τ distribution needs dof >= 2, got {dof}")
    return dof


def tau_from_t(t, dof):
    """Map Student-t values (dof − 1 degrees of freedom) to τ (dof degrees of freedom)."""
    r = _dof(dof)
    t = np.asarray(t, dtype=float)
    return np.sqrt(r) * t / np.sqrt(r - 1 + t * t)


def t_from_tau(tau, dof):
    """Inverse of :func:`tau_from_t` (|τ| < √dof; ±inf at the bounds)."""
    r = _dof(dof)
    tau = np.asarray(tau, dtype=float)
    inside = np.abs(tau) < np.sqrt(r)
    ti = np.where(inside, tau, 0.0)
    t = ti * np.sqrt(r - 1) / np.sqrt(r - ti * ti)
    return np.where(inside, t, np.copysign(np.inf, tau))


def cdf(tau, dof):
    """P(τ ≤ tau)."""
    return stats.t.cdf(t_from_tau(tau, dof), _dof(dof) - 1)


def sf(tau, dof):
    """P(τ > tau)."""
    return stats.t.sf(t_from_tau(tau, dof), _dof(dof) - 1)


def pdf(tau, dof):
    """Density of τ (0 outside (−√dof, √dof))."""
    r = _dof(dof)
    tau = np.asarray(tau, dtype=float)
    inside = np.abs(tau) < np.sqrt(r)
    t = np.where(inside, t_from_tau(np.where(inside, tau, 0.0), r), 0.0)
    # dt/dτ = √(r−1) · r / (r − τ²)^{3/2}
    ti = np.where(inside, tau, 0.0)
    jac = np.sqrt(r - 1) * r / (r - ti * ti) ** 1.5
    return np.where(inside, stats.t.pdf(t, r - 1) * jac, 0.0)


def ppf(q, dof):
    """Quantile function of τ."""
    r = _dof(dof)
    return tau_from_t(stats.t.ppf(q, r - 1), r)


def rvs(dof, size=None, rng=None):
    """Random τ values (through t ~ Student(dof − 1))."""
    r = _dof(dof)
    rng = np.random.default_rng(rng)
    return tau_from_t(rng.standard_t(r - 1, size=size), r)


def critical(alpha: float, dof: int) -> float:
    """Two-sided critical value ``τ_c`` with ``P(|τ| > τ_c) = alpha`` for one residual."""
    r = _dof(dof)
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must lie in (0, 1), got {alpha}")
    return float(tau_from_t(stats.t.isf(alpha / 2.0, r - 1), r))


def critical_max(alpha: float, dof: int, n_tests: int) -> float:
    """Critical value for the largest of ``n_tests`` |τ| (Šidák: per test 1 − (1 − α)^(1/n)).

    Conservative for correlated residuals (exact for independent ones).
    """
    n_tests = max(int(n_tests), 1)
    return critical(-np.expm1(np.log1p(-alpha) / n_tests), dof)


#: top-level name used by :mod:`baarda.pipeline.stats`
tau_critical = critical
