"""Camera models that project from the ray: fisheye, omnidirectional and wide-angle lenses.

The additive models of :mod:`.models` distort the pinhole projection ``x̄ = −c U/W``, which has no
image of a ray at 90° to the axis (``W = 0``) and a mirrored one beyond (``W > 0``).  A *ray model*
maps the camera-frame vector ``d = (U, V, W)`` (``docs/conventions.md``: the camera looks along −W)
straight to reduced image coordinates (mm, relative to the principal point, y up)::

    x = xp + fx(d; c, ap),   y = yp + fy(d; c, ap)

It declares ``ray = True`` and gives

* ``project_ray(d, params, c, meta) -> (xy (n, 2), valid (n,))`` — ``valid`` False where the model
  has no image of the ray (behind the field of a model, outside the domain of a division model …;
  ``xy`` is NaN there);
* ``ray_jacobians(d, params, c, meta, cols) -> (xy, valid, J_d (n, 2, 3), J_p (n, 2, len(cols)),
  J_c (n, 2))`` — derivatives w.r.t. the ray, the model's parameters ``cols`` and ``c``.

:class:`baarda.pipeline.adjustment.collinearity.Projector` uses these for every camera whose model
is a ray model and chains ``J_d`` into the pose and the point; an observation whose ray the model
cannot represent stops the projection with :class:`RayOutsideModel` (never a NaN in the normal
equations).  For rays in front of the camera a ray model is also an additive model
(``distortion(x̄, ȳ) = project_ray((x̄, ȳ, −c)) − (x̄, ȳ)``), so code that only knows the additive
interface (initial values, calibration-quality figures) works unchanged there.

Two families:

* COLMAP's models (``simple-fisheye`` … ``equirectangular``), parameterised as COLMAP and OpenCV
  do: the normalised coordinates of the ray in OpenCV's camera frame ``(a, b, z) = (U, −V, −W)``
  (x right, y *down*, z forward) are distorted with dimensionless coefficients and scaled with
  ``fx = c (1 + B1)`` and ``fy = c`` (mm): ``x = c (1 + B1) u_d``, ``y = −c v_d``.  ``B1 = fx/fy − 1``
  as in the ``brown`` model; a model with one focal length (``SIMPLE_…``) has no ``B1``.  With
  ``c = fy · pixel`` the parameters are COLMAP's own numbers (:mod:`.convert`).
* Photogrammetric fisheye projections (``fisheye-equidistant``, ``-equisolid``, ``-stereographic``,
  ``-orthographic``): ``r = c g(θ)`` followed by the ``brown`` model's seven terms in mm.

Formulas, units and sources: ``docs/camera-models.md``.  Jacobians are analytic; the polynomial
distortion stages of the COLMAP fisheye models are differentiated by the complex step (exact to
rounding, no truncation error), and ``tests/camera/test_ray_models.py`` checks every model against
central differences, pycolmap's ``Camera.img_from_cam`` and OpenCV's ``cv2.fisheye``.
"""

from __future__ import annotations

from abc import ABCMeta, abstractmethod
from typing import Mapping

import numpy as np

from baarda.pipeline.errors import AdjustmentError

from .models import APModel, Brown, _rows

__all__ = ["RayModel", "RayOutsideModel", "is_ray_model", "COLMAP_RAY_MODELS", "SimpleFisheye", "Fisheye",
           "SimpleRadialFisheye", "RadialFisheye", "OpenCVFisheye", "ThinPrismFisheye", "RadTanThinPrismFisheye",
           "FOV", "EUCM", "Division", "SimpleDivision", "Equirectangular", "FisheyeEquidistant",
           "FisheyeEquisolid", "FisheyeStereographic", "FisheyeOrthographic", "field_angle"]


class RayOutsideModel(AdjustmentError):
    """A camera model has no image of an observed ray (the adjustment stops with this message)."""


def is_ray_model(model) -> bool:
    return bool(getattr(model, "ray", False))


def field_angle(d) -> np.ndarray:
    """Angle between each ray ``d (n, 3)`` and the viewing direction −W, degrees."""
    d = np.asarray(d, float).reshape(-1, 3)
    return np.degrees(np.arctan2(np.hypot(d[:, 0], d[:, 1]), -d[:, 2]))


