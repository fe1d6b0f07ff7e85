"""Analytic Jacobians of the collinearity equations and AP models against central differences."""

import numpy as np
import pytest

from plugins.bundle.apmodels import APModel, get_ap_model
from plugins.bundle.collinearity import project_observations, rotation_and_derivatives
from pipeline.geometry import rotation_from_opk_many

from .synth import META, TRUE_AP, make_block

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
