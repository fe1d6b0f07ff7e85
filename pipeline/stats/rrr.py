"""Recursive Residual Rejection (Benciolini, Mussio & Sansò 1982; paper 000 eq. 8; SPEC §1).

Procedure (as in the paper's example):

1. Adjust all rows; the ``ρ`` rows with the largest ``|∇̂l_i| = |v_i / r_i|`` are the suspects,
   tested in that order (largest first); the other ``n − ρ`` rows form the clean set C.
2. For a suspect s, order C first and s last and form the standardized recursive residuals
   ``w_k = (l_k − a_k x̂_{k−1}) / (σ √(1/p_k + a_k N_{k−1}⁻¹ a_kᵀ))`` (``x̂_{k−1}``, ``N_{k−1}``
   from the first k−1 rows; weighted form: whiten first).  Then

       H_exp = w_last² / Σ_{k=u+1}^{last} w_k²  =  1 − RSS(C) / RSS(C ∪ {s}),

   the suspect's share of the sum of squares (σ cancels; the order inside C does not matter).
3. ``H_exp ≥ H``: s holds a gross error and stays out; otherwise s rejoins C before the next
   suspect is tested.

Critical value H: under H0 (no gross error) the *whole* procedure — suspect selection from the
full adjustment included — is simulated ``n_sim`` times for the actual design and weights
(x = 0, e ~ N(0, P⁻¹); the statistics do not depend on x or σ0).  Along the path on which every
suspect passes (which is the path the procedure follows until its first rejection), the largest
``H_j`` of the ρ suspects is recorded; H is its (1 − α) quantile.  So α is the probability that
RRR rejects *any* observation of a clean data set (family-wise level).

The naive value ignores the selection: without selection a single recursive residual's share of
``k`` i.i.d. N(0,1) squares is ``Beta(1/2, (k − 1)/2)``; ``H_naive`` is its (1 − α) quantile with
``k = |C| + 1 − u`` terms.  Selecting the largest ``|∇̂l|`` as suspect makes large shares far more
likely, so ``H_naive`` is too small and rejects clean observations much more often than α.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
from scipy import stats

from baarda.pipeline.errors import AdjustmentError
from baarda.pipeline.stats.baarda import estimated_errors

__all__ = ["RRRResult", "rrr", "recursive_residuals", "DEFAULT_SEED"]

#: seed used when ``rng`` is None, so that results are reproducible by default
DEFAULT_SEED = 19820101
#: smallest eigenvalue of the unit-scaled clean-set normal matrix accepted as regular
_EIG_MIN = 1e-10


def recursive_residuals(A, l, P=None, order=None, sigma0: float = 1.0) -> np.ndarray:
    """Standardized recursive residuals ``w_{u+1} … w_m`` of the rows in ``order``.

    ``w_k`` is the residual of row k predicted from the first k − 1 rows divided by its standard
    deviation ``σ0 √(1/p_k + a_k N_{k−1}⁻¹ a_kᵀ)``.  ``P`` may be None, a vector or a full matrix
    (then the rows are whitened with the lower Cholesky factor of ``Σ = P⁻¹`` in the given order,
    which makes the k-th whitened row depend on rows 1 … k only).  Σ w_k² = RSS / σ0².
    If the first ``u`` rows do not determine the unknowns (e.g. a stack of independent Helmert
    transformations ordered pair by pair), ``u`` independent rows among all but the last are moved
    to the front (column-pivoted QR).  The last row's recursive residual and the sum of squares do
    not depend on the order of the rows before it, so this changes none of RRR's statistics.
    """
    A = A.toarray() if hasattr(A, "toarray") else np.asarray(A, dtype=float)
    l = np.asarray(l, dtype=float).reshape(-1)
    order = np.arange(A.shape[0]) if order is None else np.asarray(order, dtype=int)
    order = _determining_start(A, order)
    A, l = A[order], l[order]
    m, u = A.shape
    if P is None:
        At, lt = A, l
    else:
        P = np.asarray(P, dtype=float)
        if P.ndim == 1:
            s = np.sqrt(P[order])
            At, lt = A * s[:, None], l * s
        else:
            Sig = sla.cho_solve(sla.cho_factor(P), np.eye(P.shape[0]))[np.ix_(order, order)]
            L = np.linalg.cholesky(Sig)
            At = sla.solve_triangular(L, A, lower=True)
            lt = sla.solve_triangular(L, l, lower=True)
    if m <= u:
        return np.zeros(0)
    N = At[:u].T @ At[:u]
    try:
        Ninv = np.linalg.inv(N)
        x = Ninv @ (At[:u].T @ lt[:u])
    except np.linalg.LinAlgError as e:
        raise AdjustmentError("recursive residuals: the first u rows do not determine the unknowns") from e
    out = np.empty(m - u)
    for k in range(u, m):
        a = At[k]
        Na = Ninv @ a
        d = 1.0 + a @ Na
        e = lt[k] - a @ x
        out[k - u] = e / np.sqrt(d) / sigma0
        # Sherman–Morrison update with row k
        Ninv = Ninv - np.outer(Na, Na) / d
        x = x + Na * (e / d)
    return out


def _determining_start(A: np.ndarray, order: np.ndarray) -> np.ndarray:
    """``order`` with its first u rows spanning the unknowns (the last row stays last)."""
    u = A.shape[1]
    if len(order) <= u:
        return order
    head = A[order[:u]]
    sv = np.linalg.svd(head, compute_uv=False)
    if sv.size and sv[-1] > 1e-10 * max(sv[0], 1e-300):
        return order
    body = order[:-1]
    _, _, piv = sla.qr(A[body].T, mode="economic", pivoting=True)
    first = body[np.sort(piv[:u])]
    rest = np.array([i for i in body if i not in set(first.tolist())], dtype=int)
    return np.concatenate([first, rest, order[-1:]])


@dataclass(frozen=True, eq=False)
class RRRResult:
    """Outcome of :func:`rrr`."""

    suspects: list[int]  # rows, in test order
    suspect_labels: list[str]
    nabla_hat: np.ndarray  # (ρ,) ∇̂l of the suspects in the full adjustment
    H_exp: np.ndarray  # (ρ,) as tested (clean set grows by the suspects that passed)
    H_exp_clean: np.ndarray  # (ρ,) each suspect against the initial clean set only
    H: float  # critical value used (Monte Carlo of the whole procedure unless given)
    H_mc: float  # Monte Carlo critical value (nan if n_sim = 0)
    H_ci: tuple  # 95 % distribution-free interval of that quantile (order statistics)
    H_naive: np.ndarray  # (ρ,) Beta(1/2, (k−1)/2) quantile, no selection
    k_terms: np.ndarray  # (ρ,) number of recursive residuals in each H_exp
    rejected: np.ndarray  # (ρ,) bool
    p_value: np.ndarray  # (ρ,) MC p-value P(max_j H_j ≥ H_exp) under H0
    p_naive: np.ndarray  # (ρ,) Beta survival function at H_exp
    alpha: float
    n_sim: int
    n_degenerate: int  # simulated data sets whose clean set could not determine the unknowns
    selection: str
    history: list[dict] = field(repr=False)
    labels: np.ndarray = field(repr=False)

    @property
    def rejected_labels(self) -> list[str]:
        return [lab for lab, r in zip(self.suspect_labels, self.rejected) if r]

    def summary(self) -> dict:
        return {
            "alpha": self.alpha, "H": self.H, "H_ci": list(self.H_ci), "n_sim": self.n_sim,
            "n_degenerate": self.n_degenerate, "selection": self.selection,
            "H_mc": self.H_mc, "suspects": self.suspect_labels, "H_exp": self.H_exp.tolist(),
            "H_exp_clean": self.H_exp_clean.tolist(),
            "H_naive": self.H_naive.tolist(), "k_terms": self.k_terms.tolist(),
            "p_value": self.p_value.tolist(), "p_naive": self.p_naive.tolist(),
            "rejected": self.rejected_labels, "history": self.history,
        }


# ---------------------------------------------------------------------------- core (diagonal P)
def _path_diag(At, E, sqrtp, rho, fixed, H_crit=None):
    """Batched RRR for whitened rows ``At`` (n, u) and whitened data ``E`` (m, n).

    Returns suspects (m, ρ), H (m, ρ), signed last recursive residual (m, ρ), joined-before
    counts (m, ρ) and a degenerate flag (m,).  ``H_crit=None`` follows the all-pass path.
    """
    m, n = E.shape
    u = At.shape[1]
    N = At.T @ At
    Ninv = np.linalg.inv(N)
    b_full = E @ At  # (m, u)
    if fixed is None:
        X = b_full @ Ninv
        V = E - X @ At.T
        r = 1.0 - np.einsum("ij,jk,ik->i", At, Ninv, At)
        nab = np.abs(V / (sqrtp * np.where(r > 1e-12, r, np.inf)))
        if rho < n:
            part = np.argpartition(-nab, rho - 1, axis=1)[:, :rho]
        else:
            part = np.tile(np.arange(n), (m, 1))
        vals = np.take_along_axis(nab, part, axis=1)
        S = np.take_along_axis(part, np.argsort(-vals, axis=1, kind="stable"), axis=1)
    else:
        S = np.tile(np.asarray(fixed, int), (m, 1))
    AS = At[S]  # (m, ρ, u)
    ES = np.take_along_axis(E, S, axis=1)  # (m, ρ)
    NC = N[None] - np.einsum("mki,mkj->mij", AS, AS)
    bC = b_full - np.einsum("mki,mk->mi", AS, ES)
    ssq = np.einsum("ij,ij->i", E, E) - np.einsum("ij,ij->i", ES, ES)
    dscale = 1.0 / np.sqrt(np.diag(N))
    H = np.empty((m, rho))
    W = np.empty((m, rho))
    joined = np.zeros((m, rho), int)
    degenerate = np.zeros(m, bool)
    nj = np.zeros(m, int)
    eye = np.eye(u)
    for j in range(rho):
        Ns = NC * dscale[None, :, None] * dscale[None, None, :]
        bad = np.linalg.eigvalsh(Ns)[:, 0] < _EIG_MIN
        degenerate |= bad
        NCs = np.where(bad[:, None, None], eye[None], NC)
        a = AS[:, j, :]
        sol = np.linalg.solve(NCs, np.stack([bC, a], axis=2))  # (m, u, 2)
        xC, za = sol[:, :, 0], sol[:, :, 1]
        rss = ssq - np.einsum("mi,mi->m", bC, xC)
        e = ES[:, j] - np.einsum("mi,mi->m", a, xC)
        d = 1.0 + np.einsum("mi,mi->m", a, za)
        w2 = e * e / d
        with np.errstate(invalid="ignore", divide="ignore"):
            Hj = w2 / (np.maximum(rss, 0.0) + w2)
        Hj[bad] = np.nan
        H[:, j] = Hj
        W[:, j] = e / np.sqrt(d)
        joined[:, j] = nj
        join = np.ones(m, bool) if H_crit is None else ~(Hj >= H_crit)
        NC = NC + join[:, None, None] * np.einsum("mi,mj->mij", a, a)
        bC = bC + join[:, None] * a * ES[:, j][:, None]
        ssq = ssq + join * ES[:, j] ** 2
        nj = nj + join
    return S, H, W, joined, degenerate


# ---------------------------------------------------------------------------- core (full P)
def _rss_subset(A, Sigma, rows, E):
    """RSS of the GLS fit of the rows ``rows`` for a batch of data ``E`` (m, n), and the rank."""
    rows = np.asarray(rows, int)
    L = np.linalg.cholesky(Sigma[np.ix_(rows, rows)])
    Linv = np.linalg.inv(L)
    At = Linv @ A[rows]
    Et = Linv @ E[:, rows].T  # (k, m)
    Q, R = np.linalg.qr(At)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > 1e-10 * max(d.max(), 1e-300)))
    res = Et - Q @ (Q.T @ Et)
    return np.einsum("km,km->m", res, res), rank


def _path_full(A, Sigma, P, E, rho, fixed, H_crit=None):
    """RRR for correlated observations (marginal covariance of every subset), grouped by suspects."""
    m, n = E.shape
    u = A.shape[1]
    if fixed is None:
        PA = P @ A
        N = A.T @ PA
        Ninv = np.linalg.inv(N)
        V = E - (E @ PA) @ Ninv @ A.T
        PQvvP = np.diag(P) - np.einsum("ij,jk,ik->i", PA, Ninv, PA)
        nab = np.abs((V @ P) / np.where(PQvvP > 1e-12 * np.diag(P), PQvvP, np.inf))
        S = np.argsort(-nab, axis=1, kind="stable")[:, :rho]
    else:
        S = np.tile(np.asarray(fixed, int), (m, 1))
    H = np.full((m, rho), np.nan)
    W = np.full((m, rho), np.nan)
    joined = np.zeros((m, rho), int)
    degenerate = np.zeros(m, bool)
    keys, inv = np.unique(S, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    for t, key in enumerate(keys):
        sel = np.flatnonzero(inv == t)
        Eb = E[sel]
        clean = [i for i in range(n) if i not in set(key.tolist())]
        members = [list(clean) for _ in sel]  # per sample clean set (differs only with H_crit)
        for j, s in enumerate(key):
            groups: dict[tuple, list[int]] = {}
            for q, mem in enumerate(members):
                groups.setdefault(tuple(mem), []).append(q)
            for mem, qs in groups.items():
                qs = np.asarray(qs)
                rss_c, rank = _rss_subset(A, Sigma, list(mem), Eb[qs])
                if rank < u:
                    degenerate[sel[qs]] = True
                    continue
                rss_s, _ = _rss_subset(A, Sigma, list(mem) + [int(s)], Eb[qs])
                w2 = np.maximum(rss_s - rss_c, 0.0)
                Hj = w2 / np.maximum(rss_s, 1e-300)
                H[sel[qs], j] = Hj
                # sign of the recursive residual: innovation of s given the clean rows
                W[sel[qs], j] = np.sqrt(w2)
                joined[sel[qs], j] = len(mem) - len(clean)
                for q, h in zip(qs, Hj):
                    if H_crit is None or not h >= H_crit:
                        members[q] = members[q] + [int(s)]
    return S, H, W, joined, degenerate


# ---------------------------------------------------------------------------- public
def _seed_sequence(rng) -> np.random.SeedSequence:
    """The SeedSequence the realisations are spawned from: an int / SeedSequence as given, a
    Generator's own seed sequence (``default_rng(7)`` and ``7`` agree), None → DEFAULT_SEED."""
    if isinstance(rng, np.random.SeedSequence):
        return rng
    if isinstance(rng, np.random.Generator):
        ss = rng.bit_generator.seed_seq
        if isinstance(ss, np.random.SeedSequence):
            return ss
        return np.random.SeedSequence(rng.integers(0, 2 ** 63, size=4).tolist())
    return np.random.SeedSequence(DEFAULT_SEED if rng is None else rng)


