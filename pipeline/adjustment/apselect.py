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

When the block cannot be adjusted with every candidate free (a singular system: e.g. the test
field's minimal control), :func:`select_aps` with ``on_singular = "weak-priors"`` runs
:func:`select_aps_weak_priors` instead: the candidates (``c, xp, yp`` too) carry weak a-priori σ
while selecting, so that a singular combination shows as |ρ| → 1; correlations with every unknown
(exterior orientations too) count; the final adjustment has the kept ones free.  That procedure
works on the first camera of the block (the test field's single camera).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Literal

import numpy as np
from scipy import stats

from baarda.pipeline.errors import AdjustmentError
from baarda.pipeline.model import Block

from ..camera import get_ap_model
from .adjust import BundleResult, adjust, padded_ap
from .collinearity import IOP_NAMES
from .diagnose import parameter_names
from .settings import BundleSettings, camera_meta

__all__ = ["APSelection", "APRemoval", "APKept", "select_aps", "WeakPriorSelection", "select_aps_weak_priors"]


@dataclass(frozen=True)
class APRemoval:
    """One parameter the selection fixed: by which ``rule`` (``"correlation"`` or
    ``"significance"``) and why (``reason``, text); ``rho`` and its ``partner`` for a correlation,
    ``t`` for a significance step (nan / "" where they do not apply)."""

    camera: str
    parameter: str
    rule: str
    reason: str
    rho: float = float("nan")
    partner: str = ""
    t: float = float("nan")


@dataclass(frozen=True)
class APKept:
    """One parameter left free: its ``value``, ``sigma``, ``t`` and whether ``t`` is significant."""

    camera: str
    parameter: str
    value: float
    sigma: float
    t: float
    significant: bool


@dataclass(frozen=True, eq=False)
class APSelection:
    """What the selection did, step by step (:class:`APRemoval`), what it kept free
    (:class:`APKept`), and the final result."""

    result: BundleResult
    steps: tuple = ()
    kept: tuple = ()
    rho_max: float = 0.75
    alpha: float = 0.05
    critical_t: float = float("nan")
    method: str = "correlation"
    """``"correlation"`` (the procedure above) or ``"weak-priors"`` (:func:`select_aps_weak_priors`)."""

    def summary(self) -> dict:
        return {"rho_max": self.rho_max, "alpha": self.alpha, "critical_t": self.critical_t,
                "removed": [f"{s.camera}:{s.parameter}" for s in self.steps],
                "kept": [f"{k.camera}:{k.parameter}" for k in self.kept]}

    def markdown(self) -> str:
        lines = [f"AP selection: remove |ρ| > {self.rho_max:g} one after another (the AP of the pair with the "
                 f"smaller |t| goes), then t-test at α = {self.alpha:g} (|t| > {self.critical_t:.3f}).", ""]
        if self.steps:
            lines += ["| step | camera | removed | rule | reason |", "|---|---|---|---|---|"]
            for i, s in enumerate(self.steps, 1):
                lines.append(f"| {i} | {s.camera} | {s.parameter} | {s.rule} | {s.reason} |")
        else:
            lines.append("No parameter removed.")
        lines += ["", "| camera | kept | value | σ | t | significant |", "|---|---|---|---|---|---|"]
        for k in self.kept:
            lines.append(f"| {k.camera} | {k.parameter} | {k.value:.6g} | {k.sigma:.3g} | "
                         f"{k.t:.2f} | {'yes' if k.significant else 'no'} |")
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
               max_steps: int = 100, method: Literal["correlation", "weak-priors"] = "correlation",
               on_singular: Literal["error", "weak-priors"] = "error") -> APSelection:
    """Run the paper's AP selection (see module docstring); returns :class:`APSelection`.

    ``result`` may be the adjustment of ``block`` with all candidates free (saves one run).
    ``method = "weak-priors"`` runs :func:`select_aps_weak_priors` directly; ``on_singular =
    "weak-priors"`` runs it when the block is singular with every candidate free.
    """
    if significance not in ("remove", "report"):
        raise ValueError("significance must be 'remove' or 'report'")
    settings = settings or BundleSettings()
    if method == "weak-priors":
        return _from_weak_priors(block, settings, rho_max, alpha)
    if method != "correlation":
        raise ValueError("method must be 'correlation' or 'weak-priors'")
    if on_singular not in ("error", "weak-priors"):
        raise ValueError("on_singular must be 'error' or 'weak-priors'")
    try:
        return _select_correlation(block, settings, rho_max, alpha, significance, result, max_steps)
    except AdjustmentError:
        if on_singular == "error":
            raise
        return _from_weak_priors(block, settings, rho_max, alpha)


def _select_correlation(block, settings, rho_max, alpha, significance, result, max_steps) -> APSelection:
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
        steps.append(APRemoval(str(cam_ids[j]), names[j][drop], "correlation", why, rho=float(rho),
                               partner=names[j][keep]))
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
        steps.append(APRemoval(str(cam_ids[j]), names[j][t], "significance",
                               f"|t| = {tmin:.2f} ≤ {crit:.3f} (α = {alpha:g})", t=float(tmin)))
        cur = _fix(cur, j, t)
        res = adjust(cur, settings, start=_start(res, j, t))
        crit = float(stats.t.isf(alpha / 2, max(res.dof, 1)))
    kept = []
    for (j, t), (val, sd, tt) in sorted(_t_values(res, _candidates(cur, res)).items()):
        kept.append(APKept(str(cam_ids[j]), names[j][t], val, sd, tt, bool(tt > crit)))
    return APSelection(result=res, steps=tuple(steps), kept=tuple(kept), rho_max=rho_max, alpha=alpha,
                       critical_t=crit)


def _start(res: BundleResult, j: int, t: int):
    st = res.state.copy()
    st.cam_params[j, t] = 0.0
    return st


# --------------------------------------------------------------------------------------------
# the selection with weak priors (a block singular with every candidate free)


@dataclass
class WeakPriorSelection:
    """Outcome of :func:`select_aps_weak_priors`."""

    result: object                  # the final BundleResult (kept parameters free)
    kept: list[str]                 # names of the free camera parameters
    removed: list[tuple[str, float, str]] = field(default_factory=list)  # (name, |ρ|, with what)
    adjustments: int = 0


def _from_weak_priors(block, settings, rho_max, alpha) -> APSelection:
    sel = select_aps_weak_priors(block, settings, rho_max=rho_max, alpha=alpha)
    res = sel.result
    cid = str(block.cameras.ids[0])
    names = res.cam_param_names[0]
    crit = float(stats.t.ppf(1 - alpha / 2, res.dof)) if alpha > 0 and res.dof > 0 else float("nan")
    kept = []
    for n in sel.kept:
        t = names.index(n)
        sd = float(np.sqrt(max(res.cov_cameras[0][t, t], 0.0)))
        val = float(res.state.cam_params[0, t]) - (float(block.cameras.c[0]) if n == "c" else 0.0)
        tt = abs(val) / sd if sd > 0 else np.inf
        kept.append(APKept(cid, n, float(res.state.cam_params[0, t]), sd, tt,
                           bool(tt > crit) if np.isfinite(crit) else True))
    steps = tuple(APRemoval(cid, n, "significance" if np.isnan(rho) else "correlation",
                            why if np.isnan(rho) else f"|ρ| = {rho:.3f} with {why}", rho=rho)
                  for n, rho, why in sel.removed)
    return APSelection(result=res, steps=steps, kept=tuple(kept), rho_max=rho_max, alpha=alpha, critical_t=crit,
                       method="weak-priors")


def _with_camera_sigmas(block, sig: np.ndarray):
    """Block whose camera 0 has the a-priori sigmas ``sig`` = [c, xp, yp, ap...] (ap values 0
    where fixed)."""
    cam = block.cameras
    sigma_iop = cam.sigma_iop.copy()
    sigma_iop[0] = sig[:3]
    sigma_ap = cam.sigma_ap.copy()
    sigma_ap[0] = sig[3:]
    ap = cam.ap.copy()
    ap[0, sig[3:] == 0] = 0.0
    return block.replace(cameras=cam.replace(sigma_iop=sigma_iop, sigma_ap=sigma_ap, ap=ap))


def _weak_priors(block, names: list[str], effect_mm: float) -> np.ndarray:
    """A-priori sigma per camera parameter that lets it move the image by at most ``effect_mm``
    over the format (weak enough not to bias a determinable parameter; bounds a singular one)."""
    cam = block.cameras
    model = get_ap_model(cam.ap_model[0])
    meta = camera_meta(block, BundleSettings())[0]
    w, h = cam.format_mm[0] / 2
    gx, gy = np.meshgrid(np.linspace(-w, w, 9), np.linspace(-h, h, 7))
    gx, gy = gx.ravel(), gy.ravel()
    J = model.jacobian_params(gx, gy, np.zeros((gx.size, model.n_params)), np.full(gx.size, cam.c[0]), meta)
    effect = np.abs(J).max(axis=(0, 1))
    ap_sig = effect_mm / np.where(effect > 0, effect, 1.0)
    return np.concatenate([[effect_mm * cam.c[0] / w, effect_mm, effect_mm], ap_sig])


def select_aps_weak_priors(block, settings=None, *, rho_max: float = 0.75, alpha: float = 0.05,
                                 candidates=None, weak_effect_mm: float = 1.0,
                                 adjust_fn: Callable | None = None) -> WeakPriorSelection:
    """The AP selection on a block that is singular with every candidate free (e.g. minimal
    control): adjust with every candidate parameter, find the largest
    correlation |ρ| of a candidate with any other unknown (camera, exterior orientation), remove
    (fix at 0 / at the calibrated value) that candidate — of an AP–AP pair the less significant
    one — and repeat until no |ρ| exceeds ``rho_max``.  Then (``alpha > 0``) the significance
    test SPEC §2 asks for: remove the parameter with the smallest ``|x̂/σ̂|`` while that is below
    Student's ``t(1 − alpha/2, dof)``, one at a time.

    ``candidates``: names among ``c, xp, yp`` and the AP model's parameters (default: every camera
    parameter that is free in ``block``).  While selecting, candidates carry weak a-priori sigmas
    (each can move the image by ``weak_effect_mm``) so that a singular combination shows as
    |ρ| → 1 instead of failing; the final adjustment has the kept ones free.
    """
    adjust_fn = adjust_fn or adjust
    settings = settings or BundleSettings()
    cam = block.cameras
    names = list(IOP_NAMES) + list(get_ap_model(cam.ap_model[0]).params)
    sig0 = np.concatenate([cam.sigma_iop[0], cam.sigma_ap[0][:len(names) - 3]])
    cand = [n for n, s in zip(names, sig0) if s != 0] if candidates is None else list(candidates)
    weak = _weak_priors(block, names, weak_effect_mm)
    removed = []
    count = 0
    while True:
        sig = np.array([weak[k] if n in cand else 0.0 for k, n in enumerate(names)])
        res = adjust_fn(_with_camera_sigmas(block, sig), settings)
        count += 1
        if not cand:
            break
        rho, partner, t = _candidate_correlations(res, names, cand)
        k = int(np.argmax(rho))
        if rho[k] <= rho_max:
            break
        drop = cand[k]
        if partner[k] in cand and t[cand.index(partner[k])] < t[k]:
            drop = partner[k]
        removed.append((drop, float(rho[k]), partner[k] if drop == cand[k] else cand[k]))
        cand.remove(drop)
    while True:   # the kept set must be determinable without the weak priors
        final_sig = np.array([np.inf if n in cand else 0.0 for n in names])
        try:
            res = adjust_fn(_with_camera_sigmas(block, final_sig), settings)
            count += 1
            break
        except AdjustmentError:
            count += 1
            if not cand:
                raise
            rho, partner, _ = _candidate_correlations(res, names, cand)
            k = int(np.argmax(rho))
            removed.append((cand[k], float(rho[k]), f"{partner[k]} (singular without priors)"))
            cand.remove(cand[k])
            sig = np.array([weak[j] if n in cand else 0.0 for j, n in enumerate(names)])
            res = adjust_fn(_with_camera_sigmas(block, sig), settings)
    while alpha > 0 and cand and res.dof > 0:
        _, _, t = _candidate_correlations(res, names, cand)
        k = int(np.argmin(t))
        crit = float(stats.t.ppf(1 - alpha / 2, res.dof))
        if t[k] >= crit:
            break
        removed.append((cand[k], float("nan"), f"not significant (|t| = {t[k]:.2f} < {crit:.2f})"))
        cand.remove(cand[k])
        res = adjust_fn(_with_camera_sigmas(block, np.array([np.inf if n in cand else 0.0 for n in names])),
                        settings)
        count += 1
    return WeakPriorSelection(result=res, kept=list(cand), removed=removed, adjustments=count)


def _candidate_correlations(res, names, cand):
    """For each candidate: largest |ρ| with another global unknown, that unknown's name, |x/σ|."""
    prob = res.problem
    gcols = [int(prob.g_cam[0, names.index(n)]) for n in cand]
    Qc = res.cofactor_columns(gcols)                                  # (n_g, candidates)
    d = np.sqrt(np.clip(res.cofactor_diagonal(), 1e-300, None))
    labels = parameter_names(prob)
    cam_name = {int(g): n for n, g in zip(names, prob.g_cam[0]) if g >= 0}
    rho, partner, t = [], [], []
    for i, n in enumerate(cand):
        g = gcols[i]
        row = np.abs(Qc[:, i] / (d[g] * d))
        row[g] = 0.0
        j = int(np.argmax(row))
        rho.append(row[j])
        partner.append(cam_name.get(j, labels[j]))
        val = res.state.cam_params[0, names.index(n)] - (res.block_in.cameras.c[0] if n == "c" else 0.0)
        t.append(abs(val) / (d[g] * np.sqrt(res.variance_factor)))
    return np.array(rho), partner, np.array(t)
