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

import numpy as np

from .collinearity import bmm
from .factor import solve_reduced, solve_factored
from .problem import BundleProblem


def reduced_inverse(prob: BundleProblem, red, st) -> np.ndarray:
    """``K⁻¹`` (n_x × n_x) from the scaled factorisation."""
    n_x = prob.n_g + prob.n_c
    if n_x == 0:
        return np.zeros((0, 0))
    if "factor" not in red:
        solve_reduced(prob, red, st)
    s = red["scale"]
    Ki = solve_factored(red["factor"], np.eye(n_x))
    Ki = 0.5 * (Ki + Ki.T)
    return Ki * s[:, None] * s[None, :]


def precision(prob: BundleProblem, lin, red, st, chunk_bytes: float = 6.4e7):
    """Cofactors and per-observation hat-matrix blocks.

    Returns dict with ``Qx`` (n_x × n_x, global part incl. constraint rows), ``Qpp`` (n_e, 3, 3)
    and ``H`` (k, 2, 2) for the active observations (whitened).
    """
    Qx = reduced_inverse(prob, red, st)
    n_g, n_e = prob.n_g, prob.n_e
    n_x = Qx.shape[0]
    k = len(prob.oi)
    Jc, Jp = lin["Jc"], lin["Jp"]
    Qg = np.zeros((n_g + 1, n_g + 1))
    Qg[:n_g, :n_g] = Qx[:n_g, :n_g]
    cidx = prob.cidx
    # camera–camera part, photo by photo (the photo-constant columns share one Q block)
    H = np.zeros((k, 2, 2))
    q_ph = prob.q_ph
    for s0, s1 in zip(prob.seg_start, prob.seg_end):
        idx = cidx[s0, :q_ph]
        J = Jc[s0:s1, :, :q_ph]
        T = (J.reshape(-1, q_ph) @ Qg[np.ix_(idx, idx)]).reshape(s1 - s0, 2, q_ph)
        H[s0:s1] = (T[:, :, None, :] * J[:, None, :, :]).sum(axis=3)
    if len(prob.gp_obs):
        ob = prob.gp_obs
        Qk = Qg[cidx[ob][:, :, None], cidx[ob][:, None, :]]
        Qk[:, :q_ph, :q_ph] = 0.0
        J = Jc[ob]
        H[ob] += np.einsum("kiq,kqr,kjr->kij", J, Qk, J)
    Qpp = np.zeros((n_e, 3, 3))
    if n_e:
        Li = red["Li"]
        B = red["B"]
        if prob.precision_route() == "pairs":
            _points_by_pairs(prob, Qx, B, Li, Jc, Jp, H, Qpp)
        else:
            _points_by_chunks(prob, Qx, B, Li, Jc, Jp, H, Qpp, chunk_bytes)
        # fixed coordinates of partly controlled points are not unknowns
        Qpp *= prob.elim_free[:, :, None] & prob.elim_free[:, None, :]
    return dict(Qx=Qx, Qpp=Qpp, H=H)


def _add_point_terms(prob, ob, Mk, Li, Jc, Jp, H, Qpp):
    """H_k += 2 sym(Jc Qcp Jpᵀ) + Jp Qpp Jpᵀ for observations ``ob`` given ``Mk = (K⁻¹ B_p)[cidx_k]``."""
    Qcp = -bmm(Mk, Li[prob.pidx[ob]])                                         # (kb, q, 3)
    JQ = np.matmul(Jc[ob], Qcp)                                                # (kb, 2, 3)
    X = bmm(JQ, np.transpose(Jp[ob], (0, 2, 1)))
    H[ob] += X + np.transpose(X, (0, 2, 1))
    JpQ = bmm(Jp[ob], Qpp[prob.pidx[ob]])
    H[ob] += bmm(JpQ, np.transpose(Jp[ob], (0, 2, 1)))


def _points_by_chunks(prob, Qx, B, Li, Jc, Jp, H, Qpp, chunk_bytes):
    """Dense route: ``K⁻¹ B`` for chunks of points (few points seen by many photos)."""
    n_g, n_e = prob.n_g, prob.n_e
    n_x = Qx.shape[0]
    cidx = prob.cidx
    order = np.argsort(prob.pidx, kind="stable")
    pts_sorted = prob.pidx[order]
    c = max(1, int(chunk_bytes / (24.0 * max(n_x, 1))))
    for p0 in range(0, n_e, c):
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
        loc = prob.pidx[ob] - p0
        Mk = Mpad[cidx[ob][:, :, None], 3 * loc[:, None, None] + np.arange(3)]   # (kb, q, 3)
        _add_point_terms(prob, ob, Mk, Li, Jc, Jp, H, Qpp)


