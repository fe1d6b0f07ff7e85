"""Covariances and redundancy numbers against a dense reference built from finite-difference
Jacobians, and against Monte Carlo spread."""

import numpy as np
import pytest

from baarda.pipeline.model import FREE
from baarda.pipeline.adjustment import BundleSettings, adjust
from baarda.pipeline.adjustment.collinearity import project_observations

from baarda.pipeline.synthetic.closerange import make_block, with_correlated_noise


def _dense_reference(res):
    """Full normal matrix from numeric derivatives of the projection w.r.t. every unknown."""
    prob = res.problem
    blk = res.block_in
    st = res.state
    obs = blk.observations
    oi = np.flatnonzero(res.obs_active)

    def f(cam, X0, opk, XYZ):
        pr = project_observations(obs.photo[oi], obs.point[oi], XYZ, X0, opk, blk.photos.camera, cam,
                                  blk.cameras.ap_model, prob.meta, jacobians=False)
        return pr.xy.reshape(-1)

    unknowns = []   # (kind, i, t)
    for j in range(prob.K):
        for t in range(st.cam_params.shape[1]):
            if prob.g_cam[j, t] >= 0:
                unknowns.append(("cam", j, t))
    for i in range(prob.m):
        for t in range(6):
            if prob.g_eo[i, t] >= 0:
                unknowns.append(("eo", i, t))
    for p in range(prob.n):
        for t in range(3):
            if prob.pt_free[p, t]:
                unknowns.append(("pt", p, t))
    A = np.zeros((2 * len(oi), len(unknowns)))
    for u, (kind, i, t) in enumerate(unknowns):
        cols = []
        for sgn in (1, -1):
            cam, X0, opk, XYZ = st.cam_params.copy(), st.X0.copy(), st.opk.copy(), st.XYZ.copy()
            if kind == "cam":
                h = max(1e-6 * abs(cam[i, t]), 1e-13) if t >= 3 else 1e-6
            else:
                h = 1e-7
            if kind == "cam":
                cam[i, t] += sgn * h
            elif kind == "eo":
                (X0 if t < 3 else opk)[i, t % 3] += sgn * h
            else:
                XYZ[i, t] += sgn * h
            cols.append(f(cam, X0, opk, XYZ))
        A[:, u] = (cols[0] - cols[1]) / (2 * h)
    P = np.zeros((2 * len(oi), 2 * len(oi)))
    for r, k in enumerate(oi):
        P[2 * r:2 * r + 2, 2 * r:2 * r + 2] = np.linalg.inv(obs.cov[k])
    N = A.T @ P @ A
    return unknowns, A, P, N


def _compare(res):
    unknowns, A, P, N = _dense_reference(res)
    Q = np.linalg.inv(N)
    var = res.variance_factor
    prob = res.problem
    # camera, EO and point variances
    for u, (kind, i, t) in enumerate(unknowns):
        if kind == "cam":
            got = res.cov_cameras[i][t, t]
        elif kind == "eo":
            got = res.cov_eo[i, t, t]
        else:
            got = res.cov_points[i, t, t]
        assert got == pytest.approx(var * Q[u, u], rel=2e-5), (kind, i, t)
    # a full 3×3 point block and a camera–camera correlation
    p = next(i for kind, i, t in unknowns if kind == "pt")
    idx = [u for u, (kind, i, t) in enumerate(unknowns) if kind == "pt" and i == p]
    assert np.allclose(res.cov_points[p], var * Q[np.ix_(idx, idx)], rtol=2e-5, atol=1e-12 * var * Q[idx[0], idx[0]])
    # redundancy numbers and P Qvv P
    Qvv = np.linalg.inv(P) - A @ Q @ A.T
    R = Qvv @ P
    PQP = P @ Qvv @ P
    oi = np.flatnonzero(res.obs_active)
    assert np.allclose(res.redundancy[oi].reshape(-1), np.diag(R), atol=2e-6)
    assert np.allclose(np.einsum("kii->ki", res.PQvvP[oi]).reshape(-1), np.diag(PQP), rtol=1e-4,
                       atol=1e-6 * np.abs(np.diag(PQP)).max())
    assert res.redundancy.sum() == pytest.approx(res.dof, rel=1e-8)


def test_precision_matches_dense_reference():
    blk, _ = make_block(model="brown", n_photos=5, n_points=14, noise_mm=0.002, rng=np.random.default_rng(2),
                        n_control=5)
    res = adjust(blk)
    _compare(res)


def test_correlated_image_coordinates_dense_reference():
    blk, _ = make_block(model="none", n_photos=5, n_points=14, noise_mm=0.0, n_control=5)
    blk = with_correlated_noise(blk, np.random.default_rng(4))
    res = adjust(blk)
    _compare(res)


