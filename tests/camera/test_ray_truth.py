"""Synthetic truth for every ray model: a fisheye block projected with known parameters, adjusted from
a perturbed start, recovers them (noise-free: to rounding; with noise: within the estimated σ)."""

import numpy as np
import pytest

from baarda.pipeline.adjustment import BundleSettings, adjust
from baarda.pipeline.camera.ray_models import field_angle
from baarda.pipeline.geometry import rotation_from_opk_many
from baarda.pipeline.synthetic.fisheye import TRUE_RAY_AP, make_fisheye_block


def _start(block, rng, model):
    cams, ph, pts = block.cameras, block.photos, block.points
    fixed_xp = cams.sigma_iop[0, 1] == 0
    cams0 = cams.replace(c=cams.c * 1.01, xp=cams.xp if fixed_xp else cams.xp * 0, yp=cams.yp * 0,
                         ap=cams.ap * 0.8)
    XYZ = pts.XYZ.copy()
    tie = pts.role == "tie"
    XYZ[tie] += 0.02 * rng.standard_normal((tie.sum(), 3))
    return block.replace(cameras=cams0, points=pts.replace(XYZ=XYZ),
                         photos=ph.replace(X0=ph.X0 + 0.01 * rng.standard_normal(ph.X0.shape),
                                           opk=ph.opk + 0.005 * rng.standard_normal(ph.opk.shape)))


@pytest.mark.parametrize("model", sorted(TRUE_RAY_AP))
def test_recovers_the_parameters(model):
    block, truth = make_fisheye_block(model)
    res = adjust(_start(block, np.random.default_rng(7), model), BundleSettings(covariance=False))
    est = res.state.cam_params[0, :len(truth["cam"])]
    np.testing.assert_allclose(est, truth["cam"], rtol=1e-9, atol=1e-12)
    seen = np.unique(block.observations.point)
    np.testing.assert_allclose(res.state.XYZ[seen], truth["XYZ"][seen], atol=1e-10)
    assert res.vtpv < 1e-12


def test_rays_beyond_90_degrees_take_part():
    block, _ = make_fisheye_block("opencv-fisheye")
    ph, obs = block.photos, block.observations
    R = rotation_from_opk_many(ph.opk)
    d = np.einsum("kij,kj->ki", R[obs.photo], block.points.XYZ[obs.point] - ph.X0[obs.photo])
    ang = field_angle(d)
    assert (ang > 90).sum() > 30 and ang.max() > 95


def test_noisy_block_estimates_within_their_sigma():
    rng = np.random.default_rng(11)
    block, truth = make_fisheye_block("opencv-fisheye", noise_mm=0.0015, rng=rng)
    res = adjust(_start(block, rng, "opencv-fisheye"), BundleSettings())
    est = res.state.cam_params[0, :len(truth["cam"])]
    sig = np.sqrt(np.diag(res.cov_cameras[0]))[:len(truth["cam"])]
    assert 0.7 < res.sigma0 < 1.3
    assert (np.abs(est - truth["cam"]) < 4.5 * sig).all()


def test_outside_the_domain_stops_the_bundle_with_a_clear_error():
    from baarda.pipeline.camera.ray_models import RayOutsideModel

    block, _ = make_fisheye_block("fov")
    cams = block.cameras
    # ω = 0 is the pinhole: the rays beyond 90° of this block have no image
    with pytest.raises(RayOutsideModel, match=r"'fov' cannot project \d+ observed ray\(s\).*field angle 9\d\.\d°"):
        adjust(block.replace(cameras=cams.replace(ap=cams.ap * [1, 0])), BundleSettings(covariance=False))


def test_a_trial_step_out_of_the_domain_is_damped_not_fatal():
    """The bundle's trial step that turns rays beyond an orthographic fisheye's 90° has cost ∞ (the
    step is damped); the start itself outside the domain is a clear error (above)."""
    from baarda.pipeline.adjustment.lm import _trial
    from baarda.pipeline.adjustment.problem import BundleProblem

    block, _ = make_fisheye_block("fisheye-orthographic", max_angle_deg=80.0)
    prob = BundleProblem(block, BundleSettings(covariance=False))
    st = prob.initial_state()
    assert np.isfinite(_trial(prob, st)[2])
    bad = st.copy()
    bad.opk = bad.opk + [0.0, 0.3, 0.0]                 # 17°: rays at 80° now beyond 90°
    new, parts, cost = _trial(prob, bad)
    assert cost == np.inf and parts is None
