"""The iteration: Gauss–Newton with Levenberg–Marquardt damping (Nielsen's update) on the reduced
system.  In a free network a step that falls short of the linear model's decrease is tried again
with its similarity (gauge) part applied as an exact similarity transformation
(:class:`SimilarityGauge`).  Stops when no observation moves by more than ``tol_obs`` × its σ, when
vᵀPv changes by less than ``tol_rel`` (relative) or ``1e-12`` × rows, or when the linear model
predicts no further decrease (``docs/bundle.md``, "Iteration and stopping rule")."""

from __future__ import annotations

import contextvars
import time
from dataclasses import dataclass

import numpy as np

from baarda.pipeline.camera.ray_models import RayOutsideModel
from baarda.pipeline.errors import AdjustmentError
from baarda.pipeline.geometry import (opk_from_rotation_many, rotation_and_derivatives, rotation_from_rotvec,
                                      similarity_motions)
from baarda.pipeline.model import Block

from . import kernels
from .normal import Linearisation
from .problem import BundleProblem
from .records import Convergence, Iteration, IterationEvent, Timings
from .route import ReducedSystem, Route, choose_route
from .settings import BundleSettings, BundleState

__all__ = ["solve_bundle", "SolveInfo", "final_system", "SimilarityGauge", "ITERATION_CALLBACK"]

ITERATION_CALLBACK = contextvars.ContextVar("iteration_callback", default=None)
"""An optional observer ``callback(event)`` of each iteration (an :class:`~.records.IterationEvent`: the
step, ``max_iter``, ``seconds`` since the start), set by a stage for its progress display; it never
changes the iteration."""


@dataclass(frozen=True, slots=True, eq=False)
class SolveInfo:
    """What :func:`solve_bundle` reports besides the problem and the state: the ``history``
    (:class:`~.records.Convergence`, iteration 0 the start), ``iterations``, ``timings``
    (:class:`~.records.Timings`), the final
    ``vtpv``, the solution's projection ``proj``, the :class:`~.route.Route` chosen at the start
    and — with ``final`` — the linearisation ``lin`` and undamped reduced system ``red`` at the
    solution (what the precision needs)."""

    history: Convergence
    iterations: int
    timings: Timings
    vtpv: float
    proj: object
    route: Route
    lin: Linearisation | None = None
    red: ReducedSystem | None = None