_SAFE_RAY = np.array([0.0, 0.0, -1.0])


class RayModel(APModel, metaclass=ABCMeta):
    """Base class of the ray models (see the module docstring)."""

    ray = True
    uses_c = True
    pixel_power: tuple | None = None
    """Per parameter, the power k of its unit mm⁻ᵏ (0: dimensionless; the reports' unit column)."""
    domain: str = "every ray but the zero vector"
    """What the model can project (the text of :class:`RayOutsideModel`)."""

    # -- to implement: everything at once --------------------------------------------------------
    @abstractmethod
    def _eval(self, d, P, c, meta, jac: bool):
        """``(xy (n, 2), valid (n,), J_d, J_p (all parameters), J_c)`` (Jacobians None unless ``jac``),
        for finite rays (invalid ones are replaced by the axis before the call).  The hook every ray
        model implements: a class without it cannot be instantiated (``TypeError`` naming it;
        docs/camera-models.md, the paragraph on models that project from the ray)."""

    def _prepare(self, d, params, c):
        d = np.array(d, float).reshape(-1, 3)
        n = d.shape[0]
        ok = np.isfinite(d).all(axis=1) & (np.abs(d).sum(axis=1) > 0)
        d[~ok] = _SAFE_RAY
        P = _rows(params, n, self.n_params) if self.n_params else np.zeros((n, 0))
        if P.shape[1] < self.n_params:
            P = np.concatenate([P, np.zeros((n, self.n_params - P.shape[1]))], axis=1)
        c = np.broadcast_to(np.asarray(c, float), (n,)).astype(float)
        return d, ok, P, c

    def project_ray(self, d, params, c, meta: Mapping | None = None):
        d, ok, P, c = self._prepare(d, params, c)
        xy, valid, *_ = self._eval(d, P, c, meta or {}, False)
        valid = valid & ok & np.isfinite(xy).all(axis=1)
        xy = np.where(valid[:, None], xy, np.nan)
        return xy, valid

    def ray_jacobians(self, d, params, c, meta: Mapping | None, cols):
        d, ok, P, c = self._prepare(d, params, c)
        xy, valid, Jd, Jp, Jc = self._eval(d, P, c, meta or {}, True)
        valid = valid & ok & np.isfinite(xy).all(axis=1)
        xy = np.where(valid[:, None], xy, np.nan)
        cols = np.asarray(cols, int)
        return xy, valid, Jd, Jp[:, :, cols], Jc

    # -- the additive interface, for rays in front of the camera ---------------------------------
    @staticmethod
    def _ray_of(xbar, ybar, c):
        x = np.asarray(xbar, float)
        c = np.broadcast_to(np.asarray(c, float), x.shape)
        return np.column_stack([x, np.asarray(ybar, float), -c])

    def distortion(self, xbar, ybar, params, c, meta):
        xy, _ = self.project_ray(self._ray_of(xbar, ybar, c), params, c, meta)
        return xy[:, 0] - np.asarray(xbar, float), xy[:, 1] - np.asarray(ybar, float)

    def jacobians(self, xbar, ybar, params, c, meta, cols):
        _, _, Jd, Jp, Jc = self.ray_jacobians(self._ray_of(xbar, ybar, c), params, c, meta, cols)
        D = Jd[:, :, :2].copy()
        D[:, 0, 0] -= 1.0
        D[:, 1, 1] -= 1.0
        return Jp, D, Jc - Jd[:, :, 2]          # ∂/∂c at fixed x̄: the ray (x̄, ȳ, −c) moves with c

    def jacobian_params(self, xbar, ybar, params, c, meta):
        return self.jacobians(xbar, ybar, params, c, meta, np.arange(self.n_params))[0]

    def jacobian_xy(self, xbar, ybar, params, c, meta):
        return self.jacobians(xbar, ybar, params, c, meta, ())[1]

    def jacobian_c(self, xbar, ybar, params, c, meta):
        return self.jacobians(xbar, ybar, params, c, meta, ())[2]


# ------------------------------------------------------------------------------------------------
# the field angle and a radial projection g(θ)
# ------------------------------------------------------------------------------------------------

