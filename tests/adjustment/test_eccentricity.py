"""Eccentricity of circular targets: the closed form against a numerical ellipse, zero where it must be,
the target normals, and a synthetic bundle whose bias the correction recovers (docs/targets.md)."""

import functools

import numpy as np
import pytest

from baarda.pipeline.adjustment import (BundleConfig, EccentricityConfig, adjust_block, eccentricity_corrections,
                                        project_observations)
from baarda.pipeline.geometry import rotation_from_opk_many
from baarda.pipeline.geometry.circles import ellipse_centre_direction, plane_normals, reduced_eccentricity
from baarda.pipeline.model import CircleTargets
from baarda.pipeline.synthetic.closerange import make_block


def _basis(m):
    a = np.cross(m, [1.0, 0.0, 0.0])
    if np.linalg.norm(a) < 0.3:
        a = np.cross(m, [0.0, 1.0, 0.0])
    u = a / np.linalg.norm(a)
    return u, np.cross(m / np.linalg.norm(m), u)


def _rim(d, m, r, n=720):
    """Points on the circle (camera frame)."""
    u, v = _basis(m)
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return d + r * (np.cos(t)[:, None] * u + np.sin(t)[:, None] * v)


def _conic_centre(x):
    """Centre of the least-squares conic through 2-D points (float64 SVD, centred and scaled)."""
    c0 = x.mean(axis=0)
    s = np.abs(x - c0).max()
    y = (x - c0) / s
    A = np.column_stack([y[:, 0] ** 2, y[:, 0] * y[:, 1], y[:, 1] ** 2, y[:, 0], y[:, 1], np.ones(len(y))])
    a, b, c, d, e, _ = np.linalg.svd(A)[2][-1]
    return np.linalg.solve([[2 * a, b], [b, 2 * c]], [-d, -e]) * s + c0


def _random_targets(rng, k):
    d = np.column_stack([rng.uniform(-1, 1, k), rng.uniform(-0.8, 0.8, k), -rng.uniform(1.5, 4.0, k)])
    m = rng.normal(size=(k, 3))
    m /= np.linalg.norm(m, axis=1)[:, None]
    m[m[:, 2] < 0] *= -1                        # facing the camera (sign does not matter: tested below)
    m[:, 2] += 0.3                              # not edge-on
    m /= np.linalg.norm(m, axis=1)[:, None]
    return d, m, rng.uniform(0.01, 0.1, k)


def test_closed_form_matches_the_centre_of_the_projected_rim():
    rng = np.random.default_rng(7)
    d, m, r = _random_targets(rng, 25)
    e = reduced_eccentricity(d, m, r)
    assert np.abs(e).max() > 1e-5                 # something to find
    for i in range(len(d)):
        rim = _rim(d[i], m[i], r[i])
        x = rim[:, :2] / rim[:, 2:3]
        diameter = np.ptp(x, axis=0).max()
        numeric = _conic_centre(x) - d[i, :2] / d[i, 2]
        assert np.abs(numeric - e[i]).max() < 1e-6 * diameter, i


def test_closed_form_matches_opencv_fit_ellipse():
    cv2 = pytest.importorskip("cv2")
    rng = np.random.default_rng(8)
    d, m, r = _random_targets(rng, 10)
    e = reduced_eccentricity(d, m, r)
    f = 1000.0                                     # pixels: fitEllipse works in float32
    for i in range(len(d)):
        rim = _rim(d[i], m[i], r[i], 2000)
        x = f * rim[:, :2] / rim[:, 2:3]
        centre = np.array(cv2.fitEllipse(x.astype(np.float32))[0])
        diameter = np.ptp(x, axis=0).max()
        assert np.abs(centre - f * d[i, :2] / d[i, 2] - f * e[i]).max() < 2e-5 * diameter


def test_fronto_parallel_target_has_no_eccentricity():
    rng = np.random.default_rng(9)
    d, _, r = _random_targets(rng, 20)
    m = np.tile([0.0, 0.0, 1.0], (20, 1))
    assert np.abs(reduced_eccentricity(d, m, r)).max() < 1e-15
    assert np.abs(reduced_eccentricity(d, -m, r)).max() < 1e-15


def test_normal_sign_does_not_matter_and_the_ray_keeps_the_depth():
    rng = np.random.default_rng(10)
    d, m, r = _random_targets(rng, 20)
    np.testing.assert_allclose(reduced_eccentricity(d, m, r), reduced_eccentricity(d, -m, r), atol=1e-16)
    q = ellipse_centre_direction(d, m, r)
    np.testing.assert_array_equal(q[:, 2], d[:, 2])
    d0 = d.copy()
    reduced_eccentricity(d, m, r)
    np.testing.assert_array_equal(d, d0)            # inputs unchanged


