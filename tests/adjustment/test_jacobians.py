"""Analytic Jacobians of the collinearity equations and AP models against central differences."""

import numpy as np
import pytest

from baarda.pipeline.camera import APModel, get_ap_model
from baarda.pipeline.adjustment.collinearity import project_observations
from baarda.pipeline.geometry.rotations import rotation_and_derivatives
from baarda.pipeline.geometry import rotation_from_opk_many

from baarda.pipeline.synthetic.closerange import META, TRUE_AP, make_block

MODELS = ["none", "brown", "aicon", "ebner12"]


def _setup(model):
    blk, truth = make_block(model=model, n_photos=4, n_points=12)
    o = blk.observations
    cam = truth["cam"].copy()
    # exaggerate the APs so that their image-coordinate derivatives matter
    cam[3:] *= 20
    return o.photo, o.point, truth, cam


def _proj(ph, pt, XYZ, X0, opk, cam, model, jac=False):
    return project_observations(ph, pt, XYZ, X0, opk, np.zeros(len(X0), int), cam[None], [model], [META[model]],
                                jacobians=jac)


def test_rotation_derivatives_and_convention():
    opk = np.array([[0.3, -0.2, 1.1], [-1.0, 0.4, -2.5]])
    R, dR = rotation_and_derivatives(opk)
    assert np.allclose(R, rotation_from_opk_many(opk), atol=1e-15)
    h = 1e-6
    for a in range(3):
        e = np.zeros(3)
        e[a] = h
        num = (rotation_from_opk_many(opk + e) - rotation_from_opk_many(opk - e)) / (2 * h)
        assert np.allclose(dR[:, a], num, atol=1e-9)


@pytest.mark.parametrize("model", MODELS)
def test_jacobians_match_finite_differences(model):
    ph, pt, truth, cam = _setup(model)
    XYZ, X0, opk = truth["XYZ"], truth["X0"], truth["opk"]
    pr = _proj(ph, pt, XYZ, X0, opk, cam, model, jac=True)
    k = len(ph)
    # exterior orientation
    eo = np.hstack([X0, opk])
    for t in range(6):
        h = 1e-6
        ep, em = eo.copy(), eo.copy()
        ep[:, t] += h
        em[:, t] -= h
        fp = _proj(ph, pt, XYZ, ep[:, :3], ep[:, 3:], cam, model).xy
        fm = _proj(ph, pt, XYZ, em[:, :3], em[:, 3:], cam, model).xy
        num = (fp - fm) / (2 * h)
        assert np.allclose(pr.J_eo[:, :, t], num, rtol=1e-6, atol=1e-6 * np.abs(num).max()), t
    # object point
    for t in range(3):
        h = 1e-6
        Xp, Xm = XYZ.copy(), XYZ.copy()
        Xp[:, t] += h
        Xm[:, t] -= h
        num = (_proj(ph, pt, Xp, X0, opk, cam, model).xy - _proj(ph, pt, Xm, X0, opk, cam, model).xy) / (2 * h)
        assert np.allclose(pr.J_point[:, :, t], num, rtol=1e-6, atol=1e-6 * np.abs(num).max()), t
    # camera parameters c, xp, yp, ap...
    for t in range(len(cam)):
        h = 1e-6 * max(1.0, abs(cam[t])) if t < 3 else max(abs(cam[t]) * 1e-4, 1e-14)
        cp, cm = cam.copy(), cam.copy()
        cp[t] += h
        cm[t] -= h
        num = (_proj(ph, pt, XYZ, X0, opk, cp, model).xy - _proj(ph, pt, XYZ, X0, opk, cm, model).xy) / (2 * h)
        scale = max(np.abs(num).max(), 1e-300)
        assert np.allclose(pr.J_cam[:, :, t], num, rtol=1e-5, atol=1e-6 * scale), t
    assert pr.J_cam.shape == (k, 2, len(cam))