_G = {
    "equidistant": (lambda t: t, lambda t: np.ones_like(t), np.pi),
    "equisolid": (lambda t: 2.0 * np.sin(t / 2), lambda t: np.cos(t / 2), np.pi),
    "stereographic": (lambda t: 2.0 * np.tan(t / 2), lambda t: 1.0 / np.cos(t / 2) ** 2, np.pi),
    "orthographic": (lambda t: np.sin(t), lambda t: np.cos(t), np.pi / 2),
}
"""``g(θ)``, ``g'(θ)`` and the largest field angle (exclusive, or inclusive for orthographic's 90°)."""


def _angle_map(x, y, z, kind="equidistant"):
    """``S = g(θ)/ρ`` of the ray ``(x, y, z)`` (z forward, ``ρ = √(x² + y²)``, ``θ = atan2(ρ, z)``),
    ``G = (∂S/∂ρ)/ρ``, ``Sz = ∂S/∂z`` and whether ``g`` has an image of the ray.  On the axis
    ``S = 1/z`` (every ``g`` here has ``g'(0) = 1``); there ``G`` is set to 0 (it multiplies x², xy, y²)."""
    g, dg, tmax = _G[kind]
    rho = np.hypot(x, y)
    n2 = rho * rho + z * z
    th = np.arctan2(rho, z)
    small = rho <= 1e-12 * np.sqrt(n2)
    rs = np.where(small, 1.0, rho)
    zs = np.where(small & (z > 0), z, 1.0)
    S = np.where(small, 1.0 / zs, g(th) / rs)
    gp = dg(th)
    G = np.where(small, 0.0, (gp * z / n2 - S) / (rs * rs))
    Sz = -gp / n2
    ok = (n2 > 0) & ~(small & (z <= 0))
    ok &= (th <= tmax) if kind == "orthographic" else (th < tmax)
    return S, G, Sz, th, ok


def _A(x, y, S, G, Sz):
    """``∂(x S, y S)/∂(x, y, z)`` (n, 2, 3)."""
    A = np.empty((x.shape[0], 2, 3))
    A[:, 0, 0] = S + x * x * G
    A[:, 0, 1] = A[:, 1, 0] = x * y * G
    A[:, 1, 1] = S + y * y * G
    A[:, 0, 2] = x * Sz
    A[:, 1, 2] = y * Sz
    return A


def _complex_step(fn, u, v, E):
    """``∂fn/∂(u, v)`` (n, 2, 2) and ``∂fn/∂E`` (n, 2, e) of a complex-analytic ``fn(u, v, E) -> (ud, vd)``
    by the complex step (``Im f(x + ih)/h``, h = 10⁻¹⁰⁰: exact to rounding)."""
    h = 1e-100
    n, ne = E.shape
    Juv = np.empty((n, 2, 2))
    JE = np.empty((n, 2, ne))
    uc, vc = u.astype(complex), v.astype(complex)
    for k, (du, dv) in enumerate(((1j * h, 0.0), (0.0, 1j * h))):
        a, b = fn(uc + du, vc + dv, E)
        Juv[:, 0, k], Juv[:, 1, k] = np.imag(a) / h, np.imag(b) / h
    for j in range(ne):
        Ec = E.astype(complex)
        Ec[:, j] += 1j * h
        a, b = fn(uc, vc, Ec)
        JE[:, 0, j], JE[:, 1, j] = np.imag(a) / h, np.imag(b) / h
    return Juv, JE


# ------------------------------------------------------------------------------------------------
# COLMAP's models: OpenCV's camera frame, normalised coordinates, fx = c (1 + B1), fy = c
# ------------------------------------------------------------------------------------------------

