"""External reliability of the bundle (own point / own photo, full vectors on demand) and the
covariance of chosen parameters, against a dense reference: finite-difference Jacobians, numpy
inverse (tests/adjustment/test_precision.py), on both solver routes and in free networks."""

import pickle

import numpy as np
import pytest

from baarda.pipeline.model import FREE
from baarda.pipeline.adjustment import BundleSettings, adjust
from baarda.pipeline.adjustment.reliability import (effect_vectors, own_effects, parameter_covariance,
                                                    row_mdb)
from baarda.pipeline.synthetic.closerange import make_block

from .test_precision import _dense_reference

D0 = 4.13


def _reference(res, free=False, on="pt"):
    """Dense Q, A, P, unknowns.  A free network: the inner constraints on the points' coordinates,
    ``Cᵀ x = 0`` with ``C`` the null space of N (the similarity motions) restricted to the point
    rows, through the bordered matrix ``[[N, C], [Cᵀ, 0]]⁻¹``."""
    unknowns, A, P, N = _dense_reference(res)
    if not free:
        return unknowns, A, P, np.linalg.inv(N)
    d = res.n_datum_constraints
    w, V = np.linalg.eigh(N / np.abs(N).max())
    G = V[:, :d]
    assert w[d] > 1e3 * abs(w[d - 1])                       # a d-dimensional null space
    C = G * np.array([kind == "pt" if on == "pt" else (kind == "eo" and t < 3) for kind, _, t in unknowns])[:, None]
    u = len(unknowns)
    M = np.zeros((u + d, u + d))
    M[:u, :u], M[:u, u:], M[u:, :u] = N, C, C.T
    Q = np.linalg.inv(M)[:u, :u]
    pos = _position(unknowns)
    p = next(i for kind, i, t in unknowns if kind == "pt")
    ref = res.variance_factor * Q[np.ix_(*[[pos[("pt", p, t)] for t in range(3)]] * 2)]
    assert np.allclose(res.cov_points[p], ref, rtol=1e-5)   # the same datum as the bundle's
    return unknowns, A, P, Q


def _position(unknowns):
    return {u: j for j, u in enumerate(unknowns)}


def _check_own(res, free=False, rtol=2e-4, on="pt"):
    unknowns, A, P, Q = _reference(res, free, on)
    pos = _position(unknowns)
    PQP = P - P @ A @ Q @ A.T @ P
    oi = np.flatnonzero(res.obs_active)
    eff = own_effects(res, D0)
    mdb = row_mdb(res, D0)
    obs = res.block_in.observations
    # the MDBs themselves
    assert np.allclose(mdb[oi].reshape(-1), D0 * res.sigma0 / np.sqrt(np.diag(PQP)), rtol=1e-4)
    worst = 0.0
    scale_pt = scale_eo = 0.0
    for r_loc, k in enumerate(oi):
        for c in (0, 1):
            i = 2 * r_loc + c
            dx = Q @ A.T @ P[:, i] * mdb[k, c]
            ph, pt = obs.photo[k], obs.point[k]
            ref_pt = np.array([dx[pos[("pt", pt, t)]] if ("pt", pt, t) in pos else 0.0 for t in range(3)])
            ref_eo = np.array([dx[pos[("eo", ph, t)]] if ("eo", ph, t) in pos else 0.0 for t in range(6)])
            scale_pt = max(scale_pt, np.abs(ref_pt).max())
            scale_eo = max(scale_eo, np.abs(ref_eo).max())
            worst = max(worst, np.abs(eff.point[k, c] - ref_pt).max() / max(np.abs(ref_pt).max(), 1e-12),
                        np.abs(eff.eo[k, c] - ref_eo).max() / max(np.abs(ref_eo).max(), 1e-12))
    assert worst < rtol, worst
    assert scale_pt > 0 and scale_eo > 0
    # Baarda's bound: no effect exceeds δ̄0 σ (a-priori σ)
    s_pt = eff.point_in_sigma[oi]
    assert np.all(np.nan_to_num(s_pt) <= eff.bar_delta0[oi][:, :, None] * (1 + 1e-6))
    return unknowns, A, P, Q, eff


