"""Variance components (pipeline/adjustment/variance.py) against independent references: the
restricted likelihood maximised numerically, Monte Carlo means against the true σ on a linear model
and on a simulated two-camera bundle, and the identities Σ r_g = dof, Σ Ω_g = vᵀPv."""

from __future__ import annotations

import numpy as np

from baarda.pipeline.model import SourceInfo
import pytest
from scipy import optimize

from baarda.pipeline.adjustment import (BundleSettings, Distance, adjust, estimate_components, group_parts,
                                        image_group_labels, linear_components)
from baarda.pipeline.model import Cameras
from baarda.pipeline.synthetic.closerange import make_block


def _linear_model(rng, n1=40, n2=40, u=4):
    A = rng.standard_normal((n1 + n2, u))
    groups = np.r_[np.zeros(n1, int), np.ones(n2, int)]
    return A, groups


def _neg_reml(logs, A, l, sigma, groups):
    """−2 × restricted log-likelihood of l = A x + e, e ~ N(0, diag(s_g σ_i²))."""
    d = sigma ** 2 * np.exp(logs)[groups]
    P = 1.0 / d
    N = A.T @ (P[:, None] * A)
    x = np.linalg.solve(N, A.T @ (P * l))
    v = l - A @ x
    return np.sum(np.log(d)) + np.linalg.slogdet(N)[1] + np.sum(P * v * v)


def test_linear_single_group_is_sigma0_squared():
    rng = np.random.default_rng(1)
    A, _ = _linear_model(rng)
    sigma = rng.uniform(0.5, 2.0, len(A))
    l = A @ np.ones(A.shape[1]) + 1.7 * sigma * rng.standard_normal(len(A))
    out = linear_components(A, l, sigma, np.zeros(len(A), int))
    P = 1 / sigma ** 2
    x = np.linalg.solve(A.T @ (P[:, None] * A), A.T @ (P * l))
    v = l - A @ x
    s2 = np.sum(P * v * v) / (len(A) - A.shape[1])
    assert out.s2[0] == pytest.approx(s2, rel=1e-12)
    assert out.redundancy[0] == pytest.approx(len(A) - A.shape[1], rel=1e-12)


def test_linear_fixed_point_is_the_reml_estimate():
    """The converged Förstner estimate maximises the restricted likelihood (found here by a
    general-purpose optimiser, not by the estimator's equations)."""
    rng = np.random.default_rng(2)
    A, g = _linear_model(rng, 30, 50, 5)
    sigma = np.ones(len(A))
    l = A @ rng.standard_normal(5) + np.where(g == 0, 0.5, 2.0) * rng.standard_normal(len(A))
    out = linear_components(A, l, sigma, g, tol=1e-12, max_iter=200)
    assert out.converged
    opt = optimize.minimize(_neg_reml, np.zeros(2), args=(A, l, sigma, g), method="BFGS",
                            options={"gtol": 1e-10})
    assert np.allclose(out.s2, np.exp(opt.x), rtol=1e-5)
    # at the fixed point each group's Ω_g equals its redundancy share, and Σ r_g = n − u
    assert np.allclose(out.omega, out.redundancy, rtol=1e-10)
    assert out.redundancy.sum() == pytest.approx(len(A) - 5, rel=1e-12)


def test_linear_monte_carlo_mean_is_the_truth():
    rng = np.random.default_rng(3)
    A, g = _linear_model(rng, 60, 40, 4)
    sigma = np.ones(len(A))              # a-priori σ 1 for both groups
    true = np.array([0.8, 2.5])          # true σ: factors 0.8 and 2.5
    est = []
    for _ in range(2000):
        l = A @ np.array([1.0, -2.0, 0.5, 3.0]) + true[g] * rng.standard_normal(len(A))
        est.append(linear_components(A, l, sigma, g, tol=1e-10).s2)
    est = np.array(est)
    mean, se = est.mean(axis=0), est.std(axis=0) / np.sqrt(len(est))
    assert np.all(np.abs(mean - true ** 2) < 4 * se + 0.01 * true ** 2), (mean, true ** 2, se)
    # the spread is that of χ²(r_g)/r_g: sd(s2_g) ≈ s_g √(2/r_g)
    r = np.array([60 - 4 * 60 / 100, 40 - 4 * 40 / 100])
    assert np.allclose(est.std(axis=0), true ** 2 * np.sqrt(2 / r), rtol=0.15)