def test_eccentricity_grows_with_the_square_of_the_radius():
    d = np.array([[0.3, -0.2, -2.0]])
    m = np.array([[0.0, np.sin(0.6), np.cos(0.6)]])
    e1, e2 = reduced_eccentricity(d, m, 0.01), reduced_eccentricity(d, m, 0.02)
    np.testing.assert_allclose(e2 / e1, 4.0, rtol=1e-3)


def test_plane_normals_of_a_tilted_plane_and_a_line():
    rng = np.random.default_rng(11)
    n_true = np.array([0.2, -0.3, 1.0]) / np.linalg.norm([0.2, -0.3, 1.0])
    u, v = _basis(n_true)
    P = rng.uniform(-1, 1, (50, 1)) * u + rng.uniform(-1, 1, (50, 1)) * v + 1e-6 * rng.normal(size=(50, 3))
    n, ok = plane_normals(P)
    assert ok.all()
    assert np.abs(np.abs(n @ n_true) - 1).max() < 1e-8
    line = np.outer(np.linspace(0, 1, 10), [1.0, 2.0, 3.0])
    n, ok = plane_normals(line)
    assert not ok.any() and np.isnan(n).all()


def test_circle_targets_refuse_bad_sizes_and_normals():
    with pytest.raises(ValueError, match="diameter"):
        CircleTargets.make(["1"], 0.0)
    with pytest.raises(ValueError, match="diameter"):
        CircleTargets.make(["1"], -1.0)
    with pytest.raises(ValueError, match="normal"):
        CircleTargets.make(["1"], 1.0, [0.0, 0.0, 0.0])
    c = CircleTargets.make(["1", "2"], 0.02)
    assert np.isnan(c.normal).all()


# -- a synthetic bundle with circular targets ------------------------------------------------------
DIAMETER = 0.16          # object units: the cloud spans ±1 at ≈ 3.2 (a large target for a clear bias)


@functools.lru_cache(maxsize=None)
def _circle_block(model="brown", given_normals=True):
    """The close-range block with each point a circular target (random normal within 35° of +Z) whose
    observation is the centre of the conic fitted to its projected rim — computed numerically, with the
    camera's distortion applied to the fitted centre (the model the correction uses)."""
    block, truth = make_block(n_photos=8, n_points=40, model=model, sigma_mm=0.0005)
    rng = np.random.default_rng(3)
    tilt = np.radians(rng.uniform(0, 35, len(block.points)))
    az = rng.uniform(0, 2 * np.pi, len(block.points))
    normals = np.column_stack([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)])
    obs, ph, pts = block.observations, block.photos, block.points
    R = rotation_from_opk_many(ph.opk)[obs.photo]
    Q = np.empty((len(obs), 3))
    for i in range(len(obs)):
        d = R[i] @ (pts.XYZ[obs.point[i]] - ph.X0[obs.photo[i]])
        m = R[i] @ normals[obs.point[i]]
        rim = _rim(d, m, DIAMETER / 2, 360)
        ue = _conic_centre(rim[:, :2] / rim[:, 2:3])
        Q[i] = ph.X0[obs.photo[i]] + R[i].T @ (np.r_[ue, 1.0] * d[2])
    cams = block.cameras
    cam = np.column_stack([cams.c, cams.xp, cams.yp, cams.ap])
    xy = project_observations(obs.photo, np.arange(len(obs)), Q, ph.X0, ph.opk, ph.camera, cam, cams.ap_model,
                              [dict(block.ap_meta.get("cam", {}))], jacobians=False).xy
    circles = CircleTargets.make(pts.ids, DIAMETER, normals if given_normals else None)
    return block.replace(observations=obs.replace(xy=xy), circles=circles), truth


def test_corrections_at_the_true_orientation_explain_the_measured_centres():
    block, truth = _circle_block()
    ecc = eccentricity_corrections(block)
    assert ecc.applied.all()
    exact = block.replace(circles=None)
    from baarda.pipeline.adjustment import project_block
    ideal = project_block(exact, exact.observations.photo, exact.observations.point)
    bias = block.observations.xy - ideal
    assert np.abs(bias).max() > 2e-3                            # mm: 4 σ of 0.5 µm and more
    assert np.abs(bias - ecc.correction).max() < 1e-9           # mm


