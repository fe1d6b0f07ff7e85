"""Compiled loops of the camera models (numba through :mod:`baarda.pipeline.jit`).

``brown_invert``: the ``brown-backward`` model's inverse by Newton's method, per point in one pass —
numpy evaluated g and ∂g/∂m for every point in every step (3.8 s of the 24 s CPU of DBAT's
90 561-mark Roma project; now < 0.1 s).  The arithmetic is the numpy form's own, in the same order
(``tests/adjustment/test_kernels.py`` checks it against the numpy Newton iteration).
"""

from __future__ import annotations

import numpy as np

from ..jit import JIT

__all__ = ["brown_invert"]

_jit = JIT(__file__)


@_jit
def _brown_invert(xb, yb, P, tol, max_iter, mx, my, ok):
    n = xb.shape[0]
    m0x, m0y, scale = np.empty(n), np.empty(n), np.empty(n)
    sx, sy = np.empty(n), np.empty(n)
    for i in range(n):                            # first-order start m0 = 2 x̄ − g(x̄)
        K1, K2, K3, P1, P2, asp, sk = P[i, 0], P[i, 1], P[i, 2], P[i, 3], P[i, 4], P[i, 5], P[i, 6]
        x, y = xb[i], yb[i]
        ax = (1.0 + asp) * x + sk * y
        ay = y
        r2 = ax * ax + ay * ay
        R = r2 * (K1 + r2 * (K2 + r2 * K3))
        gx = ax * (1.0 + R) + P1 * (r2 + 2 * ax * ax) + 2 * P2 * ax * ay
        gy = ay * (1.0 + R) + P2 * (r2 + 2 * ay * ay) + 2 * P1 * ax * ay
        u, v = 2 * x - gx, 2 * y - gy
        if not (np.isfinite(u) and np.isfinite(v)):
            u, v = x, y
        m0x[i], m0y[i] = u, v
        mx[i], my[i] = u, v
        scale[i] = max(1.0, abs(x) + abs(y))
    for _ in range(max_iter):
        all_done = True
        for i in range(n):
            K1, K2, K3, P1, P2, asp, sk = P[i, 0], P[i, 1], P[i, 2], P[i, 3], P[i, 4], P[i, 5], P[i, 6]
            ax = (1.0 + asp) * mx[i] + sk * my[i]
            ay = my[i]
            r2 = ax * ax + ay * ay
            R = r2 * (K1 + r2 * (K2 + r2 * K3))
            gx = ax * (1.0 + R) + P1 * (r2 + 2 * ax * ax) + 2 * P2 * ax * ay
            gy = ay * (1.0 + R) + P2 * (r2 + 2 * ay * ay) + 2 * P1 * ax * ay
            rx, ry = gx - xb[i], gy - yb[i]
            ok[i] = abs(rx) + abs(ry) <= tol * scale[i]
            all_done = all_done and ok[i]
            dR = K1 + r2 * (2.0 * K2 + 3.0 * K3 * r2)
            H00 = 1.0 + R + 2 * dR * ax * ax + 6 * P1 * ax + 2 * P2 * ay
            H01 = 2 * dR * ax * ay + 2 * P1 * ay + 2 * P2 * ax
            H10 = 2 * dR * ax * ay + 2 * P2 * ax + 2 * P1 * ay
            H11 = 1.0 + R + 2 * dR * ay * ay + 2 * P1 * ax + 6 * P2 * ay
            G00, G01 = H00 * (1.0 + asp), H00 * sk + H01
            G10, G11 = H10 * (1.0 + asp), H10 * sk + H11
            det = G00 * G11 - G01 * G10
            if det > 1e-12:                       # beyond the fold of g (det ≤ 0) there is no inverse
                sx[i] = (G11 * rx - G01 * ry) / det
                sy[i] = (-G10 * rx + G00 * ry) / det
            else:
                sx[i], sy[i] = 0.0, 0.0
        if all_done:
            break
        for i in range(n):
            mx[i] -= sx[i]
            my[i] -= sy[i]
    for i in range(n):                            # no inverse: the first-order value, finite
        if not (ok[i] and np.isfinite(mx[i]) and np.isfinite(my[i])):
            mx[i], my[i], ok[i] = m0x[i], m0y[i], False


def brown_invert(xbar, ybar, P, tol, max_iter):
    """``m = g⁻¹(x̄)`` of the ``brown-backward`` correction ``g`` (:class:`.models.BrownBackward`)
    by Newton's method: every point is stepped until all satisfy ``|g(m) − x̄|₁ ≤ tol · max(1, |x̄|₁)``
    (as the numpy form, so results agree with it to the last bit); ``P`` (n, 7) the parameters of
    each point's camera.  Returns ``(mx, my, ok)``: a point without an inverse (not converged in
    ``max_iter`` steps, beyond the fold of ``g``) keeps the first-order value ``2x̄ − g(x̄)``, ``ok``
    False."""
    n = len(xbar)
    mx, my, ok = np.empty(n), np.empty(n), np.empty(n, np.bool_)
    _brown_invert(_f(xbar), _f(ybar), _f(P), float(tol), int(max_iter), mx, my, ok)
    return mx, my, ok


def _f(a):
    """float64, C-contiguous and writeable (numba compiles read-only arrays separately)."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    return a if a.flags.writeable else a.copy()