class _CVModel(RayModel):
    colmap: str = ""
    focal2: bool = True
    extra: tuple[str, ...] = ()

    def __init_subclass__(cls, **kw):
        super().__init_subclass__(**kw)
        if cls.colmap:
            cls.params = (("B1",) if cls.focal2 else ()) + tuple(cls.extra)
            cls.default_sigma = (np.inf,) * len(cls.params)
            cls.pixel_power = (0,) * len(cls.params)

    @abstractmethod
    def _normalized(self, a, b, z, E, jac):
        """``(ud, vd, valid, Jn (n, 2, 3) w.r.t. (a, b, z), JE (n, 2, e))``: the hook of every COLMAP
        model (a class without it cannot be instantiated)."""

    def _eval(self, d, P, c, meta, jac):
        a, b, z = d[:, 0], -d[:, 1], -d[:, 2]
        off = 1 if self.focal2 else 0
        s = 1.0 + P[:, 0] if self.focal2 else np.ones_like(c)
        ud, vd, valid, Jn, JE = self._normalized(a, b, z, P[:, off:], jac)
        xy = np.column_stack([c * s * ud, -c * vd])
        if not jac:
            return xy, valid, None, None, None
        n = d.shape[0]
        Jn = Jn.copy()
        Jn[:, :, 1:] *= -1.0                               # (a, b, z) = (U, −V, −W)
        Jd = np.empty((n, 2, 3))
        Jd[:, 0] = (c * s)[:, None] * Jn[:, 0]
        Jd[:, 1] = -c[:, None] * Jn[:, 1]
        Jp = np.zeros((n, 2, self.n_params))
        if self.focal2:
            Jp[:, 0, 0] = c * ud
        Jp[:, 0, off:] = (c * s)[:, None] * JE[:, 0]
        Jp[:, 1, off:] = -c[:, None] * JE[:, 1]
        Jc = np.column_stack([s * ud, -vd])
        return xy, valid, Jd, Jp, Jc


class _CVFisheye(_CVModel):
    """COLMAP's fisheye models: the equidistant angle ``(uu, vv) = θ (a, b)/ρ`` then a polynomial
    distortion of ``(uu, vv)``.  COLMAP computes θ as ``atan(ρ/z)`` (front hemisphere only); here
    ``θ = atan2(ρ, z)``, the same in front and continued to every ray but the one straight back."""

    domain = "every ray but the one straight behind the camera (field angle < 180°)"

    def _distort(self, u, v, E):
        return u, v

    def _normalized(self, a, b, z, E, jac):
        S, G, Sz, _, ok = _angle_map(a, b, z)
        uu, vv = a * S, b * S
        ud, vd = self._distort(uu, vv, E)
        if not jac:
            return ud, vd, ok, None, None
        Juv, JE = _complex_step(self._distort, uu, vv, E)
        Jn = np.einsum("nij,njk->nik", Juv, _A(a, b, S, G, Sz))
        return ud, vd, ok, Jn, JE


def _kb(u, v, K):
    """Kannala–Brandt radial polynomial: ``(u, v)(1 + Σ K_i θ^(2i))`` with ``θ² = u² + v²``."""
    t2 = u * u + v * v
    rad = 0.0
    for i in range(K.shape[1] - 1, -1, -1):
        rad = (rad + K[:, i]) * t2
    return u * (1.0 + rad), v * (1.0 + rad)


class SimpleFisheye(_CVFisheye):
    """COLMAP ``SIMPLE_FISHEYE``: equidistant, one focal length (``r = c θ``)."""
    name, colmap, focal2, extra = "simple-fisheye", "SIMPLE_FISHEYE", False, ()


class Fisheye(_CVFisheye):
    """COLMAP ``FISHEYE``: equidistant, ``fx = c (1 + B1)``, ``fy = c``."""
    name, colmap, focal2, extra = "fisheye", "FISHEYE", True, ()


class SimpleRadialFisheye(_CVFisheye):
    """COLMAP ``SIMPLE_RADIAL_FISHEYE``: ``θ_d = θ (1 + k θ²)``."""
    name, colmap, focal2, extra = "simple-radial-fisheye", "SIMPLE_RADIAL_FISHEYE", False, ("k",)

    def _distort(self, u, v, E):
        return _kb(u, v, E)


class RadialFisheye(_CVFisheye):
    """COLMAP ``RADIAL_FISHEYE``: ``θ_d = θ (1 + k1 θ² + k2 θ⁴)``."""
    name, colmap, focal2, extra = "radial-fisheye", "RADIAL_FISHEYE", False, ("k1", "k2")

    def _distort(self, u, v, E):
        return _kb(u, v, E)


class OpenCVFisheye(_CVFisheye):
    """OpenCV's fisheye model (Kannala–Brandt), COLMAP ``OPENCV_FISHEYE``:
    ``θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)``."""
    name, colmap, focal2, extra = "opencv-fisheye", "OPENCV_FISHEYE", True, ("k1", "k2", "k3", "k4")

    def _distort(self, u, v, E):
        return _kb(u, v, E)


