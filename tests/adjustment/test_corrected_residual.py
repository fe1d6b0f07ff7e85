"""DBAT's residual definition inside the bundle (``residual = "corrected"``, pipeline/adjustment/corrected.py):
the residual is the corrected mark minus the ideal projection, the Jacobians are checked by central
differences, and the adjustment minimises DBAT's objective (its gradient vanishes)."""

from __future__ import annotations

import numpy as np
import pytest

from baarda.pipeline.adjustment import BundleSettings, adjust, project_observations
from baarda.pipeline.camera import get_ap_model
from baarda.pipeline.errors import InputError

CAM = np.array([[7.5, 0.1, -0.05, 4e-3, -4e-5, -2e-6, -6e-5, -4e-5, 4e-4, 1e-4]])


def _scene(rng, m=3, n=20):
    XYZ = rng.normal(size=(n, 3)) * 2
    X0 = np.column_stack([rng.normal(size=m), rng.normal(size=m), np.full(m, 10.0)])
    opk = rng.normal(size=(m, 3)) * 0.05
    ph, pt = np.repeat(np.arange(m), n), np.tile(np.arange(n), m)
    return XYZ, X0, opk, ph, pt, rng.normal(size=(len(ph), 2)) * 2


def test_residual_is_dbats():
    """``marks − xy`` is ``g(l − pp) − x̄``: the corrected mark minus the ideal projection."""
    XYZ, X0, opk, ph, pt, marks = _scene(np.random.default_rng(1))
    m = len(X0)
    pr = project_observations(ph, pt, XYZ, X0, opk, np.zeros(m, int), CAM, ["brown-backward"], [{}],
                              jacobians=False, marks=marks)
    ideal = project_observations(ph, pt, XYZ, X0, opk, np.zeros(m, int), CAM[:, :3], ["none"], [{}],
                                 jacobians=False).xy - CAM[0, 1:3]
    red = marks - CAM[0, 1:3]
    gx, gy = get_ap_model("brown-backward").correct(red[:, 0], red[:, 1], np.tile(CAM[0, 3:], (len(red), 1)))
    np.testing.assert_allclose(marks - pr.xy, np.column_stack([gx, gy]) - ideal, atol=1e-13)
    # without marks the model's own (measured-mark) definition, which differs
    own = project_observations(ph, pt, XYZ, X0, opk, np.zeros(m, int), CAM, ["brown-backward"], [{}], jacobians=False)
    assert np.abs(own.xy - pr.xy).max() > 1e-3


def test_jacobians_against_central_differences():
    XYZ, X0, opk, ph, pt, marks = _scene(np.random.default_rng(2))
    m = len(X0)

    def f(cam=CAM, X0=X0, opk=opk, XYZ=XYZ):
        return project_observations(ph, pt, XYZ, X0, opk, np.zeros(m, int), cam, ["brown-backward"], [{}],
                                    jacobians=False, marks=marks).xy

    pr = project_observations(ph, pt, XYZ, X0, opk, np.zeros(m, int), CAM, ["brown-backward"], [{}], marks=marks)
    h = 1e-6
    for j in range(CAM.shape[1]):
        a, b = CAM.copy(), CAM.copy()
        a[0, j] += h
        b[0, j] -= h
        num = (f(cam=a) - f(cam=b)) / (2 * h)
        np.testing.assert_allclose(pr.J_cam[:, :, j], num, atol=2e-8 * max(1.0, np.abs(num).max()), err_msg=str(j))
    for j in range(3):
        for name, arr, J in (("X0", X0, pr.J_eo[:, :, j]), ("opk", opk, pr.J_eo[:, :, 3 + j]),
                             ("XYZ", XYZ, pr.J_point[:, :, j])):
            a, b = arr.copy(), arr.copy()
            a[:, j] += h
            b[:, j] -= h
            num = (f(**{name: a}) - f(**{name: b})) / (2 * h)
            np.testing.assert_allclose(J, num, atol=1e-8, err_msg=f"{name} {j}")


def test_adjustment_minimises_dbats_objective(shared_data):
    """camcal (DBAT's demo): at the corrected bundle's solution the gradient of DBAT's objective
    Σ (g(l − pp) − x̄)ᵀ P (g(l − pp) − x̄) in the camera vanishes (against the measured bundle's)."""
    from baarda.plugins.dbat import dbat_block, read_dbat

    block = dbat_block(read_dbat(shared_data / "dbat-camcal" / "camcaldemo.xml"))
    P = np.linalg.inv(block.observations.cov)
    obs = block.observations

    def F(st, cam):
        ideal = project_observations(obs.photo, obs.point, st.XYZ, st.X0, st.opk, block.photos.camera, cam[:, :3],
                                     ["none"], [{}], jacobians=False).xy - cam[0, 1:3]
        red = obs.xy - cam[0, 1:3]
        g = np.column_stack(get_ap_model("brown-backward").correct(red[:, 0], red[:, 1],
                                                                    np.tile(cam[0, 3:], (len(red), 1))))
        r = g - ideal
        return float(np.einsum("ki,kij,kj->", r, P, r))

    def grad_sigma(res):
        st, cam = res.state, res.state.cam_params
        sig = np.sqrt(np.diag(res.cov_cameras[0]))
        out = []
        for k in np.flatnonzero(sig > 0):
            h = 1e-3 * sig[k]
            a, b = cam.copy(), cam.copy()
            a[0, k] += h
            b[0, k] -= h
            out.append((F(st, a) - F(st, b)) / (2 * h) * sig[k])    # per σ of the parameter
        return np.abs(out).max(), F(st, cam)

    corr = adjust(block, BundleSettings(datum="control", residual="corrected"))
    meas = adjust(block, BundleSettings(datum="control"))
    g_corr, F_corr = grad_sigma(corr)
    g_meas, F_meas = grad_sigma(meas)
    assert F_corr < F_meas
    assert corr.vtpv == pytest.approx(F_corr, rel=1e-10)             # the bundle's vᵀPv is DBAT's objective
    assert g_corr < 1e-5 * g_meas
    assert not np.shares_memory(corr.residuals, obs.xy)


def test_refused_for_a_model_without_a_correction():
    """A forward model has no corrected marks: the option is refused, naming the camera and the option."""
    from baarda.pipeline.synthetic.closerange import make_block

    blk, _ = make_block(model="brown", rng=np.random.default_rng(0))
    with pytest.raises(InputError, match="brown-backward") as e:
        adjust(blk, BundleSettings(residual="corrected"))
    assert e.value.field == "residual"
    # without distortion parameters the two definitions are the same adjustment
    blk, _ = make_block(model="none", noise_mm=1e-3, rng=np.random.default_rng(0))
    a, b = adjust(blk, BundleSettings()), adjust(blk, BundleSettings(residual="corrected"))
    assert a.vtpv == pytest.approx(b.vtpv, rel=1e-12)
