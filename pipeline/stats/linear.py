"""Linear Gauss–Markov model ``l = A x + e``, ``D(e) = σ0² P⁻¹`` (small/medium dense problems).

    N   = Aᵀ P A,  x̂ = N⁻¹ Aᵀ P l,  v = l − A x̂  (observed − computed),  Qxx = N⁻¹
    Qvv = P⁻¹ − A N⁻¹ Aᵀ,  r_i = (Qvv P)_ii,  (P Qvv P)_ii,  dof = n_active − u

``P`` may be ``None`` (identity), a vector (diagonal weights) or a full symmetric positive definite
matrix (correlated observations).  Inactive rows are *removed* from the adjustment: with a full
``P`` the remaining rows keep their marginal covariance, ``P_a = (Σ_aa)⁻¹`` with ``Σ = P⁻¹``
(for diagonal P this is the same as giving the row weight 0).  Removed rows stay in the snapshot
(``v = 0``, ``r = 0``) and carry their predicted residual ``l_i − a_i x̂`` in ``Snapshot.v_pred``.

``A`` may be a dense array or a ``scipy.sparse`` matrix; ``N`` and ``Qxx`` are always dense
(``u × u``).  Everything is computed with ``scipy.linalg.cho_factor``; a singular ``N`` raises
:class:`baarda.pipeline.errors.AdjustmentError` naming the undetermined unknowns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from baarda.pipeline.errors import AdjustmentError
from baarda.pipeline.stats.snapshot import GroupBlocks, Snapshot, pair_rows

__all__ = ["LinearModel", "LinearAdjustment", "factor_normal_equations", "solve_normal"]


@dataclass(frozen=True, eq=False)
class LinearAdjustment:
    """Result of :meth:`LinearModel.adjust`.

    Attributes
    ----------
    x : (u,) estimated unknowns.
    v : (n,) residuals observed − computed, 0 on inactive rows.
    v_pred : (n,) ``l − A x̂`` on every row (the predicted residual on inactive rows).
    Qxx : (u, u) cofactor matrix of the unknowns (covariance = σ0² Qxx).
    snapshot : :class:`Snapshot` for the statistics library.
    dof : degrees of freedom (active rows − u).
    sigma0_hat : √(vᵀPv / dof) (nan when dof = 0).
    active : (n,) bool, rows used.
    """

    x: np.ndarray
    v: np.ndarray
    v_pred: np.ndarray
    Qxx: np.ndarray
    snapshot: Snapshot
    dof: int
    sigma0_hat: float
    active: np.ndarray

    @property
    def Cxx(self) -> np.ndarray:
        """A-priori covariance of the unknowns, σ0² Qxx."""
        return self.snapshot.sigma0 ** 2 * self.Qxx


def _rowdot(X, Y: np.ndarray) -> np.ndarray:
    """Row-wise dot products of X (dense or sparse) and dense Y of the same shape."""
    if sp.issparse(X):
        return np.asarray(X.multiply(Y).sum(axis=1)).reshape(-1)
    return np.einsum("ij,ij->i", X, Y)


def factor_normal_equations(N: np.ndarray, names=None, rtol: float = 1e-11):
    """Cholesky-factor the normal matrix ``N`` or raise :class:`AdjustmentError`.

    The check is made on the unit-diagonal scaled matrix ``D N D`` (``D = diag(N)^-½``), so it does
    not depend on the units of the unknowns.  On failure the message names the unknowns that take
    part in the null space (e.g. ``"x2, x3 undetermined: 0.71·x2 − 0.71·x3 is not fixed by any
    observation"``).

    Returns ``(cho, scale)`` with ``cho`` the factor of the scaled matrix; solve with
    :func:`solve_normal`.
    """
    N = np.asarray(N, dtype=float)
    u = N.shape[0]
    names = [f"x{j + 1}" for j in range(u)] if names is None else [str(s) for s in names]
    d = np.diag(N).copy()
    empty = np.flatnonzero(~(d > 0))
    if empty.size:
        raise AdjustmentError(
            "rank-deficient normal equations: unknown(s) "
            + ", ".join(names[j] for j in empty)
            + " undetermined (no active observation involves them)")
    scale = 1.0 / np.sqrt(d)
    Ns = N * scale[:, None] * scale[None, :]
    try:
        cho = sla.cho_factor(Ns, lower=False, check_finite=True)
        ok = np.min(np.abs(np.diag(cho[0]))) ** 2 > rtol * u
    except np.linalg.LinAlgError:
        ok = False
    if not ok:
        w, V = np.linalg.eigh(Ns)
        tol = max(rtol * u, 1e-13) * max(w.max(), 1.0)
        null = V[:, w <= tol]
        if null.shape[1] == 0:  # poorly conditioned but regular: try once more
            cho = sla.cho_factor(Ns, lower=False)
            return cho, scale
        involved = np.flatnonzero(np.max(np.abs(null), axis=1) > 1e-6)
        combo = null[:, 0] * scale  # combination in the original unknowns
        combo = combo / np.max(np.abs(combo))
        terms = " ".join(f"{c:+.2g}·{names[j]}" for j, c in enumerate(combo) if abs(c) > 1e-6)
        raise AdjustmentError(
            f"rank-deficient normal equations (rank {u - null.shape[1]} of {u}): unknown(s) "
            + ", ".join(names[j] for j in involved)
            + f" undetermined; e.g. the combination {terms} is not fixed by the observations"
            " (missing datum or observation)")
    return cho, scale


def solve_normal(fac, b: np.ndarray) -> np.ndarray:
    """Solve ``N X = b`` with a factor from :func:`factor_normal_equations`."""
    cho, scale = fac
    b = np.asarray(b, dtype=float)
    s = scale if b.ndim == 1 else scale[:, None]
    return s * sla.cho_solve(cho, s * b)


class LinearModel:
    """Linear Gauss–Markov model ``l = A x + e``, ``D(e) = σ0² P⁻¹``.

    Parameters
    ----------
    A : (n, u) design matrix (numpy array or scipy.sparse matrix).
    l : (n,) observations.
    P : None (identity), (n,) diagonal weights, or (n, n) symmetric positive definite weights.
    sigma0 : a-priori standard deviation of unit weight.
    labels : (n,) observation labels (default ``"1" … "n"``).
    group : (n,) int group ids (x and y of one image point share a group; -1 for none).
    names : (u,) names of the unknowns, used in error messages (default ``"x1" … "xu"``).

    Inputs are copied; the model is immutable.
    """

    def __init__(self, A, l, P=None, sigma0: float = 1.0, labels=None, group=None, names=None):
        if sp.issparse(A):
            A = sp.csr_matrix(A, dtype=float, copy=True)
        else:
            A = np.array(A, dtype=float, copy=True)
            if A.ndim == 1:
                A = A[:, None]
            if A.ndim != 2:
                raise ValueError(f"A must be 2-D, got shape {A.shape}")
        n, u = A.shape
        l = np.array(l, dtype=float, copy=True).reshape(-1)
        if l.shape[0] != n:
            raise ValueError(f"l has {l.shape[0]} rows, A has {n}")
        if not np.all(np.isfinite(l)):
            raise ValueError("l contains non-finite values")
        if P is None:
            kind, Pm = "identity", np.ones(n)
        else:
            if sp.issparse(P):
                P = P.toarray()
            Pm = np.array(P, dtype=float, copy=True)
            if Pm.ndim == 1:
                if Pm.shape[0] != n:
                    raise ValueError(f"P has {Pm.shape[0]} weights, A has {n} rows")
                if not np.all(Pm > 0) or not np.all(np.isfinite(Pm)):
                    raise ValueError("diagonal weights P must be positive and finite")
                kind = "diag"
            elif Pm.shape == (n, n):
                if not np.allclose(Pm, Pm.T, rtol=1e-10, atol=1e-12 * np.abs(Pm).max()):
                    raise ValueError("full weight matrix P must be symmetric")
                Pm = 0.5 * (Pm + Pm.T)
                kind = "full"
            else:
                raise ValueError(f"P must be None, (n,) or (n, n); got shape {Pm.shape}")
        sigma0 = float(sigma0)
        if not sigma0 > 0:
            raise ValueError(f"sigma0 must be positive, got {sigma0}")
        self.A = A
        self.l = l
        self.P = Pm
        self.kind = kind
        self.sigma0 = sigma0
        self.n, self.u = n, u
        self.labels = np.array([str(i + 1) for i in range(n)] if labels is None else labels, dtype=str)
        self.group = np.full(n, -1, int) if group is None else np.array(group, dtype=int).reshape(-1)
        self.names = [f"x{j + 1}" for j in range(u)] if names is None else [str(s) for s in names]
        if self.labels.shape[0] != n or self.group.shape[0] != n or len(self.names) != u:
            raise ValueError("labels/group must have n entries and names u entries")
        self._Sigma = None
        if kind == "full":
            try:
                cho = sla.cho_factor(Pm)
            except np.linalg.LinAlgError as e:
                raise ValueError("full weight matrix P is not positive definite") from e
            self._Sigma = sla.cho_solve(cho, np.eye(n))
            self._Sigma = 0.5 * (self._Sigma + self._Sigma.T)

    # ------------------------------------------------------------------ helpers
    def _active(self, active) -> np.ndarray:
        if active is None:
            return np.ones(self.n, bool)
        act = np.array(active, dtype=bool, copy=True).reshape(-1)
        if act.shape[0] != self.n:
            raise ValueError(f"active has {act.shape[0]} entries, model has {self.n} rows")
        return act

    def _rows(self, idx):
        return self.A[idx]

    def weights_active(self, active=None):
        """Weight matrix of the active rows: (n_a,) vector or (n_a, n_a) matrix ``(Σ_aa)⁻¹``."""
        act = self._active(active)
        idx = np.flatnonzero(act)
        if self.kind != "full":
            return self.P[idx]
        if idx.size == self.n:
            return self.P
        S = self._Sigma[np.ix_(idx, idx)]
        return sla.cho_solve(sla.cho_factor(S), np.eye(idx.size))

    def weighted_design(self, active=None) -> np.ndarray:
        """Dense (n, u) ``P_a A_a`` scattered to the full row space (zero rows for inactive)."""
        act = self._active(active)
        idx = np.flatnonzero(act)
        Aa = self._rows(idx)
        Pa = self.weights_active(act)
        B = self._weight(Aa, Pa)
        out = np.zeros((self.n, self.u))
        out[idx] = B.toarray() if sp.issparse(B) else B
        return out

    def _weight(self, Aa, Pa):
        if self.kind == "full":
            return Pa @ (Aa.toarray() if sp.issparse(Aa) else Aa)
        if sp.issparse(Aa):
            return sp.diags(Pa) @ Aa
        return Aa * Pa[:, None]

    def normal_matrix(self, active=None) -> np.ndarray:
        """Dense ``N = A_aᵀ P_a A_a``."""
        act = self._active(active)
        idx = np.flatnonzero(act)
        Aa = self._rows(idx)
        B = self._weight(Aa, self.weights_active(act))
        N = Aa.T @ B
        N = N.toarray() if sp.issparse(N) else np.asarray(N)
        return 0.5 * (N + N.T)

    # ------------------------------------------------------------------ adjustment
    def adjust(self, active=None) -> LinearAdjustment:
        """Least-squares adjustment using the rows where ``active`` is True (default: all)."""
        act = self._active(active)
        idx = np.flatnonzero(act)
        n, u = self.n, self.u
        Aa = self._rows(idx)
        la = self.l[idx]
        Pa = self.weights_active(act)
        B = self._weight(Aa, Pa)  # P_a A_a
        N = Aa.T @ B
        N = N.toarray() if sp.issparse(N) else np.asarray(N)
        N = 0.5 * (N + N.T)
        fac = factor_normal_equations(N, self.names)
        x = solve_normal(fac, np.asarray(B.T @ la).reshape(-1))
        Qxx = solve_normal(fac, np.eye(u))
        Qxx = 0.5 * (Qxx + Qxx.T)

        Ax = np.asarray(self.A @ x).reshape(-1)
        v_pred = self.l - Ax
        va = v_pred[idx]
        Pv_a = Pa * va if self.kind != "full" else Pa @ va
        vtpv = float(va @ Pv_a)
        dof = int(idx.size - u)

        AQ = np.asarray(Aa @ Qxx)  # (n_a, u)
        h = _rowdot(B, AQ)  # (A Qxx Aᵀ P)_ii
        r_a = 1.0 - h
        if self.kind == "full":
            PQvvP_a = np.diag(Pa) - _rowdot(B, np.asarray(B @ Qxx))
            sig2 = np.diag(self._Sigma)
        else:
            PQvvP_a = Pa * r_a
            sig2 = 1.0 / self.P
        PQvvP_a = np.maximum(PQvvP_a, 0.0)

        v = np.zeros(n)
        v[idx] = va
        Pv = np.zeros(n)
        Pv[idx] = Pv_a
        PQvvP = np.zeros(n)
        PQvvP[idx] = PQvvP_a
        r = np.zeros(n)
        r[idx] = r_a

        # predicted residuals of inactive rows and their standard deviation
        sigma_v_pred = np.full(n, np.nan)
        out = np.flatnonzero(~act)
        if out.size:
            Ao = self._rows(out)
            var = sig2[out] + _rowdot(Ao, np.asarray(Ao @ Qxx))
            if self.kind == "full":
                # − 2 Cov(l_o, a_o x̂):  Cov(l_o, x̂) = Σ_oa P_a A_a Qxx
                Bd = B if not sp.issparse(B) else B.toarray()
                C = self._Sigma[np.ix_(out, idx)] @ (Bd @ Qxx)
                var -= 2.0 * _rowdot(Ao, C)
            sigma_v_pred[out] = self.sigma0 * np.sqrt(np.maximum(var, 0.0))

        blocks = self._blocks(idx, Pa, B, Qxx)
        snap = Snapshot(
            v=v, Pv=Pv, PQvvP=PQvvP, r=r, sigma_l=self.sigma0 * np.sqrt(sig2),
            vtpv=vtpv, dof=dof, sigma0=self.sigma0, active=act, labels=self.labels,
            group=self.group, PQvvP_blocks=blocks,
            meta={"model": "LinearModel", "weights": self.kind, "u": u},
            v_pred=v_pred, sigma_v_pred=sigma_v_pred)
        s0h = float(np.sqrt(vtpv / dof)) if dof > 0 else float("nan")
        v.flags.writeable = False
        return LinearAdjustment(x=x, v=v, v_pred=v_pred, Qxx=Qxx, snapshot=snap, dof=dof,
                                sigma0_hat=s0h, active=act)

    def _blocks(self, idx, Pa, B, Qxx) -> GroupBlocks | None:
        """2×2 blocks of P Qvv P for groups with exactly two active rows."""
        grp = self.group[idx]
        gids, pairs = pair_rows(grp)
        if gids.size == 0:
            return None
        i0, i1 = pairs[:, 0], pairs[:, 1]  # local (active) row indices, increasing order
        Bd = B.toarray() if sp.issparse(B) else np.asarray(B)
        BQ0, BQ1 = Bd[i0] @ Qxx, Bd[i1] @ Qxx
        q00 = np.einsum("ij,ij->i", BQ0, Bd[i0])
        q01 = np.einsum("ij,ij->i", BQ0, Bd[i1])
        q11 = np.einsum("ij,ij->i", BQ1, Bd[i1])
        if self.kind == "full":
            p00, p01, p11 = Pa[i0, i0], Pa[i0, i1], Pa[i1, i1]
        else:
            p00, p01, p11 = Pa[i0], np.zeros(i0.size), Pa[i1]
        blk = np.empty((i0.size, 2, 2))
        blk[:, 0, 0] = p00 - q00
        blk[:, 0, 1] = blk[:, 1, 0] = p01 - q01
        blk[:, 1, 1] = p11 - q11
        return GroupBlocks(grp[i0], blk)

    def refit(self, active) -> Snapshot:
        """Adjust again with the rows where ``active`` is True; return the snapshot (Refittable)."""
        return self.adjust(active).snapshot