def solve_bundle(block: Block, settings: BundleSettings | None = None, *, obs_active=None, row_active=None,
                 start: BundleState | None = None, problem: BundleProblem | None = None, final: bool = True):
    """Run the adjustment (see :func:`baarda.pipeline.adjustment.adjust` for the public entry point).

    Returns ``(problem, state, info)``; ``info`` (:class:`SolveInfo`) holds the history, timings,
    the route and — with ``final`` (the default) — the linearisation and reduced system at the
    solution (``info.lin``, ``info.red``, what the precision needs; ``info.proj`` is the solution's
    projection either way).
    """
    settings = settings or BundleSettings()
    t0 = time.perf_counter()
    prob = problem or BundleProblem(block, settings, obs_active=obs_active, row_active=row_active)
    st = (start or prob.initial_state()).copy()
    _check_initial(prob, st)
    route = choose_route(prob, st)
    gauge = SimilarityGauge.of(prob)
    parts = prob.residual_parts(st)
    cost = prob.cost(st, parts)
    t_setup = time.perf_counter() - t0
    t_lin = t_solve = t_res = 0.0
    lam = 0.0
    history = [Iteration(0, cost, 0.0, float("nan"))]
    converged = False
    it = 0
    eps_cost = 1e-12 * max(1, prob.n_obs_rows)
    nu = 2.0
    lin = red = None
    for it in range(1, settings.max_iter + 1):
        lin = red = None             # the last iteration's system freed before this one is built (peak memory)
        lin = prob.normals.linearize(st, parts[-1], sparse=route.sparse_normals)   # the accepted step's projection
        t_lin += lin.t
        while True:
            ts = time.perf_counter()
            red = None               # a rejected step's system freed before the damped one is formed
            red = route.reduced_system(prob, lin, st, lam)
            dx = red.solution[0]
            dp = red.back_substitute(dx)
            pred = _pred(prob, lin, dx, dp)        # J̃Δ: change of each observation in units of its σ
            max_step = float(np.max(np.abs(pred))) if pred.size else 0.0
            gain = cost - _linear_cost(prob, lin, pred, dx, dp)
            tr = time.perf_counter()
            t_solve += tr - ts
            new, new_parts, new_cost = _trial(prob, prob.apply(st, dx[:prob.n_g], dp))
            rho = _gain_ratio(cost, new_cost, gain)
            exact = False
            if gauge is not None and rho < 0.75 and gain > eps_cost:
                # short of the linear model's decrease: the same step, its similarity part exact
                alt = _trial(prob, gauge.apply(st, dx[:prob.n_g], dp))
                if alt[2] < new_cost:
                    new, new_parts, new_cost = alt
                    rho = _gain_ratio(cost, new_cost, gain)
                    exact = True
            t_res += time.perf_counter() - tr
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
                new, new_parts, new_cost, exact = st, parts, cost, False    # at the minimum already
                break
            lam = 1e-4 if lam == 0 else lam * nu
            nu *= 2.0
            if lam > 1e12:
                raise AdjustmentError(
                    f"the adjustment diverges: no damped step reduces vᵀPv (= {cost:.6g}) at iteration {it}; "
                    "check the initial values and the datum", state=st)
        rel = abs(cost - new_cost) / max(cost, 1e-300)
        st, parts, cost = new, new_parts, new_cost
        history.append(Iteration(it, cost, lam, max_step, exact))
        if (callback := ITERATION_CALLBACK.get()) is not None:
            callback(IterationEvent(history[-1], settings.max_iter, time.perf_counter() - t0))
        if (lam == 0.0 and max_step < settings.tol_obs) or rel < settings.tol_rel or gain <= eps_cost \
                or abs(cost - history[-2].vtpv) <= eps_cost:
            converged = True
            break
    if not converged:
        raise AdjustmentError(
            f"no convergence after {settings.max_iter} iterations: vᵀPv = {cost:.6g}, last correction moved an "
            f"observation by {history[-1].max_step_sigma:.3g} σ (threshold {settings.tol_obs:g}); "
            "raise max_iter, check the initial values, or look for gross errors", state=st,
            history=Convergence.of(history))
    lin = red = None
    if final:
        lin, red = final_system(prob, route, st, parts[-1])
    timings = Timings(setup=t_setup, linearize=t_lin, solve=t_solve, residuals=t_res, total=time.perf_counter() - t0)
    return prob, st, SolveInfo(Convergence.of(history), it, timings, cost, parts[-1], route, lin, red)


