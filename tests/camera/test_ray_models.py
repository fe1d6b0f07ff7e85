"""Ray models (fisheye, omnidirectional, division): projection against pycolmap and OpenCV, Jacobians
against central differences, rays beyond 90° and outside a model's domain."""

import numpy as np
import pytest

from baarda.pipeline.adjustment.collinearity import project_observations
from baarda.pipeline.camera import get_ap_model
from baarda.pipeline.camera.convert import colmap_from_ray, ray_from_colmap
from baarda.pipeline.camera.ray_models import COLMAP_RAY_MODELS, RayOutsideModel, field_angle

pycolmap = pytest.importorskip("pycolmap")

SIZE = (1280, 960)

# realistic COLMAP parameters (pixels, OpenCV frame) of every model
COLMAP_PARAMS = {
    "SIMPLE_FISHEYE": [410.0, 645.2, 470.9],
    "FISHEYE": [412.0, 405.5, 641.3, 483.0],
    "SIMPLE_RADIAL_FISHEYE": [400.0, 650.0, 477.0, 0.031],
    "RADIAL_FISHEYE": [401.0, 637.0, 476.0, 0.025, -0.004],
    "OPENCV_FISHEYE": [398.0, 402.5, 643.0, 481.5, 0.021, -0.011, 0.0042, -0.0007],
    "THIN_PRISM_FISHEYE": [405.0, 403.0, 639.0, 478.0, 0.02, -0.006, 0.0011, -0.0007, 0.001, -0.0002, 0.0009,
                           -0.0006],
    "RAD_TAN_THIN_PRISM_FISHEYE": [402.0, 401.0, 642.0, 479.0, 0.021, -0.008, 0.002, -0.0004, 0.0001, -0.00002,
                                   0.0008, -0.0005, 0.0006, -0.0001, -0.0004, 0.00007],
    "FOV": [415.0, 409.0, 640.5, 482.5, 0.93],
    "EUCM": [380.0, 378.0, 644.0, 479.0, 0.62, 1.07],
    "DIVISION": [395.0, 397.0, 641.0, 477.5, -0.17],
    "SIMPLE_DIVISION": [395.0, 641.0, 477.5, 0.12],
    "EQUIRECTANGULAR": [float(SIZE[0]), float(SIZE[1])],
}


def _rays(rng, n, max_deg):
    th = np.radians(rng.uniform(0, max_deg, n))
    az = rng.uniform(-np.pi, np.pi, n)
    dist = rng.uniform(0.5, 3.0, n)
    # baarda's camera frame: the camera looks along −W
    return np.column_stack([np.sin(th) * np.cos(az), np.sin(th) * np.sin(az), -np.cos(th)]) * dist[:, None]


def _baarda_pixels(model, d, pitch=0.01):
    cam = ray_from_colmap(model, COLMAP_PARAMS[model], SIZE, pitch)
    mdl = get_ap_model(cam["ap_model"])
    xy, valid = mdl.project_ray(d, cam["ap"][None, :], cam["c"], {})
    xy = xy + [cam["xp"], cam["yp"]]
    return np.column_stack([xy[:, 0] / pitch + SIZE[0] / 2, SIZE[1] / 2 - xy[:, 1] / pitch]), valid


def test_every_pycolmap_model_is_known():
    known = set(pycolmap.CameraModelId.__members__) - {"INVALID"}
    brown = {"SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV"}
    assert known - brown == set(COLMAP_RAY_MODELS)


@pytest.mark.parametrize("model", sorted(COLMAP_PARAMS))
def test_projection_equals_pycolmap(model):
    rng = np.random.default_rng(1)
    d = _rays(rng, 400, 85.0)
    cam = pycolmap.Camera.create_from_model_name(1, model, 400.0, *SIZE)
    cam.params = COLMAP_PARAMS[model]
    ref = cam.img_from_cam(d * [1, -1, -1])                  # OpenCV frame: (U, −V, −W)
    uv, valid = _baarda_pixels(model, d)
    ok = np.isfinite(ref).all(axis=1)
    assert ok.sum() > 200
    assert (valid == ok).all()
    np.testing.assert_allclose(uv[ok], ref[ok], rtol=0, atol=1e-8)