# ---------------------------------------------------------------------------------------------
def _two_camera_block(seed, sig_a, sig_b, prior, n_photos=8, n_points=40):
    """The close-range scene with the photos split between two cameras (same interior
    orientation); camera A's coordinates get noise sig_a, B's sig_b; a-priori σ = prior for all."""
    blk, truth = make_block(n_photos=n_photos, n_points=n_points, model="brown", noise_mm=0.0, seed=1)
    c = blk.cameras
    two = Cameras.make(["A", "B"], c.c[0], c.xp[0], c.yp[0], ap_model=c.ap_model[0], ap=np.repeat(c.ap, 2, axis=0),
                       sigma_iop=np.repeat(c.sigma_iop, 2, axis=0), sigma_ap=np.repeat(c.sigma_ap, 2, axis=0),
                       format_mm=tuple(c.format_mm[0]))
    cam_of_photo = np.arange(n_photos) % 2
    photos = blk.photos.replace(camera=cam_of_photo)
    obs = blk.observations
    rng = np.random.default_rng(seed)
    s = np.where(cam_of_photo[obs.photo] == 0, sig_a, sig_b)
    xy = obs.xy + s[:, None] * rng.standard_normal(obs.xy.shape)
    obs = obs.replace(xy=xy, cov=np.broadcast_to(np.eye(2) * prior ** 2, obs.cov.shape).copy())
    ap_meta = {"A": blk.ap_meta["cam"], "B": blk.ap_meta["cam"]}
    return blk.replace(cameras=two, photos=photos, observations=obs, ap_meta=ap_meta)


def test_group_shares_add_up_to_dof_and_vtpv():
    """Image groups, weighted control, EO priors, a weighted camera parameter and a scale bar:
    Σ r_g = dof and Σ Ω_g = vᵀPv on the dense and the sparse route (the prior and scale-bar
    redundancies come from the cofactors, the image ones from the redundancy numbers)."""
    blk = _two_camera_block(4, 0.001, 0.002, 0.0015)
    pts = blk.points
    sig = np.array(pts.sigma, float)
    full = pts.role == "full"
    sig[full] = 0.002
    rng = np.random.default_rng(5)
    blk = blk.replace(points=pts.replace(sigma=sig, XYZ=pts.XYZ + np.where(
        full[:, None], 0.002 * rng.standard_normal(pts.XYZ.shape), 0.0)))
    se = np.array(blk.photos.sigma_eo, float)
    se[:2] = [0.05, 0.05, 0.05, 0.01, 0.01, 0.01]
    si = np.array(blk.cameras.sigma_iop, float)
    si[:, 0] = 0.5
    blk = blk.replace(photos=blk.photos.replace(sigma_eo=se), cameras=blk.cameras.replace(sigma_iop=si))
    d = float(np.linalg.norm(pts.XYZ[10] - pts.XYZ[20]))
    labels = image_group_labels(blk, "camera")
    sums = {}
    for solver in ("dense", "sparse"):
        res = adjust(blk, BundleSettings(distances=(Distance("110", "120", d + 3e-4, 1e-3),), solver=solver))
        parts = group_parts(res, labels)
        assert {p.name for p in parts} == {"image camera A", "image camera B", "control", "eo", "interior",
                                              "scale bars"}
        assert sum(p.redundancy for p in parts) == pytest.approx(res.dof, rel=1e-9)
        assert sum(p.omega for p in parts) == pytest.approx(res.vtpv, rel=1e-9)
        assert all(0 <= p.redundancy <= p.n + 1e-9 for p in parts)
        sums[solver] = {p.name: p.redundancy for p in parts}
    for k in sums["dense"]:
        assert sums["dense"][k] == pytest.approx(sums["sparse"][k], rel=1e-7, abs=1e-9)


