"""The design stages' figures (report.html): the expected figures on a small run, and the numbers
drawn equal the stage's result — checked against independent references (eigenvalues of the
covariance blocks, Baarda's MDB formula, the effect of an MDB by re-adjusting with it added, the
look-at points of the stations file, the realised errors)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib.collections import EllipseCollection, LineCollection  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402
from matplotlib.quiver import Quiver  # noqa: E402

from baarda.pipeline import stats  # noqa: E402
from baarda.pipeline.adjustment import BundleSettings, adjust  # noqa: E402
from baarda.pipeline.stage import Context  # noqa: E402
from baarda.plugins.design.stage import (DesignMonteCarlo, DesignMonteCarloOptions, DesignOptions,  # noqa: E402
                                         DesignSource, CameraOptions)

FIX = Path(__file__).resolve().parents[2] / "fixtures" / "design"


def _bars(ax):
    return np.array([p.get_height() for p in ax.patches if isinstance(p, Rectangle)])


@pytest.fixture(scope="module")
def design():
    opts = DesignOptions(stations=FIX / "stations.csv", targets=FIX / "targets.csv", sigma_px=0.1,
                         sigma_control_mm=0.2, margin_px=20,
                         camera=CameraOptions(c_mm=24.0, pixel_mm=0.006, resolution=[4000, 3000], ap_model="brown",
                                              free=["c", "xp", "yp", "K1", "K2", "P1", "P2"]))
    ctx = Context(stage_id="design", project_dir=FIX, object_unit="m")
    return DesignSource().run({}, opts, ctx), ctx


@pytest.fixture(scope="module")
def bundle(design):
    return adjust(design[0].data["block"], BundleSettings(variance="a-priori"))


def _montecarlo(bundle, n_sim):
    ctx = Context(stage_id="design-montecarlo", project_dir=FIX, object_unit="m", seed=3)
    opts = DesignMonteCarloOptions(n_sim=n_sim, joint_test=False, seed=11)
    st = DesignMonteCarlo()
    res = st.run({"bundle": bundle}, opts, ctx)
    return res, st.plots(res, ctx)


def test_design_plan_figures(design):
    result, ctx = design
    figs = DesignSource().plots(result, ctx)
    assert set(figs) == {"plan", "rays"}
    assert all(isinstance(c, str) and c for _, c in figs.values())
    block = result.data["block"]
    obs, X0, XYZ = block.observations, block.photos.X0, block.points.XYZ
    fig = figs["plan"][0]
    plan, elev = fig.axes[:2]
    assert plan.get_xlabel() == "X (m)" and plan.get_ylabel() == "Y (m)" and elev.get_ylabel() == "Z (m)"
    for ax, (i, j) in ((plan, (0, 1)), (elev, (0, 2))):
        rays = [c for c in ax.collections if isinstance(c, LineCollection)][0]
        segs = np.array(rays.get_segments())
        assert len(segs) == len(obs) == 240
        np.testing.assert_allclose(segs[:, 0], X0[obs.photo][:, [i, j]])
        np.testing.assert_allclose(segs[:, 1], XYZ[obs.point][:, [i, j]])
        q = [c for c in ax.collections if isinstance(c, Quiver)][0]
        np.testing.assert_allclose(q.X, X0[:, i])
    # the viewing direction (arrows) points at each station's look-at point of the stations file
    rows = [ln.split(",") for ln in (FIX / "stations.csv").read_text().splitlines()
            if ln and not ln.startswith(("#", "id"))]
    look = np.array([[float(v) for v in r[4:7]] for r in rows])
    u = (look - X0) / np.linalg.norm(look - X0, axis=1)[:, None]
    np.testing.assert_allclose(result.data["view"], u, atol=1e-12)
    q = [c for c in plan.collections if isinstance(c, Quiver)][0]
    np.testing.assert_allclose(np.column_stack([q.U, q.V]) / np.hypot(q.U, q.V)[:, None],
                               u[:, :2] / np.linalg.norm(u[:, :2], axis=1)[:, None], atol=1e-9)
    a, b = figs["rays"][0].axes[:2]
    np.testing.assert_array_equal(_bars(a), result.tables["rays"].columns["rays"])
    np.testing.assert_array_equal(_bars(a), np.bincount(obs.point, minlength=len(XYZ)))
    np.testing.assert_array_equal(_bars(b), np.bincount(obs.photo, minlength=len(X0)))
    plt.close("all")


def test_montecarlo_figures_draw_the_results_numbers(bundle):
    res, figs = _montecarlo(bundle, n_sim=6)
    assert set(figs) == {"network", "precision", "redundancy", "reliability", "montecarlo"}
    f = res.data["figures"]
    free = f["free"]
    C = bundle.cov_points * bundle.sigma0 ** 2 / bundle.variance_factor
    # ellipses: semi-axes from the eigenvalues of the XY and XZ blocks, drawn × one factor
    net = figs["network"][0]
    for ax, idx, key in zip(net.axes[:2], ([0, 1], [0, 2]), ("ellipse_xy", "ellipse_xz")):
        ev = np.sqrt(np.linalg.eigvalsh(C[free][:, idx][:, :, idx]))
        np.testing.assert_allclose(f[key][free, 0], ev[:, 1], rtol=1e-9)
        np.testing.assert_allclose(f[key][free, 1], ev[:, 0], rtol=1e-6, atol=1e-12)
        ec = [c for c in ax.collections if isinstance(c, EllipseCollection)][0]
        k = float(net._suptitle.get_text().split("×")[1].split()[0])
        np.testing.assert_allclose(ec._widths, k * f[key][free, 0], rtol=2e-3)    # matplotlib keeps half-widths
        np.testing.assert_allclose(ec.get_offsets(), bundle.state.XYZ[free][:, idx])
    # predicted σ in mm (bars) and the realised σ = √(Σe²/N) (dots)
    ax = figs["precision"][0].axes[0]
    s = 1000 * np.sqrt(np.einsum("nii->ni", C[free]))
    np.testing.assert_allclose(np.sort(_bars(ax)), np.sort(s.ravel()), rtol=1e-9)
    np.testing.assert_allclose(res.tables["points"].columns["sigma_X_pred_m"], s[:, 0] / 1000, rtol=1e-12)
    E = res.data["montecarlo"]["errors_points"]
    assert E.shape == (6, len(free), 3)
    real = 1000 * np.sqrt(np.mean(E ** 2, axis=0))
    dots = np.concatenate([ln.get_ydata() for ln in ax.lines if ln.get_marker() == "."])
    np.testing.assert_allclose(np.sort(dots), np.sort(real.ravel()), rtol=1e-9)
    # Monte Carlo: the histogram holds every error / σ; the scatter is (predicted, realised)
    hist, scat = figs["montecarlo"][0].axes[:2]
    counts = _bars(hist)
    width = [p.get_width() for p in hist.patches][0]
    assert counts.sum() * width * E.size == pytest.approx(E.size)           # density
    pts = np.concatenate([np.column_stack(ln.get_data()) for ln in scat.lines if ln.get_label() in "XYZ"])
    np.testing.assert_allclose(np.sort(pts[:, 0]), np.sort(s.ravel()), rtol=1e-9)
    np.testing.assert_allclose(np.sort(pts[:, 1]), np.sort(real.ravel()), rtol=1e-9)
    assert figs["redundancy"][0].axes[0].get_xlabel() == "r"
    plt.close("all")


def test_reliability_against_baarda_and_a_refit(bundle):
    res, figs = _montecarlo(bundle, n_sim=0)
    assert set(figs) == {"network", "precision", "redundancy", "reliability"}       # no Monte Carlo
    f = res.data["figures"]
    block = bundle.block_in
    snap = bundle.snapshot
    tgt = np.repeat(block.observations.point, 2)
    mdb_px = stats.mdb(snap) / 0.006                                     # Baarda: δ0 σ0 / √(PQvvP)ii
    r = np.asarray(snap.r)
    for p in range(len(block.points)):
        m = tgt == p
        assert f["r_min"][p] == pytest.approx(r[m].min(), rel=1e-12)
        assert f["mdb_max_px"][p] == pytest.approx(mdb_px[m].max(), rel=1e-9)
    panels = figs["reliability"][0].axes
    np.testing.assert_allclose(_bars(panels[0]), f["r_min"])
    np.testing.assert_allclose(_bars(panels[1]), f["mdb_max_px"])
    np.testing.assert_allclose(_bars(panels[2]), 1000 * np.nan_to_num(f["effect_max"]))
    np.testing.assert_allclose(_bars(panels[3]), np.nan_to_num(f["effect_max_sigma"]))
    # the effect of an MDB, by adjusting again with it added to each row of the tie point most affected
    tie = np.flatnonzero(block.points.role == "tie")
    p = tie[np.nanargmax(f["effect_max"][tie])]
    sig = np.sqrt(np.diag(bundle.cov_points[p] * bundle.sigma0 ** 2 / bundle.variance_factor))
    mdb = stats.mdb(snap)
    eff, eff_sig = [], []
    for row in np.flatnonzero(tgt == p):
        xy = np.array(block.observations.xy, float)
        xy[row // 2, row % 2] += mdb[row]
        moved = adjust(block.replace(observations=block.observations.replace(xy=xy)),
                       BundleSettings(variance="a-priori"), start=bundle.state.copy(), covariance=False)
        d = moved.state.XYZ[p] - bundle.state.XYZ[p]
        c = np.argmax(np.abs(d) / sig)
        eff.append(abs(d[c]))
        eff_sig.append(abs(d[c]) / sig[c])
    assert max(eff) == pytest.approx(f["effect_max"][p], rel=2e-3)
    assert max(eff_sig) == pytest.approx(f["effect_max_sigma"][p], rel=2e-3)
    plt.close("all")