@pytest.mark.parametrize("model", sorted(COLMAP_PARAMS))
def test_colmap_parameters_round_trip(model):
    for pitch in (1.0, 0.0034):
        cam = ray_from_colmap(model, COLMAP_PARAMS[model], SIZE, pitch)
        name, params = colmap_from_ray(cam["ap_model"], cam["c"], cam["xp"], cam["yp"], cam["ap"], SIZE, pitch)
        assert name == model
        np.testing.assert_allclose(params, COLMAP_PARAMS[model], rtol=1e-13, atol=1e-12)


def test_opencv_fisheye_equals_cv2():
    cv2 = pytest.importorskip("cv2")
    rng = np.random.default_rng(2)
    d = _rays(rng, 300, 88.0)
    fx, fy, cx, cy, *k = COLMAP_PARAMS["OPENCV_FISHEYE"]
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    ref, _ = cv2.fisheye.projectPoints((d * [1, -1, -1]).reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K,
                                       np.array(k))
    uv, valid = _baarda_pixels("OPENCV_FISHEYE", d, pitch=1.0)
    assert valid.all()
    # cv2's pixel origin is the centre of the top-left pixel, COLMAP's its corner: the same formula
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), rtol=0, atol=1e-7)


# ------------------------------------------------------------------------------------------------
# parameters of every model for the Jacobian and beyond-90° tests (baarda's units)
# ------------------------------------------------------------------------------------------------

BROWN_AP = [2e-4, -3e-6, 1e-8, 4e-5, -2e-5, 1e-4, -5e-5]


def _model_cases():
    out = []
    for model in sorted(COLMAP_PARAMS):
        cam = ray_from_colmap(model, COLMAP_PARAMS[model], SIZE, 0.004)
        out.append((cam["ap_model"], cam["ap"], cam["c"]))
    for name in ("fisheye-equidistant", "fisheye-equisolid", "fisheye-stereographic", "fisheye-orthographic"):
        out.append((name, np.array(BROWN_AP), 1.8))
    return out


CASES = _model_cases()
REACH = {"simple-fisheye": 150, "fisheye": 150, "simple-radial-fisheye": 150, "radial-fisheye": 150,
         "opencv-fisheye": 150, "thin-prism-fisheye": 150, "rad-tan-thin-prism-fisheye": 110, "fov": 150,
         "eucm": 110, "division": 100, "simple-division": 50, "equirectangular": 170, "fisheye-equidistant": 150,
         "fisheye-equisolid": 150, "fisheye-stereographic": 150, "fisheye-orthographic": 89}
"""A field angle (°) each model with CASES' parameters can project (beyond 90° where it can)."""