def test_weighted_control_and_eo_priors_dense_reference():
    """Weighted full control, height and planimetric control, and weighted exterior orientation set
    through the stage option ``sigma_eo`` (degrees): every variance against the dense normal
    matrix of the image rows plus the prior weights 1/σ² on the constrained unknowns."""
    from baarda.pipeline.options import parse_options
    from baarda.pipeline.adjustment import BundleConfig, configure_block

    blk, truth = make_block(model="none", n_photos=5, n_points=14, noise_mm=0.002, rng=np.random.default_rng(8),
                            n_control=6)
    pts = blk.points
    sigma = np.array(pts.sigma)
    sigma[:6] = 0.002                                   # weighted full control
    sigma[6] = [np.inf, np.inf, 0.0]                    # height control
    sigma[7] = [0.0, 0.0, np.inf]                       # planimetric control
    role = pts.role.copy()
    role[6], role[7] = "z", "xy"
    blk = blk.replace(points=pts.replace(sigma=sigma, role=role))
    # the given orientations are slightly off the truth, so that the constraints do something
    ph = blk.photos
    blk = blk.replace(photos=ph.replace(X0=ph.X0 + 0.003, opk=ph.opk - 0.002))
    s_eo = [0.004, 0.005, 0.006, 0.1, 0.2, 0.3]         # object units (m), degrees
    opts = parse_options(BundleConfig, {"sigma_eo": s_eo}, path="<test>")
    blk = configure_block(blk, opts)
    sig_rad = np.r_[s_eo[:3], np.radians(s_eo[3:])]
    assert np.allclose(blk.photos.sigma_eo, sig_rad)
    res = adjust(blk)
    prob = res.problem
    # weighted constraints count as observations in the redundancy: 18 control, 30 orientation
    assert res.dof == prob.n_obs_rows + 18 + 30 - prob.n_unknowns
    assert res.cov_points[6][2, 2] == 0.0 and res.cov_points[7][0, 0] == 0.0
    unknowns, A, P, N = _dense_reference(res)
    for u, (kind, i, t) in enumerate(unknowns):
        if kind == "eo":
            N[u, u] += 1.0 / sig_rad[t] ** 2
        elif kind == "pt" and i < 6:
            N[u, u] += 1.0 / 0.002 ** 2
    Q = np.linalg.inv(N)
    var = res.variance_factor
    for u, (kind, i, t) in enumerate(unknowns):
        got = res.cov_eo[i, t, t] if kind == "eo" else res.cov_points[i, t, t] if kind == "pt" else \
            res.cov_cameras[i][t, t]
        assert got == pytest.approx(var * Q[u, u], rel=2e-5), (kind, i, t)
    # the estimate is the minimum of image rows + constraints: the dense normal equations (with
    # the prior weights) give no further correction at the solution
    oi = np.flatnonzero(res.obs_active)
    v = res.residuals[oi].reshape(-1)
    d_eo = np.hstack([ph.X0 + 0.003 - res.state.X0, ph.opk - 0.002 - res.state.opk])
    d_pt = pts.XYZ[:6] - res.state.XYZ[:6]
    rhs = A.T @ P @ v
    for u, (kind, i, t) in enumerate(unknowns):
        if kind == "eo":
            rhs[u] += d_eo[i, t] / sig_rad[t] ** 2
        elif kind == "pt" and i < 6:
            rhs[u] += d_pt[i, t] / 0.002 ** 2
    step = Q @ rhs
    assert np.max(np.abs(step) / np.sqrt(np.diag(Q))) < 1e-4
    without = Q @ (A.T @ P @ v)                         # … which the image rows alone would not say
    assert np.max(np.abs(without) / np.sqrt(np.diag(Q))) > 0.1
    # vᵀPv includes the orientation constraints: recompute it from the residuals and the priors
    vtpv = v @ P @ v + np.sum((d_eo / sig_rad) ** 2) + np.sum((d_pt / 0.002) ** 2)
    assert res.vtpv == pytest.approx(vtpv, rel=1e-9)


