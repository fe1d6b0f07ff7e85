"""Sparse symmetric positive-definite systems: a fill-reducing ordering, a supernodal multifrontal
Cholesky factorisation, solves, and the selected inversion of the factor (the entries of the
inverse on the factor's pattern, front by front).

Used for the reduced camera system of large blocks (``docs/bundle.md``, "Sparse route").  The
unknowns come in *nodes* (the parameters of one photo, one camera, one scale-bar point): the
ordering and the symbolic analysis work on the graph of nodes, the numerics on dense fronts.

Ordering
    METIS nested dissection (``pymetis``) of the graph of the ordinary nodes; the nodes listed in
    ``last`` (camera parameters, which couple to every photo of their camera) are ordered last.
Symbolic analysis
    The elimination tree of the node graph and the structure of every column of the factor; chains
    of nodes with nested structures are merged into supernodes (fundamental supernodes).
Factorisation
    Multifrontal: each supernode assembles its front from the matrix and its children's update
    matrices, factors the diagonal block (LAPACK ``potrf``) and hands the Schur complement to its
    parent.  ``K = L Lᵀ`` in the permuted order.  The assembly, the extend-add and the selected
    inversion's gather of ``Z_RR`` are compiled kernels (``kernels.front``, ``extend_add``,
    ``gather_block``; the same sums in the same order as the numpy indexing they replace).
Selected inversion
    Takahashi's equations per supernode, root first: with ``L̂_RJ = L_RJ L_JJ⁻¹``,
    ``Z_RJ = −Z_RR L̂_RJ`` and ``Z_JJ = L_JJ⁻ᵀ L_JJ⁻¹ − L̂_RJᵀ Z_RJ``; ``Z_RR`` is gathered from the
    parent's front.  Every front's block of ``K⁻¹`` (its columns and its row structure: a clique of
    the filled graph) is handed to a visitor and then dropped once its children have used it, so
    memory stays that of the fronts along one path of the tree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pymetis
import scipy.linalg as sla
import scipy.sparse as sp
from scipy.linalg import lapack
from threadpoolctl import threadpool_limits

from . import kernels

__all__ = ["Symbolic", "SupernodalCholesky", "NotPositiveDefinite", "nested_dissection"]

class NotPositiveDefinite(Exception):
    """The matrix is singular or indefinite; ``column`` is the original index of the first column
    whose pivot failed."""

    def __init__(self, column: int):
        super().__init__(f"pivot of column {column} is not positive")
        self.column = int(column)


def nested_dissection(adj: sp.csr_matrix) -> np.ndarray:
    """Fill-reducing order (new position → node) of a symmetric graph without self loops, by METIS
    nested dissection; the identity for graphs too small to matter."""
    n = adj.shape[0]
    if n < 8 or adj.nnz == 0:
        return np.arange(n)
    graph = pymetis.CSRAdjacency(adj.indptr.astype(np.int64), adj.indices.astype(np.int64))
    perm, _ = pymetis.nested_dissection(adjacency=graph)
    return np.asarray(perm, dtype=np.intp)


@dataclass
class Symbolic:
    """Ordering and supernodal structure of a symmetric pattern.

    ``perm[i]``: original column at position ``i``; ``ipos``: its inverse.  Supernode ``s`` holds the
    positions ``start[s]:start[s + 1]``; ``rows[s]`` are the (sorted) positions of its off-diagonal
    rows; ``parent[s]`` (−1 for a root); ``rel[s]``: where ``rows[s]`` sit in the parent's front
    (its own columns followed by its rows)."""

    n: int
    perm: np.ndarray
    ipos: np.ndarray
    start: np.ndarray
    rows: list
    parent: np.ndarray
    rel: list
    n_children: np.ndarray

    @property
    def n_super(self) -> int:
        return len(self.start) - 1

    @property
    def nnz_factor(self) -> int:
        w = np.diff(self.start)
        nr = np.array([len(r) for r in self.rows])
        return int(np.sum(w * (w + 1) // 2 + w * nr))

    @property
    def flops(self) -> float:
        """Floating-point operations of one factorisation (≈)."""
        w = np.diff(self.start).astype(float)
        nr = np.array([len(r) for r in self.rows], float)
        return float(np.sum(w ** 3 / 3 + w * w * nr + w * nr * nr))

    def max_front(self) -> int:
        return int(max((len(r) + int(w) for r, w in zip(self.rows, np.diff(self.start))), default=0))

    @classmethod
    def analyse(cls, pattern: sp.spmatrix, node_of_col: np.ndarray, last_nodes=()) -> "Symbolic":
        """``pattern``: symmetric (n × n) sparsity; ``node_of_col``: the node of every column (nodes
        numbered 0 … N−1, each column in exactly one); ``last_nodes``: nodes ordered last."""
        n = pattern.shape[0]
        node_of_col = np.asarray(node_of_col, np.intp)
        N = int(node_of_col.max()) + 1 if n else 0
        Pn = sp.csr_matrix((np.ones(n), (node_of_col, np.arange(n))), shape=(N, n))
        pat = sp.csr_matrix(pattern, copy=True)
        pat.data = np.ones_like(pat.data, dtype=float)
        A = (Pn @ pat @ Pn.T).tocsr()
        A.setdiag(0)
        A.eliminate_zeros()
        last = np.zeros(N, bool)
        last[np.asarray(list(last_nodes), np.intp)] = True
        first = np.flatnonzero(~last)
        sub = A[first][:, first].tocsr()
        order = np.concatenate([first[nested_dissection(sub)], np.flatnonzero(last)])
        npos = np.empty(N, np.intp)
        npos[order] = np.arange(N)
        Ap = A[order][:, order].tocsr()
        # node-level symbolic factorisation: struct(j) = higher neighbours ∪ children's structs − {j}
        struct: list = [None] * N
        kids: list = [[] for _ in range(N)]
        sn_of = np.empty(N, np.intp)
        sn_first: list[int] = []
        ind, ptr = Ap.indices, Ap.indptr
        for j in range(N):
            nb = ind[ptr[j]:ptr[j + 1]]
            s = set(nb[nb > j].tolist())
            ch = kids[j]
            for c in ch:
                s |= struct[c]
            s.discard(j)
            if len(ch) == 1 and len(struct[ch[0]]) == len(s) + 1:
                sn_of[j] = sn_of[ch[0]]                  # same supernode as its only child
                struct[ch[0]] = None
            else:
                sn_of[j] = len(sn_first)           # a new supernode; the children's structs stay
                sn_first.append(j)                 # (each child is the last node of its supernode)
            struct[j] = s
            if s:
                kids[min(s)].append(j)
        # columns: nodes in order, each node's columns together
        cols_of_node = np.argsort(node_of_col, kind="stable")
        cnt = np.bincount(node_of_col, minlength=N)
        cstart = np.r_[0, np.cumsum(cnt)]
        perm = np.concatenate([cols_of_node[cstart[v]:cstart[v + 1]] for v in order]) if N else np.zeros(0, np.intp)
        ipos = np.empty(n, np.intp)
        ipos[perm] = np.arange(n)
        ncol_pos = cnt[order]                                       # columns of the node at each position
        node_col0 = np.r_[0, np.cumsum(ncol_pos)]                  # first column position of each node position
        S = len(sn_first)
        sn_last = np.r_[np.asarray(sn_first[1:], np.intp) - 1, N - 1] if S else np.zeros(0, np.intp)
        start = np.r_[node_col0[np.asarray(sn_first, np.intp)], n] if S else np.zeros(1, np.intp)
        rows, parent = [], np.full(S, -1, np.intp)
        for s in range(S):
            st = struct[sn_last[s]]
            nodes = np.array(sorted(st), np.intp)
            if len(nodes):
                r = np.concatenate([np.arange(node_col0[v], node_col0[v + 1]) for v in nodes])
                parent[s] = sn_of[nodes[0]]
            else:
                r = np.zeros(0, np.intp)
            rows.append(r)
        rel = []
        for s in range(S):
            p = parent[s]
            if p < 0:
                rel.append(np.zeros(0, np.intp))
                continue
            front = np.concatenate([np.arange(start[p], start[p + 1]), rows[p]])
            loc = np.searchsorted(front, rows[s])
            if not np.array_equal(front[np.minimum(loc, len(front) - 1)], rows[s]):  # pragma: no cover
                raise AssertionError("symbolic analysis: a child's rows are not in its parent's front")
            rel.append(loc)
        n_children = np.bincount(parent[parent >= 0], minlength=S) if S else np.zeros(0, np.intp)
        return cls(n=n, perm=perm, ipos=ipos, start=start, rows=rows, parent=parent, rel=rel,
                   n_children=n_children)


class SupernodalCholesky:
    """``K = L Lᵀ`` (in the order of ``sym``) of a symmetric positive-definite sparse matrix.

    ``K``: scipy sparse, symmetric (both triangles stored), in the original column order.
    ``pivot_tol``: a pivot below ``pivot_tol`` × the column's diagonal raises
    :class:`NotPositiveDefinite` (a numerically singular system)."""

    def __init__(self, sym: Symbolic, K: sp.spmatrix, pivot_tol: float = 1e-11):
        self.sym = sym
        p = sym.perm
        Kp = sp.csc_matrix(K)[p][:, p].tocsc()
        Kp.sort_indices()
        self._K = Kp
        self._diag = Kp.diagonal()
        self._tol = pivot_tol
        S = sym.n_super
        self.L11: list = [None] * S
        self.L21: list = [None] * S
        self._upd: dict = {}
        self._pending: dict = {}
        with _blas(1):
            for s in range(S):
                self._factor_step(s)
        del self._K, self._upd, self._pending

    def _factor_step(self, s: int) -> None:
        sym = self.sym
        Kp = self._K
        indptr, indices, data = Kp.indptr, Kp.indices, Kp.data
        c0, c1 = int(sym.start[s]), int(sym.start[s + 1])
        ns = c1 - c0
        R = sym.rows[s]
        F = kernels.front(indptr, indices, data, c0, c1, R)   # compiled, GIL released
        for c in sorted(self._pending.pop(s, ())):           # fixed order of the sums
            kernels.extend_add(F, sym.rel[c], self._upd.pop(c))
        L11, info = lapack.dpotrf(F[:ns, :ns], lower=1, clean=1, overwrite_a=0)
        diag = self._diag[c0:c1]
        d = np.diag(L11) ** 2 if info == 0 else None
        if info != 0 or (d < self._tol * np.maximum(diag, 1e-300)).any():
            k = info - 1 if info > 0 else int(np.argmax(d < self._tol * np.maximum(diag, 1e-300)))
            raise NotPositiveDefinite(int(sym.perm[c0 + max(k, 0)]))
        self.L11[s] = L11
        if len(R):
            L21 = _trsm(L11, F[ns:, :ns].T).T
            self.L21[s] = L21
            U = F[ns:, ns:]
            U -= L21 @ L21.T
            self._upd[s] = U
            self._pending.setdefault(int(sym.parent[s]), []).append(s)
        else:
            self.L21[s] = np.zeros((0, ns))

    # ------------------------------------------------------------------------------------------
    def solve(self, b: np.ndarray) -> np.ndarray:
        """``K⁻¹ b`` for b (n,) or (n, k) in the original order."""
        sym = self.sym
        x = np.array(b, float)[sym.perm]
        for s in range(sym.n_super):
            c0, c1 = sym.start[s], sym.start[s + 1]
            y = sla.solve_triangular(self.L11[s], x[c0:c1], lower=True, check_finite=False)
            x[c0:c1] = y
            if len(sym.rows[s]):
                x[sym.rows[s]] -= self.L21[s] @ y
        for s in range(sym.n_super - 1, -1, -1):
            c0, c1 = sym.start[s], sym.start[s + 1]
            y = x[c0:c1]
            if len(sym.rows[s]):
                y = y - self.L21[s].T @ x[sym.rows[s]]
            x[c0:c1] = sla.solve_triangular(self.L11[s], y, lower=True, trans="T", check_finite=False)
        out = np.empty_like(x)
        out[sym.perm] = x
        return out

    def logdet(self) -> float:
        return float(2.0 * sum(np.sum(np.log(np.diag(L))) for L in self.L11))

    # ------------------------------------------------------------------------------------------
    def selected_inverse(self, visit) -> None:
        """Call ``visit(s, front, Z)`` for every supernode, a parent before its children: ``front``
        the original column indices of the supernode's columns followed by its rows, ``Z`` the dense
        block of ``K⁻¹`` on them (the front's own copy: the visitor may keep it)."""
        sym = self.sym
        self._fronts: dict = {}
        self._left = sym.n_children.copy()
        with _blas(1):
            for s in range(sym.n_super - 1, -1, -1):
                self._inverse_step(s, visit)
        del self._fronts, self._left

    def _inverse_step(self, s: int, visit) -> None:
        sym = self.sym
        c0, c1 = int(sym.start[s]), int(sym.start[s + 1])
        ns = c1 - c0
        R = sym.rows[s]
        nr = len(R)
        Linv = _trsm(self.L11[s], np.eye(ns))
        Z = np.empty((ns + nr, ns + nr))
        if nr:
            p = int(sym.parent[s])
            ZRR = kernels.gather_block(self._fronts[p], sym.rel[s])   # compiled, GIL released
            self._left[p] -= 1
            if self._left[p] == 0:
                del self._fronts[p]
            Lh = self.L21[s] @ Linv                       # L̂_RJ = L_RJ L_JJ⁻¹
            ZRJ = -(ZRR @ Lh)
            ZJJ = Linv.T @ Linv - Lh.T @ ZRJ
            Z[ns:, ns:] = ZRR
            Z[ns:, :ns] = ZRJ
            Z[:ns, ns:] = ZRJ.T
        else:
            ZJJ = Linv.T @ Linv
        Z[:ns, :ns] = 0.5 * (ZJJ + ZJJ.T)
        if self._left[s] > 0:
            self._fronts[s] = Z
        visit(s, sym.perm[np.r_[np.arange(c0, c1), R].astype(np.intp)], Z)


def _trsm(L, B):
    """``L⁻¹ B`` for the lower-triangular, Fortran-ordered ``L`` of ``potrf``: LAPACK ``trtrs``, the
    routine ``scipy.linalg.solve_triangular`` calls (same result, bit for bit), without its
    Python-side checks, which took longer than a small front's solve.  scipy's ``trtrs`` wrapper
    holds the GIL while it runs (two threads: no faster than one, measured)."""
    x, info = lapack.dtrtrs(L, B, lower=1)
    if info != 0:  # pragma: no cover - potrf's pivots were checked
        raise np.linalg.LinAlgError(f"trtrs: info {info}")
    return x


def _blas(n: int):
    """BLAS/OpenMP pools limited to ``n`` threads for the block (threadpoolctl).

    The sparse route keeps BLAS single-threaded everywhere, the top fronts included: two OpenBLAS
    threads were slower than one for every front size measured on the 2-core machine (a front's
    potrf + trsm + syrk: 8 ms fixed cost per call, 1.4× slower even at 2 000 columns; the top
    fronts with two BLAS threads made a 2 000-photo block 7–26 % slower in all, 1 000 photos 17–30 %).
    The route itself runs on one Python thread (independent subtrees on threads were measured not
    to pay: ``docs/benchmarks.md``, "Threads")."""
    return threadpool_limits(limits=max(1, int(n)))