class ThinPrismFisheye(_CVFisheye):
    """COLMAP ``THIN_PRISM_FISHEYE`` (Weng et al. 1992 on the equidistant angle): radial k1 k2 k3 k4,
    tangential p1 p2, thin prism sx1 sy1."""
    name, colmap, focal2 = "thin-prism-fisheye", "THIN_PRISM_FISHEYE", True
    extra = ("k1", "k2", "p1", "p2", "k3", "k4", "sx1", "sy1")

    def _distort(self, u, v, E):
        k1, k2, p1, p2, k3, k4, sx1, sy1 = (E[:, j] for j in range(8))
        u2, v2, uv = u * u, v * v, u * v
        r2 = u2 + v2
        rad = r2 * (k1 + r2 * (k2 + r2 * (k3 + r2 * k4)))
        du = u * rad + 2 * p1 * uv + p2 * (r2 + 2 * u2) + sx1 * r2
        dv = v * rad + 2 * p2 * uv + p1 * (r2 + 2 * v2) + sy1 * r2
        return u + du, v + dv


class RadTanThinPrismFisheye(_CVFisheye):
    """COLMAP ``RAD_TAN_THIN_PRISM_FISHEYE`` (Project Aria's "Fisheye624"): radial k0 … k5 on θ,
    then tangential p0 p1 and thin prism s0 … s3 on the radially distorted point."""
    name, colmap, focal2 = "rad-tan-thin-prism-fisheye", "RAD_TAN_THIN_PRISM_FISHEYE", True
    extra = ("k0", "k1", "k2", "k3", "k4", "k5", "p0", "p1", "s0", "s1", "s2", "s3")

    def _distort(self, u, v, E):
        x, y = _kb(u, v, E[:, :6])
        p0, p1, s0, s1, s2, s3 = (E[:, j] for j in range(6, 12))
        x2, y2, xy = x * x, y * y, x * y
        r2 = x2 + y2
        r4 = r2 * r2
        xd = x + 2 * p1 * xy + p0 * (r2 + 2 * x2) + s0 * r2 + s1 * r4
        yd = y + 2 * p0 * xy + p1 * (r2 + 2 * y2) + s2 * r2 + s3 * r4
        return xd, yd


class FOV(_CVModel):
    """COLMAP ``FOV`` (Devernay & Faugeras 2001): ``r_d = atan(2 tan(ω/2) tan θ)/ω``, here
    ``atan2(2 tan(ω/2) ρ, z)/ω`` so that rays beyond 90° have their image too (ω ≠ 0)."""
    name, colmap, focal2, extra = "fov", "FOV", True, ("omega",)
    domain = "every ray but the one straight behind the camera (field angle < 180°) when ω ≠ 0; " \
             "rays in front of the camera when ω = 0 (pinhole); |ω| < π"

    def _normalized(self, a, b, z, E, jac):
        w = E[:, 0]
        w0 = np.abs(w) < 1e-12
        ws = np.where(w0, 1.0, w)
        t = 2.0 * np.tan(ws / 2)
        rho = np.hypot(a, b)
        n2 = rho * rho + z * z
        small = rho <= 1e-12 * np.sqrt(n2)
        rs = np.where(small, 1.0, rho)
        zs = np.where(z > 0, z, 1.0)
        q = t * t * rho * rho + z * z
        phi = np.arctan2(t * rho, z)
        F = np.where(w0, 1.0 / zs, np.where(small, t / (zs * ws), phi / (rs * ws)))
        ok = (np.abs(w) < np.pi) & (n2 > 0) & np.where(w0 | small, z > 0, True)
        ud, vd = a * F, b * F
        if not jac:
            return ud, vd, ok, None, None
        G = np.where(w0 | small, 0.0, (t * z * rho / q - phi) / (rs ** 3 * ws))
        Fz = np.where(w0, -1.0 / zs ** 2, -t / (q * ws))
        Fw = np.where(w0, 0.0, z * (1.0 + t * t / 4) / (q * ws) - F / ws)
        Jn = _A(a, b, F, G, Fz)
        JE = np.stack([a * Fw, b * Fw], axis=1)[:, :, None]
        return ud, vd, ok, Jn, JE