@pytest.mark.parametrize("n_sim", [100, pytest.param(500, marks=pytest.mark.slow)])
def test_monte_carlo_spread_matches_reported_covariance(n_sim):
    """Repeated noisy simulations: the spread of the estimates matches the reported σ."""
    sig = 0.002
    blk, truth = make_block(model="brown", n_photos=6, n_points=25, noise_mm=0.0, n_control=5)
    obs = blk.observations
    rng = np.random.default_rng(123)
    est_c, est_pt, est_eo, s0 = [], [], [], []
    ref = None
    for _ in range(n_sim):
        noisy = blk.replace(observations=obs.replace(xy=obs.xy + sig * rng.standard_normal(obs.xy.shape),
                                                     cov=np.broadcast_to(np.eye(2) * sig ** 2, obs.cov.shape)))
        res = adjust(noisy, start=None if ref is None else ref.state)
        ref = ref or res
        est_c.append(res.state.cam_params[0, :5])
        est_pt.append(res.state.XYZ[10])
        est_eo.append(np.r_[res.state.X0[2], res.state.opk[2]])
        s0.append(res.sigma0_hat)
    # reported (a-priori scaled) standard deviations from the noise-free geometry
    var0 = 1.0 / ref.variance_factor
    pred_c = np.sqrt(np.diag(ref.cov_cameras[0])[:5] * var0)
    pred_pt = np.sqrt(np.diag(ref.cov_points[10]) * var0)
    pred_eo = np.sqrt(np.diag(ref.cov_eo[2]) * var0)
    for est, pred in ((est_c, pred_c), (est_pt, pred_pt), (est_eo, pred_eo)):
        emp = np.std(np.array(est), axis=0, ddof=1)
        ratio = emp / pred
        # sample std of n_sim draws: relative sd ≈ 1/√(2 n) ≈ 9 %; allow 4 of those
        assert np.all(np.abs(ratio - 1) < 4 / np.sqrt(2 * n_sim)), ratio
    assert np.mean(s0) == pytest.approx(1.0, abs=0.03)


@pytest.mark.parametrize("datum", ["control", "free-points", "free-centres"])
def test_schur_strategies_agree(monkeypatch, datum):
    """dense / pairs / sparse forms of B Bᵀ and both precision routes give the same numbers."""
    from baarda.pipeline.model import FREE
    from baarda.pipeline.adjustment.normal import NormalEquations

    blk, _ = make_block(model="brown", n_photos=6, n_points=30, noise_mm=0.002, rng=np.random.default_rng(1))
    st = BundleSettings()
    if datum != "control":
        pts = blk.points
        blk = blk.replace(points=pts.replace(role=np.array(["tie"] * len(pts)), sigma=np.full((len(pts), 3), FREE)))
        st = BundleSettings(datum="free", datum_centres=datum == "free-centres")
    out = {}
    for mode, route in (("dense", "chunks"), ("pairs", "pairs"), ("sparse", "chunks"), ("dense", "pairs"),
                        ("pairs", "chunks")):
        monkeypatch.setattr(NormalEquations, "gram_mode", property(lambda self, m=mode: m))
        monkeypatch.setattr(NormalEquations, "points_by_pairs", property(lambda self, r=route: r == "pairs"))
        out[mode, route] = adjust(blk, st)
    ref = out["dense", "chunks"]
    for key in list(out)[1:]:
        r = out[key]
        assert np.allclose(r.state.XYZ, ref.state.XYZ, rtol=0, atol=1e-10)
        assert np.allclose(r.cov_points, ref.cov_points, rtol=1e-8, atol=1e-12 * np.abs(ref.cov_points).max())
        assert np.allclose(r.redundancy, ref.redundancy, atol=1e-9)
        assert np.allclose(r.cov_cameras[0], ref.cov_cameras[0], rtol=1e-8, atol=1e-14)


def test_predicted_residual_of_a_removed_observation():
    """v_pred / sigma_v_pred of a removed row equals the w-test of that row when it is active
    (uncorrelated x, y: w = ∇̂/σ_∇̂ = v_pred/σ_v_pred, Baarda)."""
    from baarda.pipeline import stats

    blk, _ = make_block(model="brown", n_photos=6, n_points=25, noise_mm=0.002, rng=np.random.default_rng(9),
                        n_control=5)
    obs = blk.observations
    xy = obs.xy.copy()
    k = 40
    xy[k, 0] += 0.015
    blk = blk.replace(observations=obs.replace(xy=xy, cov=np.broadcast_to(np.eye(2) * 0.002 ** 2, obs.cov.shape)))
    full = adjust(blk)
    w_full = stats.w_test(full.snapshot)[2 * k]
    rows = np.ones(2 * len(obs), bool)
    rows[2 * k] = False
    snap = full.refit(rows)
    w_pred = snap.v_pred[2 * k] / snap.sigma_v_pred[2 * k]
    assert w_pred == pytest.approx(w_full, rel=2e-3)        # equal up to the non-linearity
    assert np.isnan(snap.sigma_v_pred[2 * k + 1]) and snap.active[2 * k + 1]