def test_bundle_two_cameras_monte_carlo():
    """Two cameras with true noise 1 µm and 2.5 µm, both given 1.5 µm a priori: the estimated
    factors average to 1/1.5 and 2.5/1.5 within the Monte Carlo spread, and the reported σ(f)
    matches that spread."""
    sa, sb, prior = 0.001, 0.0025, 0.0015
    f = []
    sf = []
    for seed in range(40):
        blk = _two_camera_block(100 + seed, sa, sb, prior)
        vc = estimate_components(blk, BundleSettings(), image_groups="camera", tol=1e-4)
        assert vc.converged and vc.iterations <= 10
        g = {x.name: x for x in vc.groups}
        f.append([g["image camera A"].factor, g["image camera B"].factor])
        sf.append([g["image camera A"].sigma_factor, g["image camera B"].sigma_factor])
        if seed == 0:
            # the re-weighted adjustment ends with σ̂0 = 1 and every group at its share
            assert vc.result.sigma0_hat == pytest.approx(1.0, abs=2e-4)
            assert vc.first.sigma0_hat > 1.05
    f, sf = np.array(f), np.array(sf)
    truth = np.array([sa, sb]) / prior
    mean, sd = f.mean(axis=0), f.std(axis=0, ddof=1)
    assert np.all(np.abs(mean - truth) < 4 * sd / np.sqrt(len(f))), (mean, truth, sd)
    assert np.allclose(sf.mean(axis=0), sd, rtol=0.35), (sf.mean(axis=0), sd)


def test_unestimable_scale_bar_and_single_group():
    """A free network's only scale bar has r ≈ 0: reported, factor 1, not estimable.  One image
    group alone: the factor is σ̂0 of the first adjustment after one step."""
    blk = _two_camera_block(7, 0.002, 0.002, 0.001)
    pts = blk.points
    blk = blk.replace(points=pts.replace(role=np.full(len(pts), "tie", dtype=object),
                                         sigma=np.full((len(pts), 3), np.inf)))
    d = float(np.linalg.norm(pts.XYZ[10] - pts.XYZ[20]))
    st = BundleSettings(datum="free", distances=(Distance("110", "120", d, 1e-4),))
    vc = estimate_components(blk, st, image_groups="all")
    g = {x.name: x for x in vc.groups}
    assert not g["scale bars"].estimable and g["scale bars"].factor == 1.0
    assert g["scale bars"].redundancy < 1e-6
    assert g["image"].factor == pytest.approx(vc.first.sigma0_hat, rel=1e-3)
    assert g["image"].rejected                      # σ 2 µm against 1 µm a priori: H0 (f = 1) rejected
    assert vc.result.sigma0_hat == pytest.approx(1.0, abs=1e-3)
    # the input block is untouched
    assert np.all(blk.observations.cov[:, 0, 0] == 1e-6)


def test_bundle_stage_option(tmp_path):
    """The bundle stage: variance_components = estimate reports the groups and keeps the a-priori
    σ; apply re-weights (σ̂0 = 1, each camera's σ scaled); results.json carries σ̂_g, r_g and the test."""
    from baarda.pipeline.errors import InputError
    from baarda.pipeline.testing import run_stage
    from baarda.plugins.bundle.stage import BundleAdjustment

    blk = _two_camera_block(11, 0.001, 0.003, 0.0015)
    est = run_stage(BundleAdjustment, {"block": blk}, {"variance_components": {"mode": "estimate"}}, tmp_path=tmp_path)
    app = run_stage(BundleAdjustment, {"block": blk}, {"variance_components": {"mode": "apply"}}, tmp_path=tmp_path)
    vc = app.summary["variance_components"]
    g = {x["name"]: x for x in vc["groups"]}
    assert vc["converged"] and vc["mode"] == "apply"
    assert 0.55 < g["image camera A"]["factor"] < 0.8 and 1.7 < g["image camera B"]["factor"] < 2.3
    assert g["image camera A"]["rejected"] and g["image camera B"]["rejected"]
    assert g["image camera A"]["redundancy"] + g["image camera B"]["redundancy"] == pytest.approx(
        app.artefacts["bundle"].dof, rel=1e-9)
    assert app.artefacts["bundle"].sigma0_hat == pytest.approx(1.0, abs=1e-3)
    assert est.artefacts["bundle"].sigma0_hat > 1.2                     # estimate only: a-priori σ kept
    ge = {x["name"]: x for x in est.summary["variance_components"]["groups"]}
    assert ge["image camera B"]["factor"] == pytest.approx(g["image camera B"]["factor"], rel=1e-6)
    assert "### Variance components" in app.report and "image camera B" in app.report
    cov = app.artefacts["bundle"].block_in.observations.cov
    on_b = blk.photos.camera[blk.observations.photo] == 1
    assert np.sqrt(cov[on_b, 0, 0]).mean() == pytest.approx(0.0015 * g["image camera B"]["factor"], rel=1e-9)
    # user-defined groups: photos P1, P2 on their own
    usr = run_stage(BundleAdjustment, {"block": blk}, {"variance_components": {
        "mode": "estimate", "photo_groups": {"first two": ["P1", "P2"]}}},
                    tmp_path=tmp_path)
    names = {x["name"] for x in usr.summary["variance_components"]["groups"]}
    assert names == {"image camera A", "image camera B", "image first two"}
    with pytest.raises(InputError, match="variance_components.photo_groups"):
        run_stage(BundleAdjustment, {"block": blk}, {"variance_components": {"mode": "estimate",
                                                                             "photo_groups": {"x": ["P99"]}}},
                  tmp_path=tmp_path)