def test_the_bundle_recovers_the_truth_with_the_correction():
    block, truth = _circle_block()
    # the measured centres are made as the closed form models them (distortion at the ellipse
    # centre), so the closed form recovers the truth exactly; the rim mode (the default) is tested
    # against rims projected through the lens in test_eccentricity_plate.py
    cfg = BundleConfig(datum="control", eccentricity=EccentricityConfig(distortion="centre"))
    off = adjust_block(block, BundleConfig(datum="control", eccentricity=EccentricityConfig(enabled=False)))
    on = adjust_block(block, cfg)
    assert on.eccentricity is not None and off.eccentricity is None
    assert on.eccentricity.settled and len(on.eccentricity.changes) <= 4
    assert on.eccentricity.remaining < 0.01
    err = lambda rep: np.abs(rep.result.state.cam_params[0, :3] - truth["cam"][:3]).max()
    assert err(off) > 1e-4                                      # mm: the bias moves c, xp, yp
    assert err(on) < 1e-7
    assert on.sigma0_hat < 1e-3 < off.sigma0_hat                # no noise: the corrected model fits
    np.testing.assert_allclose(on.result.state.XYZ, truth["XYZ"], atol=1e-8)
    # the output block keeps the measured centres (a later bundle corrects them again), the report's
    # block holds the corrected ones
    np.testing.assert_array_equal(on.output_block.observations.xy, block.observations.xy)
    np.testing.assert_allclose(on.block.observations.xy, block.observations.xy - on.eccentricity.final.correction)


def test_estimated_normals_on_a_planar_field():
    """A planar field (all targets in Z = 0, common normal): normals from the neighbours' planes give
    the same corrections as the given normal."""
    block, _ = make_block(n_photos=8, n_points=40, model="none", sigma_mm=0.0005)
    pts = block.points
    flat = pts.replace(XYZ=np.column_stack([pts.XYZ[:, :2], np.zeros(len(pts))]))
    block = block.replace(points=flat)
    given = eccentricity_corrections(block.replace(circles=CircleTargets.make(pts.ids, DIAMETER, [0, 0, 1])))
    est = eccentricity_corrections(block.replace(circles=CircleTargets.make(pts.ids, DIAMETER)))
    assert est.estimated.all() and not given.estimated.any()
    assert np.abs(given.correction).max() > 1e-4
    np.testing.assert_allclose(est.correction, given.correction, atol=1e-12)


def test_without_circles_nothing_changes():
    block, _ = make_block(n_photos=6, n_points=30, model="none", noise_mm=0.0005, sigma_mm=0.0005)
    rep = adjust_block(block)
    assert rep.eccentricity is None
    ecc = eccentricity_corrections(block)
    assert not ecc.applied.any() and not np.any(ecc.correction)


def test_rim_mode_equals_the_closed_form_without_distortion_and_a_rim_fit_with_it():
    """``distortion = "rim"``: without APs the projected rim is an exact ellipse (the closed form);
    with Brown distortion it is the centre of a conic fitted to the distorted rim (computed here per
    observation, 720 points) and differs from the closed form by the distortion's curvature."""
    block, _ = _circle_block(model="none")
    a, b = eccentricity_corrections(block), eccentricity_corrections(block, distortion="rim")
    assert np.abs(a.correction).max() > 1e-3
    np.testing.assert_allclose(b.correction, a.correction, atol=1e-12)
    block, _ = _circle_block(model="brown")
    centre, rim = eccentricity_corrections(block), eccentricity_corrections(block, distortion="rim")
    obs, ph, pts, cams = block.observations, block.photos, block.points, block.cameras
    cam = np.column_stack([cams.c, cams.xp, cams.yp, cams.ap])
    meta = [dict(block.ap_meta.get("cam", {}))]
    ideal = project_observations(obs.photo, obs.point, pts.XYZ, ph.X0, ph.opk, ph.camera, cam, cams.ap_model, meta,
                                 jacobians=False).xy
    for i in range(0, len(obs), 17):
        n = block.circles.normal[obs.point[i]]
        u, v = _basis(n / np.linalg.norm(n))
        t = np.linspace(0, 2 * np.pi, 720, endpoint=False)
        ring = pts.XYZ[obs.point[i]] + DIAMETER / 2 * (np.cos(t)[:, None] * u + np.sin(t)[:, None] * v)
        xy = project_observations(np.full(720, obs.photo[i]), np.arange(720), ring, ph.X0, ph.opk, ph.camera, cam,
                                  cams.ap_model, meta, jacobians=False).xy
        assert np.abs(_conic_centre(xy) - ideal[i] - rim.correction[i]).max() < 1e-9     # mm
    assert np.abs(rim.correction - centre.correction).max() > 1e-7
    with pytest.raises(ValueError, match="distortion"):
        eccentricity_corrections(block, distortion="edge")
