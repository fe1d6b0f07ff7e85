"""The two solver routes of the reduced camera system, one interface (:class:`Route`).

:class:`DenseRoute` holds ``K`` (n_x × n_x) with a free network's inner constraints bordered and
solves it by Cholesky (:func:`.factor.solve_dense`); its precision inverts ``K``.
:class:`SparseRoute` holds the global unknowns' ``K`` as scipy CSR and factors it with the
supernodal Cholesky of :mod:`.sparse` (a free network's datum held by ``n_c`` photo parameters and
S-transformed); its precision is the selected inversion (``docs/bundle.md``, "Sparse route").

:func:`choose_route` picks one once per adjustment, at the start state: the sparse route when the
settings or the size ask for it (:attr:`~.normal.NormalEquations.wants_sparse`), unless a free
network's datum cannot be held by photo parameters or control constrains it as well (then the
bordered dense system).  :class:`ReducedSystem` is the reduced system of one iteration, with its
solution and factor computed once on first use.
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from dataclasses import dataclass
from functools import cached_property
from typing import ClassVar

import numpy as np
import scipy.sparse as sp

from baarda.pipeline.errors import AdjustmentError

from .collinearity import bmv
from .diagnose import datum_motions, parameter_names
from .factor import SingularAt, datum_basis, minimal_datum, solve_dense, solve_sparse
from .normal import Linearisation
from .precision import (Precision, dense_precision, front_cofactors, predicted_variance_dense,
                        predicted_variance_sparse, sparse_precision)
from .settings import BundleState
from .sparse import Symbolic

__all__ = ["Route", "DenseRoute", "SparseRoute", "ReducedSystem", "choose_route"]

DENSE_DIAGNOSIS_LIMIT = 6000
"""A singular sparse system up to this many unknowns is analysed densely (:mod:`.diagnose`)."""


@dataclass(frozen=True, eq=False)
class ReducedSystem:
    """The Schur complement of one linearisation (points eliminated) on one route.

    ``K`` dense (n_x, n_x) with the inner constraints bordered (dense route) or CSR (n_g, n_g)
    (sparse route); ``rhs`` (n_x,); ``Li`` (n_e, 3, 3) with ``V = L Lᵀ``; ``z = L⁻¹ b_p``; ``B`` the
    :class:`~.normal.BMatrix`; ``Cg`` (n_g, n_c), ``Cp`` (n_e, 3, n_c) the inner-constraint rows;
    the problem, the state, the linearisation and the damping it was formed with."""

    route: Route
    prob: object
    st: BundleState
    lin: Linearisation
    lam: float
    K: object
    rhs: np.ndarray
    Li: np.ndarray
    z: np.ndarray
    B: object
    Cg: np.ndarray
    Cp: np.ndarray

    @cached_property
    def solution(self) -> tuple:
        """``(Δ (n_x,), factor)``: the step of this system and the factorisation behind it."""
        return self.route.solve(self)

    @property
    def factor(self):
        return self.solution[1]

    @cached_property
    def datum_basis(self) -> tuple:
        """``(Gg, Gp, T)`` of :func:`.factor.datum_basis` (a free network)."""
        return datum_basis(self.prob, self.Cg, self.Cp, self.st)

    def lean(self) -> "ReducedSystem":
        """This system without its linearisation and its matrix (``lin = K = None``): the same
        right-hand side, blocks, solution, factor and datum basis, for work after the solve that
        needs neither the Jacobians, residuals and projection nor ``K`` itself, only its factor
        (external reliability) — so that they can be freed (about 110 MB at 2 000 photos)."""
        new = dataclasses.replace(self, lin=None, K=None)
        for name in ("solution", "datum_basis"):          # computed once: taken over, not computed again
            if name in self.__dict__:
                new.__dict__[name] = self.__dict__[name]
        return new

    def back_substitute(self, dx: np.ndarray) -> np.ndarray:
        """Δp = L⁻ᵀ (z − B_pᵀ Δx) for every eliminated point."""
        if self.prob.n_e == 0:
            return np.zeros((0, 3))
        return bmv(np.transpose(self.Li, (0, 2, 1)), self.z - self.B.rmatvec(dx))

    def datum_Y(self) -> tuple:
        """Sparse free network: ``(Gg, Gp, T, Yg, Yp)`` with ``Y = Q₀ C`` (minimal-datum cofactors
        times the inner-constraint rows, ``n_c`` solves) for the S-transformation
        ``Δ = Δ₀ − G T Cᵀ Δ₀``, ``Cᵀ Δ₀ = Yᵀ a``."""
        prob = self.prob
        n_g, n_c = prob.n_g, prob.n_c
        Gg, Gp, T = self.datum_basis
        Cg, Cp, B, Li = self.Cg, self.Cp, self.B, self.Li
        LiT = np.transpose(Li, (0, 2, 1))
        zc = [bmv(Li, Cp[:, :, c]) for c in range(n_c)]
        rhs = np.empty((n_g, n_c))
        for c in range(n_c):
            rhs[:, c] = Cg[:, c] - (B.matvec(zc[c])[:n_g] if prob.n_e else 0.0)
        Yg = self.factor.solve(rhs)
        Yp = np.zeros((prob.n_e, 3, n_c))
        for c in range(n_c):
            if prob.n_e:
                Yp[:, :, c] = bmv(LiT, zc[c] - B.rmatvec(np.r_[Yg[:, c], np.zeros(n_c)]))
        return Gg, Gp, T, Yg, Yp


class Route(ABC):
    """How the reduced camera system is formed, solved and inverted (chosen once: :func:`choose_route`)."""

    name: ClassVar[str]
    """``"dense"`` or ``"sparse"``, as the report names the route."""
    sparse_normals: ClassVar[bool]
    """The global unknowns' normal matrix as scipy CSR (else dense)."""

    @abstractmethod
    def reduced_system(self, prob, lin: Linearisation, st: BundleState, lam: float = 0.0) -> ReducedSystem:
        """The Schur complement of ``lin`` damped by ``lam``."""

    @abstractmethod
    def solve(self, red: ReducedSystem) -> tuple:
        """``(Δ, factor)`` of ``red`` (a singular system raises the datum / parameter diagnosis)."""

    @abstractmethod
    def precision(self, prob, lin: Linearisation, red: ReducedSystem, st: BundleState) -> Precision:
        """Cofactor blocks of every unknown and the hat-matrix blocks of the observations."""

    @abstractmethod
    def predicted_variance(self, prob, st, red: ReducedSystem, pre: Precision, obs_idx) -> np.ndarray:
        """``diag(a Qxx aᵀ)`` (len, 2) of inactive block observations ``obs_idx``."""

    @abstractmethod
    def inverse(self, red: ReducedSystem, pre_Qx=None):
        """``K⁻¹`` (dense route; ``pre_Qx`` when the precision has it) or ``None`` (sparse)."""

    @abstractmethod
    def apply_inverse(self, red: ReducedSystem, Qx, r: np.ndarray) -> np.ndarray:
        """``K⁻¹ r`` for right-hand sides ``r`` (n_x, j) (sparse: the minimal-datum solution)."""

    @abstractmethod
    def held_datum(self, prob, st) -> np.ndarray | None:
        """The photo parameters that hold a free network's datum in the linearised model."""

    @abstractmethod
    def constraint_cofactors(self, red: ReducedSystem, Qx) -> tuple | None:
        """``(Qgc (n_g + 1, n_c), Qcc)``: the cofactors of the bordered constraint rows (dense
        free network), else ``None``."""

    @abstractmethod
    def datum_transform(self, red: ReducedSystem) -> tuple | None:
        """``(Gg, Gp, T, Yg, Yp)`` of :meth:`ReducedSystem.datum_Y` when the route's solutions are
        minimal-datum ones to be S-transformed onto the inner constraints, else ``None``."""

    @abstractmethod
    def hand_blocks(self, red: ReducedSystem, Qx, groups, single, tracks, singles, chunk_bytes: float) -> None:
        """Hand every point's track (``groups``: observation matrices by track length) and every
        observation of no eliminated point (``single``) the block of ``K⁻¹`` on its columns:
        ``tracks(obs_mat, Qsub)``, ``singles(obs, Qk)``."""