class _DivisionBase(_CVModel):
    """Fitzgibbon's one-parameter division model: the image point ``m`` lifts to the ray
    ``(m, 1 + k |m|²)``; projecting solves ``λ² − z λ + k ρ² = 0`` for the larger root λ,
    ``m = (a, b)/λ``.  With ``k < 0`` rays beyond 90° have an image; with ``k > 0`` only rays with
    ``tan θ < 1/(2√k)``."""
    domain = "rays with z² − 4 k ρ² > 0 whose root λ = (z + √(z² − 4kρ²))/2 is positive " \
             "(k > 0: field angle below atan(1/(2√k)), in front; k < 0: beyond 90° too)"

    def _normalized(self, a, b, z, E, jac):
        k = E[:, 0]
        r2 = a * a + b * b
        disc2 = z * z - 4.0 * k * r2
        disc = np.sqrt(np.maximum(disc2, 0.0))
        den = np.where(z - disc < 0, z - disc, -1.0)
        lam = np.where(z >= 0, (z + disc) / 2, 2.0 * k * r2 / den)
        ok = (disc2 > 0) & (lam > 1e-12 * np.sqrt(r2 + z * z))
        ls = np.where(ok, lam, 1.0)
        ud, vd = a / ls, b / ls
        if not jac:
            return ud, vd, ok, None, None
        ds = np.where(ok, disc, 1.0)
        il2 = 1.0 / (ls * ls)
        lz = (1.0 + z / ds) / 2                    # ∂λ/∂z
        lr = -k / ds                               # ∂λ/∂(ρ²)
        lk = -r2 / ds                              # ∂λ/∂k
        n = a.shape[0]
        Jn = np.empty((n, 2, 3))
        Jn[:, 0, 0] = 1.0 / ls - a * il2 * lr * 2 * a
        Jn[:, 0, 1] = -a * il2 * lr * 2 * b
        Jn[:, 1, 0] = -b * il2 * lr * 2 * a
        Jn[:, 1, 1] = 1.0 / ls - b * il2 * lr * 2 * b
        Jn[:, 0, 2] = -a * il2 * lz
        Jn[:, 1, 2] = -b * il2 * lz
        JE = np.stack([-a * il2 * lk, -b * il2 * lk], axis=1)[:, :, None]
        return ud, vd, ok, Jn, JE


class SimpleDivision(_DivisionBase):
    """COLMAP ``SIMPLE_DIVISION``: one focal length, division parameter k."""
    name, colmap, focal2, extra = "simple-division", "SIMPLE_DIVISION", False, ("k",)


class Division(_DivisionBase):
    """COLMAP ``DIVISION``: ``fx = c (1 + B1)``, ``fy = c``, division parameter k."""
    name, colmap, focal2, extra = "division", "DIVISION", True, ("k",)


class EUCM(_CVModel):
    """COLMAP ``EUCM``, the enhanced unified camera model (Khomutenko et al. 2016):
    ``m = (a, b) / (α √(β ρ² + z²) + (1 − α) z)``."""
    name, colmap, focal2, extra = "eucm", "EUCM", True, ("alpha", "beta")
    domain = "rays with z > −w √(β ρ² + z²), w = α/(1 − α) for α ≤ ½, (1 − α)/α for α > ½ " \
             "(Khomutenko et al.), β ρ² + z² > 0, 0 ≤ α ≤ 1"

    def _normalized(self, a, b, z, E, jac):
        al, be = E[:, 0], E[:, 1]
        r2 = a * a + b * b
        re2 = be * r2 + z * z
        re = np.sqrt(np.maximum(re2, 0.0))
        den = al * re + (1.0 - al) * z
        w = np.where(al <= 0.5, al / np.where(al < 1, 1.0 - al, 1.0), (1.0 - al) / np.where(al > 0, al, 1.0))
        ok = (re2 > 0) & (den > 1e-12 * np.sqrt(r2 + z * z)) & (z > -w * re) & (al >= 0) & (al <= 1)
        F = 1.0 / np.where(ok, den, 1.0)
        ud, vd = a * F, b * F
        if not jac:
            return ud, vd, ok, None, None
        rs = np.where(re > 0, re, 1.0)
        Dr = al * be / rs                       # ∂den/∂(a, b) = Dr (a, b)
        Dz = al * z / rs + 1.0 - al
        Da = re - z
        Db = al * r2 / (2 * rs)
        F2 = F * F
        n = a.shape[0]
        Jn = np.empty((n, 2, 3))
        Jn[:, 0, 0] = F - a * a * F2 * Dr
        Jn[:, 0, 1] = Jn[:, 1, 0] = -a * b * F2 * Dr
        Jn[:, 1, 1] = F - b * b * F2 * Dr
        Jn[:, 0, 2] = -a * F2 * Dz
        Jn[:, 1, 2] = -b * F2 * Dz
        JE = np.empty((n, 2, 2))
        JE[:, 0, 0], JE[:, 1, 0] = -a * F2 * Da, -b * F2 * Da
        JE[:, 0, 1], JE[:, 1, 1] = -a * F2 * Db, -b * F2 * Db
        return ud, vd, ok, Jn, JE


