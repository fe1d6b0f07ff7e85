"""Critical values and the B-method (Baarda 1968).

All significance levels are probabilities (``0.001`` = 0.1 %).  The w-test is two-sided.

    δ0(α0, β0) = Φ⁻¹(1 − α0/2) + Φ⁻¹(β0)                      (Baarda 1968; paper 000 eq. 5)

B-method (Baarda 1968, Kok 1984): the global test with ``dof`` degrees of freedom gets the
significance level α′ for which a bias that the one-dimensional w-test (α0) detects with power β0
is detected by the global test with the *same* power:

    λ0 = δ0²,   P(χ′²(dof, λ0) > χ²_{1−α′}(dof)) = β0.

α′ is found by root finding on the non-central χ² power function (``scipy.stats.ncx2``).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import optimize, stats

__all__ = ["delta0", "critical_normal", "alpha_prime", "global_power", "w_power"]


def _check_prob(name: str, value: float) -> float:
    value = float(value)
    if not 0.0 < value < 1.0:
        raise ValueError(f"{name} must lie strictly between 0 and 1, got {value}")
    return value


def critical_normal(alpha0: float = 0.001) -> float:
    """Two-sided critical value of the w-test, ``k = Φ⁻¹(1 − α0/2)`` (3.29 for α0 = 0.1 %)."""
    alpha0 = _check_prob("alpha0", alpha0)
    return float(stats.norm.isf(alpha0 / 2.0))


def delta0(alpha0: float = 0.001, beta0: float = 0.80) -> float:
    """Lower bound of the non-centrality, ``δ0 = Φ⁻¹(1 − α0/2) + Φ⁻¹(β0)`` (4.13 for 0.1 %, 80 %).

    The formula neglects the far tail of the two-sided test (≈ Φ(−k − δ0), below 1e-12 for the
    usual levels); :func:`w_power` gives the exact power.
    """
    alpha0 = _check_prob("alpha0", alpha0)
    beta0 = _check_prob("beta0", beta0)
    return float(stats.norm.isf(alpha0 / 2.0) + stats.norm.ppf(beta0))


def w_power(delta: float, alpha0: float = 0.001) -> float:
    """Exact power of the two-sided w-test for a shift ``delta`` of the standardized residual."""
    k = critical_normal(alpha0)
    return float(stats.norm.sf(k - delta) + stats.norm.cdf(-k - delta))


def global_power(alpha: float, dof: int, lam: float) -> float:
    """Power of the global test (χ², ``dof``) at level ``alpha`` for non-centrality ``lam``."""
    crit = stats.chi2.isf(alpha, dof)
    return float(stats.ncx2.sf(crit, dof, lam))


def alpha_prime(alpha0: float = 0.001, beta0: float = 0.80, dof: int = 1) -> float:
    """Significance level α′ of the global test with ``dof`` degrees of freedom (B-method).

    α′ is the level at which the global test has power ``beta0`` for the non-centrality
    ``λ0 = δ0(alpha0, beta0)²``.  ``dof = 1`` gives α′ = α0 (up to the neglected far tail); α′
    grows with ``dof`` (≈ 0.2 for dof = 10, > 0.5 for a few hundred).
    """
    alpha0 = _check_prob("alpha0", alpha0)
    beta0 = _check_prob("beta0", beta0)
    dof = int(dof)
    if dof < 1:
        raise ValueError(f"alpha_prime needs dof >= 1, got {dof}")
    lam0 = delta0(alpha0, beta0) ** 2

    def f(logit: float) -> float:
        a = 1.0 / (1.0 + math.exp(-logit))
        return global_power(a, dof, lam0) - beta0

    lo, hi = -60.0, 40.0  # α′ between ~1e-26 and 1 − 4e-18
    if f(lo) > 0:  # pragma: no cover - would need an absurd beta0
        return 1.0 / (1.0 + math.exp(-lo))
    logit = optimize.brentq(f, lo, hi, xtol=1e-12, rtol=1e-12, maxiter=500)
    return float(1.0 / (1.0 + math.exp(-logit)))
