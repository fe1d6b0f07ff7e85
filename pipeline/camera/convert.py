"""Camera models between computer-vision conventions (OpenCV, COLMAP) and baarda's.

Pure numerics (arrays in, arrays out); ``docs/colmap.md`` derives every formula here.

Pixels ↔ mm: :mod:`baarda.pipeline.geometry.image`; poses: :mod:`baarda.pipeline.geometry.pose`.

Distortion
----------
baarda's ``"brown"`` model, ``ap = (K1, K2, K3, P1, P2, B1, B2)``, evaluated at the **ideal** reduced
image coordinates ``x̄ = −c U/W``, ``ȳ = −c V/W`` (mm)::

    Δx = x̄ (K1 r² + K2 r⁴ + K3 r⁶) + P1 (r² + 2x̄²) + 2 P2 x̄ȳ + B1 x̄ + B2 ȳ
    Δy = ȳ (K1 r² + K2 r⁴ + K3 r⁶) + P2 (r² + 2ȳ²) + 2 P1 x̄ȳ
    x = xp + x̄ + Δx,   y = yp + ȳ + Δy

equals OpenCV's model (``fx, fy, k1, k2, p1, p2, k3`` on the normalized point ``xn = X/Z``) with::

    c = fy · p,  B1 = fx/fy − 1,  K1 = k1/c²,  K2 = k2/c⁴,  K3 = k3/c⁶,  P1 = p2/c,  P2 = −p1/c

exactly when ``fx = fy`` or there is no distortion (else the x terms differ by ``B1·distortion``).
"""

from __future__ import annotations

import numpy as np

from baarda.pipeline.geometry import opk_from_rotation, rotation_from_opk_many
from baarda.pipeline.geometry.image import mm_from_pixels, pixels_from_mm

BROWN = ("K1", "K2", "K3", "P1", "P2", "B1", "B2")
"""Column order of ``Cameras.ap`` for the ``"brown"`` AP model (``baarda.pipeline.camera.models.Brown``)."""

# --------------------------------------------------------------------------------------------
# OpenCV-style distortion ↔ brown
# --------------------------------------------------------------------------------------------

def brown_from_opencv(fx, fy, pixel_mm, k1=0.0, k2=0.0, p1=0.0, p2=0.0, k3=0.0) -> tuple[float, np.ndarray]:
    """``(c mm, ap (7,))`` of the brown model equal to OpenCV's ``fx, fy (px), k1, k2, p1, p2, k3``.

    Exact when ``fx == fy`` or all distortion coefficients are 0 (see :func:`opencv_brown_exact`).
    """
    c = float(fy) * float(pixel_mm)
    ap = np.array([k1 / c**2, k2 / c**4, k3 / c**6, p2 / c, -p1 / c, fx / fy - 1.0, 0.0], float)
    return c, ap


def opencv_from_brown(c, ap, pixel_mm) -> dict:
    """OpenCV ``fx, fy, k1, k2, p1, p2, k3`` (pixels, normalized) of a brown camera.

    ``B2`` (shear) has no OpenCV counterpart: ``ValueError`` when it is not 0.
    """
    ap = np.zeros(7) if ap is None else np.asarray(ap, float)
    ap = np.concatenate([ap, np.zeros(max(0, 7 - ap.size))])[:7]
    K1, K2, K3, P1, P2, B1, B2 = ap
    if B2 != 0.0:
        raise ValueError(f"brown B2 = {B2:g} (shear) cannot be written as an OpenCV/COLMAP camera")
    fy = c / pixel_mm
    return {"fx": fy * (1.0 + B1), "fy": fy, "k1": K1 * c**2, "k2": K2 * c**4, "k3": K3 * c**6,
            "p1": -P2 * c, "p2": P1 * c}


def opencv_brown_exact(fx, fy, k1=0.0, k2=0.0, p1=0.0, p2=0.0, k3=0.0) -> bool:
    """True when :func:`brown_from_opencv` is exact (``fx == fy`` or no distortion)."""
    return bool(fx == fy or (k1 == 0 and k2 == 0 and p1 == 0 and p2 == 0 and k3 == 0))


# --------------------------------------------------------------------------------------------
# COLMAP camera models
# --------------------------------------------------------------------------------------------

COLMAP_PARAMS = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
}
"""COLMAP camera models baarda reads and writes (FULL_OPENCV only with k4 = k5 = k6 = 0)."""