class Equirectangular(RayModel):
    """COLMAP ``EQUIRECTANGULAR`` (spherical panorama): ``x = c (1 + B1) · azimuth``,
    ``y = c · elevation`` with azimuth ``atan2(U, −W)`` (−π … π, the seam straight behind) and
    elevation ``atan2(V, √(U² + W²))``.  COLMAP fixes the scale by the image size
    (``c (1 + B1) = width·pixel/2π``, ``c = height·pixel/π``, principal point at the centre)."""

    name, colmap = "equirectangular", "EQUIRECTANGULAR"
    params = ("B1",)
    pixel_power = (0,)
    default_sigma = (np.inf,)
    domain = "every ray but those along the poles' axis (U = W = 0)"

    def _eval(self, d, P, c, meta, jac):
        U, V, W = d[:, 0], d[:, 1], d[:, 2]
        h2 = U * U + W * W
        ok = h2 > 1e-24 * (h2 + V * V)
        hs = np.sqrt(np.where(ok, h2, 1.0))
        az = np.arctan2(U, -W)
        el = np.arctan2(V, hs)
        s = 1.0 + P[:, 0]
        xy = np.column_stack([c * s * az, c * el])
        if not jac:
            return xy, ok, None, None, None
        n2 = h2 + V * V
        hh = np.where(ok, h2, 1.0)
        n = d.shape[0]
        Jd = np.zeros((n, 2, 3))
        Jd[:, 0, 0] = c * s * (-W) / hh
        Jd[:, 0, 2] = c * s * U / hh
        Jd[:, 1, 1] = c * hs / n2
        Jd[:, 1, 0] = -c * V / n2 * U / hs
        Jd[:, 1, 2] = -c * V / n2 * W / hs
        Jp = np.zeros((n, 2, 1))
        Jp[:, 0, 0] = c * az
        Jc = np.column_stack([s * az, el])
        return xy, ok, Jd, Jp, Jc


COLMAP_RAY_MODELS = {m.colmap: m for m in (SimpleFisheye, Fisheye, SimpleRadialFisheye, RadialFisheye,
                                           OpenCVFisheye, ThinPrismFisheye, RadTanThinPrismFisheye, FOV,
                                           EUCM, Division, SimpleDivision, Equirectangular)}
"""COLMAP model name → baarda ray model class (its ``name`` is the baarda name)."""


# ------------------------------------------------------------------------------------------------
# photogrammetric fisheye projections with the brown terms
# ------------------------------------------------------------------------------------------------

