"""Fused per-observation loops of the bundle, compiled with numba.

Each kernel does in one pass over the observations what would otherwise be a dozen numpy calls
on (k, 2, q)-sized temporaries (gathers, broadcast products, reductions): the projection, the
rotation/point part of the Jacobians, the 3×3 point blocks of the normal equations, the Schur
complement's blocks ``B_k`` and products with ``B``, and the photo-pair products of ``B Bᵀ``.
The arithmetic is the numpy formulas' own, in the same order, so results agree with them to
rounding (``tests/adjustment/test_kernels.py`` checks every kernel against its numpy formula).

Arrays in, arrays out, inputs never modified.  Every kernel releases the GIL (``nogil``), so
:func:`.normal.parallel_for` runs independent ranges on ``BundleSettings.threads`` threads.
Compiled code is cached beside this file (``__pycache__``) or, where that is not writable, in
numba's user cache; without any writable cache the kernels are compiled in every process.
"""

from __future__ import annotations

import numpy as np

from ..jit import JIT

__all__ = ["project", "eo_point_jacobians", "whitened", "point_normals", "chol3_inv", "schur_blocks", "b_matvec",
           "b_rmatvec", "pair_products", "add_blocks", "linear_change", "front", "extend_add", "gather_block"]


_jit = JIT(__file__)
"""The kernels of this file (``baarda.pipeline.jit``: numba on first call, cached on disk)."""


@_jit
def _project(XYZ, X0, R, obs_point, obs_photo, obs_cam, cam_params, d, xbar, xy):
    for i in range(obs_point.shape[0]):
        pt, ph, cm = obs_point[i], obs_photo[i], obs_cam[i]
        D0 = XYZ[pt, 0] - X0[ph, 0]
        D1 = XYZ[pt, 1] - X0[ph, 1]
        D2 = XYZ[pt, 2] - X0[ph, 2]
        for r in range(3):
            d[i, r] = R[ph, r, 0] * D0 + R[ph, r, 1] * D1 + R[ph, r, 2] * D2
        f = -cam_params[cm, 0] / d[i, 2]
        xbar[i, 0] = f * d[i, 0]
        xbar[i, 1] = f * d[i, 1]
        xy[i, 0] = cam_params[cm, 1] + xbar[i, 0]
        xy[i, 1] = cam_params[cm, 2] + xbar[i, 1]


def project(XYZ, X0, R, obs_point, obs_photo, obs_cam, cam_params):
    """Collinearity without additional parameters: ``d = R (X − X0)`` (k, 3) in the camera frame,
    ``x̄ = −c (U, V)/W`` (k, 2) and ``xy = (xp, yp) + x̄`` (k, 2)."""
    k = len(obs_point)
    d, xbar, xy = np.empty((k, 3)), np.empty((k, 2)), np.empty((k, 2))
    _project(_f(XYZ), _f(X0), _f(R), _i(obs_point), _i(obs_photo), _i(obs_cam), _f(cam_params), d, xbar, xy)
    return d, xbar, xy


