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