def test_image_groups_by_source_photo_and_user():
    """Groups per source file (the reader's source_lines, else the block's source), per photo, and
    user groups of photos overriding them; a wrong grouping is refused."""
    blk = _two_camera_block(3, 0.001, 0.001, 0.001)
    obs = blk.observations
    half = len(obs) // 2
    lines = {(int(obs.photo[i]), int(obs.point[i])): ("/data/run1/left.txt", i + 1) for i in range(half)}
    blk = blk.replace(source=SourceInfo(path="/data/right.txt", lines=lines))
    lab = image_group_labels(blk, "source")
    assert set(lab[:half]) == {"image source left.txt"} and set(lab[half:]) == {"image source right.txt"}
    lab = image_group_labels(blk, "photo", photo_groups={"pair": ["P1", "P2"]})
    assert lab[obs.photo == 0][0] == "image pair" and lab[obs.photo == 2][0] == "image photo P3"
    assert len(set(image_group_labels(blk, "photo").tolist())) == len(blk.photos)
    with pytest.raises(ValueError, match="expected all, camera, photo or source"):
        image_group_labels(blk, "lens")
    with pytest.raises(ValueError, match="one name per observation"):
        image_group_labels(blk, np.array(["a", "b"]))
    # by source: two groups with the same true σ give factors that agree within their σ(f)
    vc = estimate_components(blk, BundleSettings(), image_groups="source")
    g = {x.name: x for x in vc.groups}
    a, b = g["image source left.txt"], g["image source right.txt"]
    assert abs(a.factor - b.factor) < 4 * np.hypot(a.sigma_factor, b.sigma_factor)
    assert not a.rejected or not b.rejected


def test_bundle_stage_option_errors_and_ap_selection(tmp_path):
    """variance components without covariances is refused as an option error; after AP selection the
    components start from the selected model (the removed parameters stay removed)."""
    from baarda.pipeline.options import parse_options
    from baarda.pipeline.testing import run_stage
    from baarda.pipeline.adjustment import BundleConfig
    from baarda.plugins.bundle.stage import BundleAdjustment

    with pytest.raises(Exception, match="covariance = true"):
        parse_options(BundleConfig, {"variance_components": {"mode": "apply"}, "solver": {"covariance": False}})
    blk = _two_camera_block(21, 0.001, 0.002, 0.001)
    out = run_stage(BundleAdjustment, {"block": blk}, {"variance_components": {"mode": "apply"}, "ap_selection": {"enabled": True}},
                    tmp_path=tmp_path)
    res = out.artefacts["bundle"]
    sel = out.data["report"].selection.result
    assert sel.camera_free.sum() < (blk.cameras.sigma_ap != 0).sum() + 6     # the selection removed some
    np.testing.assert_array_equal(res.camera_free, sel.camera_free)
    assert res.sigma0_hat == pytest.approx(1.0, abs=1e-3)