@_jit
def _eo_point_jacobians(d, xbar, c, Dxy, has_dxy, R, sv, obs_photo, J_point, J_eo, J_c):
    JG = np.empty((2, 3))
    for i in range(d.shape[0]):
        ph = obs_photo[i]
        W = d[i, 2]
        f = -c[i] / W
        u = d[i, 0] / W
        v = d[i, 1] / W
        if has_dxy:
            m00, m01 = Dxy[i, 0, 0] + 1.0, Dxy[i, 0, 1]
            m10, m11 = Dxy[i, 1, 0], Dxy[i, 1, 1] + 1.0
            JG[0, 0] = m00 * f
            JG[0, 1] = m01 * f
            JG[1, 0] = m10 * f
            JG[1, 1] = m11 * f
            JG[0, 2] = -(JG[0, 0] * u + JG[0, 1] * v)
            JG[1, 2] = -(JG[1, 0] * u + JG[1, 1] * v)
            xc, yc = xbar[i, 0] / c[i], xbar[i, 1] / c[i]
            J_c[i, 0] = m00 * xc + m01 * yc
            J_c[i, 1] = m10 * xc + m11 * yc
        else:
            JG[0, 0] = f
            JG[0, 1] = 0.0
            JG[0, 2] = -f * u
            JG[1, 0] = 0.0
            JG[1, 1] = f
            JG[1, 2] = -f * v
            J_c[i, 0] = xbar[i, 0] / c[i]
            J_c[i, 1] = xbar[i, 1] / c[i]
        d0, d1, d2 = d[i, 0], d[i, 1], d[i, 2]
        for r in range(2):
            g0, g1, g2 = JG[r, 0], JG[r, 1], JG[r, 2]
            for j in range(3):                        # ∂/∂X = JG R
                J_point[i, r, j] = g0 * R[ph, 0, j] + g1 * R[ph, 1, j] + g2 * R[ph, 2, j]
                J_eo[i, r, j] = -J_point[i, r, j]
            h0 = d1 * g2 - d2 * g1                    # h = d × JG_r; ∂/∂angle_a = s_a · h
            h1 = d2 * g0 - d0 * g2
            h2 = d0 * g1 - d1 * g0
            for a in range(3):
                J_eo[i, r, 3 + a] = h0 * sv[ph, a, 0] + h1 * sv[ph, a, 1] + h2 * sv[ph, a, 2]


def eo_point_jacobians(d, xbar, c, Dxy, R, sv, obs_photo):
    """The rotation and point part of the collinearity Jacobians, after the AP model's own
    derivative ``Dxy = ∂Δ/∂(x̄, ȳ)`` (k, 2, 2; ``None`` without a model):
    ``JG = (I + Dxy) ∂(x̄, ȳ)/∂d``, ``J_point = JG R`` (k, 2, 3), ``J_eo = [−J_point, (d × JG) · s_a]``
    (k, 2, 6) with the axial vectors ``sv`` (m, 3, 3) of ``∂R/∂angle Rᵀ``, and ``(I + Dxy) x̄ / c``
    (k, 2), the principal distance's column without the model's own ``∂Δ/∂c``."""
    k = len(d)
    J_point, J_eo, J_c = np.empty((k, 2, 3)), np.empty((k, 2, 6)), np.empty((k, 2))
    has = Dxy is not None
    _eo_point_jacobians(_f(d), _f(xbar), _f(c), _f(Dxy) if has else np.zeros((0, 2, 2)), has, _f(R), _f(sv),
                        _i(obs_photo), J_point, J_eo, J_c)
    return J_point, J_eo, J_c


@_jit
def _whitened(L, J_cam, J_eo, se, J_point, spt, Jc, Jp):
    a, ne, npt = J_cam.shape[2], se.shape[0], spt.shape[0]
    for i in range(L.shape[0]):
        l00, l01, l10, l11 = L[i, 0, 0], L[i, 0, 1], L[i, 1, 0], L[i, 1, 1]
        for j in range(a):
            x0, x1 = J_cam[i, 0, j], J_cam[i, 1, j]
            Jc[i, 0, j] = l00 * x0 + l01 * x1
            Jc[i, 1, j] = l10 * x0 + l11 * x1
        for t in range(ne):
            x0, x1 = J_eo[i, 0, se[t]], J_eo[i, 1, se[t]]
            Jc[i, 0, a + t] = l00 * x0 + l01 * x1
            Jc[i, 1, a + t] = l10 * x0 + l11 * x1
        for j in range(3):
            x0, x1 = J_point[i, 0, j], J_point[i, 1, j]
            Jp[i, 0, j] = l00 * x0 + l01 * x1
            Jp[i, 1, j] = l10 * x0 + l11 * x1
        for t in range(npt):
            Jc[i, 0, a + ne + t] = Jp[i, 0, spt[t]]
            Jc[i, 1, a + ne + t] = Jp[i, 1, spt[t]]


