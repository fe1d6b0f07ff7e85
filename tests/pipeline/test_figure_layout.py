"""Fixed figure layouts (issue 22, "reports stay readable at any size"): the bundle's figures are laid
out once (``plots.fixed_layout``), saved as they are, and nothing of them is cut; the hexbin maps
are reduced in numpy and are the maps matplotlib's own ``hexbin(C=…)`` draws."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from baarda.pipeline.html import png_of, use_agg
from baarda.pipeline.plots import FIXED_LAYOUT, fixed_layout, hex_reduce, value_map, wrap_inches


def _plt():
    use_agg()
    import matplotlib.pyplot as plt

    return plt


def _png_size(png: bytes) -> tuple[int, int]:
    return int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")


@pytest.mark.parametrize("reduce", ["mean", "min", "max"])
@pytest.mark.parametrize("n, gridsize", [(6_000, 40), (60_000, 17)])
def test_value_map_draws_matplotlibs_own_hexbin(reduce, n, gridsize):
    plt = _plt()
    rng = np.random.default_rng(n + gridsize)
    x, y = rng.normal(0, 1000, n), rng.normal(500, 700, n)
    c = rng.uniform(0, 1, n)
    x[:4] = [1e5, -3e4, 2e4, 5e4]                       # far points: the grid spans them
    fn = {"mean": np.mean, "min": np.min, "max": np.max}[reduce]
    fig, ax = plt.subplots()
    ref = ax.hexbin(x, y, C=c, gridsize=gridsize, reduce_C_function=fn, mincnt=1)
    ours = value_map(ax, x, y, c, gridsize=gridsize, reduce=reduce, big=1000)
    np.testing.assert_array_equal(ours.get_offsets(), ref.get_offsets())
    np.testing.assert_allclose(ours.get_array(), ref.get_array(), rtol=1e-12, atol=0)
    # without vmin/vmax the colours span the cells' values (not hexbin's counts of one)
    fig.canvas.draw()
    assert ours.norm.vmin == pytest.approx(float(np.min(ref.get_array())))
    assert ours.norm.vmax == pytest.approx(float(np.max(ref.get_array())))
    plt.close(fig)


def test_hex_reduce_counts_every_value_once():
    rng = np.random.default_rng(3)
    x, y, c = rng.uniform(0, 10, 5000), rng.uniform(0, 4, 5000), np.ones(5000)
    cx, cy, s, extent = hex_reduce(x, y, c, 20, "mean")
    assert extent[0] <= x.min() and extent[1] >= x.max()
    assert len(cx) == len(cy) == len(s) and np.all(s == 1.0)
    assert len(np.unique(np.c_[cx, cy], axis=0)) == len(cx)           # one centre per cell


def test_fixed_layout_margins_in_inches_and_saved_as_is():
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(8, 4))
    fixed_layout(fig, left=0.8, right=0.4, bottom=0.6, top=0.5, wspace=1.0)
    assert getattr(fig, FIXED_LAYOUT)
    fig.canvas.draw()
    a, b = (ax.get_position() for ax in axes)
    assert a.x0 * 8 == pytest.approx(0.8) and (1 - b.x1) * 8 == pytest.approx(0.4)
    assert a.y0 * 4 == pytest.approx(0.6) and (1 - a.y1) * 4 == pytest.approx(0.5)
    assert (b.x0 - a.x1) * 8 == pytest.approx(1.0)
    assert _png_size(png_of(fig)) == (800, 400)          # the canvas as laid out: no tight box
    fig, ax = plt.subplots(figsize=(8, 4))                # a figure without it keeps the tight box
    ax.set_title("t")
    assert _png_size(png_of(fig)) != (800, 400)


def test_wrap_inches():
    text = "largest MDB of each point's image coordinates, plan (X, Y) (model units)"
    wrapped = wrap_inches(text, 3.0, 9)
    assert wrapped.replace("\n", " ") == text and wrapped.count("\n") >= 1
    assert wrap_inches("short", 3.0, 9) == "short"
    t = "check points: plan error vectors × 451 (adjusted − surveyed; largest 312 mm)"
    assert "312 mm" in wrap_inches(t, 5.6, 10).split("\n")[-1]        # a number keeps its unit
    assert wrap_inches("w of helmert-screening: histogram; critical |w| = 3.29", 3.9, 10).endswith("\n|w| = 3.29")


def _inside(fig, renderer) -> list[str]:
    """Texts of ``fig`` (every axes with its ticks, labels, title; the figure's own texts) that reach
    beyond the canvas."""
    W, H = fig.bbox.width, fig.bbox.height
    out = []
    for ax in fig.axes:
        bb = ax.get_tightbbox(renderer)
        if bb is not None and (bb.x0 < -1 or bb.y0 < -1 or bb.x1 > W + 1 or bb.y1 > H + 1):
            out.append(f"axes '{ax.get_title()}' {bb.bounds}")
    for t in fig.texts:
        bb = t.get_window_extent(renderer)
        if t.get_text() and (bb.x0 < -1 or bb.x1 > W + 1 or bb.y1 > H + 1):
            out.append(f"text '{t.get_text()[:40]}' {bb.bounds}")
    return out


def test_a_cut_label_is_found():
    plt = _plt()
    fig, ax = plt.subplots(figsize=(4, 3))
    fixed_layout(fig, left=0.05, bottom=0.6)
    ax.set_ylabel("a label with no room")
    fig.canvas.draw()
    assert _inside(fig, fig.canvas.get_renderer())
    plt.close(fig)


def test_bundle_figures_fixed_and_nothing_cut():
    """A small aerial block with check points and a distorting camera, its image points drawn as
    hexbins: every bundle figure has a fixed layout, no label, tick, title or colour bar beyond the
    canvas, and saves at its size."""
    from baarda.pipeline.adjustment import adjust_block
    from baarda.pipeline.synthetic.aerial import simulate_aerial
    from baarda.plugins.bundle.figures import bundle_figures

    noisy, _ = simulate_aerial(np.random.default_rng(5), n_strips=2, photos_per_strip=4, points_per_photo=900,
                               model="brown")
    assert len(noisy.observations) > 5_000                       # the maps are hexbins (plots.MAP_CELLS)
    role = np.array(noisy.points.role, dtype=object)
    role[np.flatnonzero(role == "full")[:2]] = "check"
    noisy = dataclasses.replace(noisy, points=dataclasses.replace(noisy.points, role=role.astype(str)))
    rep = adjust_block(noisy)
    figs = bundle_figures(rep.result, getattr(rep, "decision", None))
    assert {"residuals", "network", "distortion_cam", "reliability", "checkpoints", "w", "redundancy",
            "convergence"} <= set(figs)
    for name, (fig, _) in figs.items():
        assert getattr(fig, FIXED_LAYOUT, False), name
        fig.canvas.draw()
        assert not _inside(fig, fig.canvas.get_renderer()), (name, _inside(fig, fig.canvas.get_renderer()))
        w, h = fig.get_size_inches() * 100
        assert _png_size(png_of(fig)) == (round(w), round(h)), name
