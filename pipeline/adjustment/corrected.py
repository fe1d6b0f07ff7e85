"""DBAT's residual definition inside the bundle: the *corrected* mark minus the ideal projection
(``BundleSettings.residual = "corrected"``, ``docs/bundle.md`` and ``docs/dbat.md``).

A backward model (``brown-backward``: PhotoModeler, DBAT) describes the correction ``g`` of a
*measured* mark ``m = l − pp`` (reduced to the principal point).  baarda's own residual keeps the
mark as the observation, ``v = l − (pp + g⁻¹(x̄))``; DBAT's (``res_euler_brown_3.m``) is formed in
the corrected image space, ``v = g(l − pp; θ) − x̄`` — weighted, as in DBAT's
``buildweightmatrix.m``, with the mark's own σ (pixels × pixel size, mm).  Written as baarda's
"observed − computed" with the marks ``l`` as the observations, the computed value is::

    f = pp + x̄ + Δ,   Δ = m − g(m),   m = l − pp

so every other part of the bundle (whitening, normal equations, tests, reliability) is unchanged.
``Δ`` does not depend on x̄ (the pinhole part's Jacobians stay those of a camera without
distortion), and the camera enters through ``g`` at the measured mark::

    ∂f/∂θ = −∂g/∂θ (m),   ∂f/∂(xp, yp) = I + ∂Δ/∂pp = ∂g/∂m (m) = G,   ∂f/∂c = x̄ / c

A model takes part when it has ``correct_jacobians(mx, my, params) -> (gx, gy, G (n, 2, 2),
∂g/∂θ (n, 2, p))`` (:class:`~baarda.pipeline.camera.models.BrownBackward`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["has_correction", "check_models", "split_groups", "add_correction", "add_correction_jacobians"]


def has_correction(model) -> bool:
    """Whether ``model`` corrects measured marks (a backward model) and so has DBAT's residual."""
    return callable(getattr(model, "correct_jacobians", None))


def check_models(camera_ids, models) -> None:
    """``residual = "corrected"``: every camera's model corrects the measured marks (or has no
    parameters, where both definitions are the same); else an :class:`InputError` naming the camera."""
    from baarda.pipeline.errors import InputError

    for cid, mdl in zip(camera_ids, models):
        if mdl.n_params and not has_correction(mdl):
            raise InputError(f"camera {str(cid)!r}: residual = \"corrected\" (DBAT's definition) needs a model that "
                             f"corrects the measured marks (brown-backward), not {mdl.name!r}", field="residual")


def split_groups(groups, marks):
    """``(groups with the usual Δ(x̄), groups in DBAT's definition)``: without ``marks`` every group
    keeps the usual model; with them the groups of backward models use the corrected marks."""
    if marks is None:
        return list(groups), []
    usual, corr = [], []
    for g in groups:
        (corr if has_correction(g[0]) else usual).append(g)
    return usual, corr


def _reduced(marks, cp, sel, p):
    s = slice(None) if sel is None else sel
    m = marks[s] - cp[s, 1:3]
    return s, m, cp[s, 3:3 + p]


def add_correction(groups, marks, cp, xy) -> None:
    """``xy += m − g(m)`` in place for the observations of ``groups`` (``(model, sel, meta)``,
    ``sel`` None = every observation); ``marks`` (k, 2) the measured marks, ``cp`` (k, 3 + p) the
    camera parameters of each observation."""
    for model, sel, meta in groups:
        s, m, prm = _reduced(marks, cp, sel, model.n_params)
        gx, gy, _, _ = model.correct_jacobians(m[:, 0], m[:, 1], prm)
        xy[s, 0] += m[:, 0] - gx
        xy[s, 1] += m[:, 1] - gy


def add_correction_jacobians(groups, marks, cp, cols, J_cam) -> None:
    """The camera columns of the observations of ``groups`` in DBAT's definition, in place:
    ``xp, yp`` → the columns of ``G = ∂g/∂m``, the model's parameters → ``−∂g/∂θ`` (``c`` keeps
    the pinhole's ``x̄ / c``).  ``cols`` the columns of ``J_cam`` (indices into ``[c, xp, yp, ap…]``)."""
    cols = np.asarray(cols, int)
    for model, sel, meta in groups:
        s, m, prm = _reduced(marks, cp, sel, model.n_params)
        _, _, G, Gp = model.correct_jacobians(m[:, 0], m[:, 1], prm)
        for j, t in enumerate(cols.tolist()):
            if t in (1, 2):
                J_cam[s, :, j] = G[:, :, t - 1]
            elif 3 <= t < 3 + model.n_params:
                J_cam[s, :, j] = -Gp[:, :, t - 3]
