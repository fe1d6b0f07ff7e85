"""The PhotoModeler/DBAT backward Brown model (``brown-backward``): round trip, the difference to the
forward (``brown``) model, and its Jacobians against central differences — of the model and of the
whole collinearity projection."""

import numpy as np
import pytest

from baarda.pipeline.adjustment import project_observations
from baarda.pipeline.camera import get_ap_model
from baarda.pipeline.camera.models import BrownBackward

# DBAT's published calibration of the Olympus C4040Z (camcaldemo, report.txt): K1 K2 K3 P1 P2 as,
# with a made-up skew so that every term is exercised
CAMCAL = np.array([0.00458861, -4.51351e-05, -2.05253e-06, -6.12803e-05, -4.41171e-05, 0.000389598, 2e-4])
HALF = (3.63, 2.72)          # half the format, mm


def _grid(n=400, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-HALF[0], HALF[0], n), rng.uniform(-HALF[1], HALF[1], n)


def test_registered_by_name():
    m = get_ap_model("brown-backward")
    assert isinstance(m, BrownBackward)
    assert m.params == ("K1", "K2", "K3", "P1", "P2", "aspect", "skew")
    assert not m.uses_c


def test_round_trip_distortion_and_correction():
    m = BrownBackward()
    x, y = _grid()
    prm = np.tile(CAMCAL, (len(x), 1))
    dx, dy = m.distortion(x, y, prm, None, {})
    # the distortion is large here (up to ≈ 0.23 mm, 8 % of the radius) and inverted exactly
    assert np.hypot(dx, dy).max() > 0.15
    gx, gy = m.correct(x + dx, y + dy, prm)
    assert np.abs(gx - x).max() < 1e-12 and np.abs(gy - y).max() < 1e-12
    # the other way round: measured → corrected → predicted measurement
    cx, cy = m.correct(x, y, prm)
    ex, ey = m.distortion(cx, cy, prm, None, {})
    assert np.abs(cx + ex - x).max() < 1e-12 and np.abs(cy + ey - y).max() < 1e-12
    # inputs are not modified
    assert np.array_equal(prm, np.tile(CAMCAL, (len(x), 1)))


def test_correction_closed_form():
    m = BrownBackward()
    x, y = np.array([1.3, -2.0]), np.array([0.7, 2.4])
    K1, K2, K3, P1, P2, asp, sk = CAMCAL
    ax, ay = (1 + asp) * x + sk * y, y
    r2 = ax ** 2 + ay ** 2
    R = K1 * r2 + K2 * r2 ** 2 + K3 * r2 ** 3
    want_x = ax * (1 + R) + P1 * (r2 + 2 * ax ** 2) + 2 * P2 * ax * ay
    want_y = ay * (1 + R) + P2 * (r2 + 2 * ay ** 2) + 2 * P1 * ax * ay
    gx, gy = m.correct(x, y, np.tile(CAMCAL, (2, 1)))
    assert np.allclose(gx, want_x, rtol=0, atol=1e-15) and np.allclose(gy, want_y, rtol=0, atol=1e-15)


def test_backward_is_minus_forward_to_first_order():
    """With the same coefficients the backward model's distortion is the forward Brown distortion with
    the opposite sign, up to second order in the coefficients: halving them quarters the difference."""
    bw, fw = BrownBackward(), get_ap_model("brown")
    x, y = _grid(200, 1)
    diffs = []
    for s in (1.0, 0.5, 0.25):
        p = CAMCAL * s
        prm_b = np.tile(p, (len(x), 1))
        prm_f = np.tile([p[0], p[1], p[2], p[3], p[4], p[5], p[6]], (len(x), 1))   # K P, B1 = aspect, B2 = skew
        db = np.column_stack(bw.distortion(x, y, prm_b, None, {}))
        df = np.column_stack(fw.distortion(x, y, prm_f, None, {}))
        diffs.append(np.abs(db + df).max())
        assert diffs[-1] < 0.1 * np.abs(df).max()
    assert diffs[0] / diffs[1] == pytest.approx(4, rel=0.15)
    assert diffs[1] / diffs[2] == pytest.approx(4, rel=0.1)


def test_no_inverse_beyond_the_fold_stays_finite():
    """Far outside the format the correction folds back (K2, K3 < 0) and has no inverse: the
    distortion stays finite (the first-order value) instead of diverging."""
    m = BrownBackward()
    x = np.array([0.5, 6.0, 9.0, 40.0])
    y = np.array([0.2, 5.0, -8.0, 30.0])
    prm = np.tile(CAMCAL, (4, 1))
    dx, dy = m.distortion(x, y, prm, None, {})
    assert np.all(np.isfinite(dx)) and np.all(np.isfinite(dy))
    gx, gy = m.correct(x[:1] + dx[:1], y[:1] + dy[:1], prm[:1])
    assert abs(gx[0] - x[0]) < 1e-12 and abs(gy[0] - y[0]) < 1e-12
    Jp, D, _ = m.jacobians(x, y, prm, None, {}, np.arange(7))
    assert np.all(np.isfinite(Jp)) and np.all(np.isfinite(D))


