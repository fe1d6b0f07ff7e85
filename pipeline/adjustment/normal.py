"""Normal equations of the bundle: whitened Jacobians (:class:`Linearisation`), the pieces of the
reduced camera system (object points eliminated by the Schur complement) and its constraint rows.

:class:`NormalEquations` belongs to one :class:`~.problem.BundleProblem` (``problem.normals``: it
uses the problem's index bookkeeping and column layout); :mod:`.route` assembles and solves the
reduced system on the dense or the sparse route.  :class:`BMatrix` holds ``B = W V^{-1/2}`` per
observation.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from baarda.pipeline.errors import AdjustmentError
from baarda.pipeline.geometry import similarity_motions

from . import kernels
from .collinearity import bmm, bmv
from .settings import BundleState
from .sparse import Symbolic

__all__ = ["NormalEquations", "BMatrix", "Linearisation", "PairPlan"]


@dataclass(frozen=True, slots=True, eq=False)
class Linearisation:
    """The whitened normal-equation pieces at one state (:meth:`NormalEquations.linearize`).

    ``U`` (n_g, n_g; dense or CSR) and ``g`` the global unknowns' normal matrix and right-hand side,
    ``V`` (n_e, 3, 3) and ``bp`` (n_e, 3) the eliminated points', ``Jc`` (k, 2, q) / ``Jp`` (k, 2, 3)
    the whitened Jacobians, ``e`` the whitened and ``v`` the plain image residuals, ``parts`` the
    problem's :meth:`~.problem.BundleProblem.residual_parts`, ``proj`` the projection, ``Jd``,
    ``dcols`` the whitened rows on global unknowns and their columns, ``t`` seconds taken."""

    U: object
    g: np.ndarray
    V: np.ndarray
    bp: np.ndarray
    Jc: np.ndarray
    Jp: np.ndarray
    e: np.ndarray
    v: np.ndarray
    parts: tuple
    proj: object
    Jd: np.ndarray
    dcols: np.ndarray
    t: float


@dataclass(frozen=True, slots=True, eq=False)
class PairPlan:
    """The observation pairs of every eliminated point grouped by photo pair
    (:attr:`NormalEquations.pair_plan`)."""

    oa: np.ndarray
    ob: np.ndarray
    gs: list
    ge: list
    flat: np.ndarray
    flat_diag: np.ndarray
    chunks: list


PAIR_CHUNK = 1 << 13
"""Photo pairs gathered together by :attr:`NormalEquations.pair_plan` (unless one has more)."""


class NormalEquations:
    """The normal equations of a :class:`~.problem.BundleProblem` (its :attr:`~.problem.BundleProblem.normals`):
    the whitened linearisation, the Schur complement's pieces, the inner-constraint rows, and what
    they reuse (photo-pair plan, track groups, the sparsity pattern and its symbolic analysis, the
    cost models that choose the strategies), each computed once."""

    def __init__(self, prob):
        self.prob = prob
        self.layout = prob.layout

    def linearize(self, st: BundleState, proj=None, *, sparse: bool = False) -> Linearisation:
        """Whitened Jacobians and normal-equation pieces at ``st``.

        ``proj``: the projection of ``st`` already computed (the accepted trial step's), so the
        residuals are not evaluated twice; its Jacobians are added here.  ``sparse``: ``U`` as
        scipy CSR (the sparse route's :attr:`~.route.Route.sparse_normals`), else dense."""
        t0 = time.perf_counter()
        if proj is None or proj._d is None:
            proj = self.prob.project(st, False)
        if proj.J_eo is None:
            self.prob.projector.jacobians(proj)
        parts = self.prob.residual_parts(st, proj)
        v, e, dg, dpv, dd, _ = parts
        sc, se, spt = self.layout.jac_cols
        Jc, Jp = kernels.whitened(self.prob.L, proj.J_cam, proj.J_eo, se, proj.J_point, spt)   # L [J_cam J_eo J_pt]
        if not self.layout.mask_all:
            Jc *= self.layout.mask[:, None, :]
        if not self.layout.pt_mask_all:
            Jp *= self.layout.pt_mask[:, None, :]
        proj.J_cam = proj.J_eo = proj.J_point = None      # whitened copies above; recomputed if needed again
        U, g = self.gram_U(Jc, e, sparse=sparse)
        ng1 = self.prob.n_g + 1
        V, bp = kernels.point_normals(Jp, e, self.layout.pidx, self.prob.n_e)
        # priors
        U = U + _triplets(self.prob.prior_g_idx, self.prob.prior_g_idx, self.prob.prior_g_w, ng1, sparse=sparse)
        np.add.at(g, self.prob.prior_g_idx, self.prob.prior_g_w * dg)
        if len(self.prob.prior_p_idx):
            np.add.at(V, (self.prob.prior_p_idx, self.prob.prior_p_coord, self.prob.prior_p_coord), self.prob.prior_p_w)
            np.add.at(bp, (self.prob.prior_p_idx, self.prob.prior_p_coord), self.prob.prior_p_w * dpv)
        # observations on global unknowns only (scale bars, GNSS antennas): whitened rows J̃, ẽ = dd
        Jd, dcols, _ = self.prob.global_rows_linear(st)
        if len(dd):
            w = dcols.shape[1]
            sh = (len(dcols), w, w)
            U = U + _triplets(np.broadcast_to(dcols[:, :, None], sh), np.broadcast_to(dcols[:, None, :], sh),
                              Jd[:, :, None] * Jd[:, None, :], ng1, sparse=sparse)
            g = g + np.bincount(dcols.ravel(), (Jd * dd[:, None]).ravel(), minlength=ng1)[:-1]
        # free coordinates that no observation touches stay fixed
        if self.prob.n_e:
            fixed = ~self.prob.elim_free
            pi, ci = np.nonzero(fixed)
            V[pi, ci, ci] = 1.0
            bp[fixed] = 0.0
        return Linearisation(U=U, g=g, V=V, bp=bp, Jc=Jc, Jp=Jp, e=e, v=v, parts=parts, proj=proj,
                             Jd=Jd, dcols=dcols, t=time.perf_counter() - t0)

    def gram_U(self, Jc, e=None, sparse: bool = False):
        """``Σ_k Jc_kᵀ Jc_k`` over the global unknowns (and ``Σ_k Jc_kᵀ e_k`` when ``e`` is given):
        per photo with BLAS for the photo-constant columns, per observation for the few
        observations of global points.  Dense (n_g, n_g), or scipy CSR on the sparse route."""
        ng1 = self.prob.n_g + 1
        gp = np.zeros(ng1)
        q_ph = self.layout.q_ph
        whole = q_ph == self.layout.q
        A = Jc if whole else Jc[:, :, :q_ph]
        blocks = segment_sums(A, self.layout.seg_start, self.layout.seg_end, self.prob.settings.threads)
        if e is not None:
            for s0, s1, idx in zip(self.layout.seg_start.tolist(), self.layout.seg_end.tolist(), self.layout.seg_cols):
                gp[idx] += A[s0:s1].reshape(-1, q_ph).T @ e[s0:s1].reshape(-1)
        sc = self.layout.seg_cols
        U = _triplets(np.broadcast_to(sc[:, :, None], blocks.shape), np.broadcast_to(sc[:, None, :], blocks.shape),
                      blocks, ng1, sparse=sparse)
        if len(self.layout.gp_obs):
            J = Jc[self.layout.gp_obs]
            outer = bmm(np.transpose(J, (0, 2, 1)), J)
            outer[:, :q_ph, :q_ph] = 0.0          # counted above
            gc = self.layout.cidx[self.layout.gp_obs]
            U = U + _triplets(np.broadcast_to(gc[:, :, None], outer.shape), np.broadcast_to(gc[:, None, :], outer.shape),
                              outer, ng1, sparse=sparse)
            if e is not None:
                eg = e[self.layout.gp_obs]
                gv = J[:, 0, q_ph:] * eg[:, 0, None] + J[:, 1, q_ph:] * eg[:, 1, None]
                gp += np.bincount(self.layout.cidx[self.layout.gp_obs, q_ph:].ravel(), gv.ravel(), minlength=ng1)
        if e is None:
            return U
        return U, gp[:-1]

    @cached_property
    def gram_mode(self) -> str:
        """Cheapest way to form ``B Bᵀ`` on the dense route (cost model in flops-equivalents):
        ``"dense"``, ``"pairs"`` or ``"sparse"`` (:class:`BMatrix`)."""
        n_e = self.prob.n_e
        cnt = np.bincount(self.layout.pidx[self.layout.obs_elim], minlength=n_e).astype(float)
        q = self.layout.q_ph
        n_pairs = float(np.sum(cnt * (cnt - 1) / 2))
        n_seg = len(self.layout.seg_start)
        photo_pairs = min(n_pairs, n_seg * (n_seg - 1) / 2)
        # pairs: one small BLAS product per photo pair (≈ 30 µs-equivalents of overhead each),
        # the gathered blocks and the per-photo diagonal
        pairs = (2 * 3 * q * q / 4 + 2 * 3 * q * 2) * n_pairs + 3e4 * photo_pairs + len(self.prob.oi) * 3 * q * q / 4
        nnz_col = np.minimum(cnt * self.layout.q, self.prob.n_g)
        sparse = 3.0 * float(np.sum(nnz_col ** 2)) * 4.0
        dense = float(self.prob.n_g + self.prob.n_c) ** 2 * 3 * n_e / 10.0 + 3.0 * len(self.prob.oi) * self.layout.q
        dense_bytes = 8.0 * (self.prob.n_g + 1) * 3 * n_e
        pair_bytes = 16.0 * n_pairs + 8.0 * photo_pairs * q * q
        costs = {"sparse": sparse, "pairs": pairs if pair_bytes < 6e8 else np.inf,
                 "dense": dense if dense_bytes < 4e8 else np.inf}
        return min(costs, key=costs.get)

    @cached_property
    def points_by_pairs(self) -> bool:
        """How the dense route's precision forms the points' cofactors (cost model in
        flops-equivalents, independent of :attr:`gram_mode`, which chooses the Schur product):
        by pairs — per point only the (t q)² block of K⁻¹ its t observations touch (short
        tracks, e.g. aerial blocks, BAL) — or by chunks — K⁻¹ B for blocks of points, n_x² per
        point (few points seen by many photos, e.g. close range).  By pairs gathers the blocks of
        all points of one track length at once; past 2e8 bytes it is not used."""
        cnt = np.bincount(self.layout.pidx[self.layout.obs_elim], minlength=self.prob.n_e).astype(float)
        tq = cnt * self.layout.q
        n_x = self.prob.n_g + self.prob.n_c
        pairs = float(np.sum(4.0 * tq * tq * 3 + 3.0 * tq * self.prob.n_c))
        chunks = 3.0 * n_x * n_x * self.prob.n_e + 3.0 * len(self.prob.oi) * self.layout.q * 3
        lengths, inverse = np.unique(cnt, return_inverse=True) if self.prob.n_e else (np.zeros(0), np.zeros(0, int))
        group_bytes = np.bincount(inverse, 8.0 * tq * tq, minlength=len(lengths)) if self.prob.n_e else np.zeros(1)
        fits = float(group_bytes.max(initial=0.0)) < 2e8
        return bool(fits and pairs < chunks)

    @cached_property
    def track_groups(self) -> list:
        """Observations of each eliminated point grouped by track length: list of
        ``(obs_mat (N_t, t), None)``."""
        sel = np.flatnonzero(self.layout.obs_elim)
        order = sel[np.argsort(self.layout.pidx[sel], kind="stable")]
        cnt = np.bincount(self.layout.pidx[sel], minlength=self.prob.n_e)
        start = np.r_[0, np.cumsum(cnt)[:-1]]
        groups = []
        for t in np.unique(cnt[cnt > 0]):
            pts = np.flatnonzero(cnt == t)
            groups.append((order[start[pts][:, None] + np.arange(t)], None))
        return groups

    @cached_property
    def pair_plan(self) -> PairPlan:
        """The observation pairs of every eliminated point, grouped by photo pair (built once).

        ``B Bᵀ`` (global part) is ``Σ_photos Y_aᵀ Y_a + Σ_{a<b} (S_ab + S_abᵀ)`` with
        ``S_ab = Σ_{p seen in a and b} B_ap B_bpᵀ``: one BLAS product per photo pair over the
        stacked blocks of their common points.  A :class:`PairPlan`: ``oa, ob`` (observations of each
        pair, photo of ``oa`` < photo of ``ob``, sorted by photo pair), ``gs, ge`` (pair range of
        each photo pair), ``flat`` / ``flat_diag`` (where the q×q blocks go in the (n_g+1)² matrix),
        ``chunks`` (photo-pair ranges gathered together, ≤ ``chunk_pairs`` pairs unless one photo
        pair alone has more)."""
        chunk_pairs = PAIR_CHUNK
        n_seg = len(self.layout.seg_start)
        seg_of = np.repeat(np.arange(n_seg), self.layout.seg_len)
        oa_l, ob_l = [np.zeros(0, np.intp)], [np.zeros(0, np.intp)]
        for obs_mat, _ in self.track_groups:
            t = obs_mat.shape[1]
            if t < 2:
                continue
            ia, ib = np.triu_indices(t, 1)
            oa_l.append(obs_mat[:, ia].ravel())
            ob_l.append(obs_mat[:, ib].ravel())
        oa, ob = np.concatenate(oa_l), np.concatenate(ob_l)
        sa, sb = seg_of[oa], seg_of[ob]
        swap = sa > sb
        oa, ob = np.where(swap, ob, oa), np.where(swap, oa, ob)
        sa, sb = np.minimum(sa, sb), np.maximum(sa, sb)
        key = sa.astype(np.int64) * n_seg + sb
        o = np.lexsort((oa, key))
        oa, ob, key, sa, sb = oa[o], ob[o], key[o], sa[o], sb[o]
        gs = np.flatnonzero(np.r_[True, key[1:] != key[:-1]]) if len(key) else np.zeros(0, int)
        ge = np.r_[gs[1:], len(key)].astype(int)
        ng1 = self.prob.n_g + 1
        itype = np.int32 if ng1 * ng1 < 2 ** 31 else np.int64
        ra = self.layout.seg_cols[sa[gs]].astype(itype)
        rb = self.layout.seg_cols[sb[gs]].astype(itype)
        flat = (ra[:, :, None] * itype(ng1) + rb[:, None, :]).ravel()
        rd = self.layout.seg_cols.astype(itype)
        flat_diag = (rd[:, :, None] * itype(ng1) + rd[:, None, :]).ravel()
        chunks = []
        g0 = 0
        for g in range(1, len(gs) + 1):
            if g == len(gs) or ge[g] - gs[g0] > chunk_pairs:
                chunks.append((g0, g))
                g0 = g
        return PairPlan(oa=oa, ob=ob, gs=gs.tolist(), ge=ge.tolist(), flat=flat, flat_diag=flat_diag,
                        chunks=chunks)

    # ------------------------------------------------------------------------------------------
    def constraint_rows(self, st: BundleState):
        """Inner constraints Gᵀ Δ = 0: (Cg (n_g, n_c), Cp (n_e, 3, n_c))."""
        n_c = self.prob.n_c
        Cg = np.zeros((self.prob.n_g, n_c))
        Cp = np.zeros((self.prob.n_e, 3, n_c))
        if n_c == 0:
            return Cg, Cp
        pos, where = [], []
        if len(self.prob.datum_photos):
            pos.append(st.X0[self.prob.datum_photos])
        if len(self.prob.datum_elim):
            pos.append(st.XYZ[self.prob.elim_points[self.prob.datum_elim]])
        if len(self.prob.datum_glob_pts):
            pos.append(st.XYZ[self.prob.datum_glob_pts])
        allpos = np.concatenate(pos)
        ctr = allpos.mean(axis=0)
        scale = np.sqrt(np.mean(np.sum((allpos - ctr) ** 2, axis=1))) or 1.0

        def G(X):
            return similarity_motions((X - ctr) / scale, n_c)

        if len(self.prob.datum_photos):
            Gx = G(st.X0[self.prob.datum_photos])
            Cg[self.prob.g_eo[self.prob.datum_photos, :3].ravel()] = Gx.reshape(-1, n_c)
        if len(self.prob.datum_glob_pts):
            Gx = G(st.XYZ[self.prob.datum_glob_pts])
            Cg[self.prob.g_pt[self.prob.datum_glob_pts].ravel()] = Gx.reshape(-1, n_c)
        if len(self.prob.datum_elim):
            Cp[self.prob.datum_elim] = G(st.XYZ[self.prob.elim_points[self.prob.datum_elim]])
        return Cg, Cp

    # ------------------------------------------------------------------------------------------
    def schur(self, lin: Linearisation, st: BundleState, lam: float, sparse: bool) -> tuple:
        """The Schur complement's pieces common to both routes (:mod:`.route` assembles ``K``):
        ``(U, rhs, Li, z, B, Cg, Cp)`` — ``U`` damped by ``lam`` (dense, or CSR with ``sparse``),
        ``rhs`` (n_x,), ``Li`` (n_e, 3, 3) with ``V = L Lᵀ``, ``z = L⁻¹ b_p``, the :class:`BMatrix`
        and the inner-constraint rows."""
        U, g, V, bp = lin.U, lin.g, lin.V, lin.bp
        Jc, Jp = lin.Jc, lin.Jp
        n_e, n_c = self.prob.n_e, self.prob.n_c
        if not sparse and sp.issparse(U):
            U = U.toarray()
        if lam > 0:
            U = U + lam * (sp.diags(U.diagonal()) if sp.issparse(U) else np.diag(np.diag(U)))
            V = V + lam * np.einsum("pii->pi", V)[:, :, None] * np.eye(3)
        Li = _chol3_inv(V, self.prob)                                   # (n_e, 3, 3) lower, L⁻¹ with V = L Lᵀ
        # B_k = W_k L⁻ᵀ = Jcᵀ (Jp L⁻ᵀ), held transposed: BkT (k, 3, q)
        BkT = kernels.schur_blocks(Jc, Jp, Li, self.layout.pidx)
        Cg, Cp = self.constraint_rows(st)
        if n_c:                                                     # (n_e, n_c, 3) = Cpᵀ L⁻ᵀ (Cp = 0 unless
            Bc = np.einsum("pac,pba->pcb", Cp, Li) if self.prob.datum_on_elim else np.zeros((n_e, n_c, 3))   # on points)
        else:
            Bc = None
        B = BMatrix(self, BkT, Bc, sparse=sparse)
        z = bmv(Li, bp)                                             # L⁻¹ b_p
        rhs = np.concatenate([g, np.zeros(n_c)]) - (B.matvec(z) if n_e else 0.0)
        return U, rhs, Li, z, B, Cg, Cp

    @cached_property
    def wants_sparse(self) -> bool:
        """The sparse reduced system asked for (``BundleSettings.solver``; ``"auto"``: from
        :data:`SPARSE_MIN_UNKNOWNS` global unknowns on, when the symbolic analysis finds a factor
        with less than half the entries of the dense triangle).  :func:`.route.choose_route`
        decides, with the free network's conditions."""
        want = self.prob.settings.solver
        if want == "sparse":
            return True
        if want == "auto" and self.prob.n_g >= SPARSE_MIN_UNKNOWNS:
            return self.symbolic_all.nnz_factor <= 0.5 * self.prob.n_g * (self.prob.n_g + 1) / 2
        return False

    def node_of_global(self) -> tuple[np.ndarray, list[int]]:
        """The node of every global unknown (a camera's parameters, a photo's orientation, a
        scale-bar point's coordinates) and the camera nodes (ordered last by the sparse route)."""
        node = np.full(self.prob.n_g, -1)
        k = 0
        cams = []
        for j in range(self.prob.K):
            c = self.prob.g_cam[j][self.prob.g_cam[j] >= 0]
            if c.size:
                node[c] = k
                cams.append(k)
                k += 1
        rig = (self.prob.g_frame, self.prob.g_sensor) if getattr(self.prob, "rig", None) is not None else ()
        for table in (self.prob.g_eo, *rig, self.prob.g_pt):
            rows = np.flatnonzero((table >= 0).any(axis=1))
            for i in rows.tolist():
                node[table[i][table[i] >= 0]] = k
                k += 1
        return node, cams

    @cached_property
    def global_pattern(self) -> sp.csr_matrix:
        """Sparsity of the reduced system of the global unknowns (n_g, n_g): the photo blocks with
        their cameras, photo pairs that share a point, observations of scale-bar points, priors and
        the observations on global unknowns (distances, GNSS antennas)."""
        ng1 = self.prob.n_g + 1
        sc = self.layout.seg_cols
        q = sc.shape[1]
        sh = (len(sc), q, q)
        pat = _triplets(np.broadcast_to(sc[:, :, None], sh), np.broadcast_to(sc[:, None, :], sh), np.ones(sh),
                        ng1, sparse=True)
        if len(self.layout.gp_obs):
            gc = self.layout.cidx[self.layout.gp_obs]
            sh = (len(gc), gc.shape[1], gc.shape[1])
            pat = pat + _triplets(np.broadcast_to(gc[:, :, None], sh), np.broadcast_to(gc[:, None, :], sh),
                                  np.ones(sh), ng1, sparse=True)
        if self.prob.n_grow_rows:                  # scale bars, GNSS antennas
            cols = self.prob.grow_cols
            sh = (len(cols), cols.shape[1], cols.shape[1])
            pat = pat + _triplets(np.broadcast_to(cols[:, :, None], sh), np.broadcast_to(cols[:, None, :], sh),
                                  np.ones(sh), ng1, sparse=True)
        if self.prob.n_e:
            pl = self.pair_plan
            rows, cols = np.divmod(pl.flat, ng1)
            pat = pat + _triplets(rows, cols, np.ones(len(rows)), ng1, sparse=True)
            pat = pat + pat.T
        return pat.tocsr()

    def symbolic(self, keep: np.ndarray | None = None) -> Symbolic:
        """Ordering and supernodes of the reduced system of the unknowns ``keep`` (all of them:
        :attr:`symbolic_all`, computed once; the sparse route analyses its own ``keep`` once)."""
        if keep is None:
            return self.symbolic_all
        return self._analyse(keep)

    @cached_property
    def symbolic_all(self) -> Symbolic:
        """Ordering and supernodes of the reduced system of all global unknowns."""
        return self._analyse(None)

    def _analyse(self, keep):
        pat = self.global_pattern
        node, cams = self.node_of_global()
        if keep is not None:
            pat = pat[keep][:, keep]
            node = node[keep]
            used = np.unique(node)
            renum = np.full(int(node.max(initial=-1)) + 2, -1)
            renum[used] = np.arange(len(used))
            cams = [int(renum[c]) for c in cams if renum[c] >= 0]
            node = renum[node]
        return Symbolic.analyse(pat, node, last_nodes=cams)


SPARSE_MIN_UNKNOWNS = 2000
"""``solver = "auto"`` considers the sparse route from this many global unknowns on."""


def segment_sums(A, starts, ends, threads: int = 1):
    """``Yᵀ Y`` of every segment ``Y = A[s0:s1]`` flattened to rows (A (k, r, q) → (n_seg, q, q)):
    one BLAS product per segment."""
    q = A.shape[-1]
    out = np.empty((len(starts), q, q))
    st, en = starts.tolist(), ends.tolist()
    n = len(st)
    parts = max(1, min(int(threads), n // 64 or 1))

    def part(t):
        for j in range(t * n // parts, (t + 1) * n // parts):
            Y = A[st[j]:en[j]].reshape(-1, q)
            np.matmul(Y.T, Y, out=out[j])

    parallel_for(parts, part, parts)
    return out


_POOLS: dict = {}


def parallel_for(n: int, fn, threads: int = 1) -> None:
    """``fn(i)`` for i = 0 … n−1, on ``threads`` threads of a persistent pool (numpy's gathers and
    BLAS release the GIL; measured 1.7–3× for the Schur product's photo-pair loop on 2 cores).
    Each ``fn(i)`` must write only its own part of the output."""
    threads = max(1, min(int(threads), n))
    if threads == 1:
        for i in range(n):
            fn(i)
        return
    pool = _POOLS.get(threads)
    if pool is None:
        pool = _POOLS[threads] = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="baarda-normal")
    for f in [pool.submit(fn, i) for i in range(n)]:
        f.result()


def _triplets(rows, cols, vals, ng1: int, sparse: bool):
    """Σ of ``vals`` at (``rows``, ``cols``) as an (ng1 − 1)² matrix; index ng1 − 1 is the dummy
    column of fixed parameters and is dropped.  Dense array or scipy CSR."""
    r = np.asarray(rows).ravel()
    c = np.asarray(cols).ravel()
    v = np.asarray(vals, float).ravel()
    n = ng1 - 1
    keep = (r < n) & (c < n)
    r, c, v = r[keep], c[keep], v[keep]
    if sparse:
        return sp.csr_matrix((v, (r, c)), shape=(n, n))
    return np.bincount(r.astype(np.int64) * n + c, v, minlength=n * n).reshape(n, n)


def _chol3(V, prob):
    try:
        return np.linalg.cholesky(V)
    except np.linalg.LinAlgError:
        det = np.linalg.det(V)
        tr = np.einsum("pii->p", V)
        bad = int(np.argmin(det / np.maximum(tr, 1e-300) ** 3))
        pid = str(prob.block.points.ids[prob.elim_points[bad]])
        raise AdjustmentError(f"point {pid!r} cannot be determined: its rays are (nearly) parallel or it is "
                              "seen from one photo only — remove it or add observations") from None


def _chol3_inv(V, prob):
    """``L⁻¹`` of ``V = L Lᵀ`` for every 3×3 block (closed form; LAPACK's error path when a block
    is not positive definite)."""
    Li, ok = kernels.chol3_inv(V)
    if not ok:
        return np.linalg.inv(_chol3(V, prob))
    return Li


class BMatrix:
    """``B = [W V^{-1/2}; Cpᵀ V^{-1/2}]`` (n_x × 3 n_e), held as per-observation blocks, transposed:
    ``BkT`` (k, 3, q) (``Bk`` (k, q, 3) is a view), plus the constraint blocks ``Bc`` (n_e, n_c, 3).

    ``gram() = B Bᵀ`` is computed by the cheapest of three strategies:
    ``dense`` (BLAS on the dense n_g × 3n_e matrix: few points, many photos per point),
    ``pairs`` (one BLAS product per photo pair over the blocks of their common points, see
    :attr:`NormalEquations.pair_plan`: many points with short tracks, e.g. BAL),
    ``sparse`` (scipy CSR product); chosen once by :attr:`NormalEquations.gram_mode` (the sparse
    route always forms its CSR ``B Bᵀ`` by pairs: :meth:`gram_sparse`).
    """

    def __init__(self, normals: NormalEquations, BkT, Bc, sparse: bool = False):
        self.normals = normals
        self.prob = prob = normals.prob
        self.BkT, self.Bc = BkT, Bc
        self.n_x = prob.n_g + prob.n_c
        self.mode = "pairs" if sparse else normals.gram_mode
        # (no bound method kept on self: that cycle held every iteration's blocks until the
        # garbage collector's next full pass — 43 MB each at 2 000 photos)

    @property
    def Bk(self):
        return np.swapaxes(self.BkT, 1, 2)

    # -- the Schur product ---------------------------------------------------------------------
    def gram(self) -> np.ndarray:
        """``B Bᵀ`` (n_x, n_x), dense, by the strategy of :attr:`mode`."""
        out = np.zeros((self.n_x, self.n_x))
        if self.prob.n_e:
            {"dense": BMatrix._gram_dense, "pairs": BMatrix._gram_pairs, "sparse": BMatrix._gram_csr}[self.mode](self, out)
        return out

    def _gram_dense(self, out):
        D = self.dense_cols(0, self.prob.n_e)
        out[:] = D @ D.T

    def _photo_cols(self):
        q = self.prob.layout.q_ph
        return self.BkT if q == self.prob.layout.q else np.ascontiguousarray(self.BkT[:, :, :q])

    def _gram_pairs(self, out):
        X = self._photo_cols()
        pl = self.normals.pair_plan
        S, Dg = self.pair_blocks(X)
        ng1 = self.prob.n_g + 1
        kernels.add_blocks(out, pl.flat, S, ng1, True)          # S_ab and S_abᵀ
        kernels.add_blocks(out, pl.flat_diag, Dg, ng1, False)
        self._constraint_terms(out, X)

    def _gram_csr(self, out):
        n_g = self.prob.n_g
        S = self.sparse()[:n_g]
        out[:n_g, :n_g] = (S @ S.T).toarray()
        self._constraint_terms(out, self._photo_cols())

    def _constraint_terms(self, out, X):
        """The rows and columns of the inner constraints in ``B Bᵀ`` (``X`` the photo columns of ``BkT``)."""
        prob = self.prob
        n_g, n_c = prob.n_g, prob.n_c
        ng1 = n_g + 1
        q = prob.layout.q_ph
        if n_c:
            if prob.datum_on_elim:
                # cross terms with the constraint rows, Σ_k B_k Bc_pᵀ, per photo
                BcT1 = np.concatenate([np.swapaxes(self.Bc, 1, 2), np.zeros((1, 3, n_c))], axis=0)
                Z = BcT1[prob.layout.pidx]                                             # (k, 3, n_c)
                cross = np.zeros((ng1, n_c))
                for s0, s1, idx in zip(prob.layout.seg_start.tolist(), prob.layout.seg_end.tolist(), prob.layout.seg_cols):
                    cross[idx] += X[s0:s1].reshape(-1, q).T @ Z[s0:s1].reshape(-1, n_c)
                out[:n_g, n_g:] = cross[:-1]
                out[n_g:, :n_g] = cross[:-1].T
            Bcf = np.transpose(self.Bc, (1, 0, 2)).reshape(n_c, -1)
            out[n_g:, n_g:] = Bcf @ Bcf.T

    def pair_blocks(self, X=None):
        """``S_ab = Σ_p B_ap B_bpᵀ`` of every photo pair (a < b) of :attr:`NormalEquations.pair_plan` and
        ``Y_aᵀ Y_a`` of every photo: (n_pairs, q, q), (n_photos, q, q) over the photo columns."""
        prob = self.prob
        q = prob.layout.q_ph
        if X is None:
            X = self.BkT if q == prob.layout.q else np.ascontiguousarray(self.BkT[:, :, :q])
        pl = self.normals.pair_plan
        gs, ge, oa, ob = pl.gs, pl.ge, pl.oa, pl.ob
        S = np.empty((len(gs), q, q))
        gs, ge = np.asarray(gs, np.intp), np.asarray(ge, np.intp)

        def chunk(c):                                  # a compiled loop over the observation pairs of
            g0, g1 = pl.chunks[c]                   # each photo pair (no gathered copies of X)
            kernels.pair_products(X, oa, ob, gs, ge, g0, g1, S)

        parallel_for(len(pl.chunks), chunk, prob.settings.threads)
        return S, segment_sums(X, prob.layout.seg_start, prob.layout.seg_end, prob.settings.threads)

    def gram_sparse(self) -> sp.csr_matrix:
        """``B Bᵀ`` of the global unknowns (n_g, n_g) as scipy CSR (no constraint rows), by pairs."""
        ng1 = self.prob.n_g + 1
        pl = self.normals.pair_plan
        S, Dg = self.pair_blocks()
        r, c = np.divmod(pl.flat, ng1)
        A = _triplets(r, c, S.ravel(), ng1, sparse=True)
        rd, cd = np.divmod(pl.flat_diag, ng1)
        return (A + A.T + _triplets(rd, cd, Dg.ravel(), ng1, sparse=True)).tocsr()

    # -- products with vectors -----------------------------------------------------------------
    def matvec(self, z):
        """``B z`` for z (n_e, 3)."""
        prob = self.prob
        out = np.zeros(self.n_x)
        out[:prob.n_g] = kernels.b_matvec(self.BkT, z.reshape(-1, 3), prob.layout.pidx, prob.layout.seg_start, prob.layout.seg_end,
                                          prob.layout.seg_cols, prob.n_g)
        if prob.datum_on_elim:                    # (else Bc = 0)
            out[prob.n_g:] = np.einsum("pca,pa->c", self.Bc, z.reshape(-1, 3))
        return out

    def rmatvec(self, x):
        """``Bᵀ x`` as (n_e, 3)."""
        prob = self.prob
        out = kernels.b_rmatvec(self.BkT, x[:prob.n_g], prob.layout.pidx, prob.layout.seg_start, prob.layout.seg_end, prob.layout.seg_cols,
                                prob.n_e)
        if prob.datum_on_elim:
            out += np.einsum("pca,c->pa", self.Bc, x[prob.n_g:])
        return out

    # -- explicit columns ----------------------------------------------------------------------
    def dense_cols(self, p0, p1):
        """Dense ``B[:, 3 p0 : 3 p1]`` (n_x × 3 (p1 − p0))."""
        prob = self.prob
        n_g, n_c = prob.n_g, prob.n_c
        nc = p1 - p0
        sel = (prob.layout.pidx >= p0) & (prob.layout.pidx < p1)
        rows = prob.layout.cidx[sel]
        ncol = 3 * nc
        cols = 3 * (prob.layout.pidx[sel] - p0)
        flat = (rows[:, :, None] * ncol + cols[:, None, None] + np.arange(3)).ravel()
        D = np.bincount(flat, self.Bk[sel].ravel(), minlength=(n_g + 1) * ncol).reshape(n_g + 1, ncol)
        out = np.empty((self.n_x, ncol))
        out[:n_g] = D[:n_g]
        if n_c:
            out[n_g:] = np.transpose(self.Bc[p0:p1], (1, 0, 2)).reshape(n_c, ncol)
        return out

    cols_points = dense_cols

    def sparse(self):
        prob = self.prob
        Bk = self.Bk
        rows = np.broadcast_to(prob.layout.cidx[:, :, None], Bk.shape)
        cols = np.broadcast_to(3 * prob.layout.pidx[:, None, None] + np.arange(3), Bk.shape)
        S = sp.csr_matrix((Bk.ravel(), (rows.ravel(), cols.ravel())), shape=(prob.n_g + 1, 3 * (prob.n_e + 1)))
        return S[:, :3 * prob.n_e]