class _NullSimulation:
    """One task of RRR's Monte Carlo under H0: realisations ``start … stop − 1`` of the whole
    procedure, realisation i from ``default_rng(SeedSequence child i)``.  Returns (the largest H
    of each realisation, degenerate flags) in realisation order.  Picklable (module level), so a
    mapper may run it in another process."""

    def __init__(self, full, A, sqrtp, Sigma, P, L, rho, fixed):
        self.full, self.A, self.sqrtp, self.Sigma, self.P, self.L = full, A, sqrtp, Sigma, P, L
        self.rho, self.fixed = rho, fixed

    def __call__(self, task):
        root, start, stop = task
        n = self.A.shape[0]
        E = np.empty((stop - start, n))
        for k, i in enumerate(range(start, stop)):
            child = np.random.SeedSequence(root.entropy, spawn_key=tuple(root.spawn_key) + (i,),
                                           pool_size=root.pool_size)
            E[k] = np.random.default_rng(child).standard_normal(n)
        if self.full:
            _, H, _, _, deg = _path_full(self.A, self.Sigma, self.P, E @ self.L.T, self.rho, self.fixed)
        else:
            _, H, _, _, deg = _path_diag(self.A, E, self.sqrtp, self.rho, self.fixed)
        mx = np.full(stop - start, np.nan)
        if (~deg).any():
            mx[~deg] = np.max(H[~deg], axis=1)
        return mx, deg