class _ProjectionFisheye(RayModel):
    """``r = c g(θ)`` along the ray's azimuth, then the ``brown`` model's terms (mm) added at that
    ideal fisheye point (Schneider, Schwalbe & Maas 2009; Abraham & Förstner 2005)::

        θ = atan2(√(U² + V²), −W),   (x̄f, ȳf) = c g(θ) (U, V)/√(U² + V²)
        x = xp + x̄f + Δx(x̄f, ȳf),  y = yp + ȳf + Δy(x̄f, ȳf)      (Δ: brown's K1 K2 K3 P1 P2 B1 B2)
    """

    kind = "equidistant"
    params = Brown.params
    pixel_power = (2, 4, 6, 1, 1, 0, 0)
    default_sigma = Brown.default_sigma
    _brown = Brown()

    def _eval(self, d, P, c, meta, jac):
        U, V, z = d[:, 0], d[:, 1], -d[:, 2]
        S, G, Sz, _, ok = _angle_map(U, V, z, self.kind)
        xf, yf = c * U * S, c * V * S
        if not jac:
            dx, dy = self._brown.distortion(xf, yf, P, c, meta)
            return np.column_stack([xf + dx, yf + dy]), ok, None, None, None
        dx, dy = self._brown.distortion(xf, yf, P, c, meta)
        Jp, D, _ = self._brown.jacobians(xf, yf, P, c, meta, np.arange(7))
        M = D.copy()
        M[:, 0, 0] += 1.0
        M[:, 1, 1] += 1.0
        A = _A(U, V, S, G, Sz) * c[:, None, None]
        A[:, :, 2] *= -1.0                                 # z = −W
        Jd = np.einsum("nij,njk->nik", M, A)
        Jc = np.einsum("nij,nj->ni", M, np.column_stack([U * S, V * S]))
        return np.column_stack([xf + dx, yf + dy]), ok, Jd, Jp, Jc


class FisheyeEquidistant(_ProjectionFisheye):
    """Equidistant fisheye ``r = c θ`` with the brown terms (θ < 180°)."""
    name, kind = "fisheye-equidistant", "equidistant"
    domain = "field angles below 180°"


class FisheyeEquisolid(_ProjectionFisheye):
    """Equisolid-angle fisheye ``r = 2c sin(θ/2)`` with the brown terms (θ < 180°)."""
    name, kind = "fisheye-equisolid", "equisolid"
    domain = "field angles below 180°"


class FisheyeStereographic(_ProjectionFisheye):
    """Stereographic fisheye ``r = 2c tan(θ/2)`` with the brown terms (θ < 180°)."""
    name, kind = "fisheye-stereographic", "stereographic"
    domain = "field angles below 180°"


class FisheyeOrthographic(_ProjectionFisheye):
    """Orthographic fisheye ``r = c sin θ`` with the brown terms (θ ≤ 90°: beyond, r folds back)."""
    name, kind = "fisheye-orthographic", "orthographic"
    domain = "field angles up to 90° (beyond, sin θ folds back)"


# ------------------------------------------------------------------------------------------------
# what the Projector needs
# ------------------------------------------------------------------------------------------------

def ray_projection(model, d, params, c, meta, rows=None) -> np.ndarray:
    """``model.project_ray`` of the rays ``d``; :class:`RayOutsideModel` when the model has no image
    of one of them (``rows = (photo, point)`` indices name the first in the message)."""
    xy, valid = model.project_ray(d, params, c, meta)
    if not valid.all():
        bad = np.flatnonzero(~valid)
        i = int(bad[0])
        where = f" (first: photo index {int(rows[0][i])}, point index {int(rows[1][i])}" if rows is not None else " (first"
        ang = field_angle(np.asarray(d)[i:i + 1])[0]
        raise RayOutsideModel(
            f"camera model {model.name!r} cannot project {bad.size} observed ray(s){where}, field angle "
            f"{ang:.1f}°): it represents {model.domain}.  Switch such observations off, or use a model "
            "whose field reaches them")
    return xy


def ray_eo_point_jacobians(Jd, d, R, sv, obs_photo):
    """``J_point = J_d R`` (k, 2, 3) and ``J_eo = [−J_point, (d × J_d,r) · s_a]`` (k, 2, 6) of
    observations projected by a ray model (``J_d = ∂(x, y)/∂d``, ``d = R (X − X0)``), with ``sv`` the
    axial vectors of ``∂R/∂angle Rᵀ`` per photo — the chain rule of
    :func:`baarda.pipeline.adjustment.kernels.eo_point_jacobians` with ``J_d`` in place of the pinhole's."""
    Rk = R[obs_photo]
    J_point = np.einsum("kij,kjl->kil", Jd, Rk)
    h = np.cross(d[:, None, :], Jd)                  # (k, 2, 3): d × J_d,r
    J_eo = np.empty((Jd.shape[0], 2, 6))
    J_eo[:, :, :3] = -J_point
    J_eo[:, :, 3:] = np.einsum("kri,kai->kra", h, sv[obs_photo])
    return J_point, J_eo
