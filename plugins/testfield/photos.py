"""Rendered photos of the simulated test field — pure numerics (arrays in, arrays out).

The test-field simulator (:mod:`baarda.pipeline.synthetic.testfield`) gives a block and its truth; this
module turns them into what a digital camera would deliver and what a detection stage starts
from:

* :func:`image_size` — pixels ``(W, H)`` of the camera format at a pixel pitch;
* :func:`truth_from_meta` — the :class:`~baarda.pipeline.synthetic.testfield.Truth` back from
  ``block.meta["truth"]`` (the simulator stores it there as plain lists);
* :func:`true_targets` — where each target centre's true image lies in each photo (pixels,
  OpenCV's convention, systematic image errors included): the ground truth of detection;
  :func:`partial_targets` — those whose disk is cut by the image border;
* :func:`render_photo` — one photo as a ``uint8`` image (:func:`baarda.plugins.testfield.drawing.render_targets`);
* :func:`layout_block` — the block without image observations, its camera carrying the pixel
  pitch, resolution and format of the rendered images: the layout and approximate orientations a
  ``circles`` detection needs.

Pixels follow OpenCV's convention (``docs/conventions.md``): ``(0, 0)`` is the centre of the
top-left pixel, ``x_mm = (u − (W−1)/2) p``, ``y_mm = −(v − (H−1)/2) p``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from baarda.pipeline.api import Block, option
from baarda.pipeline.model import Observations
from baarda.pipeline.options import check_bounds
from baarda.plugins.testfield.drawing import projected_targets, render_targets
from baarda.pipeline.synthetic.testfield import Truth

__all__ = ["RenderSettings", "image_size", "truth_from_meta", "true_targets", "partial_targets",
           "target_radius_px", "render_photo", "layout_block", "OBJECT_UNIT_MM"]

OBJECT_UNIT_MM = {"m": 1000.0, "cm": 10.0, "mm": 1.0, "ft": 304.8}
"""Millimetres per object unit."""


@dataclass(frozen=True, kw_only=True)
class ImageSettings:
    """The rendered images' pitch, sampling and noise: one declaration for the ``testfield-render``
    stage's options and :class:`RenderSettings` (bounds checked on construction)."""

    pixel_mm: float = option(0.025, "pixel pitch of the rendered images, mm (0.025: 4680 × 3320 pixels over the "
                                    "117 × 83 mm format)")
    supersample: int = option(8, "samples per pixel side when rendering (8: 64 per pixel)", ge=1)
    sigma_noise: float = option(2.0, "grey-level noise σ (targets 235 on a background of 20); 0: noise-free")

    def __post_init__(self):
        check_bounds(self)


@dataclass(frozen=True, kw_only=True)
class RenderSettings(ImageSettings):
    """How to render: :class:`ImageSettings`, the target radius (object units), background and
    target grey levels."""

    target_radius: float = option(0.005, "target radius, object units", gt=0)
    background: float = option(20.0, "grey level of the background", ge=0, le=255)
    foreground: float = option(235.0, "grey level of the targets", ge=0, le=255)


def image_size(format_mm, pixel_mm: float) -> tuple[int, int]:
    """``(W, H)`` pixels covering the format ``(width, height)`` mm at ``pixel_mm`` (rounded)."""
    w, h = (float(v) for v in format_mm)
    if not (np.isfinite(w) and np.isfinite(h) and w > 0 and h > 0):
        raise ValueError(f"the camera format must be known to render, got {w} × {h} mm")
    return int(round(w / pixel_mm)), int(round(h / pixel_mm))


def truth_from_meta(meta: dict) -> Truth:
    """The simulator's :class:`Truth` from ``block.meta["truth"]`` (``Truth.as_dict()``).

    Raises ``KeyError`` when the block does not come from the test-field simulator.
    """
    t = meta["truth"]
    arr = lambda k: np.asarray(t[k], float)
    return Truth(photo_ids=np.asarray(t["photo_ids"], str), X0=arr("X0"), opk=arr("opk"),
                 point_ids=np.asarray(t["point_ids"], str), XYZ=arr("XYZ"), XYZ_surveyed=arr("XYZ_surveyed"),
                 c=float(t["c"]), xp=float(t["xp"]), yp=float(t["yp"]), distortion=dict(t["distortion"]),
                 xy_true=arr("xy_true").reshape(-1, 2), systematic=arr("systematic").reshape(-1, 2),
                 noise=arr("noise").reshape(-1, 2), blunder=arr("blunder").reshape(-1, 2))


def true_targets(truth: Truth, pixel_mm: float, size: tuple[int, int]) -> dict[str, dict[str, np.ndarray]]:
    """Per photo id: ``{point id: (u, v)}`` of every target whose true image centre lies in the
    image of ``size = (W, H)`` pixels (systematic image errors included)."""
    W, H = size
    return {str(pid): projected_targets(truth, k, pixel_mm, (H, W)) for k, pid in enumerate(truth.photo_ids)}


def partial_targets(truth: Truth, targets: dict, radius: float, pixel_mm: float, size: tuple[int, int],
                    margin_px: float = 1.0) -> dict[str, list[str]]:
    """Per photo id: the targets of ``targets`` (:func:`true_targets`) whose disk image (radius
    ``radius`` in object units) comes closer than ``margin_px`` to the image border — cut off or
    touching it, so a detector need not find them."""
    W, H = size
    ids = [str(q) for q in truth.point_ids]
    out = {}
    for k, pid in enumerate(truth.photo_ids):
        r = target_radius_px(truth, k, radius, pixel_mm)
        out[str(pid)] = [q for q, (u, v) in targets[str(pid)].items()
                         if min(u, v, W - 1 - u, H - 1 - v) < r[ids.index(q)] + margin_px]
    return out


def target_radius_px(truth: Truth, photo: int, radius: float, pixel_mm: float) -> np.ndarray:
    """Radius (pixels, per target) of the targets' images in ``photo`` (distance along the axis)."""
    from baarda.pipeline.geometry import rotation_from_opk

    R = rotation_from_opk(*truth.opk[photo])
    depth = -((truth.XYZ - truth.X0[photo]) @ R.T)[:, 2]
    return truth.c * radius / np.where(depth > 0, depth, np.nan) / pixel_mm


def render_photo(truth: Truth, photo, settings: RenderSettings, size: tuple[int, int],
                 rng: np.random.Generator | None) -> np.ndarray:
    """Photo ``photo`` (id or index) as a ``uint8 (H, W)`` image: bright disks on a dark ground,
    through the true camera with its systematic errors; grey-level noise from ``rng``."""
    W, H = size
    return render_targets(None, truth, photo, settings.pixel_mm, (H, W), settings.target_radius, rng,
                          supersample=settings.supersample, background=settings.background,
                          foreground=settings.foreground, sigma_noise=settings.sigma_noise)


def layout_block(block: Block, pixel_mm: float, size: tuple[int, int]) -> Block:
    """``block`` without image observations; every camera gets the pixel pitch, the resolution
    ``size = (W, H)`` and the format ``(W p, H p)`` mm of the rendered images.  Photos (with
    their approximate orientations), points, pairs and ``meta`` are kept."""
    cams = block.cameras
    k = len(cams)
    res = np.tile(np.asarray(size, int), (k, 1))
    cams = cams.replace(pixel_mm=np.full(k, float(pixel_mm)), resolution=res, format_mm=res * float(pixel_mm))
    empty = Observations.make(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2)))
    return block.replace(cameras=cams, observations=empty)