def test_own_effects_match_dense_reference_control_datum():
    blk, _ = make_block(model="brown", n_photos=5, n_points=14, noise_mm=0.002, rng=np.random.default_rng(2),
                        n_control=5)
    res = adjust(blk)
    unknowns, A, P, Q, eff = _check_own(res)
    # the largest per row is one of the own-point / own-photo entries
    j, val, s, je, vale, se = eff.largest()
    oi = np.flatnonzero(res.obs_active)
    tie = oi[res.problem.pt_free[res.block_in.observations.point[oi]].any(axis=1)]
    fixed = np.setdiff1d(oi, tie)
    assert tie.size and fixed.size
    assert np.all(j[tie] >= 0) and np.all(np.abs(val[tie]) > 0) and np.all(j[fixed] == -1)
    assert np.all(je[oi] >= 0) and np.all(se[oi] > 0)
    k = tie[3]
    assert abs(val[k, 0]) == pytest.approx(np.abs(eff.point[k, 0, j[k, 0]]))


def test_effect_vectors_full_and_on_both_routes():
    blk, _ = make_block(model="brown", n_photos=5, n_points=14, noise_mm=0.002, rng=np.random.default_rng(3),
                        n_control=5)
    for solver in ("dense", "sparse"):
        res = adjust(blk, BundleSettings(solver=solver))
        assert res.solver_route == solver
        unknowns, A, P, Q = _reference(res)
        mdb = row_mdb(res, D0)
        oi = np.flatnonzero(res.obs_active)
        rows = np.array([2 * oi[0], 2 * oi[7] + 1, 2 * oi[20]])
        ev = effect_vectors(res, rows, D0)
        loc = {k: r for r, k in enumerate(oi)}
        for j, row in enumerate(rows):
            k, c = divmod(int(row), 2)
            dx = Q @ A.T @ P[:, 2 * loc[k] + c] * mdb[k, c]
            for u, (kind, i, t) in enumerate(unknowns):
                got = ev.cameras[i][j, t] if kind == "cam" else ev.eo[j, i, t] if kind == "eo" else \
                    ev.points[j, i, t]
                assert got == pytest.approx(dx[u], rel=2e-4, abs=2e-4 * np.abs(dx).max()), (solver, kind, i, t)
        if solver == "sparse":
            _check_own(res)


@pytest.mark.parametrize("solver", ["dense", "sparse"])
@pytest.mark.parametrize("on", ["pt", "centres"])
def test_free_network_effects_on_inner_constraints(solver, on):
    """Free network, inner constraints on all points or on the projection centres: effects on that
    datum, the sparse route via minimal constraints + S-transformation."""
    blk, _ = make_block(model="none", n_photos=6, n_points=24, noise_mm=0.002, rng=np.random.default_rng(5))
    pts = blk.points
    blk = blk.replace(points=pts.replace(role=np.array(["tie"] * len(pts)), sigma=np.full((len(pts), 3), FREE)))
    res = adjust(blk, BundleSettings(datum="free", solver=solver, datum_centres=on == "centres"))
    assert res.n_datum_constraints > 0 and res.solver_route == solver
    _check_own(res, free=True, rtol=5e-4, on=on)
    if solver == "sparse":     # the S-transformation over chunks of rows: the same numbers as all at once
        from baarda.pipeline.adjustment.phases import PHASE_CALLBACK

        events = []
        token = PHASE_CALLBACK.set(events.append)
        try:
            a, b = own_effects(res), own_effects(res, chunk_bytes=2e3)
        finally:
            PHASE_CALLBACK.reset(token)
        k = len(res.problem.oi)        # progress: the system, the tracks, then the datum's chunks
        assert (events[0].phase, events[0].done, events[0].total) == ("external reliability", 0, k)
        datum = [e for e in events if e.phase == "external reliability: datum"]
        assert len(datum) > 2 and all(e.total == k for e in datum) and datum[-1].done < k
        np.testing.assert_array_equal(a.point, b.point)
        np.testing.assert_array_equal(a.eo, b.eo)



@pytest.mark.parametrize("solver", ["dense", "sparse"])
def test_own_effects_take_the_adjustments_system_once(solver):
    """The first external reliability uses the adjustment's own linearisation and factored reduced
    system (and drops it from the result); a later call rebuilds it at the solution: the same numbers."""
    blk, _ = make_block(model="none", n_photos=6, n_points=24, noise_mm=0.002, rng=np.random.default_rng(5))
    pts = blk.points
    blk = blk.replace(points=pts.replace(role=np.array(["tie"] * len(pts)), sigma=np.full((len(pts), 3), FREE)))
    res = adjust(blk, BundleSettings(datum="free", solver=solver))
    assert res.final_system is not None
    assert pickle.loads(pickle.dumps(res)).final_system is None       # a cache: not shipped to workers
    a = own_effects(res)
    assert res.final_system is None
    b = own_effects(res)
    np.testing.assert_array_equal(a.point, b.point)
    np.testing.assert_array_equal(a.eo, b.eo)
    assert adjust(blk, BundleSettings(datum="free", solver=solver), covariance=False).final_system is None

