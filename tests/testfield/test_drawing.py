"""Rendered photos: the blob centroid lies at the projected target centre (OpenCV pixel convention)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from baarda.pipeline.geometry import mm_from_pixels, pixels_from_mm
from baarda.plugins.testfield.drawing import projected_targets, render_targets
from baarda.pipeline.synthetic.testfield import TestFieldConfig, simulate_testfield

PIXEL_MM = 0.04
SHAPE = (int(83 / PIXEL_MM), int(117 / PIXEL_MM))   # 2075 × 2925
BACKGROUND = 20.0


def _centroid(img, uv, half):
    u0, v0 = np.round(uv).astype(int)
    v_lo, v_hi = max(v0 - half, 0), min(v0 + half + 1, img.shape[0])
    u_lo, u_hi = max(u0 - half, 0), min(u0 + half + 1, img.shape[1])
    win = img[v_lo:v_hi, u_lo:u_hi].astype(float) - BACKGROUND
    vv, uu = np.mgrid[v_lo:v_hi, u_lo:u_hi]
    return np.array([(win * uu).sum() / win.sum(), (win * vv).sum() / win.sum()])


def _inner(centres, half):
    H, W = SHAPE
    return {k: uv for k, uv in centres.items()
            if half <= uv[0] <= W - 1 - half and half <= uv[1] <= H - 1 - half}


def test_pixel_convention_round_trip():
    H, W = SHAPE
    # the image centre is (W−1)/2, (H−1)/2; the top-left pixel centre is (0, 0) at x < 0, y > 0
    np.testing.assert_allclose(pixels_from_mm([[0.0, 0.0]], (W, H), PIXEL_MM), [[(W - 1) / 2, (H - 1) / 2]])
    np.testing.assert_allclose(mm_from_pixels([[0.0, 0.0]], (W, H), PIXEL_MM),
                               [[-(W - 1) / 2 * PIXEL_MM, (H - 1) / 2 * PIXEL_MM]])
    xy = np.array([[12.3, -4.5], [-50.0, 30.0]])
    np.testing.assert_allclose(mm_from_pixels(pixels_from_mm(xy, (W, H), PIXEL_MM), (W, H), PIXEL_MM), xy)


def test_fronto_parallel_centroid_at_projection():
    """Camera axis normal to the target planes (ω = φ = κ = 0), no distortion, no noise: the
    projected disk is a circle centred on the projected centre; the rendered centroid lies within
    0.05 px of it (measured: < 0.005 px with 8 × 8 supersampling)."""
    block, truth = simulate_testfield(TestFieldConfig(with_ap_errors=False), np.random.default_rng(0))
    truth = dataclasses.replace(truth, opk=np.zeros_like(truth.opk))
    img = render_targets(block, truth, "13", PIXEL_MM, SHAPE, target_radius=0.004)
    assert img.dtype == np.uint8 and img.shape == SHAPE
    centres = _inner(projected_targets(truth, "13", PIXEL_MM, SHAPE), 16)
    assert len(centres) >= 8
    errs = np.array([_centroid(img, uv, 16) - uv for uv in centres.values()])
    assert np.abs(errs).max() < 0.05, errs
    # the disk radius in pixels: c · R / distance / pitch ≈ 7 px; the area matches π r²
    uv = next(iter(centres.values()))
    u0, v0 = np.round(uv).astype(int)
    area = (img[v0 - 16:v0 + 17, u0 - 16:u0 + 17].astype(float) - BACKGROUND).sum() / (235 - BACKGROUND)
    k = list(truth.point_ids).index(next(iter(centres)))
    depth = truth.X0[list(truth.photo_ids).index("13"), 2] - truth.XYZ[k, 2]
    r_px = truth.c * 0.004 / depth / PIXEL_MM
    assert area == pytest.approx(np.pi * r_px**2, rel=0.01)


def test_centroid_with_distortion_tilt_and_noise():
    """The true photo (small tilts, systematic errors) with grey-level noise: still within 0.05 px
    (perspective eccentricity and the distortion across a 7-px disk are far below that)."""
    block, truth = simulate_testfield(TestFieldConfig(), np.random.default_rng(0))
    img = render_targets(block, truth, "22", PIXEL_MM, SHAPE, 0.004, np.random.default_rng(1), sigma_noise=1.0)
    centres = _inner(projected_targets(truth, "22", PIXEL_MM, SHAPE), 16)
    errs = np.array([_centroid(img, uv, 16) - uv for uv in centres.values()])
    assert len(errs) >= 8 and np.abs(errs).max() < 0.05, errs


def test_render_is_deterministic_and_sees_the_measured_targets():
    block, truth = simulate_testfield(TestFieldConfig(), np.random.default_rng(0))
    a = render_targets(block, truth, 0, 0.2, (415, 585), 0.004, np.random.default_rng(2))
    b = render_targets(block, truth, "11", 0.2, (415, 585), 0.004, np.random.default_rng(2))
    np.testing.assert_array_equal(a, b)
    measured = set(block.points.ids[block.observations.point[block.observations.photo == 0]])
    assert measured <= set(projected_targets(truth, "11", 0.2, (415, 585)))
    with pytest.raises(ValueError, match="unknown photo"):
        render_targets(block, truth, "99", 0.2, (415, 585), 0.004)
