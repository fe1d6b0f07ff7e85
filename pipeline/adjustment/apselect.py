"""Selection of additional parameters: the paper's correlation rule, then significance tests.

1. **Correlation** (paper 001, §3.2.2): adjust with every candidate AP free; among the
   correlations of each camera's parameters (AP–AP and AP–c/xp/yp) take the largest |ρ|.  If
   it exceeds ``rho_max`` (0.75), remove one parameter of that pair — the **AP with the smaller
   |t| = |estimate / σ|** (the less significant one; if the partner is c, xp or yp, which are
   never removed, the AP goes) — and adjust again.  Repeat until no |ρ| > rho_max.
2. **Significance**: every remaining AP gets ``t = estimate / σ`` (a-posteriori σ) and is compared
   with the two-sided critical value of Student's t with the adjustment's degrees of freedom at
   level ``alpha``.  With ``significance = "remove"`` the least significant AP is removed and the
   block adjusted again, one at a time, until all remaining APs are significant; with
   ``"report"`` they are only reported.

A removed AP is fixed at 0 (a-priori σ = 0).  Only APs that were free (σ = inf) at the start are
candidates; weighted or fixed ones are left as they are.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from baarda.pipeline.model import Block

from .adjust import BundleResult, adjust, padded_ap
from .settings import BundleSettings

__all__ = ["APSelection", "select_aps"]


@dataclass
class APSelection:
    """What the selection did, step by step, and the final result."""

    result: BundleResult
    steps: list = field(default_factory=list)        # dicts: camera, parameter, rule, reason
    kept: list = field(default_factory=list)         # dicts: camera, parameter, value, sigma, t, significant
    rho_max: float = 0.75
    alpha: float = 0.05
    critical_t: float = float("nan")

    def summary(self) -> dict:
        return {"rho_max": self.rho_max, "alpha": self.alpha, "critical_t": self.critical_t,
                "removed": [f"{s['camera']}:{s['parameter']}" for s in self.steps],
                "kept": [f"{k['camera']}:{k['parameter']}" for k in self.kept]}

    def markdown(self) -> str:
        lines = [f"AP selection: remove |ρ| > {self.rho_max:g} one after another (the AP of the pair with the "
                 f"smaller |t| goes), then t-test at α = {self.alpha:g} (|t| > {self.critical_t:.3f}).", ""]
        if self.steps:
            lines += ["| step | camera | removed | rule | reason |", "|---|---|---|---|---|"]
            for i, s in enumerate(self.steps, 1):
                lines.append(f"| {i} | {s['camera']} | {s['parameter']} | {s['rule']} | {s['reason']} |")
        else:
            lines.append("No parameter removed.")
        lines += ["", "| camera | kept | value | σ | t | significant |", "|---|---|---|---|---|---|"]
        for k in self.kept:
            lines.append(f"| {k['camera']} | {k['parameter']} | {k['value']:.6g} | {k['sigma']:.3g} | "
                         f"{k['t']:.2f} | {'yes' if k['significant'] else 'no'} |")
        return "\n".join(lines)


def _candidates(block: Block, res: BundleResult) -> list[tuple[int, int]]:
    """(camera, column in the camera vector ≥ 3) of APs that are free unknowns."""
    prob = res.problem
    out = []
    for j in range(prob.K):
        for t in range(3, 3 + prob.models[j].n_params):
            if np.isinf(prob.cam_sigma[j, t]) and prob.g_cam[j, t] >= 0:
                out.append((j, t))
    return out


def _fix(block: Block, j: int, t: int) -> Block:
    """``block`` with AP column ``t − 3`` of camera ``j`` fixed at 0 (other values untouched)."""
    ap, sig = padded_ap(block.cameras)
    ap[j, t - 3] = 0.0
    sig[j, t - 3] = 0.0
    return block.replace(cameras=block.cameras.replace(ap=ap, sigma_ap=sig))


def _t_values(res: BundleResult, cands):
    out = {}
    for j, t in cands:
        sd = float(np.sqrt(max(res.cov_cameras[j][t, t], 0.0)))
        val = float(res.state.cam_params[j, t])
        out[(j, t)] = (val, sd, abs(val) / sd if sd > 0 else np.inf)
    return out


def select_aps(block: Block, settings: BundleSettings | None = None, *, rho_max: float = 0.75,
               alpha: float = 0.05, significance: str = "remove", result: BundleResult | None = None,
               max_steps: int = 100) -> APSelection:
    """Run the paper's AP selection (see module docstring); returns :class:`APSelection`.

    ``result`` may be the adjustment of ``block`` with all candidates free (saves one run).
    """
    if significance not in ("remove", "report"):
        raise ValueError("significance must be 'remove' or 'report'")
    settings = settings or BundleSettings()
    res = result or adjust(block, settings)
    cur = block
    steps = []
    names = res.cam_param_names
    cam_ids = block.cameras.ids
    # 1. correlation rule
    for _ in range(max_steps):
        cands = _candidates(cur, res)
        if not cands:
            break
        tv = _t_values(res, cands)
        best = None
        for j in sorted({c[0] for c in cands}):
            R = np.abs(res.correlation_camera(j))
            np.fill_diagonal(R, 0.0)
            free_t = [t for (jj, t) in cands if jj == j]
            for a in free_t:
                for b in range(R.shape[0]):
                    if b == a or R[a, b] <= rho_max:
                        continue
                    if b >= 3 and (j, b) not in tv:
                        continue          # partner fixed/weighted: not a candidate pair
                    if best is None or R[a, b] > best[0]:
                        best = (R[a, b], j, a, b)
        if best is None:
            break
        rho, j, a, b = best
        if b < 3:
            drop, keep = a, b
            why = (f"|ρ| = {rho:.3f} with {names[j][b]} (interior orientation is kept)")
        else:
            ta, tb = tv[(j, a)][2], tv[(j, b)][2]
            drop, keep = (a, b) if ta <= tb else (b, a)
            why = (f"|ρ| = {rho:.3f} with {names[j][keep]}; |t| {tv[(j, drop)][2]:.2f} ≤ {tv[(j, keep)][2]:.2f}")
        steps.append({"camera": str(cam_ids[j]), "parameter": names[j][drop], "rule": "correlation",
                      "reason": why, "rho": float(rho), "partner": names[j][keep]})
        cur = _fix(cur, j, drop)
        res = adjust(cur, settings, start=_start(res, j, drop))
    # 2. significance
    crit = float(stats.t.isf(alpha / 2, max(res.dof, 1)))
    for _ in range(max_steps):
        cands = _candidates(cur, res)
        tv = _t_values(res, cands)
        weak = [(v[2], c) for c, v in tv.items() if v[2] <= crit]
        if significance == "report" or not weak:
            break
        tmin, (j, t) = min(weak)
        steps.append({"camera": str(cam_ids[j]), "parameter": names[j][t], "rule": "significance",
                      "reason": f"|t| = {tmin:.2f} ≤ {crit:.3f} (α = {alpha:g})", "t": float(tmin)})
        cur = _fix(cur, j, t)
        res = adjust(cur, settings, start=_start(res, j, t))
        crit = float(stats.t.isf(alpha / 2, max(res.dof, 1)))
    kept = []
    for (j, t), (val, sd, tt) in sorted(_t_values(res, _candidates(cur, res)).items()):
        kept.append({"camera": str(cam_ids[j]), "parameter": names[j][t], "value": val, "sigma": sd, "t": tt,
                     "significant": bool(tt > crit)})
    return APSelection(result=res, steps=steps, kept=kept, rho_max=rho_max, alpha=alpha, critical_t=crit)


def _start(res: BundleResult, j: int, t: int):
    st = res.state.copy()
    st.cam_params[j, t] = 0.0
    return st