@pytest.mark.parametrize("name,ap,c", CASES, ids=[c[0] for c in CASES])
def test_jacobians_against_central_differences(name, ap, c):
    mdl = get_ap_model(name)
    rng = np.random.default_rng(3)
    d = _rays(rng, 40, REACH[name])
    P = np.broadcast_to(ap, (len(d), len(ap))).copy()
    cc = np.full(len(d), c)
    xy, valid, Jd, Jp, Jc = mdl.ray_jacobians(d, P, cc, {}, np.arange(mdl.n_params))
    assert valid.all()

    def f(dd=d, PP=P, c_=cc):
        return mdl.project_ray(dd, PP, c_, {})[0]

    for j in range(3):
        h = 1e-6
        e = np.zeros(3)
        e[j] = h
        num = (f(d + e) - f(d - e)) / (2 * h)
        np.testing.assert_allclose(Jd[:, :, j], num, rtol=1e-5, atol=1e-7 * c)
    for j in range(mdl.n_params):
        h = 1e-6 * max(1.0, abs(ap[j]))
        Pp, Pm = P.copy(), P.copy()
        Pp[:, j] += h
        Pm[:, j] -= h
        num = (f(PP=Pp) - f(PP=Pm)) / (2 * h)
        np.testing.assert_allclose(Jp[:, :, j], num, rtol=1e-5, atol=1e-6 * c * max(1.0, np.abs(num).max()))
    h = 1e-6
    num = (f(c_=cc + h) - f(c_=cc - h)) / (2 * h)
    np.testing.assert_allclose(Jc, num, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("name,ap,c", CASES, ids=[c[0] for c in CASES])
def test_additive_interface_in_front(name, ap, c):
    """For rays in front, a ray model is an additive model: distortion(x̄, ȳ) = project((x̄, ȳ, −c)) − x̄,
    with its Jacobians (the path initial values and calibration figures use)."""
    mdl = get_ap_model(name)
    rng = np.random.default_rng(4)
    d = _rays(rng, 30, 50)
    xbar = -c * d[:, :2] / d[:, 2:3]
    P = np.broadcast_to(ap, (len(d), len(ap))).copy()
    dx, dy = mdl.distortion(xbar[:, 0], xbar[:, 1], P, c, {})
    xy, _ = mdl.project_ray(d, P, c, {})
    np.testing.assert_allclose(np.column_stack([dx, dy]) + xbar, xy, atol=1e-12 * c)
    D = mdl.jacobian_xy(xbar[:, 0], xbar[:, 1], P, c, {})
    h = 1e-7 * c
    num = np.stack([(np.column_stack(mdl.distortion(xbar[:, 0] + h, xbar[:, 1], P, c, {}))
                     - np.column_stack(mdl.distortion(xbar[:, 0] - h, xbar[:, 1], P, c, {}))) / (2 * h),
                    (np.column_stack(mdl.distortion(xbar[:, 0], xbar[:, 1] + h, P, c, {}))
                     - np.column_stack(mdl.distortion(xbar[:, 0], xbar[:, 1] - h, P, c, {}))) / (2 * h)], axis=2)
    np.testing.assert_allclose(D, num, atol=1e-6)
    Jc = mdl.jacobian_c(xbar[:, 0], xbar[:, 1], P, c, {})
    hc = 1e-6
    num = (np.column_stack(mdl.distortion(xbar[:, 0], xbar[:, 1], P, c + hc, {}))
           - np.column_stack(mdl.distortion(xbar[:, 0], xbar[:, 1], P, c - hc, {}))) / (2 * hc)
    np.testing.assert_allclose(Jc, num, atol=1e-6)


def test_beyond_90_degrees_equidistant_is_linear_in_theta():
    """r = c θ up to 179°: a ray at θ has its image at radius c θ along its azimuth."""
    mdl = get_ap_model("simple-fisheye")
    th = np.radians([10.0, 89.0, 90.0, 91.0, 135.0, 179.0])
    az = np.radians([30.0, -45.0, 100.0, 170.0, -120.0, 5.0])
    d = np.column_stack([np.sin(th) * np.cos(az), np.sin(th) * np.sin(az), -np.cos(th)])
    xy, valid = mdl.project_ray(d, np.zeros((6, 0)), 2.0, {})
    assert valid.all()
    # OpenCV frame: y down; baarda's y is up again, so the image azimuth is the ray's azimuth
    np.testing.assert_allclose(np.hypot(xy[:, 0], xy[:, 1]), 2.0 * th, rtol=1e-14)
    np.testing.assert_allclose(np.arctan2(xy[:, 1], xy[:, 0]), az, atol=1e-13)
    np.testing.assert_allclose(field_angle(d), np.degrees(th), rtol=1e-13)


@pytest.mark.parametrize("name,bad_deg", [("fisheye-orthographic", 95.0), ("simple-division", 80.0),
                                          ("eucm", 150.0), ("simple-fisheye", 180.0)])
def test_rays_a_model_cannot_represent_are_flagged(name, bad_deg):
    case = {c[0]: c for c in CASES}[name]
    mdl = get_ap_model(name)
    th = np.radians([20.0, bad_deg])
    d = np.column_stack([np.sin(th), np.zeros(2), -np.cos(th)])
    xy, valid = mdl.project_ray(d, np.broadcast_to(case[1], (2, len(case[1]))), case[2], {})
    assert valid.tolist() == [True, False]
    assert np.isfinite(xy[0]).all() and np.isnan(xy[1]).all()


def _one_photo_block(d):
    """One photo at the origin looking along −Z (ω = φ = κ = 0) and points at ``d``."""
    return dict(obs_photo=np.zeros(len(d), int), obs_point=np.arange(len(d)), XYZ=d, X0=np.zeros((1, 3)),
                opk=np.zeros((1, 3)), photo_camera=np.zeros(1, int))


def test_projector_stops_with_a_clear_error_outside_the_domain():
    d = np.array([[0.3, 0.1, -1.0], [1.0, 0.0, 0.5]])            # the second: 117° off axis
    cam_params = np.array([[1.8] + BROWN_AP])
    with pytest.raises(RayOutsideModel, match=r"fisheye-orthographic.*1 observed ray.*point index 1.*116\.6°"):
        project_observations(**_one_photo_block(d), cam_params=cam_params, cam_models=["fisheye-orthographic"])
    pr = project_observations(**_one_photo_block(d), cam_params=cam_params, cam_models=["fisheye-equidistant"])
    assert np.isfinite(pr.xy).all() and np.isfinite(pr.J_eo).all() and np.isfinite(pr.J_point).all()


@pytest.mark.parametrize("name", ["opencv-fisheye", "fov", "fisheye-equisolid", "equirectangular"])
def test_projector_jacobians_beyond_90_degrees(name):
    """Whole projection (pose, point, camera) against central differences, rays to 150° off axis and one
    exactly at 90° (W = 0), two photos with different cameras (a pinhole brown one among them)."""
    case = {c[0]: c for c in CASES}[name]
    rng = np.random.default_rng(5)
    XYZ = _rays(rng, 12, 150.0)
    XYZ[0] = [1.0, 0.5, 0.0]
    opk = np.array([[0.0, 0.0, 0.0], [0.02, -0.01, 0.3]])
    X0 = np.array([[0.0, 0.0, 0.0], [0.01, 0.02, 0.9]])
    obs_photo = np.r_[np.zeros(12, int), np.ones(12, int)]
    obs_point = np.r_[np.arange(12), np.arange(12)]
    ap = np.zeros((2, 7))
    ap[0, :len(case[1])] = case[1]
    ap[1] = BROWN_AP
    cam_params = np.column_stack([[case[2], 2.0], [0.01, -0.02], [0.02, 0.01], ap])
    models = [name, "brown"]
    # the brown camera sees only points in front of it
    pts_front = XYZ[:, 2] < 0.9 - 0.5
    obs_keep = (obs_photo == 0) | pts_front[obs_point]
    obs_photo, obs_point = obs_photo[obs_keep], obs_point[obs_keep]
    kw = dict(obs_photo=obs_photo, obs_point=obs_point, photo_camera=np.array([0, 1]), cam_models=models)
    pr = project_observations(XYZ=XYZ, X0=X0, opk=opk, cam_params=cam_params, **kw)
    assert np.isfinite(pr.J_eo).all() and np.isfinite(pr.J_cam).all()

    def xy(XYZ=XYZ, X0=X0, opk=opk, cam_params=cam_params):
        return project_observations(XYZ=XYZ, X0=X0, opk=opk, cam_params=cam_params, jacobians=False, **kw).xy

    h = 1e-6
    for ph in range(2):
        rows = obs_photo == ph
        for j in range(6):
            a, b = np.concatenate([X0, opk], 1), np.concatenate([X0, opk], 1)
            a[ph, j] += h
            b[ph, j] -= h
            num = (xy(X0=a[:, :3], opk=a[:, 3:]) - xy(X0=b[:, :3], opk=b[:, 3:])) / (2 * h)
            np.testing.assert_allclose(pr.J_eo[rows, :, j], num[rows], rtol=1e-5, atol=1e-7)
    for j in range(3):
        a, b = XYZ.copy(), XYZ.copy()
        a[:, j] += h
        b[:, j] -= h
        num = (xy(XYZ=a) - xy(XYZ=b)) / (2 * h)
        np.testing.assert_allclose(pr.J_point[:, :, j], num, rtol=1e-5, atol=1e-7)
    for j in range(cam_params.shape[1]):
        a, b = cam_params.copy(), cam_params.copy()
        hj = 1e-6 * max(1.0, abs(cam_params[0, j]))
        a[:, j] += hj
        b[:, j] -= hj
        num = (xy(cam_params=a) - xy(cam_params=b)) / (2 * hj)
        np.testing.assert_allclose(pr.J_cam[:, :, j], num, rtol=1e-5, atol=1e-6 * max(1, np.abs(num).max()))


def test_fov_small_omega_branch_of_colmap_has_the_undistortion_series():
    """COLMAP's FOV distortion for ω² < 10⁻⁴ uses 1 − ω²/12 + ω² r²/3 (its undistortion's series); the
    distortion's own series is 1 + ω²/12 − ω² r²/3, which baarda's exact formula follows."""
    w, r = 0.005, np.hypot(0.8, 0.3)
    cam = pycolmap.Camera.create_from_model_name(1, "FOV", 500.0, 640, 480)
    cam.params = [500, 500, 320, 240, w]
    colmap = (cam.img_from_cam(np.array([[0.8, 0.3, 1.0]]))[0, 0] - 320) / 500 / 0.8
    xy, _ = get_ap_model("fov").project_ray(np.array([[0.8, -0.3, -1.0]]), np.array([[0.0, w]]), 1.0, {})
    ours = xy[0, 0] / 0.8
    assert ours == pytest.approx(np.arctan(2 * np.tan(w / 2) * r) / (r * w), rel=1e-14)
    assert ours == pytest.approx(1 + w * w / 12 - w * w * r * r / 3, abs=1e-9)          # O(ω⁴) apart
    assert colmap == pytest.approx(1 - w * w / 12 + w * w * r * r / 3, abs=1e-12)
    assert abs(colmap - ours) > 7e-6                                      # ≈ ω² (r²·⅔ − ⅙)


def test_every_registered_ray_model_implements_its_hooks():
    """The base classes' ``_eval`` / ``_normalized`` are abstract methods: every registered ray
    model overrides them, and a class that does not cannot be instantiated (TypeError naming it)."""
    from baarda.pipeline.camera import ap_model_names, get_ap_model
    from baarda.pipeline.camera.ray_models import RayModel, _CVModel

    rays = [get_ap_model(n) for n in ap_model_names() if isinstance(get_ap_model(n), RayModel)]
    assert len(rays) >= 16
    for m in rays:
        assert type(m)._eval is not RayModel._eval, m.name
        if isinstance(m, _CVModel):
            assert type(m)._normalized is not _CVModel._normalized, m.name

    class Incomplete(RayModel):
        name = "incomplete"

    with pytest.raises(TypeError, match="Incomplete.*_eval"):
        Incomplete()

    class IncompleteCV(_CVModel):
        name = "incomplete-cv"

    with pytest.raises(TypeError, match="IncompleteCV.*_normalized"):
        IncompleteCV()