@dataclass(frozen=True, eq=False)
class DenseRoute(Route):
    """K dense (n_x × n_x), a free network's inner constraints bordered; Cholesky; ``K⁻¹`` for the
    precision, the points' terms by pairs or by chunks (``by_pairs``, chosen once by the problem's
    cost model :attr:`~.normal.NormalEquations.points_by_pairs`)."""

    by_pairs: bool = False
    name: ClassVar[str] = "dense"
    sparse_normals: ClassVar[bool] = False

    def reduced_system(self, prob, lin, st, lam=0.0):
        U, rhs, Li, z, B, Cg, Cp = prob.normals.schur(lin, st, lam, sparse=False)
        n_g, n_c = prob.n_g, prob.n_c
        n_x = n_g + n_c
        K = np.zeros((n_x, n_x))
        K[:n_g, :n_g] = U
        if n_c:
            K[:n_g, n_g:] = Cg
            K[n_g:, :n_g] = Cg.T
        K -= B.gram()
        return ReducedSystem(self, prob, st, lin, lam, K, rhs, Li, z, B, Cg, Cp)

    def solve(self, red):
        return solve_dense(red.prob, red, red.st)

    def precision(self, prob, lin, red, st):
        return dense_precision(prob, lin, red, self.by_pairs)

    def predicted_variance(self, prob, st, red, pre, obs_idx):
        return predicted_variance_dense(prob, st, red, pre.Qx, pre.Qpp, obs_idx)

    def inverse(self, red, pre_Qx=None):
        if pre_Qx is not None:
            return pre_Qx
        if red.factor is None:
            return np.zeros((0, 0))
        return red.factor.inverse()

    def apply_inverse(self, red, Qx, r):
        return Qx @ r

    def held_datum(self, prob, st):
        return minimal_datum(prob, st) if prob.n_c else np.zeros(0, int)

    def constraint_cofactors(self, red, Qx):
        n_g, n_c = red.prob.n_g, red.prob.n_c
        if not n_c:
            return None
        Qgc = np.zeros((n_g + 1, n_c))
        Qgc[:n_g] = Qx[:n_g, n_g:]
        return Qgc, Qx[n_g:, n_g:]

    def datum_transform(self, red):
        return None

    def hand_blocks(self, red, Qx, groups, single, tracks, singles, chunk_bytes):
        """Gathered from ``K⁻¹``, points of one track length in chunks."""
        prob = red.prob
        n_g, q = prob.n_g, prob.layout.q
        Qg = np.zeros((n_g + 1, n_g + 1))
        Qg[:n_g, :n_g] = Qx[:n_g, :n_g]
        for obs_mat in groups:
            N, t = obs_mat.shape
            c = max(1, int(chunk_bytes / (8.0 * 6 * (t * q) ** 2)))
            for a in range(0, N, c):
                om = obs_mat[a:a + c]
                C = prob.layout.cidx[om].reshape(len(om), -1)
                tracks(om, Qg[C[:, :, None], C[:, None, :]])
        for a in range(0, len(single), 4096):
            ob = single[a:a + 4096]
            Ck = prob.layout.cidx[ob]
            singles(ob, Qg[Ck[:, :, None], Ck[:, None, :]])


