"""Sure convergence of the iteration (``pipeline/adjustment/lm.py``, docs/bundle.md "Iteration and
stopping rule").

* the BAL fixture's problem (fixtures/bal/bal.toml) reaches the minimum pycolmap/Ceres reaches from
  the same start (final costs within 1e-6 relative, one cost definition for both);
* a camera rig driven along a line (projection centres nearly collinear, free network on them) —
  the geometry on which additive steps crept — converges in a few iterations to the minimum an
  independent solver (scipy's MINPACK Levenberg–Marquardt on the gauge-free problem, its own
  projection code) finds, and with the exact similarity switched off it still creeps;
* the exact similarity itself: invariant vᵀPv, the exact transformation, first-order agreement
  with the additive step, and where it does not apply.
"""

from __future__ import annotations

import importlib.util
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from baarda.pipeline.adjustment import BundleSettings, Distance, adjust
from baarda.pipeline.adjustment.lm import SimilarityGauge, solve_bundle
from baarda.pipeline.adjustment.problem import BundleProblem
from baarda.pipeline.errors import AdjustmentError
from baarda.pipeline.geometry import opk_from_rotation, rotation_from_opk_many
from baarda.pipeline.model import Block, Cameras, Observations, Photos, Points

ROOT = Path(__file__).resolve().parents[2]
C_MM, SIGMA_MM = 0.5, 0.001


# ---- a camera rig driven along a street --------------------------------------------------------
def rig_block(rng, m: int = 8, n: int = 60, spread: float = 0.001) -> Block:
    """``m`` photos 1 m apart along X, all looking at a façade 6–10 m away along +Y; the centres
    leave the line by at most ``spread`` (m).  Start: points ±5 cm, centres ±3 cm, angles ±0.5°;
    image noise 1 µm = σ."""
    i = np.arange(m)
    X0 = np.column_stack([i * 1.0, spread * np.sin(2.1 * i), spread * np.cos(1.3 * i)])
    R = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])          # x_cam = X, y_cam = Z, looking along +Y
    opk = np.tile(opk_from_rotation(R), (m, 1))
    XYZ = np.column_stack([rng.uniform(-3, m + 2, n), rng.uniform(6, 10, n), rng.uniform(-3, 3, n)])
    Rm = rotation_from_opk_many(opk)
    ph, pt, xy = [], [], []
    for j in range(m):
        U = (XYZ - X0[j]) @ Rm[j].T
        x = -C_MM * U[:, :2] / U[:, 2:3]
        seen = (U[:, 2] < 0) & (np.abs(x) < 0.4).all(axis=1)
        ph += [j] * int(seen.sum())
        pt += np.flatnonzero(seen).tolist()
        xy.append(x[seen])
    xy = np.concatenate(xy) + rng.normal(0, SIGMA_MM, (len(ph), 2))
    photos = Photos.make([str(j) for j in range(m)], camera=0, X0=X0 + rng.normal(0, 0.03, X0.shape),
                         opk=opk + np.radians(rng.normal(0, 0.5, opk.shape)))
    points = Points.make([str(p) for p in range(n)], XYZ=XYZ + rng.normal(0, 0.05, XYZ.shape))
    return Block(cameras=Cameras.make(["cam"], C_MM, 0.0, 0.0), photos=photos, points=points,
                 observations=Observations.make(ph, pt, xy, sigma=SIGMA_MM), object_unit="m")


def _R(opk):
    """R3(κ) R2(φ) R1(ω) written out (docs/conventions.md), independent of baarda's geometry."""
    o, p, k = (opk[:, j] for j in range(3))
    one, zero = np.ones(len(opk)), np.zeros(len(opk))
    rows = lambda *r: np.stack([np.stack(x, -1) for x in r], 1)
    R1 = rows((one, zero, zero), (zero, np.cos(o), np.sin(o)), (zero, -np.sin(o), np.cos(o)))
    R2 = rows((np.cos(p), zero, -np.sin(p)), (zero, one, zero), (np.sin(p), zero, np.cos(p)))
    R3 = rows((np.cos(k), np.sin(k), zero), (-np.sin(k), np.cos(k), zero), (zero, zero, one))
    return R3 @ R2 @ R1


def reference_minimum(block: Block) -> float:
    """vᵀPv at the minimum found by scipy's MINPACK LM over every orientation and point (no datum:
    the gauge stays free, as in Ceres), from the block's start, with finite-difference Jacobians."""
    obs = block.observations
    m, n = len(block.photos), len(block.points)

    def residuals(x):
        X0, opk, XYZ = x[:3 * m].reshape(m, 3), x[3 * m:6 * m].reshape(m, 3), x[6 * m:].reshape(n, 3)
        U = np.einsum("kij,kj->ki", _R(opk)[obs.photo], XYZ[obs.point] - X0[obs.photo])
        return ((obs.xy + C_MM * U[:, :2] / U[:, 2:3]) / SIGMA_MM).ravel()

    x0 = np.concatenate([block.photos.X0.ravel(), block.photos.opk.ravel(), block.points.XYZ.ravel()])
    sol = least_squares(residuals, x0, method="lm", x_scale="jac", ftol=1e-15, xtol=1e-15, gtol=1e-15,
                        max_nfev=5000)
    assert sol.status > 0
    return float(np.sum(sol.fun ** 2))