class SimilarityGauge:
    """The similarity motions of a free network — 3 translations, 3 rotations and, without a
    distance, the scale — which leave vᵀPv unchanged, applied exactly.

    A step Δ of the bordered system obeys the linearised inner constraints; its similarity part is
    linear in the motion (a rotation by ε moves X by ε × X).  Added to the parameters, a rotation
    by ε moves every point ≈ ε²|X|/2 off its circle and changes ω φ κ by their first derivative
    only: vᵀPv grows by what the linear model does not predict.  When the datum points are nearly
    collinear (the projection centres of a camera rig driven along a street: BAL's Ladybug
    problems), the inner constraints fix the rotation about their line only through their small
    spread across it, every step that moves a centre across the line carries a large rotation
    about it, and additive steps are rejected or damped into a creep (vᵀPv falling by 1e-7
    relative per iteration, the gain ratio held near 0.5: BAL's Ladybug subsample, ``docs/bundle.md``).

    Here ``Δ = G θ + r``: ``G θ`` is the linearised similarity that fits Δ best (least squares
    over the centres and points that take part), ``r`` the rest.  ``r`` is added to the
    parameters, then the similarity ``θ = (t, ε, s)`` is applied exactly — centres and points
    ``X ↦ c + t + (1 + s) R(ε) (X − c)``, rotations ``R_cam_from_world ↦ R_cam_from_world R(ε)ᵀ``.
    To first order this is ``x + Δ``, so the step keeps the datum of the inner constraints; its
    vᵀPv is that of ``x + r`` exactly (cameras, AP models and image observations do not see a
    similarity).  :func:`solve_bundle` uses it for a step whose additive form gains less than
    3/4 of the predicted decrease (and keeps the better of the two): a well-conditioned network
    (gain ratios near 1) iterates exactly as with additive steps.

    :meth:`of` returns ``None`` — steps are added as they are — unless that invariance holds: a free
    network, every taking-part photo and point with free position and orientation, no weighted
    constraint on any of them (camera parameters may carry one), and the scale only without
    distances.
    """

    def __init__(self, prob: BundleProblem):
        self.prob = prob
        self.photos = np.flatnonzero(prob.photo_used)
        self.points = np.flatnonzero(prob.point_used)
        self.eo_cols = prob.g_eo[self.photos]                               # (m, 6), all ≥ 0
        glob = (prob.g_pt[self.points] >= 0).all(axis=1)
        self.pt_glob = np.flatnonzero(glob)                                 # positions in self.points
        self.pt_elim = np.flatnonzero(~glob)
        self.glob_cols = prob.g_pt[self.points[self.pt_glob]]              # (·, 3)
        self.elim_rows = prob.elim_of[self.points[self.pt_elim]]           # rows of dp
        self.n_motions = 7 if prob.n_c == 7 else 6

    @classmethod
    def of(cls, prob: BundleProblem) -> "SimilarityGauge | None":
        """The gauge of ``prob`` when vᵀPv is invariant under it, else ``None``."""
        if not prob.n_c or len(prob.prior_p_idx) or len(prob.oi) == 0 or "gnss" in prob.grow_slices:
            return None                      # (GNSS antennas are not invariant under a similarity)
        cam_cols = prob.g_cam[prob.g_cam >= 0]
        if not np.isin(prob.prior_g_idx, cam_cols).all():
            return None                      # a weighted constraint on an orientation or a point
        if not (prob.g_eo[prob.photo_used] >= 0).all():
            return None
        if not prob.pt_free[prob.point_used].all():
            return None
        return cls(prob)

    def split(self, st: BundleState, dx_g: np.ndarray, dp: np.ndarray):
        """``(θ, r_g, r_p, c)``: the similarity ``θ = (t (3), ε (3), s)`` (ε in radians, ``s`` 0
        without scale) and the rest of the step, in the layout of ``(dx_g, dp)``; ``c`` the centroid
        the rotation and scale act about.  ``None`` near φ = ±90° (ω φ κ cannot follow a rotation)."""
        X0, XYZ = st.X0[self.photos], st.XYZ[self.points]
        d_X0 = dx_g[self.eo_cols[:, :3]]
        d_XYZ = np.zeros((len(self.points), 3))
        d_XYZ[self.pt_glob] = dx_g[self.glob_cols]
        d_XYZ[self.pt_elim] = dp[self.elim_rows]
        pos = np.concatenate([X0, XYZ])
        c = pos.mean(axis=0)
        scale = float(np.sqrt(np.mean(np.sum((pos - c) ** 2, axis=1)))) or 1.0
        A = similarity_motions((pos - c) / scale, self.n_motions)                    # (N, 3, k)
        k = self.n_motions
        theta = np.linalg.lstsq(A.reshape(-1, k), np.concatenate([d_X0, d_XYZ]).ravel(), rcond=1e-12)[0]
        motion = A @ theta                                                 # (N, 3)
        eps = theta[3:6] / scale
        s = theta[6] / scale if k == 7 else 0.0
        # ω φ κ of R R(ε)ᵀ to first order: Rᵀ ∂R/∂a = [w_a]×, so Σ_a w_a d_a = −ε
        R, dR = rotation_and_derivatives(st.opk[self.photos])
        S = np.einsum("mji,majk->maik", R, dR)
        W = np.stack([S[:, :, 2, 1], S[:, :, 0, 2], S[:, :, 1, 0]], axis=2)  # (m, a, 3): w_a
        det = np.abs(np.linalg.det(W))
        if det.size and det.min() < 1e-6:
            return None
        rhs = np.broadcast_to(eps, (len(self.photos), 3))[..., None]
        d_opk = -np.linalg.solve(np.transpose(W, (0, 2, 1)), rhs)[..., 0]
        r_g = dx_g.copy()
        r_g[self.eo_cols[:, :3]] -= motion[:len(self.photos)]
        r_g[self.eo_cols[:, 3:]] -= d_opk
        mp = motion[len(self.photos):]
        r_g[self.glob_cols] -= mp[self.pt_glob]
        r_p = np.array(dp, float, copy=True)
        r_p[self.elim_rows] -= mp[self.pt_elim]
        return np.concatenate([theta[:3], eps, [s]]), r_g, r_p, c

    def apply(self, st: BundleState, dx_g: np.ndarray, dp: np.ndarray) -> BundleState:
        """The state after the step ``(dx_g, dp)``, its similarity part applied exactly (a new state)."""
        parts = self.split(st, dx_g, dp)
        if parts is None:
            return self.prob.apply(st, dx_g, dp)
        theta, r_g, r_p, c = parts
        out = self.prob.apply(st, r_g, r_p)
        t, eps, f = theta[:3], theta[3:6], 1.0 + theta[6]
        Re = rotation_from_rotvec(eps)[0]
        ph, pt = self.photos, self.points
        out.X0[ph] = c + t + f * (out.X0[ph] - c) @ Re.T
        out.XYZ[pt] = c + t + f * (out.XYZ[pt] - c) @ Re.T
        opk = out.opk[ph]
        R = rotation_and_derivatives(opk)[0] @ Re.T
        out.opk[ph] = opk + _wrap(opk_from_rotation_many(R) - opk)
        return out


