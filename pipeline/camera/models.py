"""Additional-parameter (camera distortion) models and their registry.

Every model describes the image error ``(Δx, Δy)`` that is **added** to the ideal collinearity
projection (``docs/conventions.md``)::

    x = xp + x̄ + Δx(x̄, ȳ; ap),   y = yp + ȳ + Δy(x̄, ȳ; ap),   x̄ = −c U/W,  ȳ = −c V/W

``x̄, ȳ`` are the *ideal* reduced image coordinates (projected, relative to the principal point,
mm).  Evaluating the model at the projected rather than the observed coordinates keeps the
adjustment a pure Gauss–Markov model; the difference is second order in the distortion.

The principal distance ``c`` and the principal point ``xp, yp`` are not additional parameters:
they are the interior-orientation unknowns every camera has (Ebner's dc, dxp, dyp are these).

A model is any object with

* ``name`` and ``params`` (tuple of parameter names) and ``default_sigma`` (a-priori sigmas,
  ``inf`` free, ``0`` fixed — used when a camera gives no sigma of its own);
* ``distortion(xbar, ybar, params, c, meta) -> (dx, dy)`` — vectorised: ``xbar, ybar (n,)``,
  ``params (n, p)`` (one row per point, so cameras can be mixed), ``c (n,)``;
* optionally ``jacobian_params(...) -> (n, 2, p)``, ``jacobian_xy(...) -> (n, 2, 2)``
  (``[[∂Δx/∂x̄, ∂Δx/∂ȳ], [∂Δy/∂x̄, ∂Δy/∂ȳ]]``) and ``jacobian_c(...) -> (n, 2)`` (the partial
  derivative w.r.t. ``c`` at fixed x̄, ȳ).  :class:`APModel` supplies central-difference
  fallbacks of all three, so a third-party model needs only ``distortion``; a model whose Δ does
  not depend on c sets ``uses_c = False`` (exact zero, no extra evaluations).

Models are found by name through the registry (:mod:`.registry`): built-in and third-party models
alike register through the entry-point group ``baarda.camera_models``.  Formulas and units of the
built-in models: ``docs/camera-models.md``.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

__all__ = ["APModel", "LinearAPModel", "NoAP", "Ebner12", "Brown", "Aicon", "BrownBackward", "adapt_model"]


class APModel:
    """Base class: numeric derivatives for models that give only :meth:`distortion`."""

    name: str = ""
    params: tuple[str, ...] = ()
    default_sigma: tuple[float, ...] = ()
    uses_c: bool = True
    """Whether Δ depends on c (at fixed x̄, ȳ).  Unknown for a third-party model, hence ``True``:
    ``jacobian_c`` then differentiates numerically.  The built-in models set ``False``."""

    @property
    def n_params(self) -> int:
        return len(self.params)

    def distortion(self, xbar, ybar, params, c, meta: Mapping):  # pragma: no cover - abstract
        raise NotImplementedError

    # -- numeric fallbacks -------------------------------------------------------------------
    def jacobian_params(self, xbar, ybar, params, c, meta):
        params = np.asarray(params, float)
        n, p = params.shape
        out = np.zeros((n, 2, p))
        for j in range(p):
            h = 1e-6 * np.maximum(1.0, np.abs(params[:, j]))
            pp, pm = params.copy(), params.copy()
            pp[:, j] += h
            pm[:, j] -= h
            dxp, dyp = self.distortion(xbar, ybar, pp, c, meta)
            dxm, dym = self.distortion(xbar, ybar, pm, c, meta)
            out[:, 0, j] = (dxp - dxm) / (2 * h)
            out[:, 1, j] = (dyp - dym) / (2 * h)
        return out

    def jacobian_xy(self, xbar, ybar, params, c, meta):
        xbar = np.asarray(xbar, float)
        ybar = np.asarray(ybar, float)
        h = 1e-6 * np.maximum(1.0, np.abs(xbar) + np.abs(ybar))
        out = np.zeros((xbar.shape[0], 2, 2))
        a = self.distortion(xbar + h, ybar, params, c, meta)
        b = self.distortion(xbar - h, ybar, params, c, meta)
        out[:, 0, 0] = (a[0] - b[0]) / (2 * h)
        out[:, 1, 0] = (a[1] - b[1]) / (2 * h)
        a = self.distortion(xbar, ybar + h, params, c, meta)
        b = self.distortion(xbar, ybar - h, params, c, meta)
        out[:, 0, 1] = (a[0] - b[0]) / (2 * h)
        out[:, 1, 1] = (a[1] - b[1]) / (2 * h)
        return out

    def jacobian_c(self, xbar, ybar, params, c, meta):
        """``∂(Δx, Δy)/∂c`` at fixed x̄, ȳ, ``(n, 2)``: central differences of :meth:`distortion`
        (exact zeros when the model declares ``uses_c = False``)."""
        n = np.asarray(xbar).shape[0]
        if not self.uses_c:
            return np.zeros((n, 2))
        c = np.broadcast_to(np.asarray(c, float), (n,))
        h = 1e-6 * np.maximum(1.0, np.abs(c))
        a = self.distortion(xbar, ybar, params, c + h, meta)
        b = self.distortion(xbar, ybar, params, c - h, meta)
        return np.column_stack([(a[0] - b[0]) / (2 * h), (a[1] - b[1]) / (2 * h)])

    def jacobians(self, xbar, ybar, params, c, meta, cols):
        """All derivatives at once (the bundle's inner loop): ``(J_params[:, :, cols] (n, 2, len(cols)),
        J_xy (n, 2, 2), J_c (n, 2) or None when Δ does not depend on c)``.  Models may override this
        to share work between the three; the default calls the separate methods (so a model's own
        or the central-difference ``jacobian_c`` is used unless ``uses_c = False``)."""
        cols = np.asarray(cols, int)
        Jp = self.jacobian_params(xbar, ybar, params, c, meta)[:, :, cols] if len(cols) else \
            np.zeros((np.asarray(xbar).shape[0], 2, 0))
        Jc = self.jacobian_c(xbar, ybar, params, c, meta) if self.uses_c else None
        return Jp, self.jacobian_xy(xbar, ybar, params, c, meta), Jc

    def __repr__(self):
        return f"<AP model {self.name!r}: {', '.join(self.params) or 'no parameters'}>"


class LinearAPModel(APModel):
    """A model linear in its parameters: ``Δ = basis(x̄, ȳ) @ params``.

    Subclasses give ``basis(xbar, ybar, c, meta) -> (n, 2, p)`` and
    ``basis_xy(xbar, ybar, c, meta) -> (n, 2, 2, p)`` (derivatives of the basis w.r.t. x̄, ȳ);
    distortion and all Jacobians follow exactly.
    """

    def basis(self, xbar, ybar, c, meta):  # pragma: no cover - abstract
        raise NotImplementedError

    def basis_xy(self, xbar, ybar, c, meta):  # pragma: no cover - abstract
        raise NotImplementedError

    def distortion(self, xbar, ybar, params, c, meta):
        B = self.basis(np.asarray(xbar, float), np.asarray(ybar, float), c, meta)
        d = (B * _rows(params, B.shape[0], B.shape[2])[:, None, :]).sum(axis=2)
        return d[:, 0], d[:, 1]

    def jacobian_params(self, xbar, ybar, params, c, meta):
        return self.basis(np.asarray(xbar, float), np.asarray(ybar, float), c, meta)

    def jacobian_xy(self, xbar, ybar, params, c, meta):
        Bxy = self.basis_xy(np.asarray(xbar, float), np.asarray(ybar, float), c, meta)
        return (Bxy * _rows(params, Bxy.shape[0], Bxy.shape[3])[:, None, None, :]).sum(axis=3)


def _rows(params, n, p):
    params = np.asarray(params, float)
    if params.ndim == 1:
        params = np.broadcast_to(params, (n, params.shape[0]))
    return params[:, :p]


class NoAP(LinearAPModel):
    """No additional parameters (pure collinearity with c, xp, yp)."""

    uses_c = False

    name = "none"
    params = ()
    default_sigma = ()

    def basis(self, xbar, ybar, c, meta):
        return np.zeros((np.asarray(xbar).shape[0], 2, 0))

    def basis_xy(self, xbar, ybar, c, meta):
        return np.zeros((np.asarray(xbar).shape[0], 2, 2, 0))


class Ebner12(LinearAPModel):
    """Ebner's 12 orthogonal parameters b1 … b12 (SPEC §2); ``meta['b']`` is the image base (mm).

    ``k = x̄² − 2b²/3``, ``l = ȳ² − 2b²/3``::

        Δx =  b1 x̄ + b2 ȳ − b3 (2x̄² − 4b²/3) + b4 x̄ȳ + b5 l + b7 x̄ l + b9 ȳ k + b11 k l
        Δy = −b1 ȳ + b2 x̄ + b3 x̄ȳ − b4 (2ȳ² − 4b²/3) + b6 k + b8 ȳ k + b10 x̄ l + b12 k l
    """

    uses_c = False

    name = "ebner12"
    params = tuple(f"b{i}" for i in range(1, 13))
    default_sigma = (np.inf,) * 12

    @staticmethod
    def _b(meta, n):
        b = meta.get("b") if meta is not None else None
        if b is None:
            raise ValueError("ebner12 needs the image base b (mm) in the camera's AP meta "
                             "(option 'ebner_b' or block.meta['ap_meta'][camera]['b'])")
        return np.broadcast_to(np.asarray(b, float), (n,))

    def basis(self, xbar, ybar, c, meta):
        x, y = xbar, ybar
        n = x.shape[0]
        b = self._b(meta, n)
        q = 2.0 * b * b / 3.0
        k = x * x - q
        l = y * y - q
        B = np.zeros((n, 2, 12))
        B[:, 0, 0], B[:, 1, 0] = x, -y
        B[:, 0, 1], B[:, 1, 1] = y, x
        B[:, 0, 2], B[:, 1, 2] = -2.0 * k, x * y
        B[:, 0, 3], B[:, 1, 3] = x * y, -2.0 * l
        B[:, 0, 4] = l
        B[:, 1, 5] = k
        B[:, 0, 6] = x * l
        B[:, 1, 7] = y * k
        B[:, 0, 8] = y * k
        B[:, 1, 9] = x * l
        B[:, 0, 10] = k * l
        B[:, 1, 11] = k * l
        return B

    def basis_xy(self, xbar, ybar, c, meta):
        x, y = xbar, ybar
        n = x.shape[0]
        b = self._b(meta, n)
        q = 2.0 * b * b / 3.0
        k = x * x - q
        l = y * y - q
        D = np.zeros((n, 2, 2, 12))  # [k, component, d/dx or d/dy, param]
        one = np.ones(n)
        # b1
        D[:, 0, 0, 0] = one
        D[:, 1, 1, 0] = -one
        # b2
        D[:, 0, 1, 1] = one
        D[:, 1, 0, 1] = one
        # b3: Δx = −2k, Δy = xy
        D[:, 0, 0, 2] = -4.0 * x
        D[:, 1, 0, 2] = y
        D[:, 1, 1, 2] = x
        # b4: Δx = xy, Δy = −2l
        D[:, 0, 0, 3] = y
        D[:, 0, 1, 3] = x
        D[:, 1, 1, 3] = -4.0 * y
        # b5: Δx = l
        D[:, 0, 1, 4] = 2.0 * y
        # b6: Δy = k
        D[:, 1, 0, 5] = 2.0 * x
        # b7: Δx = x l
        D[:, 0, 0, 6] = l
        D[:, 0, 1, 6] = 2.0 * x * y
        # b8: Δy = y k
        D[:, 1, 0, 7] = 2.0 * x * y
        D[:, 1, 1, 7] = k
        # b9: Δx = y k
        D[:, 0, 0, 8] = 2.0 * x * y
        D[:, 0, 1, 8] = k
        # b10: Δy = x l
        D[:, 1, 0, 9] = l
        D[:, 1, 1, 9] = 2.0 * x * y
        # b11: Δx = k l
        D[:, 0, 0, 10] = 2.0 * x * l
        D[:, 0, 1, 10] = 2.0 * y * k
        # b12: Δy = k l
        D[:, 1, 0, 11] = 2.0 * x * l
        D[:, 1, 1, 11] = 2.0 * y * k
        return D


class _RadialDecentringAffine(LinearAPModel):
    """Shared algebra of Brown/Fraser and AICON: 3 radial, 2 decentring, 2 affinity terms.

    ``Δx = x̄ Σ Ki (r^(2i) − r0^(2i)) + P1 (r² + 2x̄²) + 2 P2 x̄ȳ + B1 x̄ + B2 ȳ``,
    ``Δy = ȳ Σ Ki (r^(2i) − r0^(2i)) + P2 (r² + 2ȳ²) + 2 P1 x̄ȳ``; ``r0 = 0`` for Brown.
    """

    uses_c = False

    def _r0(self, meta, n):
        return np.zeros(n)

    def basis(self, xbar, ybar, c, meta):
        x, y = xbar, ybar
        n = x.shape[0]
        r0sq = self._r0(meta, n) ** 2
        r2 = x * x + y * y
        B = np.zeros((n, 2, 7))
        for i in range(3):
            rad = r2 ** (i + 1) - r0sq ** (i + 1)
            B[:, 0, i] = x * rad
            B[:, 1, i] = y * rad
        B[:, 0, 3] = r2 + 2 * x * x
        B[:, 1, 3] = 2 * x * y
        B[:, 0, 4] = 2 * x * y
        B[:, 1, 4] = r2 + 2 * y * y
        B[:, 0, 5] = x
        B[:, 0, 6] = y
        return B

    def basis_xy(self, xbar, ybar, c, meta):
        x, y = xbar, ybar
        n = x.shape[0]
        r0sq = self._r0(meta, n) ** 2
        r2 = x * x + y * y
        D = np.zeros((n, 2, 2, 7))
        for i in range(3):
            e = i + 1
            rad = r2 ** e - r0sq ** e
            drad = e * r2 ** (e - 1)  # d rad / d r²
            D[:, 0, 0, i] = rad + 2 * x * x * drad
            D[:, 0, 1, i] = 2 * x * y * drad
            D[:, 1, 0, i] = 2 * x * y * drad
            D[:, 1, 1, i] = rad + 2 * y * y * drad
        D[:, 0, 0, 3] = 6 * x
        D[:, 0, 1, 3] = 2 * y
        D[:, 1, 0, 3] = 2 * y
        D[:, 1, 1, 3] = 2 * x
        D[:, 0, 0, 4] = 2 * y
        D[:, 0, 1, 4] = 2 * x
        D[:, 1, 0, 4] = 2 * x
        D[:, 1, 1, 4] = 6 * y
        D[:, 0, 0, 5] = 1.0
        D[:, 0, 1, 6] = 1.0
        return D

    # -- direct formulas (no (n, 2, 2, 7) basis arrays; terms with all-zero parameters skipped) --------
    def _terms(self, xbar, ybar, params, meta):
        x = np.asarray(xbar, float)
        y = np.asarray(ybar, float)
        P = _rows(params, x.shape[0], 7)
        if P.shape[1] < 7:
            P = np.concatenate([P, np.zeros((P.shape[0], 7 - P.shape[1]))], axis=1)
        nz = [bool(np.any(P[:, j])) for j in range(7)]
        r0sq = self._r0(meta, x.shape[0]) ** 2
        return x, y, P, nz, r0sq, x * x + y * y

    @staticmethod
    def _poly(r2, K1, K2, K3, nz):
        """``K1 r² + K2 r⁴ + K3 r⁶`` and its derivative w.r.t. r² (Horner; zero K2, K3 skipped)."""
        if nz[2]:
            inner, dinner = K2 + r2 * K3, 2.0 * K2 + 3.0 * K3 * r2
        elif nz[1]:
            inner, dinner = K2, 2.0 * K2
        else:
            return K1 * r2, K1
        return r2 * (K1 + r2 * inner), K1 + r2 * dinner

    def distortion(self, xbar, ybar, params, c, meta):
        x, y, P, nz, r0sq, r2 = self._terms(xbar, ybar, params, meta)
        dx = np.zeros_like(x)
        dy = np.zeros_like(y)
        if nz[0] or nz[1] or nz[2]:
            rad, _ = self._poly(r2, P[:, 0], P[:, 1], P[:, 2], nz)
            if np.any(r0sq):
                rad = rad - self._poly(r0sq, P[:, 0], P[:, 1], P[:, 2], nz)[0]
            dx += x * rad
            dy += y * rad
        if nz[3]:
            dx += P[:, 3] * (r2 + 2 * x * x)
            dy += 2 * P[:, 3] * x * y
        if nz[4]:
            dx += 2 * P[:, 4] * x * y
            dy += P[:, 4] * (r2 + 2 * y * y)
        if nz[5]:
            dx += P[:, 5] * x
        if nz[6]:
            dx += P[:, 6] * y
        return dx, dy

    def jacobian_xy(self, xbar, ybar, params, c, meta):
        return self.jacobians(xbar, ybar, params, c, meta, ())[1]

    def jacobians(self, xbar, ybar, params, c, meta, cols):
        x, y, P, nz, r0sq, r2 = self._terms(xbar, ybar, params, meta)
        n = x.shape[0]
        D = np.zeros((n, 2, 2))
        if nz[0] or nz[1] or nz[2]:
            rad, drad = self._poly(r2, P[:, 0], P[:, 1], P[:, 2], nz)
            if np.any(r0sq):
                rad = rad - self._poly(r0sq, P[:, 0], P[:, 1], P[:, 2], nz)[0]
            t = 2.0 * drad
            xy2 = t * x * y
            D[:, 0, 0] = rad + t * x * x
            D[:, 0, 1] = xy2
            D[:, 1, 0] = xy2
            D[:, 1, 1] = rad + t * y * y
        if nz[3]:
            p1 = P[:, 3]
            D[:, 0, 0] += 6 * p1 * x
            D[:, 0, 1] += 2 * p1 * y
            D[:, 1, 0] += 2 * p1 * y
            D[:, 1, 1] += 2 * p1 * x
        if nz[4]:
            p2 = P[:, 4]
            D[:, 0, 0] += 2 * p2 * y
            D[:, 0, 1] += 2 * p2 * x
            D[:, 1, 0] += 2 * p2 * x
            D[:, 1, 1] += 6 * p2 * y
        if nz[5]:
            D[:, 0, 0] += P[:, 5]
        if nz[6]:
            D[:, 0, 1] += P[:, 6]
        cols = [int(j) for j in cols]
        Jp = np.zeros((n, 2, len(cols)))
        for a, j in enumerate(cols):
            if j < 3:
                e = j + 1
                rad = r2 ** e
                if np.any(r0sq):
                    rad = rad - r0sq ** e
                Jp[:, 0, a] = x * rad
                Jp[:, 1, a] = y * rad
            elif j == 3:
                Jp[:, 0, a] = r2 + 2 * x * x
                Jp[:, 1, a] = 2 * x * y
            elif j == 4:
                Jp[:, 0, a] = 2 * x * y
                Jp[:, 1, a] = r2 + 2 * y * y
            elif j == 5:
                Jp[:, 0, a] = x
            else:
                Jp[:, 0, a] = y
        return Jp, D, None


class Brown(_RadialDecentringAffine):
    """Brown/Fraser physical model: K1 K2 K3 (radial), P1 P2 (decentring), B1 B2 (affinity, shear).

    Units with x̄, ȳ, r in mm: K1 mm⁻², K2 mm⁻⁴, K3 mm⁻⁶, P1 P2 mm⁻¹, B1 B2 dimensionless.
    """

    name = "brown"
    params = ("K1", "K2", "K3", "P1", "P2", "B1", "B2")
    default_sigma = (np.inf,) * 7


class Aicon(_RadialDecentringAffine):
    """AICON 3D Studio's model: A1 A2 A3 (radial, balanced at r0 = ``meta['r0']`` mm),
    B1 B2 (decentring), C1 C2 (affinity, shear)."""

    name = "aicon"
    params = ("A1", "A2", "A3", "B1", "B2", "C1", "C2")
    default_sigma = (np.inf,) * 7

    def _r0(self, meta, n):
        r0 = 0.0 if meta is None else meta.get("r0", 0.0)
        return np.broadcast_to(np.asarray(r0, float), (n,))


def adapt_model(name: str, model) -> APModel:
    """``model`` as an :class:`APModel`: checked (``params``, ``distortion``), a duck-typed one wrapped
    so that missing Jacobians fall back to central differences, ``default_sigma`` completed."""
    if not name or not isinstance(name, str):
        raise ValueError("AP model name must be a non-empty string")
    for attr in ("params", "distortion"):
        if not hasattr(model, attr):
            raise ValueError(f"AP model {name!r} has no '{attr}'")
    if not isinstance(model, APModel):
        model = _Adapter(model)
    sig = tuple(getattr(model, "default_sigma", ()) or ())
    if len(sig) != len(model.params):
        model.default_sigma = (np.inf,) * len(model.params)
    return model


class _Adapter(APModel):
    """Wraps a duck-typed third-party model so missing Jacobians fall back to differences."""

    def __init__(self, inner):
        self._inner = inner
        self.name = getattr(inner, "name", "")
        self.params = tuple(inner.params)
        self.default_sigma = tuple(getattr(inner, "default_sigma", (np.inf,) * len(self.params)))
        self.uses_c = bool(getattr(inner, "uses_c", True))

    def distortion(self, xbar, ybar, params, c, meta):
        return self._inner.distortion(xbar, ybar, params, c, meta)

    def jacobian_params(self, *a):
        f = getattr(self._inner, "jacobian_params", None)
        return f(*a) if f else super().jacobian_params(*a)

    def jacobian_xy(self, *a):
        f = getattr(self._inner, "jacobian_xy", None)
        return f(*a) if f else super().jacobian_xy(*a)

    def jacobian_c(self, *a):
        f = getattr(self._inner, "jacobian_c", None)
        return f(*a) if f else super().jacobian_c(*a)


class BrownBackward(APModel):
    """PhotoModeler / DBAT "backward" Brown model (DBAT lens model 3): the distortion *correction*
    is a function of the **measured** reduced coordinates, with aspect and skew.

    With ``m = (mx, my)`` the measured coordinates relative to the principal point (mm, y up)::

        a  = (ax, ay) = ((1 + aspect) mx + skew my,  my)
        r² = ax² + ay²,   R = K1 r² + K2 r⁴ + K3 r⁶
        g(m) = a (1 + R) + (P1 (r² + 2ax²) + 2 P2 ax ay,  P2 (r² + 2ay²) + 2 P1 ax ay)

    and the observation equation of DBAT/PhotoModeler is ``g(m) = (x̄, ȳ)`` (the corrected
    measurement equals the ideal projection).  baarda keeps the measured coordinates as the
    observations: the model's distortion is the exact inverse, ``Δ(x̄) = g⁻¹(x̄) − x̄`` (Newton
    iterations to 1e-13 mm), so ``x = xp + g⁻¹(x̄)`` predicts the measurement.  Beyond the radius
    where ``g`` folds back (``det ∂g/∂m ≤ 0``, far outside the format for a real lens) there is no
    inverse; such a point keeps the first-order value ``2x̄ − g(x̄)``.  Jacobians by the
    implicit-function theorem: ``∂Δ/∂x̄ = G⁻¹ − I``, ``∂Δ/∂θ = −G⁻¹ ∂g/∂θ`` with ``G = ∂g/∂m``.
    :meth:`correct` evaluates ``g`` itself (used for initial values).

    Parameters in baarda's image frame (y up).  DBAT's image frame has y down: its P2 and skew
    are the negatives of these, K1–K3, P1 and aspect are the same (``docs/camera-models.md``).
    Units: K1 mm⁻², K2 mm⁻⁴, K3 mm⁻⁶, P1 P2 mm⁻¹, aspect and skew dimensionless.
    """

    name = "brown-backward"
    params = ("K1", "K2", "K3", "P1", "P2", "aspect", "skew")
    default_sigma = (np.inf,) * 7
    uses_c = False
    backward = True
    """Marks a model whose parameters describe the correction of the measured coordinates."""

    newton_tol = 1e-13
    newton_max_iter = 30

    # -- the correction g(m) and its derivatives ------------------------------------------------
    @staticmethod
    def _correction(mx, my, P, want_jac: bool):
        K1, K2, K3, P1, P2, asp, sk = (P[:, j] for j in range(7))
        ax = (1.0 + asp) * mx + sk * my
        ay = my
        r2 = ax * ax + ay * ay
        R = r2 * (K1 + r2 * (K2 + r2 * K3))
        gx = ax * (1.0 + R) + P1 * (r2 + 2 * ax * ax) + 2 * P2 * ax * ay
        gy = ay * (1.0 + R) + P2 * (r2 + 2 * ay * ay) + 2 * P1 * ax * ay
        if not want_jac:
            return gx, gy, None, None
        dR = K1 + r2 * (2.0 * K2 + 3.0 * K3 * r2)           # dR / d(r²)
        # H = ∂g/∂a
        H = np.empty((mx.shape[0], 2, 2))
        H[:, 0, 0] = 1.0 + R + 2 * dR * ax * ax + 6 * P1 * ax + 2 * P2 * ay
        H[:, 0, 1] = 2 * dR * ax * ay + 2 * P1 * ay + 2 * P2 * ax
        H[:, 1, 0] = 2 * dR * ax * ay + 2 * P2 * ax + 2 * P1 * ay
        H[:, 1, 1] = 1.0 + R + 2 * dR * ay * ay + 2 * P1 * ax + 6 * P2 * ay
        # G = ∂g/∂m = H A,  A = [[1 + aspect, skew], [0, 1]]
        G = np.empty_like(H)
        G[:, :, 0] = H[:, :, 0] * (1.0 + asp)[:, None]
        G[:, :, 1] = H[:, :, 0] * sk[:, None] + H[:, :, 1]
        Gp = np.empty((mx.shape[0], 2, 7))
        Gp[:, 0, 0], Gp[:, 1, 0] = ax * r2, ay * r2
        Gp[:, 0, 1], Gp[:, 1, 1] = ax * r2 ** 2, ay * r2 ** 2
        Gp[:, 0, 2], Gp[:, 1, 2] = ax * r2 ** 3, ay * r2 ** 3
        Gp[:, 0, 3], Gp[:, 1, 3] = r2 + 2 * ax * ax, 2 * ax * ay
        Gp[:, 0, 4], Gp[:, 1, 4] = 2 * ax * ay, r2 + 2 * ay * ay
        Gp[:, :, 5] = H[:, :, 0] * mx[:, None]
        Gp[:, :, 6] = H[:, :, 0] * my[:, None]
        return gx, gy, G, Gp

    @staticmethod
    def _params(params, n):
        P = _rows(params, n, 7)
        if P.shape[1] < 7:
            P = np.concatenate([P, np.zeros((n, 7 - P.shape[1]))], axis=1)
        return P

    def correct(self, mx, my, params, c=None, meta=None):
        """``g(m)``: the corrected (ideal) reduced coordinates of measured reduced coordinates."""
        mx = np.asarray(mx, float)
        my = np.asarray(my, float)
        gx, gy, _, _ = self._correction(mx, my, self._params(params, mx.shape[0]), False)
        return gx, gy

    def correct_jacobians(self, mx, my, params, c=None, meta=None):
        """``g(m)`` with its derivatives at measured reduced coordinates: ``(gx, gy, G = ∂g/∂m
        (n, 2, 2), ∂g/∂θ (n, 2, 7))`` — DBAT's residual in the bundle (``pipeline/adjustment/corrected.py``)."""
        mx = np.asarray(mx, float)
        my = np.asarray(my, float)
        return self._correction(mx, my, self._params(params, mx.shape[0]), True)

    def _invert(self, xbar, ybar, P):
        """``m = g⁻¹(x̄)`` by Newton's method; returns m (n, 2), G and ∂g/∂θ at m."""
        xb = np.asarray(xbar, float)
        yb = np.asarray(ybar, float)
        m = self._inverse(xb, yb, P)
        _, _, G, Gp = self._correction(m[:, 0], m[:, 1], P, True)
        return m, G, Gp

    def _inverse(self, xb, yb, P):
        """``m = g⁻¹(x̄)`` (n, 2) alone: Newton per point in one compiled pass (numpy evaluated g and
        ∂g/∂m for every point in every step: 3.8 s of the 24 s CPU of DBAT's 90 561-mark Roma
        project, now < 0.1 s); a point without an inverse (far outside the format, beyond the
        radius where the correction folds back) keeps the first-order value m ≈ x̄ − (g(x̄) − x̄):
        finite, so that initial iterations can go on."""
        from .kernels import brown_invert

        mx, my, _ = brown_invert(xb, yb, P, self.newton_tol, self.newton_max_iter)
        return np.column_stack([mx, my])

    def distortion(self, xbar, ybar, params, c, meta):
        xb = np.asarray(xbar, float)
        yb = np.asarray(ybar, float)
        m = self._inverse(xb, yb, self._params(params, xb.shape[0]))
        return m[:, 0] - xb, m[:, 1] - yb

    def jacobians(self, xbar, ybar, params, c, meta, cols):
        xb = np.asarray(xbar, float)
        n = xb.shape[0]
        _, G, Gp = self._invert(xb, ybar, self._params(params, n))
        det = G[:, 0, 0] * G[:, 1, 1] - G[:, 0, 1] * G[:, 1, 0]
        Gi = np.empty_like(G)
        Gi[:, 0, 0] = G[:, 1, 1] / det
        Gi[:, 0, 1] = -G[:, 0, 1] / det
        Gi[:, 1, 0] = -G[:, 1, 0] / det
        Gi[:, 1, 1] = G[:, 0, 0] / det
        D = Gi.copy()
        D[:, 0, 0] -= 1.0
        D[:, 1, 1] -= 1.0
        cols = np.asarray(cols, int)
        Jp = -np.einsum("nij,njk->nik", Gi, Gp[:, :, cols]) if len(cols) else np.zeros((n, 2, 0))
        return Jp, D, None

    def jacobian_params(self, xbar, ybar, params, c, meta):
        return self.jacobians(xbar, ybar, params, c, meta, np.arange(7))[0]

    def jacobian_xy(self, xbar, ybar, params, c, meta):
        return self.jacobians(xbar, ybar, params, c, meta, ())[1]