@dataclass(frozen=True, eq=False)
class SparseRoute(Route):
    """K of the global unknowns as CSR; the supernodal Cholesky of :mod:`.sparse` without the
    ``held`` unknowns (a free network's minimal datum, chosen at the start state; ``None``:
    control datum), whose symbolic analysis ``sym`` is done once here."""

    held: np.ndarray | None
    sym: Symbolic
    name: ClassVar[str] = "sparse"
    sparse_normals: ClassVar[bool] = True

    @classmethod
    def of(cls, prob, held: np.ndarray | None) -> "SparseRoute":
        keep = None
        if held is not None:
            keep = np.ones(prob.n_g, bool)
            keep[held] = False
        return cls(held, prob.normals.symbolic(keep))

    def reduced_system(self, prob, lin, st, lam=0.0):
        U, rhs, Li, z, B, Cg, Cp = prob.normals.schur(lin, st, lam, sparse=True)
        K = sp.csr_matrix(U) - B.gram_sparse() if prob.n_e else sp.csr_matrix(U)
        if prob.n_c:
            rhs[prob.n_g:] = 0.0
        return ReducedSystem(self, prob, st, lin, lam, K.tocsr(), rhs, Li, z, B, Cg, Cp)

    def solve(self, red):
        try:
            return solve_sparse(red, self.held, self.sym)
        except SingularAt as e:
            self._diagnose(red, e)

    @staticmethod
    def _diagnose(red, e: SingularAt):
        """Raise the datum / parameter diagnosis for a singular sparse system: the dense analysis for
        systems small enough to hold densely, else the parameter at the failing pivot."""
        prob, st = red.prob, red.st
        if prob.n_g + prob.n_c <= DENSE_DIAGNOSIS_LIMIT:
            dense = DenseRoute()
            dense.reduced_system(prob, red.lin, st, red.lam).solution
        name = parameter_names(prob)[e.column]
        if e.zero:
            raise AdjustmentError(f"{name} cannot be determined: no observation depends on it — fix it or give it "
                                  "an a-priori sigma", state=st)
        raise AdjustmentError(f"the normal equations are singular at {name}: it cannot be determined from the "
                              "observations and the datum — check the control points (or set datum = 'free'), its "
                              "observations, or fix it", state=st)

    def precision(self, prob, lin, red, st):
        return sparse_precision(prob, lin, red, st)

    def predicted_variance(self, prob, st, red, pre, obs_idx):
        return predicted_variance_sparse(prob, st, red, obs_idx)

    def inverse(self, red, pre_Qx=None):
        return None

    def apply_inverse(self, red, Qx, r):
        x = np.zeros(r.shape)
        x[:red.prob.n_g] = red.factor.solve(r[:red.prob.n_g])
        return x

    def held_datum(self, prob, st):
        return self.held if self.held is not None else np.zeros(0, int)

    def constraint_cofactors(self, red, Qx):
        return None

    def datum_transform(self, red):
        return red.datum_Y() if red.prob.n_c else None

    def hand_blocks(self, red, Qx, groups, single, tracks, singles, chunk_bytes):
        """Hand every track (and every scale-bar-point observation) the block of ``K⁻¹`` on its columns
        from the selected inversion, in the front of its first column in the elimination order (the
        columns form a clique of the filled graph, so that front holds them all)."""
        prob = red.prob
        F, d, kidx = red.factor.F, red.factor.d, red.factor.kidx
        sym = F.sym
        n_g, n = prob.n_g, sym.n
        posg = np.full(n_g + 1, n)
        posg[kidx] = sym.ipos
        sn_of_pos = np.repeat(np.arange(sym.n_super), np.diff(sym.start))

        def by_owner(C):
            m = posg[C].reshape(len(C), -1).min(axis=1) if len(C) else np.zeros(0, int)
            own = np.where(m < n, sn_of_pos[np.minimum(m, n - 1)], -1)
            order = np.argsort(own, kind="stable")
            return order, np.searchsorted(own[order], np.arange(-1, sym.n_super + 1))

        Cs = [prob.layout.cidx[om].reshape(len(om), -1) for om in groups]
        own_t = [by_owner(C) for C in Cs]
        Csg = prob.layout.cidx[single]
        own_s = by_owner(Csg)

        def take(ob, s):
            order, bounds = ob
            return order[bounds[s + 1]:bounds[s + 2]]

        def visit(s, front, Z):
            Zx, loc = front_cofactors(front, Z, d, sym.ipos, posg)
            _hand(s, Zx, loc)

        def _hand(s, Zx, loc):
            for g, om in enumerate(groups):
                sel = take(own_t[g], s)
                if sel.size:
                    w = Cs[g].shape[1]
                    c = max(1, int(chunk_bytes / (8.0 * 6 * w * w)))
                    for a in range(0, sel.size, c):
                        ss = sel[a:a + c]
                        Cl = loc(Cs[g][ss]) if Zx is not None else None
                        Qsub = Zx[Cl[:, :, None], Cl[:, None, :]] if Zx is not None else np.zeros((ss.size, w, w))
                        tracks(om[ss], Qsub)
            sel = take(own_s, s)
            if sel.size:
                Cl = loc(Csg[sel]) if Zx is not None else None
                w = Csg.shape[1]
                singles(single[sel], Zx[Cl[:, :, None], Cl[:, None, :]] if Zx is not None
                        else np.zeros((sel.size, w, w)))

        F.selected_inverse(visit)
        _hand(-1, None, None)                       # tracks whose columns are all fixed


