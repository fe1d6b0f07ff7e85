"""The ``metashape`` AP model: Agisoft Metashape's frame camera in baarda's units, for the terms
``brown`` cannot hold (k4, p3, p4, and b1/b2 applied to the distorted coordinates).

With ideal reduced coordinates ``x̄, ȳ`` (mm, y up), ``r² = x̄² + ȳ²``::

    rad  = K1 r² + K2 r⁴ + K3 r⁶ + K4 r⁸          tan = 1 + P3 r² + P4 r⁴
    x_d  = x̄ (1 + rad) + (P1 (r² + 2x̄²) + 2 P2 x̄ȳ) · tan
    y_d  = ȳ (1 + rad) + (P2 (r² + 2ȳ²) + 2 P1 x̄ȳ) · tan
    Δx   = x_d − x̄ + B1 x_d + B2 y_d                Δy = y_d − ȳ

From Metashape's pixel terms (f, b1, b2 px; k, p of normalised coordinates) with ``c = f·p``:
K1..K4 = k1/c², k2/c⁴, k3/c⁶, k4/c⁸; P1 = p1/c, P2 = −p2/c; P3 = p3/c², P4 = p4/c⁴;
B1 = b1/f, B2 = −b2/f (``docs/metashape-opensfm.md``).  Δ does not depend on c.
"""

from __future__ import annotations

import numpy as np

from .models import APModel


class MetashapeAP(APModel):
    name = "metashape"
    params = ("K1", "K2", "K3", "K4", "P1", "P2", "P3", "P4", "B1", "B2")
    default_sigma = (np.inf,) * 10
    uses_c = False

    @staticmethod
    def _parts(x, y, q):
        r2 = x * x + y * y
        K1, K2, K3, K4, P1, P2, P3, P4, B1, B2 = (q[:, j] for j in range(10))
        rad = r2 * (K1 + r2 * (K2 + r2 * (K3 + r2 * K4)))
        tan = 1 + r2 * (P3 + r2 * P4)
        dx = P1 * (r2 + 2 * x * x) + 2 * P2 * x * y
        dy = P2 * (r2 + 2 * y * y) + 2 * P1 * x * y
        xd, yd = x * (1 + rad) + dx * tan, y * (1 + rad) + dy * tan
        return r2, rad, tan, dx, dy, xd, yd, B1, B2

    def distortion(self, xbar, ybar, params, c, meta):
        x, y = np.asarray(xbar, float), np.asarray(ybar, float)
        q = np.broadcast_to(np.asarray(params, float), (x.shape[0], 10))
        r2, rad, tan, dx, dy, xd, yd, B1, B2 = self._parts(x, y, q)
        return xd - x + B1 * xd + B2 * yd, yd - y

    def jacobian_params(self, xbar, ybar, params, c, meta):
        x, y = np.asarray(xbar, float), np.asarray(ybar, float)
        n = x.shape[0]
        q = np.broadcast_to(np.asarray(params, float), (n, 10))
        r2, rad, tan, dx, dy, xd, yd, B1, B2 = self._parts(x, y, q)
        # ∂(x_d, y_d)/∂params, then Δx = (1 + B1) x_d + B2 y_d − x̄, Δy = y_d − ȳ
        D = np.zeros((n, 2, 10))
        for i in range(4):
            D[:, 0, i] = x * r2 ** (i + 1)
            D[:, 1, i] = y * r2 ** (i + 1)
        D[:, 0, 4], D[:, 1, 4] = (r2 + 2 * x * x) * tan, 2 * x * y * tan
        D[:, 0, 5], D[:, 1, 5] = 2 * x * y * tan, (r2 + 2 * y * y) * tan
        D[:, 0, 6], D[:, 1, 6] = dx * r2, dy * r2
        D[:, 0, 7], D[:, 1, 7] = dx * r2 * r2, dy * r2 * r2
        J = np.zeros((n, 2, 10))
        J[:, 0, :8] = (1 + B1)[:, None] * D[:, 0, :8] + B2[:, None] * D[:, 1, :8]
        J[:, 1, :8] = D[:, 1, :8]
        J[:, 0, 8], J[:, 0, 9] = xd, yd
        return J

    def jacobian_xy(self, xbar, ybar, params, c, meta):
        x, y = np.asarray(xbar, float), np.asarray(ybar, float)
        n = x.shape[0]
        q = np.broadcast_to(np.asarray(params, float), (n, 10))
        K1, K2, K3, K4, P1, P2, P3, P4, B1, B2 = (q[:, j] for j in range(10))
        r2, rad, tan, dx, dy, xd, yd, _, _ = self._parts(x, y, q)
        drad = K1 + r2 * (2 * K2 + r2 * (3 * K3 + r2 * 4 * K4))          # ∂rad/∂r²
        dtan = P3 + 2 * P4 * r2                                           # ∂tan/∂r²
        # ∂x_d/∂x̄ etc. (∂r²/∂x̄ = 2x̄)
        xdx = 1 + rad + x * drad * 2 * x + (P1 * 6 * x + 2 * P2 * y) * tan + dx * dtan * 2 * x
        xdy = x * drad * 2 * y + (P1 * 2 * y + 2 * P2 * x) * tan + dx * dtan * 2 * y
        ydx = y * drad * 2 * x + (P2 * 2 * x + 2 * P1 * y) * tan + dy * dtan * 2 * x
        ydy = 1 + rad + y * drad * 2 * y + (P2 * 6 * y + 2 * P1 * x) * tan + dy * dtan * 2 * y
        out = np.zeros((n, 2, 2))
        out[:, 0, 0] = (1 + B1) * xdx + B2 * ydx - 1
        out[:, 0, 1] = (1 + B1) * xdy + B2 * ydy
        out[:, 1, 0] = ydx
        out[:, 1, 1] = ydy - 1
        return out
