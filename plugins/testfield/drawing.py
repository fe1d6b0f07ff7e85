"""Render simulated photos of the test field: bright circular (retro-reflective) targets on a dark
background, seen through the true camera with its systematic image errors.

Each target is a disk of radius ``target_radius`` (object units) lying in the plane Z = const
through its centre (the object's front, facing the cameras).  Every pixel is supersampled on an
``s × s`` grid; each sample's image point is turned back into a ray (the image errors removed by
fixed-point iteration), intersected with the target's plane and tested against the disk, so the
projected ellipse, its perspective eccentricity and the distortion are exact up to the sampling.

Pixels follow OpenCV's convention (``docs/conventions.md``, *Pixels ↔ mm*): ``u`` right, ``v``
down, origin at the centre of the top-left pixel, ``x_mm = (u − (W−1)/2) p``,
``y_mm = −(v − (H−1)/2) p``.
"""

from __future__ import annotations

import numpy as np

from baarda.pipeline.geometry import mm_from_pixels, pixels_from_mm, rotation_from_opk

from baarda.pipeline.synthetic.testfield import Truth, physical_distortion, project_truth


def _photo_index(truth: Truth, photo) -> int:
    ids = [str(p) for p in truth.photo_ids]
    if isinstance(photo, (int, np.integer)) and not isinstance(photo, bool):
        if not 0 <= int(photo) < len(ids):
            raise ValueError(f"photo index {photo} out of range (0…{len(ids) - 1})")
        return int(photo)
    try:
        return ids.index(str(photo))
    except ValueError:
        raise ValueError(f"unknown photo {photo!r}; photos: {', '.join(ids)}") from None


def projected_targets(truth: Truth, photo, pixel_mm: float, shape: tuple[int, int]) -> dict[str, np.ndarray]:
    """Pixel position (u, v) of each target centre's true image (systematic errors included) in
    ``photo``; only targets in front of the camera and inside the image are returned."""
    i = _photo_index(truth, photo)
    xy, depth = project_truth(truth.XYZ, truth.X0[i:i + 1], truth.opk[i:i + 1], truth.c, truth.xp, truth.yp,
                              truth.distortion)
    H, W = shape
    uv = pixels_from_mm(xy[0], (W, H), pixel_mm, "opencv")
    ok = (depth[0] > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= W - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= H - 0.5)
    return {str(pid): uv[k] for k, pid in enumerate(truth.point_ids) if ok[k]}


def _ideal_reduced(xy: np.ndarray, truth: Truth, iterations: int = 6) -> np.ndarray:
    """Remove the image errors: reduced ideal coordinates x̄ with ``x̄ + Δ(x̄) = xy − (xp, yp)``."""
    target = xy - (truth.xp, truth.yp)
    xbar = target.copy()
    for _ in range(iterations):
        dx, dy = physical_distortion(xbar[:, 0], xbar[:, 1], truth.distortion)
        xbar = target - np.column_stack([dx, dy])
    return xbar


def render_targets(block, truth: Truth, photo, pixel_mm: float, shape: tuple[int, int],
                   target_radius: float, rng: np.random.Generator | None = None, *,
                   supersample: int = 8, background: float = 20.0, foreground: float = 235.0,
                   sigma_noise: float = 2.0) -> np.ndarray:
    """Render ``photo`` (id or index) as a ``uint8`` image of ``shape = (H, W)`` pixels.

    ``pixel_mm`` is the pixel pitch (mm), ``target_radius`` the disk radius in object units.
    With ``rng`` Gaussian grey-level noise of ``sigma_noise`` is added; without it the image is
    noise-free (deterministic).  ``block`` supplies nothing the truth does not already hold and
    may be ``None``; it is accepted so callers can pass the pair they have.
    """
    i = _photo_index(truth, photo)
    H, W = int(shape[0]), int(shape[1])
    R = rotation_from_opk(*truth.opk[i])
    X0 = truth.X0[i]
    centres = projected_targets(truth, i, pixel_mm, (H, W))
    depth = (truth.XYZ - X0) @ R.T
    coverage = np.zeros((H, W))
    s = int(supersample)
    offsets = (np.arange(s) + 0.5) / s - 0.5
    for k, pid in enumerate(truth.point_ids):
        pid = str(pid)
        if pid not in centres:
            continue
        r_px = truth.c * target_radius / (-depth[k, 2]) / pixel_mm
        half = int(np.ceil(1.3 * r_px + 2))
        u0, v0 = np.round(centres[pid]).astype(int)
        us = np.arange(max(u0 - half, 0), min(u0 + half + 1, W))
        vs = np.arange(max(v0 - half, 0), min(v0 + half + 1, H))
        if us.size == 0 or vs.size == 0:
            continue
        # sample positions (v, u, sv, su) flattened
        su = (us[None, :, None] + offsets[None, None, :])            # (1, nu, s)
        sv = (vs[:, None, None] + offsets[None, None, :])            # (nv, 1, s)
        U = np.broadcast_to(su[:, :, None, :], (vs.size, us.size, s, s))
        V = np.broadcast_to(sv[:, :, :, None], (vs.size, us.size, s, s))
        xy = mm_from_pixels(np.column_stack([U.reshape(-1), V.reshape(-1)]), (W, H), pixel_mm, "opencv")
        xbar = _ideal_reduced(xy, truth)
        d_cam = np.column_stack([xbar, np.full(len(xbar), -truth.c)])
        d_world = d_cam @ R                                          # Rᵀ · d_cam for each row
        t = (truth.XYZ[k, 2] - X0[2]) / d_world[:, 2]
        hit = X0[:2] + t[:, None] * d_world[:, :2]
        inside = (np.sum((hit - truth.XYZ[k, :2]) ** 2, axis=1) <= target_radius ** 2) & (t > 0)
        cov = inside.reshape(vs.size, us.size, s * s).mean(axis=2)
        block_view = coverage[vs[0]:vs[-1] + 1, us[0]:us[-1] + 1]
        np.maximum(block_view, cov, out=block_view)
    img = background + (foreground - background) * coverage
    if rng is not None and sigma_noise > 0:
        img = img + rng.normal(0.0, sigma_noise, size=img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)