def whitened(L, J_cam, J_eo, se, J_point, spt):
    """``(L [J_cam, J_eo[:, :, se], J_point[:, :, spt]], L J_point)``: the whitened Jacobian of the
    global columns (k, 2, q) and of the point (k, 2, 3), ``L`` (k, 2, 2) per observation."""
    k = len(L)
    Jc, Jp = np.empty((k, 2, J_cam.shape[2] + len(se) + len(spt))), np.empty((k, 2, 3))
    _whitened(_f(L), _f(J_cam), _f(J_eo), _i(se), _f(J_point), _i(spt), Jc, Jp)
    return Jc, Jp


@_jit
def _point_normals(Jp, e, pidx, V, bp):
    for i in range(Jp.shape[0]):
        p = pidx[i]
        for a in range(3):
            for b in range(3):
                V[p, a, b] += Jp[i, 0, a] * Jp[i, 0, b] + Jp[i, 1, a] * Jp[i, 1, b]
            bp[p, a] += Jp[i, 0, a] * e[i, 0] + Jp[i, 1, a] * e[i, 1]


def point_normals(Jp, e, pidx, n_e):
    """``V_p = Σ Jp_kᵀ Jp_k`` (n_e, 3, 3) and ``b_p = Σ Jp_kᵀ e_k`` (n_e, 3) over the observations
    of each eliminated point (``pidx == n_e``: an observation of no eliminated point)."""
    V, bp = np.zeros((n_e + 1, 3, 3)), np.zeros((n_e + 1, 3))
    _point_normals(_f(Jp), _f(e), _i(pidx), V, bp)
    return V[:-1], bp[:-1]


@_jit
def _chol3_inv(V, Li):
    ok = True
    for p in range(V.shape[0]):
        l00 = np.sqrt(V[p, 0, 0])
        l10 = V[p, 1, 0] / l00
        l20 = V[p, 2, 0] / l00
        l11 = np.sqrt(V[p, 1, 1] - l10 * l10)
        l21 = (V[p, 2, 1] - l20 * l10) / l11
        l22 = np.sqrt(V[p, 2, 2] - l20 * l20 - l21 * l21)
        i00, i11, i22 = 1.0 / l00, 1.0 / l11, 1.0 / l22
        Li[p, 0, 0], Li[p, 1, 1], Li[p, 2, 2] = i00, i11, i22
        Li[p, 1, 0] = -l10 * i00 * i11
        Li[p, 2, 1] = -l21 * i11 * i22
        Li[p, 2, 0] = (l10 * l21 - l11 * l20) * i00 * i11 * i22
        for a in range(3):
            for b in range(3):
                if not np.isfinite(Li[p, a, b]):
                    ok = False
    return ok


def chol3_inv(V):
    """``(L⁻¹, ok)`` with ``V = L Lᵀ`` for every 3×3 block (closed form; ``ok`` False when a
    block is not positive definite, its ``L⁻¹`` then holds NaN or inf)."""
    Li = np.zeros((len(V), 3, 3))
    ok = _chol3_inv(_f(V), Li)
    return Li, bool(ok)


@_jit
def _schur_blocks(Jc, Jp, Li, pidx, BkT):
    n_e = Li.shape[0]
    q = Jc.shape[2]
    Jh = np.empty((2, 3))
    for i in range(Jc.shape[0]):
        p = pidx[i]
        if p < n_e:
            for r in range(2):
                for a in range(3):
                    Jh[r, a] = Jp[i, r, 0] * Li[p, a, 0] + Jp[i, r, 1] * Li[p, a, 1] + Jp[i, r, 2] * Li[p, a, 2]
        else:
            for r in range(2):
                for a in range(3):
                    Jh[r, a] = Jp[i, r, a]
        for a in range(3):
            h0, h1 = Jh[0, a], Jh[1, a]
            for j in range(q):
                BkT[i, a, j] = h0 * Jc[i, 0, j] + h1 * Jc[i, 1, j]