def datum_is_null_space(prob, st) -> bool:
    """Do the similarity motions span the null space of the reduced system?  Only then a free
    network's inner constraints are a choice of datum (the sparse route's minimal constraints and
    S-transformation); with control, fixed coordinates or orientations, or priors on anything the
    motions move, they constrain the solution, and the bordered dense system solves that."""
    if prob.n_c == 0:
        return False
    if (~prob.pt_free[prob.point_used]).any() or (prob.g_eo[prob.photo_used] < 0).any() or len(prob.prior_p_idx):
        return False
    if len(prob.prior_g_idx):
        G = datum_motions(prob, st)[:, :prob.n_c]
        if np.abs(G[prob.prior_g_idx]).max() > 0:
            return False
    return True


def choose_route(prob, st: BundleState) -> Route:
    """The route of an adjustment, once, at its start state ``st``: sparse when
    :attr:`~.normal.NormalEquations.wants_sparse`, unless a free network's datum cannot be held by
    ``n_c`` photo parameters (:func:`.factor.minimal_datum`) or is constrained by control as well
    (:func:`datum_is_null_space`); else dense."""
    if prob.normals.wants_sparse:
        if not prob.n_c:
            return SparseRoute.of(prob, None)
        held = minimal_datum(prob, st)
        if held is not None and datum_is_null_space(prob, st):
            return SparseRoute.of(prob, held)
    return DenseRoute(by_pairs=prob.normals.points_by_pairs)
