"""Solution of the reduced camera system: Jacobi-scaled Cholesky (control datum) or the bordered
system of a free network through the Cholesky factor of ``N + C Cᵀ`` (dense route); the supernodal
Cholesky of the global unknowns with a free network's datum held by ``n_c`` photo parameters and
S-transformed onto the inner constraints (sparse route).  A singular system becomes a datum /
parameter diagnosis (:mod:`.diagnose`).  The routes themselves are :mod:`.route`."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from .diagnose import datum_motions, point_motions, raise_rank_defect
from .sparse import NotPositiveDefinite, SupernodalCholesky, Symbolic

__all__ = ["DenseFactor", "CholeskyFactor", "BorderedFactor", "SparseFactor", "SingularAt", "solve_dense",
           "solve_sparse", "minimal_datum", "datum_basis"]


class DenseFactor(ABC):
    """A factorisation of the Jacobi-scaled dense reduced system ``S K S`` (``scale`` the diagonal of S)."""

    scale: np.ndarray

    @abstractmethod
    def solve_scaled(self, r: np.ndarray) -> np.ndarray:
        """``(S K S)⁻¹ r`` for r (n_x,) or (n_x, j)."""

    def inverse(self) -> np.ndarray:
        """``K⁻¹`` (n_x × n_x)."""
        s = self.scale
        n_x = len(s)
        if n_x == 0:
            return np.zeros((0, 0))
        Ki = self.solve_scaled(np.eye(n_x))
        Ki = 0.5 * (Ki + Ki.T)
        return Ki * s[:, None] * s[None, :]


@dataclass(frozen=True, eq=False)
class CholeskyFactor(DenseFactor):
    """``S K S = Rᵀ R`` (a control datum: K positive definite)."""

    cf: tuple
    scale: np.ndarray

    def solve_scaled(self, r):
        return sla.cho_solve(self.cf, r, check_finite=False)


@dataclass(frozen=True, eq=False)
class BorderedFactor(DenseFactor):
    """The bordered system ``[[N, C], [Cᵀ, −E]]`` of a free network (scaled).

    ``N Δ + C k = b``, ``Cᵀ Δ − E k = r_c``.  Adding C × the second row to the first gives
    ``M Δ + C (I − E) k = b + C r_c`` with ``M = N + C Cᵀ``, so ``Δ = y₀ − M⁻¹C (I − E) k``,
    ``y₀ = M⁻¹ (b + C r_c)``, and the second row becomes
    ``(Cᵀ M⁻¹ C (I − E) + E) k = Cᵀ y₀ − r_c`` (n_c × n_c; the identity at an undamped step)."""

    cf: tuple
    C: np.ndarray
    Yc: np.ndarray
    IE: np.ndarray
    zf: tuple
    scale: np.ndarray

    def solve_scaled(self, r):
        n_g = self.C.shape[0]
        b, rc = r[:n_g], r[n_g:]
        y0 = sla.cho_solve(self.cf, b + self.C @ rc, check_finite=False)
        k = sla.lu_solve(self.zf, self.C.T @ y0 - rc, check_finite=False)
        return np.concatenate([y0 - self.Yc @ (self.IE @ k), k], axis=0)


@dataclass(frozen=True, eq=False)
class SparseFactor:
    """The sparse route's factor: ``F`` the supernodal Cholesky of the Jacobi-scaled (``d``) system
    of the unknowns ``kidx`` (all but a free network's held ones)."""

    F: SupernodalCholesky
    d: np.ndarray
    kidx: np.ndarray

    def solve(self, r: np.ndarray) -> np.ndarray:
        """``K⁻¹ r`` (r (n_g,) or (n_g, j)); unknowns held by the minimal datum get 0 (the
        minimal-constraint cofactors)."""
        out = np.zeros(r.shape)
        dd = self.d if r.ndim == 1 else self.d[:, None]
        out[self.kidx] = self.F.solve(r[self.kidx] * dd) * dd
        return out


class SingularAt(Exception):
    """The sparse system is singular at global unknown ``column`` (``zero``: its diagonal is 0)."""

    def __init__(self, column: int, zero: bool = False):
        super().__init__(f"singular at column {column}")
        self.column, self.zero = int(column), zero


def solve_dense(prob, red, st) -> tuple[np.ndarray, DenseFactor | None]:
    """Solve K Δ = rhs with Jacobi scaling; on singularity raise a datum / parameter diagnosis.

    Without inner constraints K is positive definite: Cholesky.  With them K is the saddle-point
    matrix ``[[N, C], [Cᵀ, −E]]`` (E = the constraints' share of the eliminated points); it is
    solved through the Cholesky factor of ``M = N + C Cᵀ`` (positive definite when C fixes the
    datum) and an n_c × n_c system — exactly the bordered solution (see :class:`BorderedFactor`).
    """
    K, rhs = red.K, red.rhs
    n_g, n_c = prob.n_g, prob.n_c
    if n_g == 0:
        return np.zeros(n_c), None
    d = np.sqrt(np.abs(np.diag(K)[:n_g]))
    if (d == 0).any():
        raise_rank_defect(prob, red, st)
    s = np.ones(n_g + n_c)
    s[:n_g] = 1.0 / d
    if n_c:
        s[n_g:] = 1.0 / np.maximum(np.linalg.norm(K[:n_g, n_g:] * s[:n_g, None], axis=0), 1e-300)
    Ks = K * s[:, None] * s[None, :]
    try:
        if n_c == 0:
            cf = sla.cho_factor(Ks, lower=False, check_finite=False)
            if (np.diag(cf[0]) ** 2).min() < 1e-11:
                raise np.linalg.LinAlgError
            fac = CholeskyFactor(cf, s)
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
            fac = BorderedFactor(cf, C, Yc, IE, zf, s)
        y = fac.solve_scaled(rhs * s)
        if not np.isfinite(y).all():
            raise np.linalg.LinAlgError
    except (np.linalg.LinAlgError, ValueError):
        raise_rank_defect(prob, red, st)
    return y * s, fac


def minimal_datum(prob, st) -> np.ndarray | None:
    """Global unknowns fixed to hold a free network's datum on the sparse route: ``n_c`` photo
    parameters whose datum motions are the most independent (QR with column pivoting of the
    motions' rows) at state ``st``; ``None`` when the motions do not reach ``n_c`` independent
    parameters."""
    G = datum_motions(prob, st)[:, :prob.n_c]
    cand = np.flatnonzero(np.abs(G).sum(axis=1) > 0)
    if len(cand) < prob.n_c:
        return None
    Gn = G[cand] / np.maximum(np.linalg.norm(G[cand], axis=0), 1e-300)
    _, R, piv = sla.qr(Gn.T, mode="economic", pivoting=True)
    r = np.abs(np.diag(R))
    return np.sort(cand[piv[:prob.n_c]]) if r.min() > 1e-8 * r.max() else None


def datum_basis(prob, Cg, Cp, st):
    """The datum motions of every unknown (``Gg`` (n_g, n_c), ``Gp`` (n_e, 3, n_c)) and
    ``T = (Cᵀ G)⁻¹`` for the inner constraints ``C = (Cg, Cp)`` of the free network."""
    n_c = prob.n_c
    Gg = datum_motions(prob, st)[:, :n_c]
    Gp = point_motions(prob, st, st.XYZ[prob.elim_points])[:, :, :n_c] * prob.elim_free[:, :, None]
    CtG = Cg.T @ Gg + np.einsum("pac,pad->cd", Cp, Gp)
    return Gg, Gp, np.linalg.inv(CtG)


def solve_sparse(red, held: np.ndarray | None, sym: Symbolic) -> tuple[np.ndarray, SparseFactor]:
    """Jacobi-scaled supernodal Cholesky of the reduced system (``sym`` its symbolic analysis
    without the ``held`` unknowns); a free network's step is the minimal-constraint solution
    S-transformed onto the inner constraints (``Δ = Δ₀ − G (Cᵀ G)⁻¹ Cᵀ Δ₀``: the same step as the
    bordered system's).  :class:`SingularAt` when the system is singular."""
    prob = red.prob
    n_g, n_c = prob.n_g, prob.n_c
    K = red.K
    keep = np.ones(n_g, bool)
    if held is not None:
        keep[held] = False
    kidx = np.flatnonzero(keep)
    Kk = K[kidx][:, kidx] if held is not None else K
    dg = Kk.diagonal()
    if (dg <= 0).any():
        raise SingularAt(int(kidx[np.argmax(dg <= 0)]), zero=True)
    d = 1.0 / np.sqrt(dg)
    Ds = sp.diags(d)
    Ks = (Ds @ Kk @ Ds).tocsc()
    try:
        F = SupernodalCholesky(sym, Ks)
    except NotPositiveDefinite as e:
        raise SingularAt(int(kidx[e.column])) from None
    fac = SparseFactor(F, d, kidx)
    dx = np.zeros(n_g + n_c)
    dx[kidx] = F.solve(red.rhs[kidx] * d) * d
    if n_c:
        Gg, _, T = red.datum_basis
        dp = red.back_substitute(dx)
        c = red.Cg.T @ dx[:n_g] + np.einsum("pac,pa->c", red.Cp, dp)
        dx[:n_g] -= Gg @ (T @ c)
    if not np.isfinite(dx).all():
        raise SingularAt(int(np.argmax(~np.isfinite(dx[:n_g]))))
    return dx, fac
