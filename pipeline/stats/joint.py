"""Joint test of the two coordinates of an image point (Förstner 1985; Baarda 1968, b = 2).

For a group g (the x and y rows of one image point) with the 2×2 block ``B_g = (P Qvv P)_gg``:

    T_g = (Pv)_gᵀ B_g⁻¹ (Pv)_g / σ0²  ~ χ²(2) under H0,

the w-test generalised to a 2-D bias (both coordinates of the point wrong).  Needs
``Snapshot.PQvvP_blocks`` (filled by :class:`~baarda.pipeline.stats.linear.LinearModel` and
:func:`~baarda.pipeline.stats.arrays.snapshot_from_arrays`).  Groups whose block is singular (a point
without redundancy, or with its residuals in one direction: :data:`SINGULAR_BLOCK`) get ``T = nan``
and are not flagged.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from baarda.pipeline.stats.snapshot import GroupBlocks, Snapshot, pair_rows

__all__ = ["JointTestResult", "joint_test_2d", "SINGULAR_BLOCK"]

SINGULAR_BLOCK = 1e-6
"""A block with ``det B < SINGULAR_BLOCK · B_xx B_yy`` (correlation |ρ| above 0.9999995) is taken as
singular: its residuals live in one direction (e.g. a point of two rays, whose single redundancy
is shared by the four coordinates), the 2-D test does not exist, and the determinant left is
rounding — a threshold of 1e-10 let COLMAP two-ray points through with T from noise (0.19, 5.6
from one run to the next)."""


@dataclass(frozen=True, eq=False)
class JointTestResult:
    groups: np.ndarray  # (m,) group ids tested
    rows: np.ndarray  # (m, 2) row indices (increasing)
    T: np.ndarray  # (m,) χ²(2) statistics
    critical: float  # χ²(1 − α; 2)
    p_value: np.ndarray
    flagged: np.ndarray  # (m,) bool
    alpha: float
    labels: np.ndarray = field(repr=False)

    @property
    def flagged_groups(self) -> list[int]:
        return [int(g) for g in self.groups[self.flagged]]

    def summary(self) -> dict:
        return {"alpha": self.alpha, "critical": self.critical, "n_tested": int(self.groups.size),
                "flagged": [[str(self.labels[i]) for i in r] for r in self.rows[self.flagged]]}


def joint_test_2d(snap: Snapshot, alpha: float = 0.001) -> JointTestResult:
    """Joint χ²(2) test of every group with two active rows (image point x, y)."""
    groups, rows = pair_rows(np.where(snap.active, snap.group, -1))
    blocks = GroupBlocks.of(snap.PQvvP_blocks)
    have = blocks.has(groups)
    if not have.all():
        missing = [int(g) for g in groups[~have]]
        raise ValueError(f"joint_test_2d needs Snapshot.PQvvP_blocks for every 2-row group; "
                         f"missing for {len(missing)} group(s), e.g. {missing[:5]}")
    B = blocks.take(groups)
    g = snap.Pv[rows] if rows.size else np.zeros((0, 2))
    det = B[:, 0, 0] * B[:, 1, 1] - B[:, 0, 1] * B[:, 1, 0]
    scale = np.maximum(B[:, 0, 0] * B[:, 1, 1], 1e-300)
    ok = det > SINGULAR_BLOCK * scale
    with np.errstate(invalid="ignore", divide="ignore"):
        T = (B[:, 1, 1] * g[:, 0] ** 2 - 2 * B[:, 0, 1] * g[:, 0] * g[:, 1]
             + B[:, 0, 0] * g[:, 1] ** 2) / det / snap.sigma0 ** 2
    T = np.where(ok, T, np.nan)
    crit = float(stats.chi2.isf(alpha, 2))
    p = stats.chi2.sf(T, 2)
    flagged = ok & (T > crit)
    return JointTestResult(groups, rows, T, crit, p, flagged, float(alpha), snap.labels)
