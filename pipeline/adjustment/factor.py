"""Solution of the reduced camera system: Jacobi-scaled Cholesky (control datum) or the bordered
system of a free network through the Cholesky factor of ``N + C Cᵀ``; a singular system becomes a
datum / parameter diagnosis (:mod:`.diagnose`)."""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from baarda.pipeline.errors import AdjustmentError

__all__ = ["solve_reduced", "solve_factored", "minimal_datum", "datum_basis"]


def solve_reduced(prob, red, st, diagnose=False):
    """Solve K Δ = rhs with Jacobi scaling; on singularity raise a datum / parameter diagnosis.

    Without inner constraints K is positive definite: Cholesky.  With them K is the saddle-point
    matrix ``[[N, C], [Cᵀ, −E]]`` (E = the constraints' share of the eliminated points); it is
    solved through the Cholesky factor of ``M = N + C Cᵀ`` (positive definite when C fixes the
    datum) and an n_c × n_c system — exactly the bordered solution (see :func:`solve_factored`).
    """
    if red.get("route") == "sparse":
        return _solve_sparse(prob, red, st)
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


# ---- sparse route ------------------------------------------------------------------------------
def minimal_datum(prob, st) -> np.ndarray | None:
    """Global unknowns fixed to hold a free network's datum on the sparse route: ``n_c`` photo
    parameters whose datum motions are the most independent (QR with column pivoting of the
    motions' rows); ``None`` when the motions do not reach ``n_c`` independent parameters."""
    if getattr(prob, "_minimal_datum", None) is None:
        from .diagnose import datum_motions

        G = datum_motions(prob, st)[:, :prob.n_c]
        cand = np.flatnonzero(np.abs(G).sum(axis=1) > 0)
        if len(cand) < prob.n_c:
            prob._minimal_datum = (None,)
            return None
        Gn = G[cand] / np.maximum(np.linalg.norm(G[cand], axis=0), 1e-300)
        _, R, piv = sla.qr(Gn.T, mode="economic", pivoting=True)
        r = np.abs(np.diag(R))
        ok = r.min() > 1e-8 * r.max()
        prob._minimal_datum = (np.sort(cand[piv[:prob.n_c]]) if ok else None,)
    return prob._minimal_datum[0]


def datum_basis(prob, red, st):
    """The datum motions of every unknown (``Gg`` (n_g, n_c), ``Gp`` (n_e, 3, n_c)) and
    ``T = (Cᵀ G)⁻¹`` for the inner constraints ``C`` of the free network (cached in ``red``)."""
    if "datum_basis" not in red:
        from .diagnose import datum_motions, point_motions

        n_c = prob.n_c
        Gg = datum_motions(prob, st)[:, :n_c]
        Gp = point_motions(prob, st, st.XYZ[prob.elim_points])[:, :, :n_c] * prob.elim_free[:, :, None]
        Cg, Cp = red["Cg"], red["Cp"]
        CtG = Cg.T @ Gg + np.einsum("pac,pad->cd", Cp, Gp)
        red["datum_basis"] = (Gg, Gp, np.linalg.inv(CtG))
    return red["datum_basis"]


def _solve_sparse(prob, red, st):
    """Sparse route: Jacobi-scaled supernodal Cholesky of the reduced system; a free network's
    step is the minimal-constraint solution S-transformed onto the inner constraints
    (``Δ = Δ₀ − G (Cᵀ G)⁻¹ Cᵀ Δ₀``: the same step as the bordered system's)."""
    from .sparse import NotPositiveDefinite, SupernodalCholesky

    import scipy.sparse as sp

    n_g, n_c = prob.n_g, prob.n_c
    K = red["K"]
    keep = np.ones(n_g, bool)
    if n_c:
        piv = minimal_datum(prob, st)
        if piv is None:                                      # pragma: no cover - guarded by solver_route
            raise AdjustmentError("free network: no photo parameters to hold the datum on the sparse route; "
                                  "use solver = 'dense'", state=st)
        keep[piv] = False
    kidx = np.flatnonzero(keep)
    Kk = K[kidx][:, kidx] if n_c else K
    dg = Kk.diagonal()
    if (dg <= 0).any():
        _sparse_singular(prob, red, st, int(kidx[np.argmax(dg <= 0)]), zero=True)
    d = 1.0 / np.sqrt(dg)
    Ds = sp.diags(d)
    Ks = (Ds @ Kk @ Ds).tocsc()
    try:
        F = SupernodalCholesky(prob.symbolic(keep if n_c else None), Ks)
    except NotPositiveDefinite as e:
        _sparse_singular(prob, red, st, int(kidx[e.column]))
    dx = np.zeros(n_g + n_c)
    dx[kidx] = F.solve(red["rhs"][kidx] * d) * d
    fac = ("sparse", (F, d, kidx))
    red["factor"] = fac
    red["scale"] = None
    if n_c:
        Gg, _, T = datum_basis(prob, red, st)
        dp = prob.back_substitute(red, dx)
        c = red["Cg"].T @ dx[:n_g] + np.einsum("pac,pa->c", red["Cp"], dp)
        dx[:n_g] -= Gg @ (T @ c)
    if not np.isfinite(dx).all():
        _sparse_singular(prob, red, st, int(np.argmax(~np.isfinite(dx[:n_g]))))
    return dx, fac


def sparse_solve(red, r: np.ndarray) -> np.ndarray:
    """``K⁻¹ r`` (r (n_g,) or (n_g, j)) with the sparse route's factor; unknowns held by the minimal
    datum get 0 (the minimal-constraint cofactors)."""
    F, d, kidx = red["factor"][1]
    out = np.zeros(r.shape)
    dd = d if r.ndim == 1 else d[:, None]
    out[kidx] = F.solve(r[kidx] * dd) * dd
    return out


def _sparse_singular(prob, red, st, col: int, zero: bool = False):
    """Raise the datum / parameter diagnosis for a singular sparse system: the dense analysis for
    systems small enough to hold densely, else the parameter at the failing pivot."""
    from .diagnose import parameter_names

    if prob.n_g + prob.n_c <= 6000:
        dense = prob.reduced_system(red["lin"], st, red["lam"], route="dense")
        solve_reduced(prob, dense, st)
    name = parameter_names(prob)[col]
    if zero:
        raise AdjustmentError(f"{name} cannot be determined: no observation depends on it — fix it or give it an "
                              "a-priori sigma", state=st)
    raise AdjustmentError(f"the normal equations are singular at {name}: it cannot be determined from the "
                          "observations and the datum — check the control points (or set datum = 'free'), its "
                          "observations, or fix it", state=st)