def test_model_jacobians_match_central_differences():
    m = BrownBackward()
    x, y = _grid(100, 2)
    prm = np.tile(CAMCAL, (len(x), 1))
    Jp, D, Jc = m.jacobians(x, y, prm, None, {}, np.arange(7))
    assert Jc is None
    for j in range(7):
        h = 1e-5 * abs(CAMCAL[j])
        pp, pm = prm.copy(), prm.copy()
        pp[:, j] += h
        pm[:, j] -= h
        num = (np.column_stack(m.distortion(x, y, pp, None, {})) - np.column_stack(m.distortion(x, y, pm, None, {}))) / (2 * h)
        assert np.allclose(Jp[:, :, j], num, rtol=1e-5, atol=1e-7 * np.abs(num).max()), j
    for k, (ex, ey) in enumerate([(1e-6, 0.0), (0.0, 1e-6)]):
        num = (np.column_stack(m.distortion(x + ex, y + ey, prm, None, {}))
               - np.column_stack(m.distortion(x - ex, y - ey, prm, None, {}))) / 2e-6
        assert np.allclose(D[:, :, k], num, atol=1e-8), k
    # the public single Jacobians agree with jacobians()
    assert np.allclose(m.jacobian_params(x, y, prm, None, {}), Jp)
    assert np.allclose(m.jacobian_xy(x, y, prm, None, {}), D)


def _scene():
    rng = np.random.default_rng(5)
    XYZ = np.column_stack([rng.uniform(-0.3, 0.3, 30), rng.uniform(-0.3, 0.3, 30), rng.uniform(-0.05, 0.05, 30)])
    X0 = np.array([[0.1, -0.1, 1.6], [-0.15, 0.1, 1.5], [0.1, 0.15, 1.7]])
    opk = np.array([[0.1, -0.05, 0.3], [-0.15, 0.2, -1.4], [0.2, 0.25, 2.9]])
    ph = np.repeat(np.arange(3), 30)
    pt = np.tile(np.arange(30), 3)
    cam = np.r_[7.457, -0.0097, 0.1058, CAMCAL]
    return ph, pt, XYZ, X0, opk, cam


def _proj(ph, pt, XYZ, X0, opk, cam, jac=False):
    return project_observations(ph, pt, XYZ, X0, opk, np.zeros(len(X0), int), cam[None], ["brown-backward"], [{}],
                                jacobians=jac)


def test_projection_jacobians_match_central_differences():
    ph, pt, XYZ, X0, opk, cam = _scene()
    pr = _proj(ph, pt, XYZ, X0, opk, cam, jac=True)
    # the predicted measurement, corrected with g, is the ideal projection
    m = BrownBackward()
    ideal = _proj(ph, pt, XYZ, X0, opk, np.r_[cam[:3], np.zeros(7)])
    gx, gy = m.correct(pr.xy[:, 0] - cam[1], pr.xy[:, 1] - cam[2], np.tile(cam[3:], (len(ph), 1)))
    assert np.allclose(np.column_stack([gx, gy]) + cam[1:3], ideal.xy, rtol=0, atol=1e-12)
    eo = np.hstack([X0, opk])
    for t in range(6):
        h = 1e-7
        ep, em = eo.copy(), eo.copy()
        ep[:, t] += h
        em[:, t] -= h
        num = (_proj(ph, pt, XYZ, ep[:, :3], ep[:, 3:], cam).xy - _proj(ph, pt, XYZ, em[:, :3], em[:, 3:], cam).xy) / (2 * h)
        assert np.allclose(pr.J_eo[:, :, t], num, rtol=1e-6, atol=1e-6 * np.abs(num).max()), t
    for t in range(3):
        h = 1e-7
        Xp, Xm = XYZ.copy(), XYZ.copy()
        Xp[:, t] += h
        Xm[:, t] -= h
        num = (_proj(ph, pt, Xp, X0, opk, cam).xy - _proj(ph, pt, Xm, X0, opk, cam).xy) / (2 * h)
        assert np.allclose(pr.J_point[:, :, t], num, rtol=1e-6, atol=1e-6 * np.abs(num).max()), t
    for t in range(len(cam)):
        h = 1e-6 * max(1.0, abs(cam[t])) if t < 3 else 1e-5 * abs(cam[t])
        cp, cm = cam.copy(), cam.copy()
        cp[t] += h
        cm[t] -= h
        num = (_proj(ph, pt, XYZ, X0, opk, cp).xy - _proj(ph, pt, XYZ, X0, opk, cm).xy) / (2 * h)
        assert np.allclose(pr.J_cam[:, :, t], num, rtol=1e-5, atol=1e-6 * np.abs(num).max()), t


def test_resection_removes_the_correction_exactly():
    """Initial values: resection from 4 coplanar points with the backward model undoes the correction
    exactly (``correct``), so noise-free data give the orientation to rounding."""
    from baarda.pipeline.adjustment import resection

    ph, pt, XYZ, X0, opk, cam = _scene()
    pts = np.array([[0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    xy = _proj(np.zeros(4, int), np.arange(4), pts, X0[:1] + [0.5, 0.5, 0.0], opk[:1], cam).xy
    res = resection(xy, pts, cam[0], cam[1], cam[2], ap_model="brown-backward", ap=cam[3:])
    assert res.method == "plane"
    assert np.allclose(res.X0, X0[0] + [0.5, 0.5, 0.0], atol=1e-9)
    assert np.allclose(res.opk, opk[0], atol=1e-9)
