"""Rigs in the bundle core: Jacobians against finite differences, truth recovery on a simulated
stereo rig, fixed / weighted sensors, the stability test, and the structure's errors."""

import numpy as np
import pytest

from baarda.pipeline.adjustment import BundleProblem, BundleSettings, adjust, rig_result
from baarda.pipeline.adjustment.rig import compose_photos
from baarda.pipeline.errors import InputError
from baarda.pipeline.model import FrameMembers
from baarda.pipeline.synthetic.rig import make_rig_block


def _perturbed(block, seed=5):
    rng = np.random.default_rng(seed)
    ph, pts = block.photos, block.points
    tie = (pts.role == "tie")[:, None]
    return block.replace(photos=ph.replace(X0=ph.X0 + rng.normal(0, 0.03, ph.X0.shape),
                                           opk=ph.opk + rng.normal(0, 0.01, ph.opk.shape)),
                         points=pts.replace(XYZ=np.where(tie, pts.XYZ + rng.normal(0, 0.02, pts.XYZ.shape), pts.XYZ)))


def test_rig_jacobians_match_finite_differences():
    block, truth = make_rig_block(np.random.default_rng(0), n_frames=4, n_points=20,
                                  sensors=((0, 0, 0, 0, 0, 0), (0.3, 0.05, -0.1, 0.2, -0.4, 0.3)))
    prob = BundleProblem(block, BundleSettings())
    st = prob.initial_state()
    pr = prob.project(st, jacobians=True)
    J = pr.J_eo                                                   # (k, 2, 12): frame 6 | sensor 6
    assert J.shape[2] == 12
    h = 1e-7
    for which, arr in (("frame", 0), ("sensor", 6)):
        for t in range(6):
            xy = []
            for sgn in (1, -1):
                s2 = st.copy()
                target = s2.frame if which == "frame" else s2.sensor
                target[:, t] += sgn * h
                s2.X0, s2.opk = compose_photos(prob.rig, s2.frame, s2.sensor, s2.X0, s2.opk)
                xy.append(prob.project(s2, jacobians=False).xy)
            fd = (xy[0] - xy[1]) / (2 * h)
            col = J[:, :, arr + t]
            if which == "sensor":          # only the non-reference sensor's photos depend on it
                on = prob.rig.photo_sensor[prob.obs_photo] == 1
                fd, col = fd[on], col[on]
            np.testing.assert_allclose(col, fd, atol=1e-5 * np.abs(fd).max() + 1e-9)


def test_stereo_rig_recovers_truth_within_sigma():
    block, truth = make_rig_block(np.random.default_rng(1), noise_mm=0.001)
    res = adjust(_perturbed(block))
    assert abs(res.sigma0_hat - 1) < 0.1
    rr = rig_result(res)
    s = rr.sensors[1]
    assert not s.reference_sensor and s.status == ("estimated",) * 6
    z = (s.value - truth["sensor"][1]) / s.sigma
    assert np.all(np.abs(z) < 4), z
    np.testing.assert_allclose(s.baseline, np.linalg.norm(truth["sensor"][1][:3]), atol=4 * s.sigma_baseline)
    # photos' orientations are the composition, with the covariance propagated (non-zero for every photo)
    assert (res.eo_sigmas()[res.photo_used] > 0).all()
    assert np.abs(res.state.X0 - truth["X0"]).max() < 5e-3


def test_rig_has_fewer_unknowns_than_independent_photos():
    block, _ = make_rig_block(np.random.default_rng(1), noise_mm=0.001)
    free = adjust(block.replace(rigs=type(block.rigs)()))
    rig = adjust(block)
    F, S = 8, 2
    assert rig.dof - free.dof == 6 * F * S - (6 * F + 6)
    assert rig.vtpv >= free.vtpv