def test_parameter_covariance_against_dense_inverse():
    blk, _ = make_block(model="brown", n_photos=5, n_points=14, noise_mm=0.002, rng=np.random.default_rng(2),
                        n_control=5)
    for solver in ("dense", "sparse"):
        res = adjust(blk, BundleSettings(solver=solver))
        unknowns, A, P, Q = _reference(res)
        pos = _position(unknowns)
        tie = next(i for kind, i, t in unknowns if kind == "pt")
        ph = res.block_in.photos.ids[2]
        cam = res.block_in.cameras.ids[0]
        pid = res.block_in.points.ids[tie]
        names, C = parameter_covariance(res, [f"photo {ph}", f"point {pid}", f"camera {cam}", f"point {pid} Z"])
        assert names[:6] == [f"photo {ph} {n}" for n in ("X0", "Y0", "Z0", "omega", "phi", "kappa")]
        assert names[-1] == f"point {pid} Z" and len(names) == 6 + 3 + len(res.cam_param_names[0]) + 1
        keys = [("eo", 2, t) for t in range(6)] + [("pt", tie, t) for t in range(3)] + \
            [("cam", 0, t) for t in range(len(res.cam_param_names[0]))] + [("pt", tie, 2)]
        idx = [pos.get(k, -1) for k in keys]
        ref = np.zeros((len(keys), len(keys)))
        for a, ia in enumerate(idx):
            for b, ib in enumerate(idx):
                if ia >= 0 and ib >= 0:
                    ref[a, b] = res.variance_factor * Q[ia, ib]
        assert np.allclose(C, ref, rtol=1e-4, atol=1e-6 * np.abs(ref).max()), solver
        # the reported blocks agree
        assert np.allclose(C[:6, :6], res.cov_eo[2], rtol=1e-6, atol=1e-12)
    with pytest.raises(KeyError, match="no point with id 'nope'"):
        parameter_covariance(res, ["point nope"])


def test_bundle_stage_tables_report_and_summary(tmp_path):
    """The stage's ext_* columns, the largest effect in results.json, the points' ellipses and the
    requested covariance table agree with the library functions; a wrong name is an InputError."""
    from baarda.pipeline.errors import InputError
    from baarda.pipeline.stats.ellipses import error_ellipsoids, plan_ellipses
    from baarda.pipeline.testing import run_stage
    from baarda.plugins.bundle.stage import BundleAdjustment

    blk, _ = make_block(model="brown", n_photos=6, n_points=30, noise_mm=0.002, rng=np.random.default_rng(4),
                        n_control=5)
    ph, pt = str(blk.photos.ids[1]), str(blk.points.ids[12])
    res = run_stage(BundleAdjustment, {"block": blk},
                    {"output": {"confidence": 0.95, "covariance_of": [f"photo {ph}", f"point {pt}"]}}, tmp_path=tmp_path)
    b = res.artefacts["bundle"]
    eff = own_effects(b, 4.13)          # δ0(0.1 %, 80 %) = 4.13, the stage's defaults
    t = res.tables["observations"].columns
    k = np.flatnonzero(b.obs_active & b.problem.pt_free[blk.observations.point].any(axis=1))[5]
    s = eff.point_in_sigma[k, 0]
    j = int(np.nanargmax(s))
    assert t["ext_point_coord_x"][k] == "XYZ"[j]
    assert t["ext_point_in_sigma_x"][k] == pytest.approx(s[j], rel=1e-3)
    ext = next(c for c in t if c.startswith("ext_point_x_"))     # ext_point_x_<object unit>
    assert t[ext][k] == pytest.approx(eff.point[k, 0, j], rel=1e-3)
    big = res.summary["external_reliability"]["largest_on_point"]
    assert big["in_sigma"] == pytest.approx(np.nanmax(eff.point_in_sigma), rel=1e-3)
    assert "### External reliability" in res.report and big["point"] in res.report
    pts = res.tables["points"].columns
    semi, _ = error_ellipsoids(b.cov_points, 0.95)
    a, _, _ = plan_ellipses(b.cov_points, 0.95)
    i = 12
    o = ext[len("ext_point_x"):]
    assert pts[f"ellipsoid_a1{o}"][i] == pytest.approx(semi[i, 0]) and pts[f"plan_a{o}"][i] == pytest.approx(a[i])
    cov = res.tables["covariance"].columns
    names, C = parameter_covariance(b, [f"photo {ph}", f"point {pt}"])
    assert cov["parameter"] == names and len(names) == 9
    assert np.allclose(np.column_stack([cov[n] for n in names]), C)
    assert np.allclose(C[6:, 6:], b.cov_points[12], rtol=1e-6)
    assert "### Covariance of the requested parameters" in res.report
    for bad, msg in ((["point nope"], "no point with id 'nope'"), (["photo"], "expected 'photo <id>'"),
                     ([f"point {pt} W"], "point components are X, Y, Z"),
                     ([f"camera {blk.cameras.ids[0]} K9"], "camera components are")):
        with pytest.raises(InputError, match="covariance_of") as e:
            run_stage(BundleAdjustment, {"block": blk}, {"output": {"covariance_of": bad}}, tmp_path=tmp_path)
        assert msg in str(e.value)


