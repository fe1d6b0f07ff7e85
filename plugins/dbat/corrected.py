"""DBAT's residual definition (corrected marks) in baarda's bundle — pure numerics.

DBAT forms the residual of a mark in the corrected image space, ``r_D = g(l − pp) − x̄`` (``g`` the
backward model's correction, ``x̄`` the ideal projection), weighted with the mark's σ; baarda keeps
the marks as observations: ``r_B = l − (pp + g⁻¹(x̄))``.  To first order ``r_D = J r_B`` with
``J = ∂g/∂m`` at the mark, so DBAT's objective ``Σ r_Dᵀ P r_D`` is baarda's with the mark's weight
``Jᵀ P J`` — its covariance ``J⁻¹ Σ J⁻ᵀ``.  :func:`adjust_corrected` adjusts with those weights,
recomputes ``J`` at the adjusted camera and adjusts again until the camera no longer moves
(``docs/dbat.md``, "Residual definition").  The second-order rest is of the order of the residual
over the image size (0.5 px against 5 000 px) and does not show in the printed digits.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from baarda.pipeline.camera import get_ap_model

H_MM = 1e-4
"""Step (mm) of the central differences of ``g`` (a polynomial of the reduced coordinates)."""


def correction_jacobian(model, lb: np.ndarray, params: np.ndarray, c: float) -> np.ndarray:
    """(n, 2, 2) ``∂g/∂m`` at the reduced marks ``lb`` (n, 2) by central differences."""
    n = len(lb)
    prm = np.tile(params, (n, 1))
    J = np.empty((n, 2, 2))
    for axis in (0, 1):
        d = np.zeros(2)
        d[axis] = H_MM
        gp = np.column_stack(model.correct(lb[:, 0] + d[0], lb[:, 1] + d[1], prm, c, {}))
        gm = np.column_stack(model.correct(lb[:, 0] - d[0], lb[:, 1] - d[1], prm, c, {}))
        J[:, :, axis] = (gp - gm) / (2 * H_MM)
    return J


def corrected_cov(block, cam_params: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """(k, 2, 2) the covariances ``J⁻¹ Σ J⁻ᵀ`` that make baarda's weighted residuals DBAT's, at the
    camera values ``cam_params`` (n_cam, 3 + n_ap); ``cov`` the marks' own.  Observations of cameras
    whose model has no ``correct`` (no backward model) keep ``cov``."""
    obs = block.observations
    out = np.array(cov, float, copy=True)
    cam_of_obs = np.asarray(block.photos.camera)[obs.photo]
    for j, name in enumerate(block.cameras.ap_model.tolist()):
        model = get_ap_model(name)
        if not callable(getattr(model, "correct", None)):
            continue
        sel = np.flatnonzero(cam_of_obs == j)
        if not len(sel):
            continue
        lb = np.asarray(obs.xy, float)[sel] - cam_params[j, 1:3]
        J = correction_jacobian(model, lb, cam_params[j, 3:3 + model.n_params], cam_params[j, 0])
        Ji = np.linalg.inv(J)
        out[sel] = Ji @ out[sel] @ np.transpose(Ji, (0, 2, 1))
    return out


def adjust_corrected(block, run: Callable, *, max_outer: int = 6, tol_sigma: float = 0.01):
    """Adjust ``block`` in DBAT's residual definition.  ``run(block) -> (result, adjusted_block)``
    adjusts a block (``result.state.cam_params``, ``result.camera_table``); the next round starts
    from ``adjusted_block`` (its adjusted values, the same observations) with the covariances of
    :func:`corrected_cov` at the adjusted camera.  Rounds stop when no camera parameter moves by
    more than ``tol_sigma`` of its σ, or after ``max_outer`` rounds.

    Returns (result, the reweighted block it adjusted, rounds, the last round's largest move in σ)."""
    cov0 = np.array(block.observations.cov, float)
    res, nxt = run(block)
    used = block
    rounds, move = 1, float("inf")
    prev = np.array(res.state.cam_params, float)
    while rounds < max_outer:
        cov = corrected_cov(nxt, prev, cov0)
        used = nxt.replace(observations=nxt.observations.replace(cov=cov))
        res, nxt = run(used)
        rounds += 1
        cur = np.array(res.state.cam_params, float)
        sig = _camera_sigmas(res, cur.shape)
        free = np.isfinite(sig) & (sig > 0)
        move = float(np.max(np.abs(cur - prev)[free] / sig[free])) if free.any() else 0.0
        prev = cur
        if move < tol_sigma:
            break
    return res, used, rounds, move


def _camera_sigmas(res, shape) -> np.ndarray:
    """(n_cam, n_params) a-posteriori σ of the camera parameters (nan where fixed)."""
    out = np.full(shape, np.nan)
    for j in range(shape[0]):
        try:
            table = res.camera_table(j)
        except Exception:                           # a camera not adjusted
            continue
        names = res.cam_param_names[j]
        for k, name in enumerate(names[:shape[1]]):
            row = next((r for r in table if r["parameter"] == name), None)
            if row is not None and row.get("sigma") is not None:
                out[j, k] = float(row["sigma"])
    return out


def dbat_objective(block, state, marks_cov, active=None) -> float:
    """DBAT's ``Σ r_Dᵀ P r_D`` over the (active) marks of backward-model cameras: ``r_D`` the corrected
    marks' residuals (:func:`~.quality.corrected_space_residuals`), ``P`` the marks' own weights."""
    from .quality import corrected_space_residuals

    rc = corrected_space_residuals(block, state, active)
    ok = np.isfinite(rc).all(axis=1)
    if active is not None:
        ok &= np.asarray(active, bool)
    P = np.linalg.inv(np.asarray(marks_cov, float)[ok])
    return float(np.einsum("ki,kij,kj->", rc[ok], P, rc[ok]))


def camera_at_dbat_minimum(block, result, marks_cov) -> dict:
    """The camera one Newton step from the reweighted solution towards the minimum of DBAT's own
    objective: ``Δθ = −½ Q_cc ∇_θ F_D``, the gradient of :func:`dbat_objective` with respect to the
    free camera parameters (central differences, the orientations and points held), ``Q_cc`` their
    a-posteriori cofactor matrix (``cov / σ̂0²``: the marginal of the full inverse, so the step is the
    camera block of the full Newton step when the gradient's other components vanish).

    The reweighting leaves a gradient ``∇F_D`` in the camera because DBAT differentiates its
    residual at the measured mark (``docs/dbat.md``).  Returns ``cam_params`` (n_cam, 3 + p) after
    the step, the ``step`` itself, ``F_before`` and the quadratic prediction ``F_after`` of DBAT's
    objective."""
    import dataclasses

    st = result.state
    active = np.asarray(result.obs_active, bool)
    cp0 = np.array(st.cam_params, float)
    step = np.zeros_like(cp0)
    F0 = dbat_objective(block, st, marks_cov, active)
    s0 = float(result.sigma0_hat) if np.isfinite(result.sigma0_hat) and result.sigma0_hat > 0 else 1.0
    pred = 0.0
    for j in range(cp0.shape[0]):
        C = np.asarray(result.cov_cameras[j], float)
        free = np.flatnonzero(np.diag(C) > 0)
        if not len(free):
            continue
        sig = np.sqrt(np.diag(C)[free])
        G = np.zeros(len(free))
        for i, (k, s) in enumerate(zip(free, sig)):
            h = 1e-2 * s
            cp = cp0.copy()
            cp[j, k] += h
            Fp = dbat_objective(block, dataclasses.replace(st, cam_params=cp), marks_cov, active)
            cp[j, k] -= 2 * h
            Fm = dbat_objective(block, dataclasses.replace(st, cam_params=cp), marks_cov, active)
            G[i] = (Fp - Fm) / (2 * h)
        Q = C[np.ix_(free, free)] / s0 ** 2
        d = -0.5 * Q @ G
        step[j, free] = d
        pred += 0.5 * float(G @ d)
    return {"cam_params": cp0 + step, "step": step, "F_before": F0, "F_after": F0 + pred}