RIG = dict(datum="free", datum_centres=True, max_iter=50, covariance=False)


@pytest.mark.parametrize("seed", [2, 7, 9])
def test_rig_reaches_the_independent_minimum_in_a_few_iterations(seed):
    block = rig_block(np.random.default_rng(seed))
    _, _, info = solve_bundle(block, BundleSettings(**RIG), final=False)
    assert info.iterations <= 8
    assert info.history.exact_similarity.any()
    ref = reference_minimum(block)
    assert info.vtpv == pytest.approx(ref, rel=1e-9)


def test_thirty_rigs_converge_in_a_few_iterations():
    """Additive steps needed 5 to more than 50 iterations on these (three did not converge)."""
    its = [solve_bundle(rig_block(np.random.default_rng(seed)), BundleSettings(**RIG), final=False)[2].iterations
           for seed in range(30)]
    assert max(its) <= 8


def test_rig_creeps_with_additive_steps(monkeypatch):
    """The same problem with every step added as it is (the rule before the exact similarity):
    vᵀPv creeps, 50 iterations do not converge, and the last cost is above the minimum."""
    block = rig_block(np.random.default_rng(2))
    monkeypatch.setattr(SimilarityGauge, "of", classmethod(lambda cls, prob: None))
    with pytest.raises(AdjustmentError, match="no convergence after 50 iterations") as e:
        solve_bundle(block, BundleSettings(**RIG), final=False)
    hist = e.value.history
    assert hist[-1].vtpv > reference_minimum(block) * (1 + 1e-8)       # the exact steps: within 1e-9
    assert np.sum(hist.lam > 0) > 25                              # held by the damping: the creep


def test_well_conditioned_free_network_iterates_as_before(monkeypatch):
    """Gain ratios near 1 never call for the exact similarity: the same iterates as additive steps."""
    block = rig_block(np.random.default_rng(6), spread=0.5)
    s = BundleSettings(datum="free", max_iter=50, covariance=False)
    _, st_a, info_a = solve_bundle(block, s, final=False)
    assert not info_a.history.exact_similarity.any()
    monkeypatch.setattr(SimilarityGauge, "of", classmethod(lambda cls, prob: None))
    _, st_b, info_b = solve_bundle(block, s, final=False)
    assert info_a.vtpv == info_b.vtpv
    np.testing.assert_array_equal(st_a.XYZ, st_b.XYZ)


# ---- the exact similarity ----------------------------------------------------------------------
def _problem(block, **kw):
    prob = BundleProblem(block, BundleSettings(**{**RIG, **kw}))
    return prob, prob.initial_state()


def _similarity_step(prob, st, t, eps, s):
    """The linearised similarity (t, ε, s) about the centroid c of the positions as a step
    (dx_g, dp) — built from the motion itself, ω φ κ by central differences of R R(ε)ᵀ."""
    c = np.concatenate([st.X0[prob.photo_used], st.XYZ[prob.point_used]]).mean(axis=0)
    move = lambda X: t + np.cross(eps, X - c) + s * (X - c)
    dx = np.zeros(prob.n_g)
    dx[prob.g_eo[:, :3]] = move(st.X0)
    h = 1e-6
    Rp = rotation_from_opk_many(st.opk) @ Rotation.from_rotvec(h * eps).as_matrix().T
    Rm = rotation_from_opk_many(st.opk) @ Rotation.from_rotvec(-h * eps).as_matrix().T
    dx[prob.g_eo[:, 3:]] = (np.array([opk_from_rotation(r) for r in Rp])
                            - np.array([opk_from_rotation(r) for r in Rm])) / (2 * h)
    dp = move(st.XYZ)[prob.elim_points]
    return dx, dp, c


