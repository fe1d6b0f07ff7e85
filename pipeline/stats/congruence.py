"""Deformation analysis of two epochs: S-transformation, congruence test, localisation (pure numerics).

Two adjustments of the same points give coordinates ``X1, X2`` (n, dim) with cofactor matrices
``Q1, Q2`` (dim·n × dim·n, coordinates point by point: x1, y1, z1, x2, …) and a-priori variance
factor ``σ0²``.  The displacement vector ``d = X2 − X1`` has the cofactor ``Q_dd = Q1 + Q2``
(independent epochs).  Each epoch may be a free network: its coordinates then carry an arbitrary
datum, and ``Q_dd`` may be singular along the datum directions ``G`` (translations, rotations,
scale: :func:`similarity_basis`).

**The displacement model** (Delft school: Baarda 1973, Kok 1982; Niemeier 1985)::

    d = G t + C_M ∇_M + e,     e ~ (0, σ0² Q_dd)

``t`` the datum difference between the epochs (a small similarity transformation), ``∇_M`` the
displacements of the points ``M`` held to have moved (``C_M`` selects their coordinates).  The
quadratic form of the least-squares residuals, ``Ω(M) = êᵀ Q_dd⁻ ê``, does not depend on the datum
of either epoch: ``Q_dd`` may be replaced by ``Q_dd + G Gᵀ`` (regular), since ``G`` is in the
model (Rao's unified least squares), which is what :func:`congruence` does.

* **Global congruence test** (nothing moved, ``M = ∅``): ``T = Ω(∅) / (h σ0²)`` with
  ``h = dim·n − rank G`` degrees of freedom; ``T ~ χ²(h)/h`` when σ0 is known, or ``F(h, f)``
  against the epochs' pooled ``σ̂0² = (Ω1 + Ω2)/(f1 + f2)`` with ``f = f1 + f2``.
* **Localisation** (Kok/Niemeier, iterated): each point ``i`` still held stable gets the test value of
  the hypothesis "point i moved", ``T_i = (Ω(M) − Ω(M ∪ {i})) / (dim σ0²)`` (a dim-dimensional
  w-test); while the remaining congruence is rejected at ``alpha`` or the largest ``T_i`` exceeds its
  critical value at ``alpha_point``, that point is declared moved and the tests are repeated on the
  rest (the global test alone has little power against one moved point among many).  The datum of the result is that of the points
  still held stable.
* **Displacements**: ``∇̂_i`` and its cofactor ``N_i⁻¹``, ``N_i = C̄_iᵀ P C̄_i`` with ``C̄_i`` the
  part of ``C_i`` not explained by the datum (and the other moved points); the **minimal detectable
  displacement** of a point in its worst direction, ``MDD_i = σ0 √(λ0 / λ_min(N_i))``, with λ0 the
  non-centrality at which the dim-dimensional test at level α has power β0.

An **S-transformation** (Baarda 1973) re-expresses coordinates and cofactors in the datum defined
by a subset of points, without re-adjusting: ``S = I − G (Gᵀ E G)⁻¹ Gᵀ E`` (E selects the datum
points' coordinates), ``x' = S x``, ``Q' = S Q Sᵀ``: :func:`s_transform`.

Conventions: ``d = X2 − X1`` (later minus earlier); coordinates in the block's object unit; cofactors
relative to σ0² (``docs/statistics.md``, "Deformation analysis").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg, optimize, stats

__all__ = ["similarity_basis", "s_transform", "congruence", "CongruenceResult", "PointDisplacement",
           "variance_ratio_test", "lambda0_multi", "DATUM_KINDS"]

DATUM_KINDS = {
    1: {"translation": 1, "similarity": 2},
    2: {"translation": 2, "rigid": 3, "similarity": 4},
    3: {"translation": 3, "rigid": 6, "similarity": 7},
}
"""Number of datum parameters per dimension and kind (heights: shift and scale; plane: shift,
rotation, scale; space: shift, rotations, scale)."""


def _as_points(X, dim=None) -> np.ndarray:
    X = np.array(X, dtype=float, copy=True)
    if X.ndim == 1:
        X = X[:, None]
    if X.ndim != 2 or X.shape[1] not in (1, 2, 3):
        raise ValueError(f"coordinates must be (n, 1|2|3), got {X.shape}")
    if dim is not None and X.shape[1] != dim:
        raise ValueError(f"coordinates have {X.shape[1]} components, expected {dim}")
    if not np.all(np.isfinite(X)):
        raise ValueError("coordinates must be finite")
    return X


def similarity_basis(X, kind: str = "similarity") -> np.ndarray:
    """The datum directions ``G`` (dim·n, u) of the points ``X`` (n, dim): translations, rotations
    about the centroid, scale — in that order, each column normalised to unit length.

    ``kind``: ``"translation"``, ``"rigid"`` (translations and rotations; not for heights) or
    ``"similarity"`` (with scale); see :data:`DATUM_KINDS`."""
    X = _as_points(X)
    n, dim = X.shape
    if kind not in DATUM_KINDS[dim]:
        raise ValueError(f"datum kind {kind!r} is not defined for {dim}-D points "
                         f"(choose from {sorted(DATUM_KINDS[dim])})")
    Xc = X - X.mean(axis=0)
    cols = []
    for a in range(dim):
        g = np.zeros((n, dim))
        g[:, a] = 1.0
        cols.append(g)
    if kind in ("rigid", "similarity") and dim >= 2:
        x, y = Xc[:, 0], Xc[:, 1]
        if dim == 2:
            cols.append(np.column_stack([-y, x]))
        else:
            z = Xc[:, 2]
            zero = np.zeros(n)
            cols.append(np.column_stack([zero, -z, y]))   # about X
            cols.append(np.column_stack([z, zero, -x]))   # about Y
            cols.append(np.column_stack([-y, x, zero]))   # about Z
    if kind == "similarity":
        cols.append(Xc.copy())
    G = np.column_stack([c.reshape(-1) for c in cols])
    norms = np.linalg.norm(G, axis=0)
    if np.any(norms == 0):
        raise ValueError("the points do not define the datum (all at one place?)")
    return G / norms


def _coordinate_rows(points, dim: int) -> np.ndarray:
    points = np.asarray(points, int)
    return (points[:, None] * dim + np.arange(dim)[None, :]).reshape(-1)


def s_transform(x, Q, X, datum_points, kind: str = "similarity"):
    """Coordinates (or a displacement vector) ``x`` (dim·n) and cofactor ``Q`` re-expressed in the
    datum of ``datum_points`` (indices), without re-adjusting.

    ``X`` (n, dim) are approximate coordinates that define the datum directions (:func:`similarity_basis`);
    returns ``(x', Q', S)`` with ``S = I − G (Gᵀ E G)⁻¹ Gᵀ E``, ``x' = S x``, ``Q' = S Q Sᵀ``.
    The datum points must determine the datum (e.g. ≥ 3 non-collinear points for a 3-D
    similarity); otherwise a ValueError names what is missing."""
    X = _as_points(X)
    n, dim = X.shape
    x = np.asarray(x, float).reshape(-1)
    Q = np.asarray(Q, float)
    if x.shape[0] != n * dim or Q.shape != (n * dim, n * dim):
        raise ValueError(f"x must have {n * dim} elements and Q be {n * dim}×{n * dim}")
    G = similarity_basis(X, kind)
    rows = _coordinate_rows(np.unique(np.asarray(datum_points, int)), dim)
    E = np.zeros(n * dim)
    E[rows] = 1.0
    GEG = G.T @ (E[:, None] * G)
    if np.linalg.matrix_rank(GEG) < G.shape[1]:
        raise ValueError(f"the {len(np.unique(datum_points))} datum point(s) do not determine a "
                         f"{dim}-D {kind} datum ({G.shape[1]} parameters)")
    S = np.eye(n * dim) - G @ np.linalg.solve(GEG, G.T * E[None, :])
    return S @ x, S @ Q @ S.T, S


def lambda0_multi(alpha: float, beta0: float, dof: int) -> float:
    """Non-centrality ``λ0`` at which a χ²(``dof``) test at level ``alpha`` has power ``beta0``."""
    crit = stats.chi2.isf(alpha, dof)
    f = lambda lam: stats.ncx2.sf(crit, dof, lam) - beta0  # noqa: E731
    hi = 10.0
    while f(hi) < 0:
        hi *= 2
    return float(optimize.brentq(f, 1e-9, hi, xtol=1e-12))


def variance_ratio_test(s1: float, f1: int, s2: float, f2: int, alpha: float = 0.05) -> dict:
    """Two-sided F-test of ``σ̂1² / σ̂2²`` (the epochs' variance factors) at level ``alpha``."""
    F = (s1 * s1) / (s2 * s2)
    lo, hi = stats.f.ppf(alpha / 2, f1, f2), stats.f.isf(alpha / 2, f1, f2)
    p = 2 * min(stats.f.cdf(F, f1, f2), stats.f.sf(F, f1, f2))
    return {"F": float(F), "lower": float(lo), "upper": float(hi), "p": float(min(p, 1.0)),
            "differ": bool(F < lo or F > hi), "dof": (int(f1), int(f2)), "alpha": float(alpha)}


@dataclass(frozen=True)
class PointDisplacement:
    """One point's displacement in the datum of the stable points: estimate ``d`` (dim), cofactor
    ``Q`` (dim, dim), test value ``T`` (dim-D test, ``χ²(dim)/dim`` or F), its p-value, the minimal
    detectable displacement ``mdd`` (worst direction, object unit), and whether it was declared
    moved."""

    index: int
    d: np.ndarray
    Q: np.ndarray
    T: float
    p: float
    mdd: float
    moved: bool


@dataclass(frozen=True)
class CongruenceResult:
    """Outcome of :func:`congruence`.

    ``T0, p0, dof0``: the global congruence test with nothing moved; ``T, p, dof``: the remaining
    congruence after localisation (accepted unless ``n_max_moved`` stopped it); ``moved``: indices
    of the points declared moved, in the order found; ``points``: a :class:`PointDisplacement` for
    every point not in the datum (or every point when localising); ``critical``: the critical
    value of the global test at ``alpha``; ``sigma0`` the σ0 the tests use and ``test`` the
    distribution (``"chi2"`` or ``"F"`` with ``dof_sigma`` for the estimated variance factor);
    ``lambda0`` the non-centrality of the point tests' MDD."""

    T0: float
    p0: float
    dof0: int
    T: float
    p: float
    dof: int
    critical: float
    accepted0: bool
    moved: tuple
    points: tuple
    sigma0: float
    test: str
    dof_sigma: float
    alpha: float
    alpha_point: float
    beta0: float
    lambda0: float
    history: tuple = field(default=())


def _check_defect(Qdd, G, kind: str) -> None:
    """``Q_dd + G Gᵀ`` must be regular (Rao: rank(Q_dd : G) full): every direction in which the epochs'
    cofactors are singular (their datum defect, e.g. ``E G`` for inner constraints on a subset E of the
    points) must have a component along the datum directions of ``kind``; else the test would weigh an
    undetermined direction (two free networks without scale, compared in a rigid datum)."""
    w, V = np.linalg.eigh((Qdd + Qdd.T) / 2)
    null = V[:, w <= 1e-9 * max(float(w[-1]), 1e-300)]
    if null.shape[1] == 0:
        return
    sv = np.linalg.svd(G.T @ null, compute_uv=False)
    missing = int(null.shape[1] - np.sum(sv > 1e-6))
    if missing > 0:
        raise ValueError(f"the epochs' cofactors are singular in {null.shape[1]} direction(s), {missing} of "
                         f"them not covered by a {kind} datum (two free networks without scale compare in a "
                         "'similarity' datum; or give the epochs scale bars / control)")


def _omega(d, P, D):
    """Least-squares fit of d = D a + e with weight P: returns (Ω, a, N⁻¹)."""
    N = D.T @ P @ D
    b = D.T @ P @ d
    c = linalg.cho_factor(N)
    a = linalg.cho_solve(c, b)
    e = d - D @ a
    return float(e @ P @ e), a, linalg.cho_solve(c, np.eye(N.shape[0]))


def congruence(X1, Q1, X2, Q2, *, sigma0: float = 1.0, kind: str = "similarity", datum_points=None,
               alpha: float = 0.05, alpha_point: float = 0.001, beta0: float = 0.80,
               sigma0_hat: tuple | None = None, localise: bool = True,
               n_max_moved: int | None = None, basis_at=None) -> CongruenceResult:
    """Congruence test of two epochs and localisation of moved points (see the module text).

    ``X1, X2`` (n, dim) the same points in both epochs (same order); ``Q1, Q2`` their cofactor
    matrices (dim·n square; may be singular along the datum directions of a free network);
    ``sigma0`` the a-priori σ0 (cofactors are relative to σ0²). ``datum_points``: indices of the
    points declared stable (the datum); ``None`` lets localisation find them among all points.
    ``sigma0_hat = ((s1, f1), (s2, f2))``: the epochs' estimated variance factors and dof — the tests
    then use the pooled estimate and the F distribution (else σ0 known, χ²). ``alpha`` is the
    level of the global test; ``alpha_point`` that of the per-point tests and their MDD (0.1 %, as
    data snooping's α0: many points are tested). ``basis_at`` (n, dim): the coordinates the datum directions are computed at (default
    the mean of the epochs; a linear network passes its approximate coordinates)."""
    X1 = _as_points(X1)
    n, dim = X1.shape
    X2 = _as_points(X2, dim)
    if X2.shape[0] != n:
        raise ValueError(f"epoch 2 has {X2.shape[0]} points, epoch 1 {n}")
    m = n * dim
    Q1 = np.asarray(Q1, float)
    Q2 = np.asarray(Q2, float)
    if Q1.shape != (m, m) or Q2.shape != (m, m):
        raise ValueError(f"cofactor matrices must be {m}×{m}")
    for name, v in (("alpha", alpha), ("beta0", beta0)):
        if not 0 < v < 1:
            raise ValueError(f"{name} must lie strictly between 0 and 1, got {v}")
    alpha_point = float(alpha_point)
    d = (X2 - X1).reshape(-1)
    G = similarity_basis((X1 + X2) / 2 if basis_at is None else _as_points(basis_at, dim), kind)
    Qdd = Q1 + Q2
    _check_defect(Qdd, G, kind)
    Qreg = Qdd + G @ G.T * (np.trace(Qdd) / m if np.trace(Qdd) > 0 else 1.0)
    P = np.linalg.inv(Qreg)
    P = (P + P.T) / 2

    if sigma0_hat is not None:
        (s1, f1), (s2, f2) = sigma0_hat
        s2p = (s1 * s1 * f1 + s2 * s2 * f2) / (f1 + f2)
        s0, test, fs = math.sqrt(s2p), "F", float(f1 + f2)
    else:
        s0, test, fs = float(sigma0), "chi2", math.inf

    def dist_sf(T, h):
        return float(stats.chi2.sf(T * h, h)) if test == "chi2" else float(stats.f.sf(T, h, fs))

    def dist_isf(a, h):
        return float(stats.chi2.isf(a, h) / h) if test == "chi2" else float(stats.f.isf(a, h, fs))

    all_pts = np.arange(n)
    if datum_points is None:
        stable = list(all_pts)
        others: list[int] = []
    else:
        stable = sorted(set(int(i) for i in datum_points))
        if any(i < 0 or i >= n for i in stable):
            raise ValueError(f"datum point index out of range 0…{n - 1}")
        others = [i for i in all_pts if i not in set(stable)]

    def design(moved):
        cols = [G]
        for i in moved:
            C = np.zeros((m, dim))
            C[i * dim:(i + 1) * dim, :] = np.eye(dim)
            cols.append(C)
        return np.column_stack(cols)

    def fit(moved):
        D = design(moved)
        if np.linalg.matrix_rank(D) < D.shape[1]:
            raise ValueError(f"the {n - len(moved)} points held stable do not determine a {dim}-D "
                             f"{kind} datum")
        return _omega(d, P, D)

    h_full = m - G.shape[1]
    moved = list(others)
    Om, _, _ = fit(moved)
    h = h_full - dim * len(moved)
    if h <= 0:
        raise ValueError(f"no redundancy for the congruence test: {len(stable)} stable point(s) "
                         f"and a {G.shape[1]}-parameter datum")
    T0 = Om / (h * s0 * s0)
    p0 = dist_sf(T0, h)
    crit0 = dist_isf(alpha, h)
    T, p, dof, history = T0, p0, h, []
    found: list[int] = []
    limit = n_max_moved if n_max_moved is not None else len(stable) - math.ceil(G.shape[1] / dim) - 1
    crit_point = dist_isf(alpha_point, dim)
    while localise and len(found) < limit:
        best, best_T = None, -1.0
        for i in stable:
            if i in found:
                continue
            try:
                Om_i, _, _ = fit(moved + [i])
            except (ValueError, linalg.LinAlgError):
                continue
            Ti = (Om - Om_i) / (dim * s0 * s0)
            if Ti > best_T:
                best, best_T = i, Ti
        if best is None or (T <= dist_isf(alpha, dof) and best_T <= crit_point):
            break
        found.append(best)
        moved.append(best)
        Om, _, _ = fit(moved)
        dof = h_full - dim * len(moved)
        T = Om / (dof * s0 * s0) if dof > 0 else 0.0
        p = dist_sf(T, dof) if dof > 0 else 1.0
        history.append({"moved": int(best), "T_point": float(best_T), "T_rest": float(T), "p_rest": float(p),
                        "dof_rest": int(dof)})

    # every point's displacement in the datum of the stable points (moved ones estimated jointly)
    lam0 = lambda0_multi(alpha_point, beta0, dim)
    _, a, Ninv = fit(moved)
    k = G.shape[1]
    results = []
    for i in all_pts:
        if i in moved:
            j = moved.index(i)
            di = a[k + j * dim:k + (j + 1) * dim]
            Qi = Ninv[k + j * dim:k + (j + 1) * dim, k + j * dim:k + (j + 1) * dim]
        else:
            # the hypothesis "i moved" tested against the current model
            _, ai, Ninvi = fit(moved + [i])
            di = ai[-dim:]
            Qi = Ninvi[-dim:, -dim:]
        Ni = np.linalg.inv(Qi)
        Ti = float(di @ Ni @ di) / (dim * s0 * s0)
        mdd = s0 * math.sqrt(lam0 / max(np.linalg.eigvalsh((Ni + Ni.T) / 2)[0], 1e-300))
        results.append(PointDisplacement(int(i), di.copy(), Qi.copy(), Ti, dist_sf(Ti, dim), float(mdd),
                                         bool(i in found)))
    return CongruenceResult(T0=float(T0), p0=p0, dof0=int(h), T=float(T), p=float(p), dof=int(dof),
                            critical=crit0, accepted0=bool(T0 <= crit0), moved=tuple(int(i) for i in found),
                            points=tuple(results), sigma0=float(s0), test=test, dof_sigma=fs,
                            alpha=float(alpha), alpha_point=alpha_point, beta0=float(beta0),
                            lambda0=lam0, history=tuple(history))