@pytest.mark.parametrize("model", ["brown", "aicon", "ebner12"])
def test_ap_model_image_derivatives(model):
    m = get_ap_model(model)
    rng = np.random.default_rng(0)
    n = 50
    x, y = rng.uniform(-15, 15, n), rng.uniform(-10, 10, n)
    prm = np.broadcast_to(np.array(TRUE_AP[model]) * 30, (n, m.n_params))
    c = np.full(n, 25.0)
    J = m.jacobian_xy(x, y, prm, c, META[model])
    Jn = APModel.jacobian_xy(m, x, y, prm, c, META[model])   # base-class central differences
    assert np.allclose(J, Jn, rtol=1e-6, atol=1e-9 * np.abs(J).max())
    Jp = m.jacobian_params(x, y, prm, c, META[model])
    Jpn = APModel.jacobian_params(m, x, y, np.array(prm), c, META[model])
    assert np.allclose(Jp, Jpn, rtol=1e-5, atol=1e-8 * np.abs(Jp).max())


def test_aicon_radial_balanced_at_r0():
    """AICON: the radial term vanishes on the balancing radius r0."""
    m = get_ap_model("aicon")
    r0 = 13.488
    ang = np.linspace(0, 2 * np.pi, 7)
    x, y = r0 * np.cos(ang), r0 * np.sin(ang)
    prm = np.zeros((7, 7))
    prm[:, 0], prm[:, 1], prm[:, 2] = -1.1e-4, 1.5e-7, 3e-10
    dx, dy = m.distortion(x, y, prm, np.full(7, 28.8), {"r0": r0})
    assert np.allclose(dx, 0, atol=1e-15) and np.allclose(dy, 0, atol=1e-15)


class _CDependent(APModel):
    """A third-party model whose distortion depends on c (a radial term in the field angle
    r/c): only ``distortion`` is given, every derivative comes from the base class."""

    name = "c-dependent-test"
    params = ("k1", "k2")
    default_sigma = (np.inf, np.inf)

    def distortion(self, x, y, p, c, meta):
        p = np.asarray(p, float)
        t2 = (x * x + y * y) / (c * c)                 # tan² of the field angle
        f = p[:, 0] * t2 + p[:, 1] * t2 * t2
        return x * f * c / 25.0, y * f


class _Duck:
    """The same model without the base class (wrapped by register_ap_model)."""

    params = ("k1", "k2")

    def distortion(self, x, y, p, c, meta):
        return _CDependent().distortion(x, y, p, c, meta)


@pytest.mark.parametrize("name, model", [("c-dependent-test", _CDependent()), ("c-dependent-duck", _Duck())])
def test_third_party_model_using_c_gets_its_c_derivative(name, model):
    """∂(x, y)/∂c of the full projection (incl. ∂Δ/∂c at fixed x̄, ȳ, by the base class's central
    differences) against central differences of the projection; the ∂Δ/∂c part is a large share
    of it here (≈ 4 %, against a tolerance of 1e-6), so a zero fallback would fail."""
    from baarda.pipeline.camera import register_ap_model

    register_ap_model(name, model, replace=True)
    ph, pt, truth, _ = _setup("none")
    cam = np.array([25.0, 0.05, -0.03, -0.3, 0.05])
    XYZ, X0, opk = truth["XYZ"], truth["X0"], truth["opk"]

    def proj(cm, jac=False):
        return project_observations(ph, pt, XYZ, X0, opk, np.zeros(len(X0), int), cm[None], [name], [{}],
                                    jacobians=jac)

    pr = proj(cam, True)
    for t in range(len(cam)):
        h = 1e-6 * max(1.0, abs(cam[t]))
        cp, cm = cam.copy(), cam.copy()
        cp[t] += h
        cm[t] -= h
        num = (proj(cp).xy - proj(cm).xy) / (2 * h)
        assert np.allclose(pr.J_cam[:, :, t], num, rtol=1e-6, atol=1e-7 * np.abs(num).max()), t
    # the model's own ∂Δ/∂c (closed form of the formula above) is what the base class returns
    m = get_ap_model(name)
    x, y = pr.xbar[:, 0], pr.xbar[:, 1]
    p = np.broadcast_to(cam[3:], (len(x), 2))
    c = np.full(len(x), 25.0)
    t2 = (x * x + y * y) / c ** 2
    f = p[:, 0] * t2 + p[:, 1] * t2 ** 2
    df = (p[:, 0] + 2 * p[:, 1] * t2) * (-2 * t2 / c)
    exact = np.column_stack([x * (f + c * df) / 25.0, y * df])
    Jc = m.jacobian_c(x, y, p, c, {})
    assert np.allclose(Jc, exact, rtol=1e-6, atol=1e-9 * np.abs(exact).max())
    assert np.abs(exact).max() > 0.02 * np.abs(pr.J_cam[:, :, 0]).max()     # ≫ the FD tolerance
    assert np.allclose(m.jacobians(x, y, p, c, {}, [0, 1])[2], exact, rtol=1e-6, atol=1e-9 * np.abs(exact).max())