def _points_by_pairs(prob, Qx, B, Li, Jc, Jp, H, Qpp):
    """Sparse route: per point, only the rows of K⁻¹ its observations touch (short tracks).

    ``M_k = Σ_l K⁻¹[cidx_k, cidx_l] B_l + K⁻¹[cidx_k, λ] Bc_p`` and
    ``T_p = Σ_k B_kᵀ M_k + Bc_pᵀ (K⁻¹[λ, ·] B_p)``.
    """
    n_g, n_c = prob.n_g, prob.n_c
    q = prob.q
    Qg = np.zeros((n_g + 1, n_g + 1))
    Qg[:n_g, :n_g] = Qx[:n_g, :n_g]
    if n_c:
        Qgc = np.zeros((n_g + 1, n_c))
        Qgc[:n_g] = Qx[:n_g, n_g:]
        Qcc = Qx[n_g:, n_g:]
    for obs_mat, _ in prob.track_groups():
        N, t = obs_mat.shape
        C = prob.cidx[obs_mat].reshape(N, t * q)                               # (N, tq)
        X = B.Bk[obs_mat].reshape(N, t * q, 3)
        Qsub = Qg[C[:, :, None], C[:, None, :]]                                # (N, tq, tq)
        M = np.matmul(Qsub, X)                                                 # (N, tq, 3)
        pts = prob.pidx[obs_mat[:, 0]]
        if n_c:
            Bcp = B.Bc[pts]                                                    # (N, n_c, 3)
            M += np.matmul(Qgc[C], Bcp)
        T = np.matmul(np.transpose(X, (0, 2, 1)), M)                           # (N, 3, 3)
        if n_c:
            lamB = np.matmul(np.transpose(Qgc[C], (0, 2, 1)), X) + np.matmul(Qcc[None], Bcp)   # (N, n_c, 3)
            T += np.matmul(np.transpose(Bcp, (0, 2, 1)), lamB)
        T[:, [0, 1, 2], [0, 1, 2]] += 1.0
        Lc = Li[pts]
        Qpp[pts] = bmm(bmm(np.transpose(Lc, (0, 2, 1)), T), Lc)
        _add_point_terms(prob, obs_mat.ravel(), M.reshape(N * t, q, 3), Li, Jc, Jp, H, Qpp)


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


def predicted_variance(prob: BundleProblem, st, red, Qx: np.ndarray, Qpp: np.ndarray, obs_idx: np.ndarray):
    """``diag(a Qxx aᵀ)`` (len, 2) of block observations ``obs_idx`` that are *not* in the
    adjustment (inactive): the cofactor of their prediction from all the others (nan where the
    photo or the point is not adjusted)."""
    from .collinearity import project_observations

    obs = prob.block.observations
    idx = np.asarray(obs_idx, int)
    out = np.full((len(idx), 2), np.nan)
    ph, pt = obs.photo[idx], obs.point[idx]
    ok = prob.photo_used[ph] & prob.point_used[pt]
    if not ok.any():
        return out
    sel = np.flatnonzero(ok)
    ph, pt = ph[sel], pt[sel]
    pr = project_observations(ph, pt, st.XYZ, st.X0, st.opk, prob.block.photos.camera, st.cam_params,
                              prob.block.cameras.ap_model, prob.meta)
    cam = prob.block.photos.camera[ph]
    n_g = prob.n_g
    C = np.concatenate([prob.g_cam[cam], prob.g_eo[ph], prob.g_pt[pt]], axis=1)
    J = np.concatenate([pr.J_cam, pr.J_eo, pr.J_point], axis=2)
    J = J * (C >= 0)[:, None, :]
    C = np.where(C >= 0, C, n_g)
    Qg = np.zeros((n_g + 1, n_g + 1))
    Qg[:n_g, :n_g] = Qx[:n_g, :n_g]
    H = np.einsum("kiq,kqr,kjr->kij", J, Qg[C[:, :, None], C[:, None, :]], J)
    e = prob.elim_of[pt]
    Jp = pr.J_point * prob.pt_free[pt][:, None, :]
    B = red["B"]
    Li = red["Li"]
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