def test_fixed_and_weighted_sensor_and_stability_test():
    block, truth = make_rig_block(np.random.default_rng(2), noise_mm=0.001)
    rs = block.rigs.sensors
    good = truth["sensor"][1]
    # fixed at the truth: no sensor unknowns
    fixed = block.replace(rigs=block.rigs.replace(sensors=rs.replace(
        centre=np.array([[0, 0, 0], good[:3]]), opk=np.array([[0, 0, 0], good[3:]]), sigma=np.zeros((2, 6)))))
    r_fixed = adjust(fixed)
    assert (r_fixed.problem.g_sensor < 0).all()
    np.testing.assert_allclose(r_fixed.state.sensor[1], good)
    # weighted with a prior 2 mm / 0.01° off: redundancy numbers in (0, 1), test passes
    sig = np.r_[np.full(3, 0.002), np.full(3, np.radians(0.01))]
    prior = good + np.r_[0.001, 0, 0, 0, 0, 0]
    weighted = block.replace(rigs=block.rigs.replace(sensors=rs.replace(
        centre=np.array([[0, 0, 0], prior[:3]]), opk=np.array([[0, 0, 0], prior[3:]]),
        sigma=np.array([np.zeros(6), sig]))))
    rr = rig_result(adjust(weighted))
    s = rr.sensors[1]
    assert s.status == ("weighted",) * 6
    assert np.all((s.redundancy > 0) & (s.redundancy < 1))
    assert s.stability["stable"] and s.stability["mode"] == "weighted"
    # estimated, with a calibration 5 cm off: the stability test rejects it
    bad = good + np.r_[0.05, 0, 0, 0, 0, 0]
    est = block.replace(rigs=block.rigs.replace(sensors=rs.replace(
        centre=np.array([[0, 0, 0], bad[:3]]), opk=np.array([[0, 0, 0], bad[3:]]),
        sigma=np.array([np.zeros(6), np.full(6, np.inf)]), prior_sigma=np.array([np.full(6, np.nan), sig]))))
    rr = rig_result(adjust(est))
    s = rr.sensors[1]
    assert s.stability["mode"] == "estimated" and not s.stability["stable"]
    assert rr.stability["T"] == s.stability["T"]
    # ... and accepts a calibration within its σ
    ok = est.replace(rigs=est.rigs.replace(sensors=est.rigs.sensors.replace(
        centre=np.array([[0, 0, 0], good[:3]]), opk=np.array([[0, 0, 0], good[3:]]))))
    assert rig_result(adjust(ok)).sensors[1].stability["stable"]


def test_structure_errors_name_the_frame_and_photo():
    block, _ = make_rig_block(np.random.default_rng(0), n_frames=3, n_points=20)
    fm = block.rigs.frames
    # a frame without the reference sensor's photo
    drop = FrameMembers(frame=fm.frame[1:], photo=fm.photo[1:], line=np.arange(2, len(fm) + 1))
    with pytest.raises(InputError, match="no photo of rig 'rig'.s reference sensor") as e:
        BundleProblem(block.replace(rigs=block.rigs.replace(frames=drop, frames_path="frames.csv")), BundleSettings())
    assert e.value.path == "frames.csv" and e.value.field == "frame"
    # a photo in two frames
    two = FrameMembers(frame=np.r_[fm.frame, ["F09"]], photo=np.r_[fm.photo, [0]], line=np.arange(1, len(fm) + 2))
    with pytest.raises(InputError, match="is in frame 'F01' already") as e:
        BundleProblem(block.replace(rigs=block.rigs.replace(frames=two, frames_path="frames.csv")), BundleSettings())
    assert e.value.line == len(fm) + 1 and e.value.field == "photo"