@pytest.mark.parametrize("model", MODELS)
def test_builtin_models_do_not_depend_on_c(model):
    """The built-in models' Δ does not involve c: ∂Δ/∂c is exactly zero (no numeric noise)."""
    m = get_ap_model(model)
    rng = np.random.default_rng(3)
    x, y = rng.uniform(-15, 15, 20), rng.uniform(-10, 10, 20)
    p = np.broadcast_to(np.array(TRUE_AP[model], float) * 30, (20, m.n_params))
    c1, c2 = np.full(20, 25.0), np.full(20, 40.0)
    assert np.array_equal(np.c_[m.distortion(x, y, p, c1, META[model])], np.c_[m.distortion(x, y, p, c2, META[model])])
    assert not m.jacobian_c(x, y, p, c1, META[model]).any()
    assert m.jacobians(x, y, p, c1, META[model], [])[2] is None


def test_distance_jacobian_matches_finite_differences():
    """The scale bar's whitened row ∂(σ0/σ_d · |Xa − Xb|)/∂(Xa, Xb) and its share of the gradient
    against central differences of the distance and of vᵀPv (distance residual made large)."""
    from baarda.pipeline.model import FREE
    from baarda.pipeline.adjustment import BundleSettings, Distance
    from baarda.pipeline.adjustment.problem import BundleProblem

    blk, truth = make_block(model="none", n_photos=6, n_points=20, noise_mm=0.001, n_control=0)
    pts = blk.points
    blk = blk.replace(points=pts.replace(sigma=np.full((len(pts), 3), FREE)))
    d = float(np.linalg.norm(truth["XYZ"][3] - truth["XYZ"][11]))
    sd = 2e-4
    prob = BundleProblem(blk, BundleSettings(datum="free", distances=(Distance("103", "111", d, sd),)))
    st = prob.initial_state()
    st.XYZ[11] += [0.004, -0.003, 0.002]             # the bar is now ≈ 30 σ off
    lin = prob.normals.linearize(st)
    Jd, cols = lin.Jd[0], lin.dcols[0]
    assert list(cols) == list(prob.g_pt[3]) + list(prob.g_pt[11])
    zero_p = np.zeros((prob.n_e, 3))

    def moved(col, h):
        dx = np.zeros(prob.n_g)
        dx[col] = h
        return prob.apply(st, dx, zero_p)

    for j, col in enumerate(cols):
        h = 1e-7
        sp, sm = moved(col, h), moved(col, -h)
        dist = lambda s: np.linalg.norm(s.XYZ[3] - s.XYZ[11]) / sd
        num = (dist(sp) - dist(sm)) / (2 * h)
        assert Jd[j] == pytest.approx(num, rel=1e-6)
        # gradient of the cost: ∂(vᵀPv)/∂x = −2 g
        h = 1e-6
        numc = (prob.cost(moved(col, h)) - prob.cost(moved(col, -h))) / (2 * h)
        assert -2 * lin.g[col] == pytest.approx(numc, rel=1e-5)