def test_a_similarity_step_is_applied_exactly_and_keeps_vtpv():
    block = rig_block(np.random.default_rng(1), spread=0.5)
    prob, st = _problem(block)
    gauge = SimilarityGauge.of(prob)
    t, eps, s = np.array([0.3, -0.2, 0.1]), np.array([0.2, -0.1, 0.4]), 0.05     # 26° rotation
    dx, dp, c = _similarity_step(prob, st, t, eps, s)
    theta, r_g, r_p, c_used = gauge.split(st, dx, dp)
    np.testing.assert_allclose(theta, np.r_[t, eps, s], atol=1e-9)
    np.testing.assert_allclose(c_used, c, atol=1e-12)
    assert max(np.abs(r_g).max(), np.abs(r_p).max()) < 1e-8              # nothing but the similarity
    new = gauge.apply(st, dx, dp)
    Re = Rotation.from_rotvec(eps).as_matrix()
    np.testing.assert_allclose(new.XYZ, c + t + (1 + s) * (st.XYZ - c) @ Re.T, atol=1e-9)
    np.testing.assert_allclose(new.X0, c + t + (1 + s) * (st.X0 - c) @ Re.T, atol=1e-9)
    np.testing.assert_allclose(rotation_from_opk_many(new.opk), rotation_from_opk_many(st.opk) @ Re.T, atol=1e-9)
    # vᵀPv is that of the rest alone (here ≈ the start's): the similarity does not change it
    assert prob.cost(new) == pytest.approx(prob.cost(prob.apply(st, r_g, r_p)), rel=1e-12)
    assert prob.cost(new) == pytest.approx(prob.cost(st), rel=1e-8)
    assert abs(prob.cost(prob.apply(st, dx, dp)) / prob.cost(st) - 1) > 1e-2   # the additive step does not


def test_the_exact_step_agrees_with_the_additive_one_to_first_order():
    block = rig_block(np.random.default_rng(2), spread=0.5)
    prob, st = _problem(block)
    gauge = SimilarityGauge.of(prob)
    rng = np.random.default_rng(3)
    dx, dp = rng.normal(0, 1e-2, prob.n_g), rng.normal(0, 1e-2, (prob.n_e, 3))
    diff = []
    for h in (1.0, 0.5, 0.25):
        a, b = gauge.apply(st, h * dx, h * dp), prob.apply(st, h * dx, h * dp)
        diff.append(max(np.abs(a.XYZ - b.XYZ).max(), np.abs(a.X0 - b.X0).max(), np.abs(a.opk - b.opk).max()))
    assert diff[0] > 0
    assert diff[0] / diff[1] == pytest.approx(4, rel=0.1) and diff[1] / diff[2] == pytest.approx(4, rel=0.1)


def test_where_the_exact_similarity_does_not_apply():
    block = rig_block(np.random.default_rng(4), spread=0.5)
    # a distance fixes the scale: six motions
    assert SimilarityGauge.of(_problem(block, distances=(Distance("0", "1", 3.0, 0.01),))[0]).n_motions == 6
    assert SimilarityGauge.of(_problem(block)[0]).n_motions == 7
    # a weighted orientation is not invariant under a similarity
    sig = np.full((len(block.photos), 6), np.inf)
    sig[0] = 0.01
    weighted = block.replace(photos=block.photos.replace(sigma_eo=sig))
    assert SimilarityGauge.of(_problem(weighted)[0]) is None
    # control points: a control datum, no gauge
    pts = block.points
    ctrl = block.replace(points=Points.make(pts.ids, XYZ=pts.XYZ, role=["full"] * 3 + ["tie"] * (len(pts) - 3)))
    assert SimilarityGauge.of(BundleProblem(ctrl, BundleSettings(covariance=False))) is None


# ---- the BAL fixture against pycolmap ----------------------------------------------------------
def _bench():
    path = ROOT / "benchmarks" / "bal_vs_pycolmap.py"
    spec = importlib.util.spec_from_file_location("bal_vs_pycolmap", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("bal_vs_pycolmap", mod)
    spec.loader.exec_module(mod)
    return mod


def test_bal_fixture_problem_reaches_pycolmaps_minimum(shared_data):
    """fixtures/bal/bal.toml's problem (its file, its datum: inner constraints on the projection
    centres, its max_iter), the 31 observations of points behind their camera switched off for both
    (COLMAP gives them a zero residual); pycolmap's Ceres LM from the same values with a tight
    function tolerance.  Both final costs evaluated with baarda's collinearity.  About 2 s."""
    project = tomllib.loads((ROOT / "fixtures" / "bal" / "bal.toml").read_text())
    source, bundle = project["stage"][0]["options"], project["stage"][1]["options"]
    path = shared_data / Path(source["path"]).relative_to("../../../shared/data")
    if not path.exists():
        pytest.skip(f"{path} not found")
    bench = _bench()
    block, behind = bench.load_problem(path)
    assert behind == 31
    settings = BundleSettings(datum=bundle["datum"], datum_centres=bundle["datum_on"] == "centres",
                              max_iter=bundle["solver"]["max_iter"], covariance=False)
    res = adjust(block, settings)
    cost_b = bench.cost_px(res.block.replace(observations=block.observations))
    assert cost_b == pytest.approx(res.vtpv / 2, rel=1e-9)              # one cost definition
    col = bench.run_pycolmap(block, max_iter=200, function_tolerance=1e-12, num_threads=1)
    assert col["termination"] == "CONVERGENCE"
    assert abs(cost_b - col["cost"]) / col["cost"] < 1e-6
    assert res.iterations <= 15
