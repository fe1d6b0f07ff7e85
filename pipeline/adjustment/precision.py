"""Precision and reliability of a converged bundle: cofactor matrices of every unknown and the
2×2 blocks of ``Qvv`` per image point, without forming a dense inverse of the whole system.

With the points eliminated (``K`` the reduced system incl. any inner-constraint rows,
``B = [W; Cpᵀ] V^{-1/2}``, ``V_p = L_p L_pᵀ``)::

    Qcc    = K⁻¹                                   (global unknowns; n_x × n_x)
    Qcp_p  = −K⁻¹ B_p L_p⁻¹                        (global × point p)
    Qpp_p  = L_p⁻ᵀ (I + B_pᵀ K⁻¹ B_p) L_p⁻¹        (point p, 3×3)

and for an image point k with whitened Jacobian rows ``[Jc_k | Jp_k]``
``H_k = J̃_k Qxx J̃_kᵀ`` (2×2) from the blocks above; ``Qvv P = L⁻¹ (I − H) L``,
``P Qvv P = Lᵀ (I − H) L`` with ``LᵀL = P``.  Points are processed in chunks, so memory stays
bounded (n_x × 3·chunk).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from .collinearity import bmm, project_observations
from .phases import phase_step
from .problem import BundleProblem

__all__ = ["Precision", "DenseCofactors", "SparseCofactors", "dense_precision", "sparse_precision",
           "reliability_rows", "predicted_variance_dense", "predicted_variance_sparse", "front_cofactors"]


@dataclass(frozen=True, slots=True, eq=False)
class Precision:
    """Cofactors and per-observation hat-matrix blocks of a converged bundle (a route's
    :meth:`~.route.Route.precision`).

    ``Qpp`` (n_e, 3, 3) the eliminated points', ``H`` (k, 2, 2) the whitened hat-matrix blocks of
    the active observations, ``Q_cam`` (per camera, over ``[c, xp, yp, ap…]``), ``Q_eo`` (m, 6, 6),
    ``Q_gpt`` (n, 3, 3; the global points' rows, zero elsewhere), ``cofactors`` the global
    unknowns' (:class:`DenseCofactors` / :class:`SparseCofactors`) and — dense route only — ``Qx``
    (n_x × n_x, global part incl. constraint rows)."""

    Qx: np.ndarray | None
    Qpp: np.ndarray
    H: np.ndarray
    Q_cam: list
    Q_eo: np.ndarray
    Q_gpt: np.ndarray
    cofactors: Cofactors


def dense_precision(prob: BundleProblem, lin, red, by_pairs: bool, chunk_bytes: float = 6.4e7) -> Precision:
    """Dense route: ``K⁻¹`` from the factor, the points' terms by pairs (short tracks) or by
    chunks of points (``by_pairs``)."""
    Qx = red.route.inverse(red)
    n_g, n_e = prob.n_g, prob.n_e
    n_x = Qx.shape[0]
    k = len(prob.oi)
    Jc, Jp = lin.Jc, lin.Jp
    Qg = np.zeros((n_g + 1, n_g + 1))
    Qg[:n_g, :n_g] = Qx[:n_g, :n_g]
    cidx = prob.layout.cidx
    # camera–camera part, photo by photo (the photo-constant columns share one Q block)
    H = np.zeros((k, 2, 2))
    q_ph = prob.layout.q_ph
    _photo_terms(prob, range(len(prob.layout.seg_start)), lambda idx: Qg[np.ix_(idx, idx)], Jc, H)
    if len(prob.layout.gp_obs):
        ob = prob.layout.gp_obs
        Qk = Qg[cidx[ob][:, :, None], cidx[ob][:, None, :]]
        Qk[:, :q_ph, :q_ph] = 0.0
        J = Jc[ob]
        H[ob] += np.einsum("kiq,kqr,kjr->kij", J, Qk, J)
    Qpp = np.zeros((n_e, 3, 3))
    if n_e:
        Li = red.Li
        B = red.B
        if by_pairs:
            _points_by_pairs(prob, Qx, B, Li, Jc, Jp, H, Qpp)
        else:
            _points_by_chunks(prob, Qx, B, Li, Jc, Jp, H, Qpp, chunk_bytes)
        # fixed coordinates of partly controlled points are not unknowns
        Qpp *= prob.elim_free[:, :, None] & prob.elim_free[:, None, :]
    Q_cam, Q_eo, Q_gpt = _global_blocks(prob, lambda idx: Qg[idx[..., :, None], idx[..., None, :]])
    return Precision(Qx, Qpp, H, Q_cam, Q_eo, Q_gpt, DenseCofactors(Qx[:n_g, :n_g]))


def _global_blocks(prob, gather):
    """Cofactor blocks of the cameras, the photos' orientations and the global points through
    ``gather(idx)`` (idx (..., c) global columns, n_g = fixed → the block (..., c, c))."""
    n_g = prob.n_g
    P = 3 + prob.pmax
    Q_cam = []
    for j, mdl in enumerate(prob.models):
        idx = prob.g_cam[j, :3 + mdl.n_params]
        Q_cam.append(gather(np.where(idx >= 0, idx, n_g)))
    Q_eo = gather(np.where(prob.g_eo >= 0, prob.g_eo, n_g))
    Q_gpt = np.zeros((prob.n, 3, 3))
    gp = np.flatnonzero((prob.g_pt >= 0).any(axis=1))
    if gp.size:
        Q_gpt[gp] = gather(np.where(prob.g_pt[gp] >= 0, prob.g_pt[gp], n_g))
    del P
    return Q_cam, Q_eo, Q_gpt


def _add_point_terms(prob, ob, Mk, Li, Jc, Jp, H, Qpp):
    """H_k += 2 sym(Jc Qcp Jpᵀ) + Jp Qpp Jpᵀ for observations ``ob`` given ``Mk = (K⁻¹ B_p)[cidx_k]``."""
    Qcp = -bmm(Mk, Li[prob.layout.pidx[ob]])                                         # (kb, q, 3)
    JQ = np.matmul(Jc[ob], Qcp)                                                # (kb, 2, 3)
    X = bmm(JQ, np.transpose(Jp[ob], (0, 2, 1)))
    H[ob] += X + np.transpose(X, (0, 2, 1))
    JpQ = bmm(Jp[ob], Qpp[prob.layout.pidx[ob]])
    H[ob] += bmm(JpQ, np.transpose(Jp[ob], (0, 2, 1)))


def _points_by_chunks(prob, Qx, B, Li, Jc, Jp, H, Qpp, chunk_bytes):
    """Dense route: ``K⁻¹ B`` for chunks of points (few points seen by many photos)."""
    n_g, n_e = prob.n_g, prob.n_e
    n_x = Qx.shape[0]
    cidx = prob.layout.cidx
    order = np.argsort(prob.layout.pidx, kind="stable")
    pts_sorted = prob.layout.pidx[order]
    c = max(1, int(chunk_bytes / (24.0 * max(n_x, 1))))
    for p0 in range(0, n_e, c):
        phase_step("precision", p0, n_e, "points")
        p1 = min(n_e, p0 + c)
        Bc = B.dense_cols(p0, p1)                             # (n_x, 3c)
        M = Qx @ Bc if n_x else np.zeros((0, 3 * (p1 - p0)))  # K⁻¹ B_p
        nc = p1 - p0
        T = np.einsum("rpa,rpb->pab", Bc.reshape(n_x, nc, 3), M.reshape(n_x, nc, 3))
        T[:, [0, 1, 2], [0, 1, 2]] += 1.0
        Lc = Li[p0:p1]
        Qpp[p0:p1] = np.einsum("pba,pbc,pcd->pad", Lc, T, Lc)
        a, b = np.searchsorted(pts_sorted, [p0, p1])
        ob = order[a:b]
        if ob.size == 0:
            continue
        Mpad = np.vstack([M[:n_g], np.zeros((1, 3 * nc))])
        loc = prob.layout.pidx[ob] - p0
        Mk = Mpad[cidx[ob][:, :, None], 3 * loc[:, None, None] + np.arange(3)]   # (kb, q, 3)
        _add_point_terms(prob, ob, Mk, Li, Jc, Jp, H, Qpp)


def _points_by_pairs(prob, Qx, B, Li, Jc, Jp, H, Qpp):
    """Sparse route of the dense system: per point, only the rows of K⁻¹ its observations touch
    (short tracks), for all points of one track length at once."""
    n_g, n_c = prob.n_g, prob.n_c
    Qg = np.zeros((n_g + 1, n_g + 1))
    Qg[:n_g, :n_g] = Qx[:n_g, :n_g]
    cons = None
    if n_c:
        Qgc = np.zeros((n_g + 1, n_c))
        Qgc[:n_g] = Qx[:n_g, n_g:]
        cons = (Qgc, Qx[n_g:, n_g:])
    for obs_mat, _ in prob.normals.track_groups:
        N, t = obs_mat.shape
        C = prob.layout.cidx[obs_mat].reshape(N, t * prob.layout.q)                          # (N, tq)
        _track_terms(prob, Qg[C[:, :, None], C[:, None, :]], C, obs_mat, B, Li, Jc, Jp, H, Qpp, cons)


def _track_terms(prob, Qsub, C, obs_mat, B, Li, Jc, Jp, H, Qpp, cons=None):
    """Points whose observations are the rows of ``obs_mat`` (N, t), with ``Qsub`` (N, tq, tq) the
    cofactors of their observations' global columns ``C`` (N, tq):

    ``M_k = Σ_l K⁻¹[cidx_k, cidx_l] B_l (+ K⁻¹[cidx_k, λ] Bc_p)``,
    ``Qpp_p = L_p⁻ᵀ (I + Σ_k B_kᵀ M_k (+ Bc_pᵀ K⁻¹[λ, ·] B_p)) L_p⁻¹``; then the observations' H."""
    N, t = obs_mat.shape
    q = prob.layout.q
    X = B.Bk[obs_mat].reshape(N, t * q, 3)
    M = np.matmul(Qsub, X)                                                     # (N, tq, 3)
    pts = prob.layout.pidx[obs_mat[:, 0]]
    if cons is not None:
        Qgc, Qcc = cons
        Bcp = B.Bc[pts]                                                        # (N, n_c, 3)
        M += np.matmul(Qgc[C], Bcp)
    T = np.matmul(np.transpose(X, (0, 2, 1)), M)                               # (N, 3, 3)
    if cons is not None:
        lamB = np.matmul(np.transpose(Qgc[C], (0, 2, 1)), X) + np.matmul(Qcc[None], Bcp)   # (N, n_c, 3)
        T += np.matmul(np.transpose(Bcp, (0, 2, 1)), lamB)
    T[:, [0, 1, 2], [0, 1, 2]] += 1.0
    Lc = Li[pts]
    Qpp[pts] = bmm(bmm(np.transpose(Lc, (0, 2, 1)), T), Lc)
    _add_point_terms(prob, obs_mat.ravel(), M.reshape(N * t, q, 3), Li, Jc, Jp, H, Qpp)


def _photo_terms(prob, segs, gather, Jc, H):
    """H_k += Jc_k Q Jc_kᵀ over the photo-constant columns, for the photo segments ``segs``."""
    q_ph = prob.layout.q_ph
    for j in segs:
        s0, s1 = int(prob.layout.seg_start[j]), int(prob.layout.seg_end[j])
        J = Jc[s0:s1, :, :q_ph]
        T = (J.reshape(-1, q_ph) @ gather(prob.layout.seg_cols[j])).reshape(s1 - s0, 2, q_ph)
        H[s0:s1] += (T[:, :, None, :] * J[:, None, :, :]).sum(axis=3)


def sparse_precision(prob, lin, red, st) -> Precision:
    """Sparse route: the selected inversion of the reduced system's factor visits every front
    (:meth:`.sparse.SupernodalCholesky.selected_inverse`); each photo, point and scale-bar
    observation is handled in the front of its first column in the elimination order, which holds
    the cofactors of all the columns it touches (they form a clique of the filled graph).  A free
    network's minimal-constraint cofactors are S-transformed onto the inner constraints (H, and so
    the redundancy numbers, are datum-invariant; the orientations' and points' cofactors are not)."""
    fac = red.factor
    F, d, kidx = fac.F, fac.d, fac.kidx
    sym = F.sym
    n_g, n_e = prob.n_g, prob.n_e
    n = sym.n
    Jc, Jp = lin.Jc, lin.Jp
    Li, B = red.Li, red.B
    k = len(prob.oi)
    H = np.zeros((k, 2, 2))
    Qpp = np.zeros((n_e, 3, 3))
    posg = np.full(n_g + 1, n)                                   # elimination position (n: fixed)
    posg[kidx] = sym.ipos
    scale = np.zeros(n_g + 1)
    scale[kidx] = d
    sn_of_pos = np.repeat(np.arange(sym.n_super), np.diff(sym.start))

    def owners(C):
        m = posg[C].reshape(len(C), -1).min(axis=1) if len(C) else np.zeros(0, int)
        return np.where(m < n, sn_of_pos[np.minimum(m, n - 1)], -1)

    def by_owner(own):
        order = np.argsort(own, kind="stable")
        bounds = np.searchsorted(own[order], np.arange(-1, sym.n_super + 1))
        return order, bounds

    items = {}
    items["seg"] = by_owner(owners(prob.layout.seg_cols))
    tracks = [(obs_mat, prob.layout.cidx[obs_mat].reshape(len(obs_mat), -1)) for obs_mat, _ in prob.normals.track_groups]
    items["trk"] = [by_owner(owners(C)) for _, C in tracks]
    gpo = prob.layout.gp_obs
    items["gp"] = by_owner(owners(prob.layout.cidx[gpo]))
    blk_cols = {"eo": np.where(prob.g_eo >= 0, prob.g_eo, n_g)}
    blk_cols["cam"] = [np.where(prob.g_cam[j, :3 + m.n_params] >= 0, prob.g_cam[j, :3 + m.n_params], n_g)
                       for j, m in enumerate(prob.models)]
    gpt = np.flatnonzero((prob.g_pt >= 0).any(axis=1))
    blk_cols["gpt"] = np.where(prob.g_pt[gpt] >= 0, prob.g_pt[gpt], n_g)
    items["eo"] = by_owner(owners(blk_cols["eo"]))
    items["gpt"] = by_owner(owners(blk_cols["gpt"]))
    w_cam = max((len(c) for c in blk_cols["cam"]), default=0)
    cam_own = owners(np.array([np.resize(c, w_cam) for c in blk_cols["cam"]])) \
        if blk_cols["cam"] else np.zeros(0, int)
    Q_cam = [np.zeros((len(c), len(c))) for c in blk_cols["cam"]]
    Q_diag = np.zeros(n_g)
    Q_eo = np.zeros((prob.m, 6, 6))
    Q_gpt = np.zeros((prob.n, 3, 3))

    def take(kind, s, sub=None):
        order, bounds = items[kind] if sub is None else items[kind][sub]
        return order[bounds[s + 1]:bounds[s + 2]]

    visited = [0]

    def visit(s, front, Z):
        phase_step("precision", visited[0], sym.n_super, "fronts")
        visited[0] += 1
        Zx, loc = front_cofactors(front, Z, d, sym.ipos, posg)
        nf = len(front)

        def gather(idx):
            li = loc(idx)
            return Zx[li[..., :, None], li[..., None, :]]

        ns = int(sym.start[s + 1] - sym.start[s])
        Q_diag[kidx[front[:ns]]] = np.diag(Zx)[:ns]
        _photo_terms(prob, take("seg", s), gather, Jc, H)
        for g, (obs_mat, C) in enumerate(tracks):
            sel = take("trk", s, g)
            if sel.size:
                Cl = loc(C[sel])
                _track_terms(prob, Zx[Cl[:, :, None], Cl[:, None, :]], None, obs_mat[sel], B, Li, Jc, Jp, H, Qpp)
        ob = gpo[take("gp", s)]
        if ob.size:
            Qk = gather(prob.layout.cidx[ob])
            Qk[:, :prob.layout.q_ph, :prob.layout.q_ph] = 0.0
            H[ob] += np.einsum("kiq,kqr,kjr->kij", Jc[ob], Qk, Jc[ob])
        sel = take("eo", s)
        if sel.size:
            Q_eo[sel] = gather(blk_cols["eo"][sel])
        sel = take("gpt", s)
        if sel.size:
            Q_gpt[gpt[sel]] = gather(blk_cols["gpt"][sel])
        for j in np.flatnonzero(cam_own == s):
            Q_cam[j] = gather(blk_cols["cam"][j])

    F.selected_inverse(visit)
    # observations and points whose columns are all fixed: only their own terms
    for kind, sub in [("trk", g) for g in range(len(tracks))]:
        sel = take(kind, -1, sub)
        if sel.size:
            obs_mat, C = tracks[sub]
            Z0 = np.zeros((len(sel), C.shape[1], C.shape[1]))
            _track_terms(prob, Z0, None, obs_mat[sel], B, Li, Jc, Jp, H, Qpp)
    datum = _s_transform(prob, red, Q_eo, Q_gpt, gpt, Qpp, Q_diag) if prob.n_c else None
    if n_e:
        Qpp *= prob.elim_free[:, :, None] & prob.elim_free[:, None, :]
    return Precision(None, Qpp, H, Q_cam, Q_eo, Q_gpt, SparseCofactors(fac, Q_diag, datum, prob.g_eo, Q_eo))


def front_cofactors(front, Z, d, ipos, posg):
    """A front of the selected inversion as cofactors of the global unknowns: ``Zx`` (nf + 1)² —
    the scaled block ``Z`` unscaled by the Jacobi factors ``d``, with a zero row and column for fixed
    parameters — and ``loc(C)``: the row of ``Zx`` of global columns ``C`` (``posg``: elimination
    position of every global column, ``len(ipos)`` for a fixed one)."""
    nf = len(front)
    n = len(ipos)
    Zx = np.zeros((nf + 1, nf + 1))
    sc = d[front]
    Zx[:nf, :nf] = Z * sc[:, None] * sc[None, :]
    fpos = ipos[front]

    def loc(C):
        p = posg[C]
        return np.where(p < n, np.searchsorted(fpos, np.minimum(p, n - 1)), nf)

    return Zx, loc


def _s_transform(prob, red, Q_eo, Q_gpt, gpt, Qpp, Q_diag):
    """Minimal-constraint cofactors → inner constraints: ``Q = S Q₀ Sᵀ``, ``S = I − G T Cᵀ``,
    ``T = (Cᵀ G)⁻¹``; per block ``Q_a − G_a T Y_aᵀ − Y_a Tᵀ G_aᵀ + G_a T (Cᵀ Y) Tᵀ G_aᵀ`` with
    ``Y = Q₀ C`` (n_c solves).  Camera parameters do not move with the datum (G = 0 there)."""
    n_g, n_c = prob.n_g, prob.n_c
    Gg, Gp, T, Yg, Yp = red.datum_Y()
    Cg, Cp = red.Cg, red.Cp
    CY = Cg.T @ Yg + np.einsum("pac,pad->cd", Cp, Yp)

    def correct(Q, G, Y):
        GT = G @ T
        YT = Y @ T.T
        Q += -GT @ np.swapaxes(Y, -1, -2) - YT @ np.swapaxes(G, -1, -2) + GT @ CY @ np.swapaxes(GT, -1, -2)

    Gx = np.vstack([Gg, np.zeros((1, n_c))])
    Yx = np.vstack([Yg, np.zeros((1, n_c))])
    eo = np.where(prob.g_eo >= 0, prob.g_eo, n_g)
    correct(Q_eo, Gx[eo], Yx[eo])
    if gpt.size:
        idx = np.where(prob.g_pt[gpt] >= 0, prob.g_pt[gpt], n_g)
        Qg = Q_gpt[gpt]
        correct(Qg, Gx[idx], Yx[idx])
        Q_gpt[gpt] = Qg
    if prob.n_e:
        correct(Qpp, Gp, Yp)
    Qd = Q_diag[:, None, None].copy()
    correct(Qd, Gg[:, None, :], Yg[:, None, :])
    Q_diag[:] = Qd[:, 0, 0]
    return Gg, T, Yg, CY


class Cofactors(ABC):
    """The cofactors of the global unknowns, one interface for both routes: the ``diagonal()``
    (n_g,), ``columns(cols)`` (n_g, len(cols)) and ``blocks(cols)`` (G, w, w) for index groups
    ``cols`` (G, w) where ``n_g`` marks a fixed unknown (its rows and columns 0)."""

    @abstractmethod
    def diagonal(self) -> np.ndarray:
        """The diagonal of the cofactor matrix of the global unknowns (n_g,)."""

    @abstractmethod
    def columns(self, cols) -> np.ndarray:
        """Its columns ``cols`` (n_g, len(cols))."""

    @abstractmethod
    def blocks(self, cols) -> np.ndarray:
        """Its diagonal blocks for index groups ``cols`` (G, w) → (G, w, w)."""


@dataclass(frozen=True, eq=False)
class DenseCofactors(Cofactors):
    """Cofactors of the global unknowns from the dense inverse ``Qg`` (n_g, n_g)."""

    Qg: np.ndarray

    def diagonal(self) -> np.ndarray:
        return np.diag(self.Qg).copy()

    def columns(self, cols) -> np.ndarray:
        return self.Qg[:, np.asarray(cols, int)].copy()

    def blocks(self, cols) -> np.ndarray:
        """Gathered from ``Qg``."""
        n_g = len(self.Qg)
        cols = np.asarray(cols, int)
        Qp = np.zeros((n_g + 1, n_g + 1))
        Qp[:n_g, :n_g] = self.Qg
        return Qp[cols[:, :, None], cols[:, None, :]]


@dataclass(frozen=True, eq=False)
class SparseCofactors(Cofactors):
    """Cofactors of the global unknowns from the sparse factor: the diagonal (from the selected
    inversion) and any columns on demand (solves; a free network's S-transformation applied).
    ``g_eo`` (m, 6) the orientations' columns (−1 fixed) and ``Q_eo`` (m, 6, 6) their cofactor
    blocks (the selected inversion) serve :meth:`blocks` within one photo's orientation."""

    factor: object
    diag: np.ndarray
    datum: tuple | None = None
    g_eo: np.ndarray | None = None
    Q_eo: np.ndarray | None = None

    def diagonal(self) -> np.ndarray:
        return self.diag.copy()

    def blocks(self, cols) -> np.ndarray:
        """A group within one photo's orientation from its cofactor block, any other by solves."""
        cols = np.asarray(cols, int)
        n_g = len(self.diag)
        G, w = cols.shape
        m = 0 if self.g_eo is None else len(self.g_eo)
        out = np.zeros((G, w, w))
        Q_eo = np.zeros((m + 1, 7, 7))
        photo = np.full(n_g + 1, m)
        comp = np.full(n_g + 1, 6)
        if m:
            Q_eo[:m, :6, :6] = self.Q_eo
            on = self.g_eo >= 0
            photo[self.g_eo[on]], comp[self.g_eo[on]] = np.nonzero(on)
        ph = photo[cols]
        fixed = cols >= n_g
        first = np.where(fixed, m + 1, ph).min(axis=1)
        one = (np.where(fixed, first[:, None], ph) == first[:, None]).all(axis=1) & (first < m)
        c = comp[cols]
        out[one] = Q_eo[first[one][:, None, None], c[one][:, :, None], c[one][:, None, :]]
        for j in np.flatnonzero(~one):
            ok = ~fixed[j]
            if ok.any():
                cj = cols[j, ok]
                out[j][np.ix_(ok, ok)] = self.columns(cj)[cj]
        return out

    def columns(self, cols) -> np.ndarray:
        cols = np.asarray(cols, int)
        n_g = len(self.diag)
        E = np.zeros((n_g, len(cols)))
        E[cols, np.arange(len(cols))] = 1.0
        Q = self.factor.solve(E)
        if self.datum is not None:
            G, T, Y, CY = self.datum
            GT, YT = G @ T, Y @ T.T
            Q += -GT @ Y[cols].T - YT @ G[cols].T + GT @ CY @ GT[cols].T
        return Q


def reliability_rows(prob: BundleProblem, H: np.ndarray):
    """Per active observation: ``r`` (k, 2) = diag(Qvv P), ``PQvvP`` (k, 2, 2) blocks."""
    L = prob.L
    R = np.eye(2)[None] - H
    ra = prob.row_active[prob.oi]
    both = ra.all(axis=1)
    r = np.zeros((len(L), 2))
    PQ = np.einsum("kji,kjl,klm->kim", L, R, L)
    if both.any():
        Linv = np.linalg.inv(L[both])
        r[both] = np.einsum("kij,kjl,kli->ki", Linv, R[both], L[both])
    for c in (0, 1):
        only = ra[:, c] & ~ra[:, 1 - c]
        r[only, c] = R[only, c, c]
    r *= ra
    PQ *= ra[:, :, None] & ra[:, None, :]
    return r, PQ


def predicted_variance_dense(prob: BundleProblem, st, red, Qx: np.ndarray, Qpp: np.ndarray, obs_idx: np.ndarray):
    """``diag(a Qxx aᵀ)`` (len, 2) of block observations ``obs_idx`` that are *not* in the
    adjustment (inactive): the cofactor of their prediction from all the others (nan where the
    photo or the point is not adjusted).  Dense route (``Qx`` = K⁻¹)."""
    obs = prob.block.observations
    idx = np.asarray(obs_idx, int)
    out = np.full((len(idx), 2), np.nan)
    ph, pt = obs.photo[idx], obs.point[idx]
    ok = prob.photo_used[ph] & prob.point_used[pt]
    if not ok.any():
        return out
    sel = np.flatnonzero(ok)
    ph, pt = ph[sel], pt[sel]
    pr, eo_cols = _predicted_projection(prob, st, ph, pt, marks=prob.marks_of(idx[sel]))
    cam = prob.block.photos.camera[ph]
    n_g = prob.n_g
    C = np.concatenate([prob.g_cam[cam], eo_cols, prob.g_pt[pt]], axis=1)
    J = np.concatenate([pr.J_cam, pr.J_eo, pr.J_point], axis=2)
    J = J * (C >= 0)[:, None, :]
    C = np.where(C >= 0, C, n_g)
    Qg = np.zeros((n_g + 1, n_g + 1))
    Qg[:n_g, :n_g] = Qx[:n_g, :n_g]
    H = np.einsum("kiq,kqr,kjr->kij", J, Qg[C[:, :, None], C[:, None, :]], J)
    e = prob.elim_of[pt]
    Jp = pr.J_point * prob.pt_free[pt][:, None, :]
    B = red.B
    Li = red.Li
    for p in np.unique(e[e >= 0]):
        rows = np.flatnonzero(e == p)
        M = Qx @ B.dense_cols(p, p + 1)                         # (n_x, 3) = K⁻¹ B_p
        Mpad = np.vstack([M[:n_g], np.zeros((1, 3))])
        Qcp = -Mpad[C[rows]] @ Li[p]                             # (r, q, 3)
        X = np.einsum("kiq,kqa,kja->kij", J[rows], Qcp, Jp[rows])
        H[rows] += X + np.transpose(X, (0, 2, 1))
        H[rows] += np.einsum("kia,ab,kjb->kij", Jp[rows], Qpp[p], Jp[rows])
    out[sel] = np.einsum("kii->ki", H)
    return out


def _predicted_projection(prob, st, ph, pt, marks=None):
    """Projection with Jacobians of observations ``(ph, pt)`` and their orientation columns: the
    photos' own 6, or with rigs (``docs/rigs.md``) the frame's and the sensor's 12.  ``marks``: the
    observations' measured marks when the residual is DBAT's (:meth:`BundleProblem.marks_of`)."""
    if getattr(prob, "rig", None) is not None:
        return prob.project_rows(st, ph, pt, marks=marks)
    pr = project_observations(ph, pt, st.XYZ, st.X0, st.opk, prob.block.photos.camera, st.cam_params,
                              prob.block.cameras.ap_model, prob.meta, marks=marks)
    return pr, prob.g_eo[ph]


def _prediction_rows(prob, st, obs_idx):
    """Jacobian rows of block observations ``obs_idx`` over the global unknowns (``J`` (r, 2, q'),
    columns ``C``, n_g = fixed) and the eliminated point (``Jp`` (r, 2, 3), ``e`` its index or −1);
    ``sel``: the observations whose photo and point are adjusted."""
    obs = prob.block.observations
    idx = np.asarray(obs_idx, int)
    ph, pt = obs.photo[idx], obs.point[idx]
    sel = np.flatnonzero(prob.photo_used[ph] & prob.point_used[pt])
    ph, pt = ph[sel], pt[sel]
    pr, eo_cols = _predicted_projection(prob, st, ph, pt, marks=prob.marks_of(idx[sel]))
    cam = prob.block.photos.camera[ph]
    C = np.concatenate([prob.g_cam[cam], eo_cols, prob.g_pt[pt]], axis=1)
    J = np.concatenate([pr.J_cam, pr.J_eo, pr.J_point], axis=2) * (C >= 0)[:, None, :]
    C = np.where(C >= 0, C, prob.n_g)
    Jp = pr.J_point * prob.pt_free[pt][:, None, :]
    return sel, J, C, Jp, prob.elim_of[pt]


def predicted_variance_sparse(prob, st, red, obs_idx, chunk: int = 256):
    """:func:`predicted_variance_dense` with the sparse factor: ``a Q aᵀ`` through solves of the whole
    system, ``x = K⁻¹ (a_g − B L⁻¹ a_p)``, ``y = L⁻ᵀ (L⁻¹ a_p − Bᵀ x)`` (a free network's
    minimal-constraint cofactors give the same value: a prediction does not depend on the datum)."""
    out = np.full((len(obs_idx), 2), np.nan)
    sel, J, C, Jp, e = _prediction_rows(prob, st, obs_idx)
    n_g = prob.n_g
    Li, B = red.Li, red.B
    csr = prob.layout.obs_to_point.tocsr()
    var = np.zeros((len(sel), 2))
    for c0 in range(0, len(sel), chunk):
        rows = range(c0, min(c0 + chunk, len(sel)))
        R = np.zeros((n_g + 1, 2 * len(rows)))
        zp = {}
        for j, r in enumerate(rows):
            np.add.at(R[:, 2 * j:2 * j + 2], C[r], J[r].T)
            if e[r] >= 0:
                z = Li[e[r]] @ Jp[r].T                                  # L⁻¹ a_pᵀ (3, 2)
                zp[r] = z
                ol = csr.indices[csr.indptr[e[r]]:csr.indptr[e[r] + 1]]
                np.add.at(R[:, 2 * j:2 * j + 2], prob.layout.cidx[ol], -np.matmul(B.Bk[ol], z))
        X = red.factor.solve(R[:n_g])
        Xp = np.vstack([X, np.zeros((1, X.shape[1]))])
        for j, r in enumerate(rows):
            x = Xp[:, 2 * j:2 * j + 2]
            v = np.einsum("iq,qi->i", J[r], x[C[r]])
            if r in zp:
                ol = csr.indices[csr.indptr[e[r]]:csr.indptr[e[r] + 1]]
                Btx = np.einsum("kaq,kqi->ai", B.BkT[ol], x[prob.layout.cidx[ol]])      # B_pᵀ x (3, 2)
                y = Li[e[r]].T @ (zp[r] - Btx)
                v = v + np.einsum("ia,ai->i", Jp[r], y)
            var[r] = v
    out[sel] = var
    return out
