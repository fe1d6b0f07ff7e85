"""The iteration: Gauss–Newton with Levenberg–Marquardt damping (Nielsen's update) on the reduced
system, until no observation moves by more than ``tol_obs`` × its σ."""

from __future__ import annotations

import time

import numpy as np

from baarda.pipeline.errors import AdjustmentError
from baarda.pipeline.model import Block

from .factor import solve_reduced
from .problem import BundleProblem
from .settings import BundleSettings, BundleState

__all__ = ["solve_bundle", "final_system"]


def solve_bundle(block: Block, settings: BundleSettings | None = None, *, obs_active=None, row_active=None,
                 start: BundleState | None = None, problem: BundleProblem | None = None, final: bool = True):
    """Run the adjustment (see :func:`baarda.pipeline.adjustment.adjust` for the public entry point).

    Returns ``(problem, state, info)``; ``info`` holds the history, timings and — with ``final``
    (the default) — the linearisation and reduced system at the solution (``lin``, ``red``, what
    the precision needs; ``info["proj"]`` is the solution's projection either way).
    """
    settings = settings or BundleSettings()
    t0 = time.perf_counter()
    prob = problem or BundleProblem(block, settings, obs_active=obs_active, row_active=row_active)
    st = (start or prob.initial_state()).copy()
    _check_initial(prob, st)
    parts = prob.residual_parts(st)
    cost = prob.cost(st, parts)
    timings = {"setup": time.perf_counter() - t0, "linearize": 0.0, "solve": 0.0, "residuals": 0.0}
    history = []
    lam = 0.0
    history.append({"iteration": 0, "vtpv": cost, "lambda": 0.0, "max_step_sigma": float("nan")})
    converged = False
    it = 0
    eps_cost = 1e-12 * max(1, prob.n_obs_rows)
    nu = 2.0
    for it in range(1, settings.max_iter + 1):
        lin = prob.linearize(st, parts[-1])            # the accepted step's projection, Jacobians added
        timings["linearize"] += lin["t"]
        while True:
            ts = time.perf_counter()
            red = prob.reduced_system(lin, st, lam)
            dx, fac = solve_reduced(prob, red, st, diagnose=(it == 1 and lam == 0.0))
            dp = prob.back_substitute(red, dx)
            pred = _pred(prob, lin, dx, dp)        # J̃Δ: change of each observation in units of its σ
            max_step = float(np.max(np.abs(pred))) if pred.size else 0.0
            gain = cost - _linear_cost(prob, lin, pred, dx, dp)
            tr = time.perf_counter()
            timings["solve"] += tr - ts
            new = prob.apply(st, dx[:prob.n_g], dp)
            new_parts = prob.residual_parts(new)
            new_cost = prob.cost(new, new_parts)
            timings["residuals"] += time.perf_counter() - tr
            if not np.isfinite(new_cost):
                new_cost = np.inf
            rho = (cost - new_cost) / gain if gain > 0 else (1.0 if new_cost <= cost else -1.0)
            if gain <= eps_cost and new_cost <= cost + eps_cost:
                break                                 # nothing left to gain: converged
            if new_cost <= cost * (1 + 1e-10) + eps_cost or not settings.damping:
                # accepted: Nielsen's update of the damping
                if lam > 0:
                    lam *= max(1.0 / 3.0, 1.0 - (2.0 * min(rho, 1.0) - 1.0) ** 3)
                    if lam < 1e-7:
                        lam = 0.0
                elif rho < 0.25 and settings.damping:
                    lam = 1e-4                  # Gauss–Newton overshoots: start damping next time
                nu = 2.0
                break
            if lam == 0.0 and max_step < settings.tol_obs:
                new, new_parts, new_cost = st, parts, cost    # at the minimum already
                break
            lam = 1e-4 if lam == 0 else lam * nu
            nu *= 2.0
            if lam > 1e12:
                raise AdjustmentError(
                    f"the adjustment diverges: no damped step reduces vᵀPv (= {cost:.6g}) at iteration {it}; "
                    "check the initial values and the datum", state=st)
        rel = abs(cost - new_cost) / max(cost, 1e-300)
        st, parts, cost = new, new_parts, new_cost
        history.append({"iteration": it, "vtpv": cost, "lambda": lam, "max_step_sigma": max_step})
        if (lam == 0.0 and max_step < settings.tol_obs) or rel < settings.tol_rel or gain <= eps_cost \
                or abs(cost - history[-2]["vtpv"]) <= eps_cost:
            converged = True
            break
    if not converged:
        err = AdjustmentError(
            f"no convergence after {settings.max_iter} iterations: vᵀPv = {cost:.6g}, last correction moved an "
            f"observation by {history[-1]['max_step_sigma']:.3g} σ (threshold {settings.tol_obs:g}); "
            "raise max_iter, check the initial values, or look for gross errors", state=st)
        err.history = history
        raise err
    info = dict(history=history, iterations=it, timings=timings, vtpv=cost, proj=parts[-1])
    if final:
        lin, red = final_system(prob, st, parts[-1])
        info.update(lin=lin, red=red)
    return prob, st, info


def final_system(prob: BundleProblem, st: BundleState, proj=None):
    """Linearisation and undamped reduced system at the solution (for the precision)."""
    lin = prob.linearize(st, proj)
    return lin, prob.reduced_system(lin, st, 0.0)


def _pred(prob, lin, dx, dp) -> np.ndarray:
    """Whitened change J̃Δ of every observation (k, 2)."""
    xk = np.append(dx[:prob.n_g], 0.0)[prob.cidx]                          # (k, q)
    pred = np.matmul(lin["Jc"], xk[:, :, None])[:, :, 0]
    if prob.n_e:
        pk = np.vstack([dp, np.zeros((1, 3))])[prob.pidx]
        pred += np.matmul(lin["Jp"], pk[:, :, None])[:, :, 0]
    return pred


def _linear_cost(prob, lin, pred, dx, dp) -> float:
    """vᵀPv of the linearised model after the step Δ (for the gain ratio of the damping)."""
    v, e, dg, dpv, dd, _ = lin["parts"]
    c = float(np.sum((e - pred) ** 2))
    c += float(np.sum(prob.prior_g_w * (dg - dx[prob.prior_g_idx]) ** 2))
    if len(prob.prior_p_idx):
        c += float(np.sum(prob.prior_p_w * (dpv - dp[prob.prior_p_idx, prob.prior_p_coord]) ** 2))
    if len(prob.dist_l):
        wd = prob.settings.sigma0 / prob.dist_s
        step = (lin["Jd"] * np.append(dx[:prob.n_g], 0.0)[lin["dcols"]]).sum(axis=1)
        c += float(np.sum((wd * dd - step) ** 2))
    return c


def _check_initial(prob: BundleProblem, st: BundleState):
    bad = prob.photo_used & ~np.isfinite(np.concatenate([st.X0, st.opk], axis=1)).all(axis=1)
    if bad.any():
        raise AdjustmentError(f"photo {str(prob.block.photos.ids[np.argmax(bad)])!r} has no initial orientation "
                              "(compute initial values first)")
    bad = prob.point_used & ~np.isfinite(st.XYZ).all(axis=1)
    if bad.any():
        raise AdjustmentError(f"point {str(prob.block.points.ids[np.argmax(bad)])!r} has no initial coordinates "
                              "(compute initial values first)")
