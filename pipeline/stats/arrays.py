"""Build a :class:`Snapshot` from arrays an adjustment computed itself (bundle, nonlinear models).

The adjustment supplies residuals, weights and the cofactor matrix of the residuals in the form it
has them: diagonal, or 2×2 blocks per image point (correlated x, y).  Everything is O(n).
"""

from __future__ import annotations

import numpy as np

from baarda.pipeline.stats.snapshot import GroupBlocks, Snapshot, group_rows, pair_rows

__all__ = ["snapshot_from_arrays"]


def _pair_rows(group: np.ndarray, n_blocks: int, name: str) -> tuple[np.ndarray, np.ndarray]:
    ids, _, counts, _ = group_rows(group)
    if np.any(counts != 2):
        raise ValueError(f"{name}: every group id >= 0 must have exactly two rows")
    if ids.size != n_blocks:
        raise ValueError(f"{name}: {n_blocks} blocks for {ids.size} groups")
    return pair_rows(group)


def snapshot_from_arrays(v, dof: int, *, p=None, P_blocks=None, qvv=None, Qvv_blocks=None,
                         group=None, sigma0: float = 1.0, active=None, labels=None,
                         vtpv_extra: float = 0.0, meta: dict | None = None) -> Snapshot:
    """Snapshot from residuals, weights and residual cofactors.

    Parameters
    ----------
    v : (n,) residuals observed − computed (values on inactive rows are ignored → 0).
    dof : degrees of freedom of the adjustment (observations + constraints − unknowns).
    p : (n,) diagonal weights (default 1) — or
    P_blocks : (m, 2, 2) weight blocks, one per group, groups in increasing id order, rows of a
        group in increasing row order (correlated x, y of an image point).
    qvv : (n,) diagonal of Qvv — or
    Qvv_blocks : (m, 2, 2) blocks of Qvv for the same groups (needed for the joint 2-D test and
        for correct w with correlated weights; rows outside groups then need ``qvv``).
    group : (n,) int group ids, required with blocks (two rows per id >= 0, -1 for single rows).
    vtpv_extra : contribution of weighted constraints / pseudo-observations to vᵀPv.

    With blocks, ``Pv``, ``P Qvv P`` (diagonal and 2×2 blocks) and ``r = (Qvv P)_ii`` are formed
    per block; ``sigma_l = σ0 √(P⁻¹)_ii``.
    """
    v = np.array(v, dtype=float).reshape(-1)
    n = v.shape[0]
    act = np.ones(n, bool) if active is None else np.array(active, bool).reshape(-1)
    v = np.where(act, v, 0.0)
    grp = np.full(n, -1, int) if group is None else np.array(group, int).reshape(-1)
    pd = np.ones(n) if p is None else np.array(p, dtype=float).reshape(-1)
    qd = None if qvv is None else np.array(qvv, dtype=float).reshape(-1)
    if qd is None and Qvv_blocks is None:
        raise ValueError("snapshot_from_arrays needs qvv or Qvv_blocks")
    Pv = pd * v
    sig2 = 1.0 / pd
    PQvvP = np.zeros(n)
    r = np.zeros(n)
    if qd is not None:
        PQvvP = pd * pd * qd
        r = qd * pd
    blocks = None
    if P_blocks is not None or Qvv_blocks is not None:
        m = len(P_blocks) if P_blocks is not None else len(Qvv_blocks)
        gids, rows = _pair_rows(grp, m, "blocks")
        Pb = np.zeros((m, 2, 2))
        if P_blocks is None:
            Pb[:, 0, 0], Pb[:, 1, 1] = pd[rows[:, 0]], pd[rows[:, 1]]
        else:
            Pb = np.array(P_blocks, dtype=float).reshape(m, 2, 2)
        if Qvv_blocks is None:
            if qd is None:
                raise ValueError("rows in groups need Qvv_blocks or qvv")
            Qb = np.zeros((m, 2, 2))
            Qb[:, 0, 0], Qb[:, 1, 1] = qd[rows[:, 0]], qd[rows[:, 1]]
        else:
            Qb = np.array(Qvv_blocks, dtype=float).reshape(m, 2, 2)
        vg = v[rows]  # (m, 2)
        Pv[rows] = np.einsum("mij,mj->mi", Pb, vg)
        PQP = Pb @ Qb @ Pb
        QP = Qb @ Pb
        PQvvP[rows[:, 0]], PQvvP[rows[:, 1]] = PQP[:, 0, 0], PQP[:, 1, 1]
        r[rows[:, 0]], r[rows[:, 1]] = QP[:, 0, 0], QP[:, 1, 1]
        det = Pb[:, 0, 0] * Pb[:, 1, 1] - Pb[:, 0, 1] ** 2
        sig2[rows[:, 0]], sig2[rows[:, 1]] = Pb[:, 1, 1] / det, Pb[:, 0, 0] / det
        if Qvv_blocks is not None:
            live = act[rows].all(axis=1)
            blocks = GroupBlocks(gids[live], PQP[live])
    PQvvP = np.where(act, PQvvP, 0.0)
    r = np.where(act, r, 0.0)
    Pv = np.where(act, Pv, 0.0)
    vtpv = float(v @ Pv) + float(vtpv_extra)
    return Snapshot(v=v, Pv=Pv, PQvvP=PQvvP, r=r, sigma_l=sigma0 * np.sqrt(sig2), vtpv=vtpv,
                    dof=int(dof), sigma0=float(sigma0), active=act, labels=labels, group=grp,
                    PQvvP_blocks=blocks, meta=dict(meta or {}))