def test_photo_covariances_of_a_rig_match_a_numerical_propagation():
    """The composed photos' covariance (bundle_eo.csv, calibration-quality's joint covariance) is the
    frame's and sensor's covariance propagated through the composition: checked against finite
    differences of compose_photos."""
    from baarda.pipeline.adjustment.calquality import joint_covariance
    from baarda.pipeline.adjustment.rig import photo_columns

    block, _ = make_rig_block(np.random.default_rng(4), n_frames=5, n_points=30, noise_mm=0.001)
    res = adjust(block)
    prob, st = res.problem, res.state
    p = int(np.flatnonzero(prob.rig.photo_sensor == 1)[2])
    cols, T = photo_columns(prob, st, [p])
    h = 1e-7
    for t in range(12):
        s2 = st.copy()
        (s2.frame[prob.rig.photo_frame[p]] if t < 6 else s2.sensor[1])[t % 6] += h
        X0, opk = compose_photos(prob.rig, s2.frame, s2.sensor, st.X0, st.opk)
        s3 = st.copy()
        (s3.frame[prob.rig.photo_frame[p]] if t < 6 else s3.sensor[1])[t % 6] -= h
        X0m, opkm = compose_photos(prob.rig, s3.frame, s3.sensor, st.X0, st.opk)
        fd = np.r_[X0[p] - X0m[p], opk[p] - opkm[p]] / (2 * h)
        np.testing.assert_allclose(T[0][:, t], fd, atol=1e-6)
    C = joint_covariance(res, 1, [p])[-6:, -6:]
    np.testing.assert_allclose(C, res.cov_eo[p], rtol=1e-8, atol=1e-20)
    assert (np.diag(C) > 0).all()


def test_opencv_T_of_a_sensor_pose():
    """T = −F R_s c is OpenCV's x_s = R x_ref + T: a point's coordinates in both y-down frames agree."""
    from baarda.pipeline.geometry import rotation_from_opk
    from baarda.plugins.bundle.rigreport import t_cv, t_cv_covariance

    pose = np.array([0.3, 0.02, -0.05, 0.1, -0.2, 0.05])
    F = np.diag([1.0, -1.0, -1.0])
    Rs = rotation_from_opk(*pose[3:])
    p_ref = np.array([0.4, -0.2, -3.0])                       # baarda frame of the reference camera
    p_s = Rs @ (p_ref - pose[:3])
    R_cv = F @ Rs @ F
    np.testing.assert_allclose(F @ p_s, R_cv @ (F @ p_ref) + t_cv(pose), atol=1e-12)
    C = t_cv_covariance(pose, np.diag([1e-6] * 3 + [1e-8] * 3))
    assert C.shape == (3, 3) and np.all(np.linalg.eigvalsh(C) > 0)


def test_sigma_eo_option_weights_the_frames_of_a_rig():
    """The bundle option sigma_eo weights the frames (through their reference photos), not the
    non-reference photos whose orientation follows from frame and sensor."""
    from baarda.pipeline.adjustment import BundleConfig, configure_block

    block, _ = make_rig_block(np.random.default_rng(6), n_frames=4, n_points=30, noise_mm=0.001)
    b = configure_block(block, BundleConfig(sigma_eo=[0.01, 0.01, 0.01, 0.1, 0.1, 0.1]))
    ref = np.isin(np.arange(len(b.photos)), [0, 2, 4, 6])
    assert np.isfinite(b.photos.sigma_eo[ref]).all() and np.isinf(b.photos.sigma_eo[~ref]).all()
    prob = BundleProblem(b, BundleSettings())
    assert len(prob.prior_g_idx) == 6 * 4 and np.isin(prob.prior_g_idx, prob.g_frame).all()


def test_weighted_sensor_is_a_variance_component_group():
    """A weighted sensor pose is its own group ("rig") of the variance components: its redundancy
    share is the sum of the six constraints' redundancy numbers."""
    from baarda.pipeline.adjustment import group_parts, image_group_labels

    block, truth = make_rig_block(np.random.default_rng(7), n_frames=5, n_points=30, noise_mm=0.001)
    rs = block.rigs.sensors
    good = truth["sensor"][1]
    sig = np.r_[np.full(3, 0.002), np.full(3, np.radians(0.02))]
    b = block.replace(rigs=block.rigs.replace(sensors=rs.replace(
        centre=np.array([[0, 0, 0], good[:3]]), opk=np.array([[0, 0, 0], good[3:]]), sigma=np.array([np.zeros(6), sig]))))
    res = adjust(b)
    parts = {p.name: p for p in group_parts(res, image_group_labels(b, "camera"))}
    assert "rig" in parts and parts["rig"].n == 6
    np.testing.assert_allclose(parts["rig"].redundancy, np.sum(rig_result(res).sensors[1].redundancy), rtol=1e-8)
    assert abs(sum(p.redundancy for p in parts.values()) - res.dof) < 1e-6 * res.dof