def rrr(model, rho: int, alpha: float = 0.001, n_sim: int = 100_000, rng=None, suspects=None,
        active=None, chunk: int | None = None, critical: float | None = None,
        mapper=None) -> RRRResult:
    """Recursive Residual Rejection on a :class:`~baarda.pipeline.stats.linear.LinearModel`.

    Parameters
    ----------
    model : LinearModel (diagonal or full P).
    rho : number of suspects (largest |∇̂l| of the full adjustment); needs ``n − ρ > u``.
    alpha : family-wise level: probability that the procedure rejects anything in clean data.
    n_sim : Monte Carlo repetitions for the critical value H.
    rng : seed (int), SeedSequence or numpy Generator (its seed sequence); None uses
        :data:`DEFAULT_SEED` (reproducible).  Realisation i draws from the i-th child of that
        SeedSequence, so the result does not depend on how the realisations are distributed.
    suspects : optional rows (indices or labels) to test in this order instead of selecting them;
        the Monte Carlo then keeps the same fixed suspects (no selection effect).
    active : optional (n,) bool; RRR then works on the active rows only.
    chunk : simulations per task (memory, parallelism); default: ``n_sim`` in about 32 tasks, at most
        ≈ 2e6 / n per task.  Results depend on it only through rounding (the batched algebra).
    mapper : runs the Monte Carlo's tasks: any callable with the signature of the built-in ``map``
        (``mapper(fn, tasks)`` → results in order), e.g. the engine of
        :mod:`baarda.pipeline.montecarlo` (Dask); default: the built-in ``map``, in this process.
    critical : optional critical value H to use instead of the Monte Carlo one (e.g. the paper's
        0.993, to show what it implies); the Monte Carlo still runs for the p-values unless
        ``n_sim = 0``.
    """
    act = np.ones(model.n, bool) if active is None else np.array(active, bool).reshape(-1)
    rows = np.flatnonzero(act)
    A = model.A.toarray() if hasattr(model.A, "toarray") else np.asarray(model.A)
    A = A[rows]
    l = model.l[rows]
    labels = model.labels[rows]
    n, u = A.shape
    full = model.kind == "full"
    snap = model.adjust(act).snapshot
    nab_all = estimated_errors(snap)[rows]

    if suspects is not None:
        lab_index = {str(s): i for i, s in enumerate(labels)}
        fixed = []
        for s in suspects:
            if isinstance(s, (int, np.integer)):
                pos = np.flatnonzero(rows == int(s))
                if pos.size == 0:
                    raise ValueError(f"suspect row {s} is not active")
                fixed.append(int(pos[0]))
            else:
                if str(s) not in lab_index:
                    raise ValueError(f"unknown suspect label {s!r}")
                fixed.append(lab_index[str(s)])
        fixed = np.asarray(fixed, int)
        rho = len(fixed)
        selection = "given"
    else:
        fixed = None
        selection = "largest |nabla_hat| of the full adjustment"
    rho = int(rho)
    if rho < 1:
        raise ValueError("rho must be at least 1")
    if n - rho <= u:
        raise ValueError(f"rho = {rho} leaves a clean set of {n - rho} rows for {u} unknowns; "
                         "RRR needs n − rho > u (at least one redundant clean row)")
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must lie in (0, 1), got {alpha}")

    if full:
        Sigma = model._Sigma[np.ix_(rows, rows)]
        P = sla.cho_solve(sla.cho_factor(Sigma), np.eye(n))
        L = np.linalg.cholesky(Sigma)

        def path(E, H_crit=None):
            return _path_full(A, Sigma, P, E, rho, fixed, H_crit)

        data = l[None, :]
    else:
        p = model.P[rows]
        sqrtp = np.sqrt(p)
        At = A * sqrtp[:, None]

        def path(E, H_crit=None):
            return _path_diag(At, E, sqrtp, rho, fixed, H_crit)

        data = (l * sqrtp)[None, :]

    # -------- Monte Carlo of the whole procedure under H0 (all-pass path): tasks of `chunk`
    # realisations, realisation i drawing from its own SeedSequence child i (results do not depend
    # on who computes a task); `mapper` runs the tasks (built-in map: here, in order)
    n_sim = int(n_sim)
    root = _seed_sequence(rng)
    chunk = int(chunk or min(max(1000, 2_000_000 // max(n, 1)), max(250, -(-n_sim // 32))))
    sim = _NullSimulation(full, At if not full else A, sqrtp if not full else None,
                          Sigma if full else None, P if full else None, L if full else None, rho, fixed)
    tasks = [(root, a, min(a + chunk, n_sim)) for a in range(0, n_sim, chunk)]
    parts = list((mapper or map)(sim, tasks))
    n_deg = int(sum(int(np.sum(deg)) for _, deg in parts))
    stats_max = [mx[~deg] for mx, deg in parts]
    M = np.sort(np.concatenate(stats_max)) if stats_max else np.zeros(0)
    mm = M.size
    if n_sim > 0 and mm == 0:
        raise AdjustmentError("RRR: no simulated clean set determined the unknowns")
    if mm:
        q = 1.0 - alpha
        idx = min(int(np.ceil(q * mm)) - 1, mm - 1)
        H_mc = float(M[max(idx, 0)])
        half = 1.96 * np.sqrt(mm * alpha * (1 - alpha))
        lo = int(np.clip(np.floor(q * mm - half) - 1, 0, mm - 1))
        hi = int(np.clip(np.ceil(q * mm + half) - 1, 0, mm - 1))
        H_ci = (float(M[lo]), float(M[hi]))
    else:
        H_mc, H_ci = float("nan"), (float("nan"), float("nan"))
    if critical is None:
        if not mm:
            raise ValueError("rrr needs n_sim > 0 or an explicit critical value")
        H = H_mc
    else:
        H = float(critical)

    # -------- the observed data
    S, Hobs, Wobs, joined, deg = path(data, H_crit=H)
    if deg[0]:
        raise AdjustmentError("RRR: the clean set does not determine the unknowns; reduce rho")
    S, Hobs, Wobs, joined = S[0], Hobs[0], Wobs[0], joined[0]
    rejected = Hobs >= H
    k_terms = (n - rho) + joined + 1 - u
    H_naive = np.array([stats.beta.isf(alpha, 0.5, (k - 1) / 2.0) if k > 1 else 1.0
                        for k in k_terms])
    p_naive = np.array([stats.beta.sf(h, 0.5, (k - 1) / 2.0) if k > 1 else 1.0
                        for h, k in zip(Hobs, k_terms)])
    p_value = np.array([(1 + np.sum(M >= h)) / (mm + 1) if mm else np.nan for h in Hobs])
    Sig_sub = Sigma if full else np.diag(1.0 / model.P[rows])
    clean0 = [i for i in range(n) if i not in set(S.tolist())]
    rss0, _ = _rss_subset(A, Sig_sub, clean0, l[None, :])
    with np.errstate(invalid="ignore", divide="ignore"):
        H_exp_clean = np.array([1.0 - rss0[0] / _rss_subset(A, Sig_sub, clean0 + [int(s)],
                                                              l[None, :])[0][0] for s in S])

    history = []
    clean = [i for i in range(n) if i not in set(S.tolist())]
    for j, s in enumerate(S):
        order = clean + [int(s)]
        Pw = model.P[rows] if not full else P
        if full:
            Psub = sla.cho_solve(sla.cho_factor(Sigma[np.ix_(order, order)]), np.eye(len(order)))
            rec = recursive_residuals(A[order], l[order], Psub, sigma0=model.sigma0)
        else:
            rec = recursive_residuals(A[order], l[order], Pw[order], sigma0=model.sigma0)
        history.append({
            "suspect": str(labels[s]), "row": int(rows[s]), "nabla_hat": float(nab_all[s]),
            "clean": [str(labels[i]) for i in clean], "k_terms": int(k_terms[j]),
            "recursive_residuals": rec.tolist(), "H_exp": float(Hobs[j]),
            "H_exp_initial_clean_set": float(H_exp_clean[j]), "H": H,
            "H_naive": float(H_naive[j]), "p_value": float(p_value[j]),
            "decision": "rejected" if rejected[j] else "accepted (rejoins the clean set)",
        })
        if not rejected[j]:
            clean = clean + [int(s)]

    return RRRResult(
        suspects=[int(rows[s]) for s in S], suspect_labels=[str(labels[s]) for s in S],
        nabla_hat=nab_all[S], H_exp=Hobs, H_exp_clean=H_exp_clean, H=H, H_mc=H_mc, H_ci=H_ci, H_naive=H_naive,
        k_terms=np.asarray(k_terms), rejected=rejected, p_value=p_value, p_naive=p_naive,
        alpha=float(alpha), n_sim=n_sim, n_degenerate=n_deg, selection=selection,
        history=history, labels=model.labels)
