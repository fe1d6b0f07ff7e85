"""Figures over the image format are drawn in the frame a reader of the source uses
(:class:`baarda.pipeline.plots.ImageFrame`): a pixel source (COLMAP, OpenCV) in its image's pixel frame —
origin top-left, v down, 0 … width × 0 … height, the x_px/y_px of bundle_observations.csv — and a
metric source in mm, origin at the format centre, y up."""

from __future__ import annotations

import numpy as np
import pytest

from baarda.pipeline.geometry.image import mm_from_pixels
from baarda.pipeline.model import SourceInfo
from baarda.pipeline.plots import ImageFrame
from baarda.pipeline.synthetic.closerange import make_block

W, H, PITCH = 1200, 800, 0.03          # the synthetic camera's 36 × 24 mm format


def _block(fmt=None):
    blk, _ = make_block(model="brown", n_photos=6, n_points=20, noise_mm=0.001, rng=np.random.default_rng(1))
    cams = blk.cameras
    k = len(cams)
    blk = blk.replace(cameras=cams.replace(pixel_mm=np.full(k, PITCH), resolution=np.tile((W, H), (k, 1)),
                                           format_mm=np.tile((W * PITCH, H * PITCH), (k, 1))))
    return blk if fmt is None else blk.replace(source=SourceInfo(path="x", format=fmt, pixel_format=fmt))


@pytest.mark.parametrize("fmt, convention, corner", [("OpenCV", "opencv", -0.5), ("COLMAP", "colmap", 0.0)])
def test_pixel_frame(fmt, convention, corner):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    blk = _block(fmt)
    f = ImageFrame(blk)
    assert f.pixels and f.y_down and f.unit == "px"
    uv = np.array([[10.0, 20.0], [700.0, 500.0]])
    xy = mm_from_pixels(uv, (W, H), PITCH, convention)
    np.testing.assert_allclose(f.positions(xy, [0, 0]), uv, atol=1e-9)
    np.testing.assert_allclose(f.camera_positions(xy, 0), uv, atol=1e-9)
    # a residual of +1 µm in x and +2 µm up (mm, y up) is 1/30 px right and 2/30 px up = −2/30 px in v
    np.testing.assert_allclose(f.vectors([[0.001, 0.002]]), [[1 / 30, -2 / 30]])
    assert f.extent(0) == pytest.approx((corner, corner + W, corner + H, corner))     # imshow, origin="upper"
    fig, ax = plt.subplots()
    f.finish(ax, 0)
    lo, hi = ax.get_xlim()
    top, bottom = ax.get_ylim()[1], ax.get_ylim()[0]
    assert ax.yaxis_inverted() and top < 0 + 1 and bottom > H - 1           # v grows downwards, 0 at the top
    assert lo <= corner and hi >= corner + W and hi - lo < 1.1 * W
    assert "down" in ax.get_ylabel()
    plt.close(fig)


def test_metric_and_bal_frames():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    f = ImageFrame(_block())
    assert not f.pixels and not f.y_down and f.unit == "mm"
    xy = np.array([[1.0, -1.5]])
    np.testing.assert_allclose(f.positions(xy, [0]), xy)
    np.testing.assert_allclose(f.vectors([[0.001, 0.002]]), [[0.001, 0.002]])        # mm, y up
    assert f.extent(0) == pytest.approx((-W * PITCH / 2, W * PITCH / 2, -H * PITCH / 2, H * PITCH / 2))
    fig, ax = plt.subplots()
    f.finish(ax, 0)
    assert not ax.yaxis_inverted() and ax.get_ylim()[0] < 0 < ax.get_ylim()[1]       # centred, y up
    plt.close(fig)
    bal = ImageFrame(_block("BAL"))          # BAL's own convention: centred, y up (as its files and x_px, y_px)
    assert bal.pixels and not bal.y_down
    np.testing.assert_allclose(bal.positions(xy, [0]), xy / PITCH)
    np.testing.assert_allclose(bal.vectors([[0.001, 0.002]]), [[1 / 30, 2 / 30]])


def test_residual_and_reliability_figures_of_a_pixel_source_are_in_the_pixel_frame():
    import matplotlib
    matplotlib.use("Agg")

    from baarda.pipeline.adjustment import adjust_block
    from baarda.plugins.bundle.figures import reliability_maps, residual_vectors

    for fmt, inverted in (("COLMAP", True), (None, False)):
        rep = adjust_block(_block(fmt))
        res = rep.result
        fig = residual_vectors(res)
        ax = fig.axes[0]
        assert bool(ax.yaxis_inverted()) is inverted, fmt
        if inverted:                              # 0 … W × 0 … H (a little padding), the image's pixel frame
            assert -0.05 * W < ax.get_xlim()[0] <= 0 and W <= ax.get_xlim()[1] < 1.05 * W
            assert "origin top-left, v down" in fig._suptitle.get_text()
            # the arrows start at the observations' pixel coordinates (the table's x_px, y_px)
            from baarda.pipeline.units import ImageUnits
            iu = ImageUnits.of(res.block_in)
            obs = res.block_in.observations
            uv = iu.coordinates(res.block_in, obs.xy, obs.photo)
            q = ax.collections[0]
            offs = np.asarray(q.get_offsets())
            assert np.all((offs[:, 0] >= 0) & (offs[:, 0] <= W) & (offs[:, 1] >= 0) & (offs[:, 1] <= H))
            assert all(np.isclose(uv, o).all(axis=1).any() for o in offs)
        else:
            assert ax.get_xlim()[0] < 0 < ax.get_xlim()[1] and "y up" in fig._suptitle.get_text()
        maps = reliability_maps(res)
        assert bool(maps.axes[0].yaxis_inverted()) is inverted and not maps.axes[2].yaxis_inverted()   # the plan: y up
