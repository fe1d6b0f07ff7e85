"""Image coordinates: pixels ↔ mm, with one signature for every stage.

Pixels
------
``"opencv"``: pixel (0, 0) is the *centre* of the top-left pixel (OpenCV).  ``"colmap"``: (0, 0) is
the top-left *corner* of the image, the centre of the top-left pixel is (0.5, 0.5) (COLMAP's
documented convention; also Blender/libmv).  With pitch ``p`` (mm) and ``W × H`` pixels::

    opencv:  x_mm = (u − (W − 1)/2) · p     y_mm = −(v − (H − 1)/2) · p
    colmap:  x_mm = (u − W/2) · p           y_mm = −(v − H/2) · p

Both put the origin at the centre of the format (``docs/conventions.md``, *Pixels ↔ mm*).
"""

from __future__ import annotations

import numpy as np

PIXEL_CONVENTIONS = ("opencv", "colmap")


def _centre(size, convention: str) -> np.ndarray:
    w, h = np.asarray(size, float)[..., 0], np.asarray(size, float)[..., 1]
    if convention == "opencv":
        return np.stack([(w - 1.0) / 2.0, (h - 1.0) / 2.0], axis=-1)
    if convention == "colmap":
        return np.stack([w / 2.0, h / 2.0], axis=-1)
    raise ValueError(f"pixel convention must be one of {PIXEL_CONVENTIONS}, got {convention!r}")


def mm_from_pixels(uv, size, pixel_mm, convention: str = "opencv") -> np.ndarray:
    """Image coordinates in mm (x right, y up, origin at the format centre) of pixels ``uv (n, 2)``.

    ``size`` is ``(W, H)`` in pixels (or ``(n, 2)`` per point), ``pixel_mm`` the pitch (scalar or
    ``(n,)``), ``convention`` ``"opencv"`` or ``"colmap"`` (see the module docstring).
    """
    uv = np.asarray(uv, float)
    d = uv - _centre(size, convention)
    p = np.asarray(pixel_mm, float)[..., None]
    return np.stack([d[..., 0], -d[..., 1]], axis=-1) * p


def pixels_from_mm(xy, size, pixel_mm, convention: str = "opencv") -> np.ndarray:
    """Inverse of :func:`mm_from_pixels`."""
    xy = np.asarray(xy, float)
    p = np.asarray(pixel_mm, float)[..., None]
    d = xy / p
    return np.stack([d[..., 0], -d[..., 1]], axis=-1) + _centre(size, convention)