def schur_blocks(Jc, Jp, Li, pidx):
    """``B_kᵀ = (Jp_k L⁻ᵀ)ᵀ Jc_k`` (k, 3, q) for every observation, ``L⁻¹`` of its point
    (``pidx == n_e``: no eliminated point, ``L⁻¹ = I``)."""
    BkT = np.empty((len(Jc), 3, Jc.shape[2]))
    _schur_blocks(_f(Jc), _f(Jp), _f(Li), _i(pidx), BkT)
    return BkT


@_jit
def _b_matvec(BkT, z, pidx, seg_start, seg_end, seg_cols, out):
    n_e = z.shape[0]
    q = seg_cols.shape[1]
    ys = np.empty(q)
    for s in range(seg_start.shape[0]):
        for j in range(q):
            ys[j] = 0.0
        for i in range(seg_start[s], seg_end[s]):
            p = pidx[i]
            if p < n_e:
                for j in range(q):
                    ys[j] += z[p, 0] * BkT[i, 0, j] + z[p, 1] * BkT[i, 1, j] + z[p, 2] * BkT[i, 2, j]
        for j in range(q):
            out[seg_cols[s, j]] += ys[j]


def b_matvec(BkT, z, pidx, seg_start, seg_end, seg_cols, n_g):
    """``Σ_k B_k z_p`` over the photo columns (n_g,) for z (n_e, 3): per photo segment, then
    scattered to its columns ``seg_cols`` (column ``n_g``: fixed, dropped)."""
    out = np.zeros(n_g + 1)
    _b_matvec(_f(BkT), _f(z), _i(pidx), _i(seg_start), _i(seg_end), _i(seg_cols), out)
    return out[:-1]


@_jit
def _b_rmatvec(BkT, x1, pidx, seg_start, seg_end, seg_cols, out):
    q = seg_cols.shape[1]
    xg = np.empty(q)
    for s in range(seg_start.shape[0]):
        for j in range(q):
            xg[j] = x1[seg_cols[s, j]]
        for i in range(seg_start[s], seg_end[s]):
            p = pidx[i]
            for a in range(3):
                acc = 0.0
                for j in range(q):
                    acc += BkT[i, a, j] * xg[j]
                out[p, a] += acc


def b_rmatvec(BkT, x, pidx, seg_start, seg_end, seg_cols, n_e):
    """``Σ_k B_kᵀ x`` per eliminated point (n_e, 3) over the photo columns, x (n_g,)."""
    out = np.zeros((n_e + 1, 3))
    _b_rmatvec(_f(BkT), np.append(np.asarray(x, float), 0.0), _i(pidx), _i(seg_start), _i(seg_end), _i(seg_cols),
               out)
    return out[:-1]


@_jit
def _pair_products(X, oa, ob, gs, ge, g0, g1, S):
    q = X.shape[2]
    acc = np.empty((q, q))
    for g in range(g0, g1):
        for i in range(q):
            for j in range(q):
                acc[i, j] = 0.0
        for t in range(gs[g], ge[g]):
            a, b = oa[t], ob[t]
            for i in range(q):
                x0, x1, x2 = X[a, 0, i], X[a, 1, i], X[a, 2, i]
                for j in range(q):
                    acc[i, j] += x0 * X[b, 0, j] + x1 * X[b, 1, j] + x2 * X[b, 2, j]
        for i in range(q):
            for j in range(q):
                S[g, i, j] = acc[i, j]


def pair_products(X, oa, ob, gs, ge, g0, g1, S):
    """``S[g] = Σ_{t in gs[g]:ge[g]} X[oa_t]ᵀ X[ob_t]`` (q × q) for the groups g0 … g1 − 1, in place
    (the photo-pair blocks of ``B Bᵀ``; X (k, 3, q) C-contiguous; ranges may run on threads)."""
    _pair_products(X, oa, ob, gs, ge, g0, g1, S)


@_jit
def _add_blocks(out, flat, vals, ng1, mirror):
    n = ng1 - 1
    for t in range(flat.shape[0]):
        r = flat[t] // ng1
        c = flat[t] - r * ng1
        if r < n and c < n:
            out[r, c] += vals[t]
            if mirror:
                out[c, r] += vals[t]