def test_predicted_variance_of_a_removed_rig_observation():
    """A switched-off observation of a rig photo is predicted through its frame's and sensor's
    unknowns: its predicted variance Σ + A Q' Aᵀ (the adjustment without it) is the inverse of the
    P Qvv P block of the adjustment with it (σ0 = 1)."""
    block, _ = make_rig_block(np.random.default_rng(8), n_frames=5, n_points=30, noise_mm=0.001)
    obs = block.observations
    k = int(np.flatnonzero(~block.rigs.sensors.reference[block.photos.camera[obs.photo]])[5])
    act = np.array(obs.active)
    act[k] = False
    out = adjust(block.replace(observations=obs.replace(active=act)))
    full = adjust(block)
    pred = out.snapshot.sigma_v_pred.reshape(-1, 2)[k]
    M = np.linalg.inv(full.PQvvP[k])
    np.testing.assert_allclose(pred ** 2, np.diag(M), rtol=1e-4)         # two linearisation points


def test_external_reliability_on_a_rig_photo_is_its_composed_orientation():
    """The effect of a bias in an observation of a non-reference photo on that photo's orientation
    (own_effects) is the change of its composed orientation when the bias is added and the block
    re-adjusted (linear: a small bias)."""
    from baarda.pipeline.adjustment import own_effects

    block, _ = make_rig_block(np.random.default_rng(9), n_frames=5, n_points=30, noise_mm=0.001)
    res = adjust(block)
    obs = block.observations
    k = int(np.flatnonzero(~block.rigs.sensors.reference[block.photos.camera[obs.photo]])[3])
    bias = np.zeros((len(obs), 2))
    bias[k, 0] = 0.002
    eff = own_effects(res, bias=bias).eo[k, 0]
    xy = np.array(obs.xy)
    xy[k, 0] += 0.002
    res2 = adjust(block.replace(observations=obs.replace(xy=xy)), start=res.state)
    p = obs.photo[k]
    change = np.r_[res2.state.X0[p] - res.state.X0[p], res2.state.opk[p] - res.state.opk[p]]
    np.testing.assert_allclose(eff, change, rtol=1e-3, atol=1e-9)


def test_covariance_of_a_rig_photo_on_demand():
    """output.covariance_of for a rig photo: its composed orientation's covariance (bundle_eo.csv's)."""
    from baarda.pipeline.adjustment import parameter_covariance

    block, _ = make_rig_block(np.random.default_rng(10), n_frames=4, n_points=30, noise_mm=0.001)
    res = adjust(block)
    p = int(np.flatnonzero(res.problem.rig.photo_sensor == 1)[1])
    names, C = parameter_covariance(res, [f"photo {block.photos.ids[p]}"])
    assert len(names) == 6
    np.testing.assert_allclose(C, res.cov_eo[p], rtol=1e-7, atol=1e-22)


def test_free_network_with_a_rig_datum_motions_and_linearised_model():
    """A free network of a rig: the similarity motions include the frames (moved as poses) and the
    sensors (their centres scale), so the minimal datum and the linearised model (RRR's design)
    exist, with the bundle's degrees of freedom; and a similarity of the solution leaves vᵀPv."""
    from baarda.pipeline.adjustment import linearised_model
    from baarda.pipeline.adjustment.diagnose import datum_motions

    block, _ = make_rig_block(np.random.default_rng(11), n_frames=4, n_points=25, noise_mm=0.001)
    n = len(block.points)
    block = block.replace(points=block.points.replace(role=np.array(["tie"] * n), sigma=np.full((n, 3), np.inf)))
    res = adjust(block, BundleSettings(datum="free"))
    model, _ = linearised_model(res)
    assert np.linalg.matrix_rank(model.A) == model.A.shape[1]
    assert model.A.shape[0] - model.A.shape[1] == res.dof
    prob, st = res.problem, res.state
    G = datum_motions(prob, st)
    # the scale motion of a sensor's centre is the centre itself (per unit of the motions' scale)
    s = prob.g_sensor[1, :3]
    np.testing.assert_allclose(G[s, 6] / np.linalg.norm(G[s, 6]), st.sensor[1, :3] / np.linalg.norm(st.sensor[1, :3]))