def _trial(prob: BundleProblem, new: BundleState):
    """``(state, residual parts, vᵀPv)`` of a trial state (vᵀPv = inf when not finite, or when the
    step takes a ray out of its camera model's domain: the step is then damped, never accepted)."""
    try:
        parts = prob.residual_parts(new)
    except RayOutsideModel:
        if not prob.settings.damping:
            raise
        return new, None, np.inf
    cost = prob.cost(new, parts)
    return new, parts, (cost if np.isfinite(cost) else np.inf)


def _gain_ratio(cost: float, new_cost: float, gain: float) -> float:
    """Actual over predicted decrease of vᵀPv (±1 when the linear model predicts none)."""
    return (cost - new_cost) / gain if gain > 0 else (1.0 if new_cost <= cost else -1.0)


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def final_system(prob: BundleProblem, route: Route, st: BundleState, proj=None) -> tuple:
    """Linearisation and undamped reduced system on ``route`` at the solution (for the precision)."""
    lin = prob.normals.linearize(st, proj, sparse=route.sparse_normals)
    return lin, route.reduced_system(prob, lin, st, 0.0)


def _pred(prob, lin, dx, dp) -> np.ndarray:
    """Whitened change J̃Δ of every observation (k, 2)."""
    return kernels.linear_change(lin.Jc, prob.layout.cidx, dx[:prob.n_g], lin.Jp, prob.layout.pidx,
                                 dp if prob.n_e else None)


def _linear_cost(prob, lin, pred, dx, dp) -> float:
    """vᵀPv of the linearised model after the step Δ (for the gain ratio of the damping)."""
    v, e, dg, dpv, dd, _ = lin.parts
    c = float(np.sum((e - pred) ** 2))
    c += float(np.sum(prob.prior_g_w * (dg - dx[prob.prior_g_idx]) ** 2))
    if len(prob.prior_p_idx):
        c += float(np.sum(prob.prior_p_w * (dpv - dp[prob.prior_p_idx, prob.prior_p_coord]) ** 2))
    if len(dd):                  # rows on global unknowns (scale bars, GNSS antennas), whitened
        step = (lin.Jd * np.append(dx[:prob.n_g], 0.0)[lin.dcols]).sum(axis=1)
        c += float(np.sum((dd - step) ** 2))
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