def _weighted_block():
    """Weighted control, EO priors and a scale bar: every kind of constraint row."""
    from baarda.pipeline.adjustment import Distance

    blk, _ = make_block(model="none", n_photos=5, n_points=16, noise_mm=0.002, rng=np.random.default_rng(8),
                        n_control=6)
    pts = blk.points
    sigma = np.array(pts.sigma)
    sigma[:6] = 0.002
    blk = blk.replace(points=pts.replace(sigma=sigma))
    ph = blk.photos
    blk = blk.replace(photos=ph.replace(X0=ph.X0 + 0.003, sigma_eo=np.tile([0.01, 0.01, 0.01, 0.002, 0.002, 0.002],
                                                                           (len(ph), 1))))
    a, b = str(pts.ids[8]), str(pts.ids[9])
    d = float(np.linalg.norm(pts.XYZ[8] - pts.XYZ[9])) + 0.001
    return blk, BundleSettings(distances=(Distance(a, b, d, 0.002),))


@pytest.mark.parametrize("case", ["weighted", "free", "correlated"])
def test_linearised_model_reproduces_the_bundle(case):
    from baarda.pipeline import stats
    from baarda.pipeline.adjustment.reliability import linearised_model
    from baarda.pipeline.synthetic.closerange import with_correlated_noise

    if case == "weighted":
        blk, st = _weighted_block()
    elif case == "free":
        blk, _ = make_block(model="none", n_photos=6, n_points=24, noise_mm=0.002, rng=np.random.default_rng(5))
        pts = blk.points
        blk = blk.replace(points=pts.replace(role=np.array(["tie"] * len(pts)), sigma=np.full((len(pts), 3), FREE)))
        st = BundleSettings(datum="free")
    else:
        blk, _ = make_block(model="none", n_photos=5, n_points=14, noise_mm=0.0, n_control=5)
        blk = with_correlated_noise(blk, np.random.default_rng(4))
        st = BundleSettings()
    res = adjust(blk, st)
    model, n_img = linearised_model(res)
    assert n_img == res.snapshot.n and model.n > n_img or case != "weighted"
    act = np.r_[res.snapshot.active, np.ones(model.n - n_img, bool)]
    a = model.adjust(act)
    assert a.snapshot.dof == res.dof
    assert a.snapshot.vtpv == pytest.approx(res.vtpv, rel=1e-8)
    assert np.allclose(a.snapshot.r[:n_img], res.snapshot.r, atol=1e-8)
    assert np.allclose(stats.w_test(a.snapshot)[:n_img], stats.w_test(res.snapshot), atol=1e-5)
    assert np.abs(a.x).max() < 1e-6 * max(1.0, np.abs(res.state.XYZ[np.isfinite(res.state.XYZ)]).max())
    with pytest.raises(ValueError, match="dense .* design matrix"):
        linearised_model(res, max_entries=100)


