"""Solution of the reduced camera system: Jacobi-scaled Cholesky (control datum) or the bordered
system of a free network through the Cholesky factor of ``N + C Cᵀ``; a singular system becomes a
datum / parameter diagnosis (:mod:`.diagnose`)."""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

__all__ = ["solve_reduced", "solve_factored"]


def solve_reduced(prob, red, st, diagnose=False):
    """Solve K Δ = rhs with Jacobi scaling; on singularity raise a datum / parameter diagnosis.

    Without inner constraints K is positive definite: Cholesky.  With them K is the saddle-point
    matrix ``[[N, C], [Cᵀ, −E]]`` (E = the constraints' share of the eliminated points); it is
    solved through the Cholesky factor of ``M = N + C Cᵀ`` (positive definite when C fixes the
    datum) and an n_c × n_c system — exactly the bordered solution (see :func:`solve_factored`).
    """
    K, rhs = red["K"], red["rhs"]
    n_g, n_c = prob.n_g, prob.n_c
    if n_g == 0:
        return np.zeros(n_c), None
    d = np.sqrt(np.abs(np.diag(K)[:n_g]))
    zero = d == 0
    if zero.any():
        from .diagnose import raise_rank_defect
        raise_rank_defect(prob, red, st)
    s = np.ones(n_g + n_c)
    s[:n_g] = 1.0 / d
    if n_c:
        s[n_g:] = 1.0 / np.maximum(np.linalg.norm(K[:n_g, n_g:] * s[:n_g, None], axis=0), 1e-300)
    Ks = K * s[:, None] * s[None, :]
    try:
        if n_c == 0:
            fac = ("chol", sla.cho_factor(Ks, lower=False, check_finite=False))
            piv = np.diag(fac[1][0]) ** 2
            if piv.min() < 1e-11:
                raise np.linalg.LinAlgError
        else:
            C = Ks[:n_g, n_g:]
            E = -Ks[n_g:, n_g:]
            M = Ks[:n_g, :n_g] + C @ C.T
            cf = sla.cho_factor(M, lower=False, check_finite=False)
            piv = np.diag(cf[0]) ** 2
            if piv.min() < 1e-11 * np.max(np.diag(M)):
                raise np.linalg.LinAlgError
            IE = np.eye(n_c) - E
            Yc = sla.cho_solve(cf, C, check_finite=False)             # M⁻¹ C
            Z = C.T @ Yc @ IE + E
            zf = sla.lu_factor(Z, check_finite=False)
            u = np.abs(np.diag(zf[0]))
            if u.min() < 1e-11 * max(u.max(), 1.0):
                raise np.linalg.LinAlgError
            fac = ("bordered", (cf, C, Yc, IE, zf))
        y = solve_factored(fac, rhs * s)
        if not np.isfinite(y).all():
            raise np.linalg.LinAlgError
    except (np.linalg.LinAlgError, ValueError):
        from .diagnose import raise_rank_defect
        raise_rank_defect(prob, red, st)
    red["factor"] = fac
    red["scale"] = s
    return y * s, fac


def solve_factored(fac, r):
    """Solve with a factorisation of :func:`solve_reduced` (scaled system); ``r`` (n_x,) or (n_x, j).

    ``bordered``: ``N Δ + C k = b``, ``Cᵀ Δ − E k = r_c``.  Adding C × the second row to the first
    gives ``M Δ + C (I − E) k = b + C r_c`` with ``M = N + C Cᵀ``, so ``Δ = y₀ − M⁻¹C (I − E) k``,
    ``y₀ = M⁻¹ (b + C r_c)``, and the second row becomes
    ``(Cᵀ M⁻¹ C (I − E) + E) k = Cᵀ y₀ − r_c`` (n_c × n_c; the identity at an undamped step).
    """
    kind, f = fac
    if kind == "chol":
        return sla.cho_solve(f, r, check_finite=False)
    if kind == "lu":
        return sla.lu_solve(f, r, check_finite=False)
    cf, C, Yc, IE, zf = f
    n_g = C.shape[0]
    b, rc = r[:n_g], r[n_g:]
    y0 = sla.cho_solve(cf, b + C @ rc, check_finite=False)
    k = sla.lu_solve(zf, C.T @ y0 - rc, check_finite=False)
    return np.concatenate([y0 - Yc @ (IE @ k), k], axis=0)