FREE_BROWN = {
    "SIMPLE_PINHOLE": (), "PINHOLE": ("B1",), "SIMPLE_RADIAL": ("K1",), "RADIAL": ("K1", "K2"),
    "OPENCV": ("K1", "K2", "P1", "P2", "B1"), "FULL_OPENCV": ("K1", "K2", "K3", "P1", "P2", "B1"),
}
"""Brown parameters that a COLMAP model has (the others are 0 and held fixed)."""


class UnsupportedCamera(ValueError):
    """A camera that has no exact counterpart on the other side."""


def _named(model: str, params) -> dict:
    names = COLMAP_PARAMS[model]
    params = np.asarray(params, float).reshape(-1)
    if params.size != len(names):
        raise UnsupportedCamera(f"{model} needs {len(names)} parameters, got {params.size}")
    v = dict(zip(names, params.tolist()))
    if "f" in v:
        v["fx"] = v["fy"] = v.pop("f")
    if "k" in v:
        v["k1"] = v.pop("k")
    return v


def brown_from_colmap(model: str, params, size, pixel_mm) -> dict:
    """baarda camera (``c, xp, yp`` mm, ``ap`` (7,) brown) of a COLMAP camera.

    Returns ``{"c", "xp", "yp", "ap", "exact"}``; ``exact`` is False only for OPENCV/FULL_OPENCV
    with ``fx ≠ fy`` and distortion (then brown differs by ``(fx/fy − 1)·distortion`` in x).
    Raises :class:`UnsupportedCamera` for other models and FULL_OPENCV with k4–k6 ≠ 0.
    """
    if model not in COLMAP_PARAMS:
        raise UnsupportedCamera(
            f"COLMAP camera model {model} is not supported (supported: {', '.join(COLMAP_PARAMS)})")
    v = _named(model, params)
    if model == "FULL_OPENCV" and any(v[k] != 0.0 for k in ("k4", "k5", "k6")):
        raise UnsupportedCamera("FULL_OPENCV with k4, k5, k6 ≠ 0 (rational radial model) is not supported")
    dist = {k: v.get(k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3")}
    c, ap = brown_from_opencv(v["fx"], v["fy"], pixel_mm, **dist)
    xp, yp = mm_from_pixels([v["cx"], v["cy"]], size, pixel_mm, "colmap")
    return {"c": c, "xp": float(xp), "yp": float(yp), "ap": ap,
            "exact": opencv_brown_exact(v["fx"], v["fy"], **dist)}


def colmap_from_brown(c, xp, yp, ap, size, pixel_mm, model: str = "auto") -> tuple[str, np.ndarray]:
    """``(model, params)`` of the COLMAP camera equal to a brown camera.

    ``model="auto"`` picks the simplest of SIMPLE_PINHOLE, SIMPLE_RADIAL, RADIAL, PINHOLE, OPENCV,
    FULL_OPENCV that holds the non-zero parameters.  Raises :class:`UnsupportedCamera` when the
    requested model cannot hold them exactly (B2; B1 together with distortion).
    """
    v = opencv_from_brown(c, ap, pixel_mm)
    cx, cy = pixels_from_mm([xp, yp], size, pixel_mm, "colmap")
    ap = np.concatenate([np.asarray(ap if ap is not None else [], float), np.zeros(7)])[:7]
    nonzero = {name for name, val in zip(BROWN, ap) if val != 0.0}
    if "B1" in nonzero and nonzero & {"K1", "K2", "K3", "P1", "P2"}:
        raise UnsupportedCamera("brown B1 (fx ≠ fy) together with distortion has no exact COLMAP model")
    if model == "auto":
        for m in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "PINHOLE", "OPENCV", "FULL_OPENCV"):
            if nonzero <= set(FREE_BROWN[m]):
                model = m
                break
    if model not in COLMAP_PARAMS:
        raise UnsupportedCamera(f"cannot write COLMAP camera model {model} (supported: {', '.join(COLMAP_PARAMS)})")
    extra = nonzero - set(FREE_BROWN[model])
    if extra:
        raise UnsupportedCamera(f"COLMAP {model} cannot hold brown {', '.join(sorted(extra))}")
    v.update(cx=float(cx), cy=float(cy), k4=0.0, k5=0.0, k6=0.0, f=v["fy"], k=v["k1"])
    return model, np.array([v[name] for name in COLMAP_PARAMS[model]], float)


# --------------------------------------------------------------------------------------------
# COLMAP's fisheye, omnidirectional and division models ↔ baarda's ray models
# --------------------------------------------------------------------------------------------

def _ray_models():
    from .ray_models import COLMAP_RAY_MODELS
    return COLMAP_RAY_MODELS


def colmap_ray_model_names() -> dict:
    """COLMAP model name → baarda ray-model name (``OPENCV_FISHEYE`` → ``opencv-fisheye`` …)."""
    return {k: v.name for k, v in _ray_models().items()}


def ray_from_colmap(model: str, params, size, pixel_mm) -> dict:
    """baarda camera of a COLMAP camera whose model is one of :data:`.ray_models.COLMAP_RAY_MODELS`.

    ``{"c", "xp", "yp" (mm), "ap_model", "ap" (the ray model's parameters), "free" (names of the
    parameters COLMAP's bundle refines: focal lengths and extra parameters)}``.  With ``fx, fy``:
    ``c = fy · pixel``, ``B1 = fx/fy − 1``; one focal length ``f``: ``c = f · pixel``; the extra
    parameters are COLMAP's own (dimensionless, OpenCV's camera frame).  ``EQUIRECTANGULAR``
    (parameters: image width and height) becomes ``c = h · pixel/π``, ``B1 = w/(2h) − 1``, principal
    point at the image centre, all held fixed (COLMAP has nothing to refine).
    """
    cls = _ray_models()[model]
    params = np.asarray(params, float).reshape(-1)
    p = float(pixel_mm)
    if model == "EQUIRECTANGULAR":
        w, h = params
        if not (w > 0 and h > 0):
            raise UnsupportedCamera(f"EQUIRECTANGULAR needs a positive width and height, got {w:g}, {h:g}")
        xp, yp = mm_from_pixels([w / 2, h / 2], size, p, "colmap")
        return {"c": h * p / np.pi, "xp": float(xp), "yp": float(yp), "ap_model": cls.name,
                "ap": np.array([w / (2 * h) - 1.0]), "free": ()}
    nf = 2 if cls.focal2 else 1
    need = nf + 2 + len(cls.extra)
    if params.size != need:
        raise UnsupportedCamera(f"{model} needs {need} parameters, got {params.size}")
    fx, fy = (params[0], params[1]) if nf == 2 else (params[0], params[0])
    if not (fx > 0 and fy > 0):
        raise UnsupportedCamera(f"{model}: focal length must be positive, got {fx:g}, {fy:g}")
    cx, cy = params[nf], params[nf + 1]
    xp, yp = mm_from_pixels([cx, cy], size, p, "colmap")
    ap = np.concatenate([[fx / fy - 1.0] if nf == 2 else [], params[nf + 2:]])
    return {"c": fy * p, "xp": float(xp), "yp": float(yp), "ap_model": cls.name, "ap": ap,
            "free": tuple(cls.params)}


def colmap_from_ray(ap_model: str, c, xp, yp, ap, size, pixel_mm) -> tuple[str, np.ndarray]:
    """``(COLMAP model, params)`` of a camera with one of baarda's COLMAP ray models (the inverse of
    :func:`ray_from_colmap`).  :class:`UnsupportedCamera` for another model, and for an
    equirectangular camera whose ``c``, ``B1`` and principal point are not those COLMAP's image size
    implies."""
    by_name = {v.name: (k, v) for k, v in _ray_models().items()}
    if ap_model not in by_name:
        raise UnsupportedCamera(f"AP model {ap_model!r} has no COLMAP equivalent")
    model, cls = by_name[ap_model]
    p = float(pixel_mm)
    ap = np.concatenate([np.asarray(ap if ap is not None else [], float).reshape(-1), np.zeros(len(cls.params))])
    ap = ap[:len(cls.params)]
    cx, cy = pixels_from_mm([xp, yp], size, p, "colmap")
    if model == "EQUIRECTANGULAR":
        w, h = float(size[0]), float(size[1])
        ok = (np.isclose(c, h * p / np.pi, rtol=1e-9) and np.isclose(c * (1 + ap[0]), w * p / (2 * np.pi), rtol=1e-9)
              and np.isclose(cx, w / 2, atol=1e-6) and np.isclose(cy, h / 2, atol=1e-6))
        if not ok:
            raise UnsupportedCamera("COLMAP's EQUIRECTANGULAR camera is fixed by its image size (c = height·pixel/π, "
                                    "c (1 + B1) = width·pixel/2π, principal point at the centre): this camera's "
                                    "c, B1 or principal point differ")
        return model, np.array([w, h])
    fy = float(c) / p
    head = [fy * (1.0 + ap[0]), fy] if cls.focal2 else [fy]
    extra = ap[1:] if cls.focal2 else ap
    return model, np.array(head + [float(cx), float(cy)] + list(extra), float)


def camera_from_colmap(model: str, params, size, pixel_mm) -> dict:
    """baarda camera of any supported COLMAP camera: ``{"c", "xp", "yp", "ap_model", "ap", "names"}``
    (brown for the pinhole models, the ray model of the same name for the others)."""
    if model in _ray_models():
        b = ray_from_colmap(model, params, size, pixel_mm)
        from .registry import get_ap_model
        return {**b, "names": tuple(get_ap_model(b["ap_model"]).params)}
    b = brown_from_colmap(model, params, size, pixel_mm)
    return {**b, "ap_model": "brown", "names": BROWN}


# --------------------------------------------------------------------------------------------
# Reporting a camera in the units of its source (pixels, OpenCV's coefficients)
# --------------------------------------------------------------------------------------------

def pixel_source(block) -> str | None:
    """Name of the pixel source (``"COLMAP"``, ``"BAL"``, ``"libmv"``, ``"OpenCV"``) a block was
    read from (``block.source.pixel_format``), or None for a source measured in mm (comparator,
    AICON, DBAT, test field)."""
    return block.source.pixel_format


OPENCV_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


def opencv_style(c, xp, yp, ap_model: str, ap, cov, size, pixel_mm, convention: str = "opencv",
                 drop_shear: bool = False) -> list[dict] | None:
    """A camera as OpenCV writes it — ``fx, fy, cx, cy`` (px) and ``k1, k2, p1, p2, k3`` — with σ.

    ``cov`` is the covariance of ``(c, xp, yp, *ap)`` (mm; the AP model's units), propagated
    linearly (every relation is polynomial; the Jacobian is exact at the estimate).  Returns
    ``[{"name", "value", "sigma"}]`` in :data:`OPENCV_NAMES` order, or None when the camera has no
    OpenCV form (an AP model other than ``none``/``brown``, or a brown shear ``B2 ≠ 0`` unless
    ``drop_shear``: then the other coefficients are given and B2 is left out — the caller says so).
    """
    if ap_model not in ("none", "brown"):
        return None
    p = float(pixel_mm)
    apv = np.zeros(7)
    n_ap = 7 if ap_model == "brown" else 0
    if n_ap:
        a = np.asarray(ap, float).reshape(-1)[:7]
        apv[:a.size] = a
    K1, K2, K3, P1, P2, B1, B2 = apv
    if B2 != 0.0 and not drop_shear:
        return None
    apv[6] = B2 = 0.0
    v = opencv_from_brown(c, apv, p)
    cx, cy = pixels_from_mm([xp, yp], size, p, convention)
    values = {"fx": v["fx"], "fy": v["fy"], "cx": float(cx), "cy": float(cy),
              **{k: v[k] for k in ("k1", "k2", "p1", "p2", "k3")}}
    J = np.zeros((9, 3 + n_ap))
    J[0, 0], J[1, 0], J[2, 1], J[3, 2] = (1.0 + B1) / p, 1.0 / p, 1.0 / p, -1.0 / p
    if n_ap:
        iK1, iK2, iK3, iP1, iP2, iB1 = 3, 4, 5, 6, 7, 8
        J[0, iB1] = c / p
        J[4, 0], J[4, iK1] = 2 * K1 * c, c**2
        J[5, 0], J[5, iK2] = 4 * K2 * c**3, c**4
        J[6, 0], J[6, iP2] = -P2, -c
        J[7, 0], J[7, iP1] = P1, c
        J[8, 0], J[8, iK3] = 6 * K3 * c**5, c**6
    C = np.asarray(cov, float)
    m = min(C.shape[0], J.shape[1])
    S = J[:, :m] @ C[:m, :m] @ J[:, :m].T
    sig = np.sqrt(np.clip(np.diag(S), 0.0, None))
    return [{"name": k, "value": float(values[k]), "sigma": float(s)} for k, s in zip(OPENCV_NAMES, sig)]


def opencv_rms(residuals_px) -> float:
    """OpenCV's RMS re-projection error (``calibrateCamera``'s return value): the root of the sum
    of squared 2-D residual lengths over the number of image points (not of coordinates)."""
    v = np.asarray(residuals_px, float).reshape(-1, 2)
    return float(np.sqrt(np.sum(v * v) / len(v))) if len(v) else float("nan")