def add_blocks(out, flat, vals, ng1, mirror):
    """``out[r, c] += vals`` (and ``out[c, r]`` with ``mirror``) at the flat positions
    ``flat = r ng1 + c`` of an ng1 × ng1 layout, in place; row or column ``ng1 − 1`` (fixed
    parameters) dropped.  ``out`` (≥ ng1 − 1 square, C-contiguous float64)."""
    _add_blocks(out, _i(flat), _f(vals).ravel(), ng1, mirror)


@_jit
def _linear_change(Jc, cidx, x1, Jp, pidx, p1, pred):
    q = Jc.shape[2]
    for i in range(Jc.shape[0]):
        for r in range(2):
            acc = 0.0
            for j in range(q):
                acc += Jc[i, r, j] * x1[cidx[i, j]]
            if p1.shape[0]:
                p = pidx[i]
                acc += Jp[i, r, 0] * p1[p, 0] + Jp[i, r, 1] * p1[p, 1] + Jp[i, r, 2] * p1[p, 2]
            pred[i, r] = acc


def linear_change(Jc, cidx, dx_g, Jp, pidx, dp):
    """``Jc_k Δx + Jp_k Δp`` (k, 2): the change of every (whitened) observation in the linear
    model; ``cidx`` (k, q) columns of ``Δx`` (n_g: fixed), ``pidx`` rows of ``Δp`` (n_e: none);
    ``dp`` None when no point is eliminated."""
    x1 = np.append(np.asarray(dx_g, float), 0.0)
    p1 = np.zeros((0, 3)) if dp is None else np.vstack([np.asarray(dp, float).reshape(-1, 3), np.zeros((1, 3))])
    pred = np.empty((len(Jc), 2))
    _linear_change(_f(Jc), _i(cidx), x1, _f(Jp) if Jp is not None else np.zeros((0, 2, 3)), _i(pidx), p1, pred)
    return pred


@_jit
def _front(indptr, indices, data, c0, c1, R):
    ns = c1 - c0
    nr = R.shape[0]
    F = np.zeros((ns + nr, ns + nr))
    for j in range(ns):
        t = 0
        for k in range(indptr[c0 + j], indptr[c0 + j + 1]):
            r = indices[k]
            if r < c0:
                continue
            if r < c1:
                F[r - c0, j] = data[k]
            else:
                while t < nr and R[t] < r:             # searchsorted(R, r): the column's rows ascend
                    t += 1
                F[ns + t, j] = data[k]
    return F


def front(indptr, indices, data, c0, c1, R):
    """The front (ns + nr)² of the columns ``c0 … c1 − 1`` (ns) of a CSC matrix with sorted
    indices, rows: those columns, then the rows ``R`` (sorted, nr): the matrix entries of rows
    ≥ c0 of those columns scattered into the front's first ns columns, zeros elsewhere (the
    multifrontal factorisation's assembly; every row ≥ c1 of the columns is in ``R``)."""
    return _front(indptr, indices, data, int(c0), int(c1), R)


@_jit
def _extend_add(F, rel, U):
    n = rel.shape[0]
    for i in range(n):
        ri = rel[i]
        for j in range(n):
            F[ri, rel[j]] += U[i, j]


def extend_add(F, rel, U):
    """``F[np.ix_(rel, rel)] += U`` in place (rel distinct; ``U`` any strides): a child's update
    matrix added into its parent's front."""
    _extend_add(F, rel, U)


@_jit
def _gather_block(Z, rel, out):
    n = rel.shape[0]
    for i in range(n):
        ri = rel[i]
        for j in range(n):
            out[i, j] = Z[ri, rel[j]]


def gather_block(Z, rel):
    """``Z[np.ix_(rel, rel)]`` as a new C-contiguous array."""
    out = np.empty((len(rel), len(rel)))
    _gather_block(Z, rel, out)
    return out


def _f(a):
    """float64, C-contiguous and writeable (numba compiles read-only arrays separately)."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    return a if a.flags.writeable else a.copy()


def _i(a):
    a = np.ascontiguousarray(a, dtype=np.intp)
    return a if a.flags.writeable else a.copy()