def test_rrr_and_pope_on_the_bundle_through_blunder_rejection(tmp_path):
    """RRR on the bundle (linearised at the solution, H from the Monte Carlo of this design) finds a
    planted 15 σ blunder; Pope's τ of the bundle equals τ of the linearised model."""
    from baarda.pipeline import stats
    from baarda.pipeline.adjustment.reliability import linearised_model
    from baarda.pipeline.testing import run_stage
    from baarda.plugins.blunder_rejection.stage import BlunderRejection
    from baarda.plugins.bundle.stage import BundleAdjustment

    blk, st = _weighted_block()
    obs = blk.observations
    xy = obs.xy.copy()
    k = 23
    xy[k, 0] += 0.03                                   # 15 σ
    blk = blk.replace(observations=obs.replace(xy=xy))
    a, b = st.distances[0].a, st.distances[0].b
    bres = run_stage(BundleAdjustment, {"block": blk},
                     {"distances": [{"from": a, "to": b, "distance": st.distances[0].distance, "sigma": 0.002}]},
                     tmp_path=tmp_path)
    art = bres.artefacts["adjustment"]
    assert art.supports_rrr
    out = run_stage(BlunderRejection, {"adjustment": art, "block": bres.artefacts["block"]},
                    {"method": "all", "decide_by": "rrr", "n_sim": 2000, "rho": 3}, tmp_path=tmp_path)
    rep = out.artefacts["blunders"]
    r = rep.methods["rrr"]
    assert r.skipped is None
    assert 2 * k in r.rejected and 2 * k in rep.methods["pope"].rejected
    assert list(rep.acted_observations) == [k]
    assert r.summary["n_sim"] == 2000 and 0.0 < r.summary["H"] < 1.0     # H of this design (Monte Carlo)
    # Pope's τ (σ̂0 of the adjustment) of the bundle snapshot and of the linearised model
    res = bres.artefacts["bundle"]
    model, n_img = linearised_model(res)
    lin_snap = model.adjust(np.r_[res.snapshot.active, np.ones(model.n - n_img, bool)]).snapshot
    t_b = stats.pope_test(res.snapshot).tau
    t_l = stats.pope_test(lin_snap).tau[:n_img]
    assert np.allclose(t_b, t_l, atol=1e-5)
    assert np.argmax(np.abs(t_b)) == 2 * k


@pytest.mark.parametrize("solver", ["dense", "sparse"])
def test_own_effects_with_priors_and_a_scale_bar_dense_reference(solver):
    """Weighted control, orientation priors and a scale bar (its points are global unknowns, not
    eliminated): the dense reference appends the prior rows (unit rows, weights 1/σ²) and the
    distance's finite-difference row to the image rows."""
    blk, st = _weighted_block()
    res = adjust(blk, BundleSettings(distances=st.distances, solver=solver))
    assert res.solver_route == solver
    unknowns, A, P, N = _dense_reference(res)
    pos = _position(unknowns)
    prob = res.problem
    sig_eo = blk.photos.sigma_eo
    rows, w = [], []
    for u, (kind, i, t) in enumerate(unknowns):
        s = sig_eo[i, t] if kind == "eo" else blk.points.sigma[i, t] if kind == "pt" else np.inf
        if np.isfinite(s) and s > 0:
            e = np.zeros(len(unknowns))
            e[u] = 1.0
            rows.append(e)
            w.append(1.0 / s ** 2)
    d = st.distances[0]
    ia, ib = blk.points.index_of([d.a, d.b])
    diff = res.state.XYZ[ia] - res.state.XYZ[ib]
    unit = diff / np.linalg.norm(diff)
    e = np.zeros(len(unknowns))
    for t in range(3):
        e[pos[("pt", ia, t)]] += unit[t]
        e[pos[("pt", ib, t)]] -= unit[t]
    rows.append(e)
    w.append(1.0 / d.sigma ** 2)
    n_img = A.shape[0]
    A = np.vstack([A, np.array(rows)])
    Pf = np.zeros((A.shape[0], A.shape[0]))
    Pf[:n_img, :n_img] = P
    Pf[np.arange(n_img, A.shape[0]), np.arange(n_img, A.shape[0])] = w
    Q = np.linalg.inv(A.T @ Pf @ A)
    assert res.cov_points[ia] == pytest.approx(res.variance_factor * Q[np.ix_(*[[pos[("pt", ia, t)]
                                                                                  for t in range(3)]] * 2)], rel=1e-5)
    PQP = Pf - Pf @ A @ Q @ A.T @ Pf
    eff = own_effects(res, D0)
    mdb = row_mdb(res, D0)
    oi = np.flatnonzero(res.obs_active)
    obs = blk.observations
    seen_global = False
    worst = 0.0
    for r_loc, k in enumerate(oi):
        for c in (0, 1):
            i = 2 * r_loc + c
            assert mdb[k, c] == pytest.approx(D0 * res.sigma0 / np.sqrt(PQP[i, i]), rel=1e-4)
            dx = Q @ A.T @ Pf[:, i] * mdb[k, c]
            ph, pt = obs.photo[k], obs.point[k]
            ref = np.r_[[dx[pos[("pt", pt, t)]] if ("pt", pt, t) in pos else 0.0 for t in range(3)],
                        [dx[pos[("eo", ph, t)]] if ("eo", ph, t) in pos else 0.0 for t in range(6)]]
            got = np.r_[eff.point[k, c], eff.eo[k, c]]
            worst = max(worst, np.abs(got - ref).max() / np.abs(ref).max())
            seen_global |= pt in (ia, ib)
    assert seen_global and (prob.g_pt[ia] >= 0).all()
    assert worst < 2e-4, worst
