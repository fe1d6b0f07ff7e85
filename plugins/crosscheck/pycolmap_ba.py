"""A baarda bundle as a pycolmap problem: reconstruction, solve, covariance, solution read back.

The reconstruction is built by :func:`baarda.pipeline.colmap.writer.reconstruction_from_block` (cameras
with one trivial rig, images with one trivial frame, one keypoint per observation, 3-D points
with tracks) from a copy of the block in which

* each camera's pixel is its a-priori σ (``plan.sigma_mm``) — pycolmap's unweighted cost then is
  baarda's weighted one (``docs/crosscheck.md``);
* the COLMAP model is the one the plan chose (set afterwards with
  :func:`baarda.pipeline.camera.convert.colmap_from_brown`);
* poses, points and intrinsics are the start values, except what the plan holds at baarda's
  adjusted values;
* "corrected" cameras become pinholes and their observations are corrected by baarda's adjusted
  distortion.

Everything here is numerics; nothing is logged.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from baarda.pipeline.geometry.rotations import rotation_from_rotvec

from baarda.pipeline.geometry.image import mm_from_pixels
from baarda.pipeline.geometry.pose import pose_from_cv
from baarda.pipeline.camera.convert import camera_from_colmap, colmap_from_brown
from baarda.pipeline.camera.ray_models import COLMAP_RAY_MODELS
from baarda.pipeline.api import reconstruction_from_block

from .plan import CrossCheckPlan, brown_vector

__all__ = ["SolverSettings", "PycolmapSolution", "RecMap", "build_reconstruction", "block_to_reconstruction",
           "solve_pycolmap", "run_adjuster", "read_solution", "block_with_solution", "estimate_covariance",
           "pose_covariance_baarda"]


@dataclass(frozen=True)
class SolverSettings:
    """Ceres settings of pycolmap's bundle adjustment (tight by default: we compare optima)."""

    max_iter: int = 200
    function_tolerance: float = 1e-15
    gradient_tolerance: float = 1e-15
    parameter_tolerance: float = 1e-15
    num_threads: int = -1
    covariance: bool = True


@dataclass
class RecMap:
    """Where each block item sits in the reconstruction."""

    image_id: np.ndarray        # (m,) image id per photo (0 = not in the reconstruction)
    camera_id: np.ndarray       # (K,)
    point3D_id: np.ndarray      # (n,) (0 = not in the reconstruction)
    obs_point2D: np.ndarray     # (k,) keypoint index of each observation in its image (-1 unused)
    size: np.ndarray            # (K, 2) σ-pixel grid of each camera
    xy_used: np.ndarray         # (k, 2) observations as given to pycolmap (mm; corrected where planned)
    rig_sensors: object = None  # the block's RigSensors (rigs only)


@dataclass
class PycolmapSolution:
    """pycolmap's result in baarda's terms (block units, baarda's conventions)."""

    X0: np.ndarray              # (m, 3) (nan: photo not in the problem)
    opk: np.ndarray             # (m, 3)
    XYZ: np.ndarray             # (n, 3)
    cam: list                   # per camera: dict(c, xp, yp, ap (7,) brown) or None
    residuals: np.ndarray       # (k, 2) observed − computed, mm (nan: unused)
    initial_cost: float
    final_cost: float
    iterations: int
    termination: str
    seconds: float
    setup_seconds: float
    cov_eo: np.ndarray | None = None        # (m, 6, 6) X0 Y0 Z0 ω φ κ, σ = 1 pixel (unscaled)
    cov_cameras: list | None = None         # per camera: (names, (p, p)) in baarda's parameters, unscaled
    covariance_seconds: float = float("nan")
    message: str = ""
    extra: dict = field(default_factory=dict)


def _grid(block, j, sigma) -> tuple[int, int]:
    """An integer σ-pixel image size covering camera ``j``'s format (or its observations)."""
    cams = block.cameras
    fmt = np.asarray(cams.format_mm[j], float)
    if not (np.isfinite(fmt).all() and (fmt > 0).all()):
        obs = block.observations
        sel = block.photos.camera[obs.photo] == j
        ext = np.abs(obs.xy[sel]).max(axis=0) if sel.any() else np.ones(2)
        fmt = 2.0 * ext + 2.0 * sigma
    return tuple(int(v) for v in np.maximum(2, np.ceil(fmt / sigma)).astype(int))


def corrected_observations(result, plan: CrossCheckPlan) -> np.ndarray:
    """Observations (k, 2) mm; for "corrected" cameras ``l − Δ(x̄̂)`` with baarda's adjusted AP
    model at its adjusted ideal reduced coordinates (so that v = (l − Δ̂) − pinhole exactly)."""
    from baarda.pipeline.adjustment import project_observations

    block = result.block_in
    obs = block.observations
    xy = np.array(obs.xy, float)
    bad = [p.index for p in plan.cameras if p.mode == "corrected"]
    if not bad:
        return xy
    st = result.state
    rows = np.flatnonzero(np.isin(block.photos.camera[obs.photo], bad) & plan.obs_used)
    full = project_observations(obs.photo[rows], obs.point[rows], st.XYZ, st.X0, st.opk, block.photos.camera,
                                st.cam_params, block.cameras.ap_model, result.camera_meta, jacobians=False)
    cam = block.photos.camera[obs.photo[rows]]
    pinhole = full.xbar + st.cam_params[cam, 1:3]
    xy[rows] -= full.xy - pinhole
    return xy


def start_block(result, plan: CrossCheckPlan, start, *, xy=None):
    """The block pycolmap starts from: ``start`` (a Block with the start values) with held items at
    baarda's adjusted values, each camera's pixel = σ, the plan's camera modes applied."""
    adj = result.block
    cams0 = start.cameras
    K = len(cams0)
    c = np.array(cams0.c, float)
    xp, yp = np.array(cams0.xp, float), np.array(cams0.yp, float)
    ap = np.zeros((K, max(7, cams0.ap.shape[1])))
    models = []
    for p in plan.cameras:
        j = p.index
        src = cams0 if p.mode == "refine" else adj.cameras
        c[j], xp[j], yp[j] = src.c[j], src.xp[j], src.yp[j]
        bv = brown_vector(src, j)
        if p.colmap_model in COLMAP_RAY_MODELS and p.mode != "unused":      # a ray model: its own parameters
            ap[j, :src.ap.shape[1]] = src.ap[j]
            models.append(str(src.ap_model[j]))
        elif p.mode == "corrected" or bv is None:
            models.append("none")
        else:
            ap[j] = bv
            models.append("brown")
    sigma = np.where(np.isfinite(plan.sigma_mm), plan.sigma_mm, 1.0)
    size = np.array([_grid(result.block_in, j, sigma[j]) for j in range(K)], int).reshape(-1, 2)
    cameras = cams0.replace(c=c, xp=xp, yp=yp, ap_model=np.array(models, dtype=str), ap=ap,
                            sigma_ap=np.zeros_like(ap), pixel_mm=sigma, resolution=size)
    ph = start.photos
    X0 = np.where(plan.photo_held[:, None], adj.photos.X0, ph.X0)
    opk = np.where(plan.photo_held[:, None], adj.photos.opk, ph.opk)
    XYZ = np.where(plan.point_held[:, None], adj.points.XYZ, start.points.XYZ)
    obs = start.observations
    obs = obs.replace(active=plan.obs_used, xy=obs.xy if xy is None else xy)
    meta = {}       # no source's private data: the COLMAP writer numbers cameras, images and points afresh
    out = start.replace(cameras=cameras, photos=ph.replace(X0=X0, opk=opk), points=start.points.replace(XYZ=XYZ),
                        observations=obs, meta=meta)
    if plan.sensor_constant is not None:
        out = out.replace(rigs=_start_rigs(result, plan, out))
    return out, size


def _start_rigs(result, plan: CrossCheckPlan, blk):
    """The rigs pycolmap starts from: held sensors at baarda's adjusted pose, the others at the
    rig table's pose or, where it has none, at the start (``initial_rig_state`` of the start photos;
    docs/rigs.md)."""
    from baarda.pipeline.adjustment import initial_rig_state

    struct = result.rig
    rs = blk.rigs.sensors
    adj = result.block.rigs.sensors
    _, start = initial_rig_state(struct, rs, blk.photos.X0, blk.photos.opk)
    pose = np.where(plan.sensor_held[:, None], np.c_[adj.centre, adj.opk], start)
    return blk.rigs.replace(sensors=rs.replace(centre=pose[:, :3], opk=pose[:, 3:]))


def build_reconstruction(result, plan: CrossCheckPlan, start):
    """``(reconstruction, RecMap)`` of the cross-check's pycolmap problem (module docstring).

    A constant 3-D point seen in one image only (a control point with one ray: sxb's 403, odm's
    HV18) gets a second observation with a zero residual in an image of its own camera, both
    constant (:func:`twin_single_tracks`): pycolmap refuses a track of length one
    (``Check failed: point3D.track.Length() > 1``) although such a point constrains its photo."""
    xy = corrected_observations(result, plan)
    blk, size = start_block(result, plan, start, xy=xy)
    models = [None if p.mode == "unused" else p.colmap_model for p in plan.cameras]
    rec, recmap = block_to_reconstruction(blk, models, size)
    twin_single_tracks(rec, recmap.point3D_id[plan.point_constant & (recmap.point3D_id > 0)])
    return rec, recmap


def twin_single_tracks(rec, constant_ids) -> int:
    """Give every constant 3-D point of ``rec`` (ids ``constant_ids``) that is observed in one image
    a second observation in an extra image of an extra camera (SIMPLE_PINHOLE, f 1000 px, 1000 × 1000),
    identity rotation, the point 10 units straight ahead, so it projects exactly onto the keypoint
    (500, 500): a zero residual.  The extra image is in no adjuster configuration, so COLMAP holds
    its pose constant; the point is constant: neither the cost nor any variable's gradient changes.
    Returns how many points were twinned."""
    import pycolmap

    constant = {int(i) for i in np.asarray(constant_ids).ravel()}
    n = 0
    for pid, p3 in list(rec.points3D.items()):
        if p3.track.length() > 1 or int(pid) not in constant:
            continue
        cid, iid = max(rec.cameras) + 1, max(rec.images) + 1
        rec.add_camera_with_trivial_rig(pycolmap.Camera.create_from_model_name(cid, "SIMPLE_PINHOLE", 1000.0,
                                                                                1000, 1000))
        image = pycolmap.Image(name=f"twin of point3D {pid}", keypoints=np.array([[500.0, 500.0]]),
                               camera_id=cid, image_id=iid)
        t = np.array([0.0, 0.0, 10.0]) - np.asarray(p3.xyz, float)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(np.eye(3)), t))
        rec.add_observation(pid, pycolmap.TrackElement(iid, 0))
        n += 1
    return n


def block_to_reconstruction(blk, models, size=None):
    """``(reconstruction, RecMap)`` of a block whose cameras are "none"/"brown" with a pixel pitch.

    The writer (:func:`baarda.pipeline.colmap.writer.reconstruction_from_block`, on a copy without the
    source's private ``meta``, so ids are 1, 2, … in block order and each active observation is one keypoint) builds
    cameras, rigs, frames, images and tracks; camera ``j`` then gets the COLMAP model
    ``models[j]`` (None: keep the writer's choice) with :func:`colmap_from_brown`.  ``size``
    (K, 2) overrides the cameras' resolution (the pixel grid).
    """
    import pycolmap

    if size is not None:
        blk = blk.replace(cameras=blk.cameras.replace(resolution=np.asarray(size, int)))
    blk = blk.replace(meta={})      # no source's private data (a COLMAP model's ids): ids 1, 2, … in block order
    size = np.asarray(blk.cameras.resolution, int)
    rec, info = reconstruction_from_block(blk, camera_model="auto")
    cams, photos, obs = blk.cameras, blk.photos, blk.observations
    camera_id = np.arange(1, len(cams) + 1)
    image_id = np.where(photos.has_orientation, np.arange(1, len(photos) + 1), 0)
    for j, want in enumerate(models):
        if want is None or want in COLMAP_RAY_MODELS:      # the writer wrote a ray model's own COLMAP model
            continue
        model, params = colmap_from_brown(cams.c[j], cams.xp[j], cams.yp[j], cams.ap[j], tuple(size[j]),
                                          cams.pixel_mm[j], want)
        cam = rec.cameras[int(camera_id[j])]
        if cam.model.name != model:
            cam.model = getattr(pycolmap.CameraModelId, model)
        cam.params = params
    # keypoint index: rank of the observation among all observations of its photo (writer's rule)
    kp = np.full(len(obs), -1)
    by_photo = [np.flatnonzero(obs.photo == k) for k in range(len(photos))]
    for rows in by_photo:
        kp[rows] = np.arange(rows.size)
    point3D_id = np.zeros(len(blk.points), int)
    for pid, p3 in rec.points3D.items():
        js = {int(obs.point[by_photo[int(el.image_id) - 1][el.point2D_idx]]) for el in p3.track.elements}
        if len(js) != 1:
            raise RuntimeError(f"reconstruction_from_block changed its keypoint order: point3D {pid} maps to {js}")
        point3D_id[js.pop()] = pid
    in_rec = obs.active & (image_id[obs.photo] > 0) & (point3D_id[obs.point] > 0)
    recmap = RecMap(image_id=image_id, camera_id=camera_id, point3D_id=point3D_id,
                    obs_point2D=np.where(in_rec, kp, -1), size=size, xy_used=np.array(obs.xy, float),
                    rig_sensors=blk.rigs.sensors if blk.rigs else None)
    return rec, recmap


def ba_options(refine: dict, solver: SolverSettings):
    """pycolmap ``BundleAdjustmentOptions`` with the refine switches and Ceres settings."""
    import pycolmap

    opts = pycolmap.BundleAdjustmentOptions()
    opts.refine_focal_length = bool(refine["focal"])
    opts.refine_principal_point = bool(refine["principal_point"])
    opts.refine_extra_params = bool(refine["extra"])
    opts.print_summary = False
    so = opts.ceres.solver_options
    so.max_num_iterations = solver.max_iter
    so.function_tolerance = solver.function_tolerance
    so.gradient_tolerance = solver.gradient_tolerance
    so.parameter_tolerance = solver.parameter_tolerance
    so.num_threads = solver.num_threads
    return opts


def _config(rec, recmap: RecMap, plan: CrossCheckPlan):
    import pycolmap

    config = pycolmap.BundleAdjustmentConfig()
    used_ph = plan.photo_variable | plan.photo_constant
    for k in np.flatnonzero(used_ph):
        config.add_image(int(recmap.image_id[k]))
    for k in np.flatnonzero(plan.photo_constant):
        config.set_constant_rig_from_world_pose(int(rec.images[int(recmap.image_id[k])].frame_id))
    for j in np.flatnonzero(plan.point_constant & (recmap.point3D_id > 0)):
        config.add_constant_point(int(recmap.point3D_id[j]))
    for p in plan.cameras:
        if p.mode != "unused" and not p.refined:
            config.set_constant_cam_intrinsics(int(recmap.camera_id[p.index]))
    if plan.sensor_constant is not None:        # rigs: sensors fixed in baarda or held (docs/rigs.md)
        rs = recmap.rig_sensors
        for i in np.flatnonzero(plan.sensor_constant & ~rs.reference):
            config.set_constant_sensor_from_rig_pose(
                pycolmap.sensor_t(type=pycolmap.SensorType.CAMERA, id=int(recmap.camera_id[rs.camera[i]])))
    return config


def run_adjuster(rec, config, refine: dict, solver: SolverSettings | None = None):
    """Run pycolmap's Ceres bundle adjuster on ``rec`` (in place) with ``config``.

    Returns ``(summary dict, adjuster)``: initial/final cost (½ Σ ‖r‖², pixels), iterations
    (successful + unsuccessful steps), termination, solve seconds (``adjuster.solve()`` only) and
    set-up seconds (options, config, problem construction)."""
    import pycolmap

    solver = solver or SolverSettings()
    pycolmap.logging.minloglevel = 2
    t0 = time.perf_counter()
    opts = ba_options(refine, solver)
    adjuster = pycolmap.create_default_ceres_bundle_adjuster(opts, config, rec)
    t1 = time.perf_counter()
    summary = adjuster.solve()
    t2 = time.perf_counter()
    cs = summary.ceres_summary
    out = {"initial_cost": float(cs.initial_cost), "final_cost": float(cs.final_cost),
           "iterations": int(cs.num_successful_steps + cs.num_unsuccessful_steps),
           "termination": str(cs.termination_type).split(".")[-1], "message": str(cs.message),
           "seconds": t2 - t1, "setup_seconds": t1 - t0, "usable": bool(summary.is_solution_usable()),
           "linear_solver": str(cs.linear_solver_type_used).split(".")[-1],
           "num_residuals": int(cs.num_residuals), "threads": int(cs.num_threads_used)}
    return out, adjuster


def solve_pycolmap(rec, recmap: RecMap, plan: CrossCheckPlan, solver: SolverSettings | None = None):
    """The cross-check's pycolmap solve (constants and refine switches from the plan)."""
    t0 = time.perf_counter()
    config = _config(rec, recmap, plan)
    t_config = time.perf_counter() - t0
    out, adjuster = run_adjuster(rec, config, plan.refine, solver)
    out["setup_seconds"] += t_config
    return out, adjuster


def read_solution(rec, recmap: RecMap, sigma_mm, block) -> dict:
    """Poses, points, cameras (brown, mm) and residuals (mm) of the solved reconstruction.

    ``sigma_mm`` (K,) is each camera's pixel in the reconstruction (mm)."""
    m, n, k = len(block.photos), len(block.points), len(block.observations)
    X0 = np.full((m, 3), np.nan)
    opk = np.full((m, 3), np.nan)
    for i in np.flatnonzero(recmap.image_id > 0):
        cfw = rec.images[int(recmap.image_id[i])].cam_from_world()
        X0[i], opk[i] = pose_from_cv(cfw.rotation.matrix(), cfw.translation)
    XYZ = np.full((n, 3), np.nan)
    for j in np.flatnonzero(recmap.point3D_id > 0):
        XYZ[j] = rec.points3D[int(recmap.point3D_id[j])].xyz
    used_cam = np.zeros(len(block.cameras), bool)
    used_cam[block.photos.camera[block.observations.photo[recmap.obs_point2D >= 0]]] = True
    cam = []
    for j in range(len(block.cameras)):
        if not used_cam[j]:
            cam.append(None)
            continue
        cc = rec.cameras[int(recmap.camera_id[j])]
        b = camera_from_colmap(cc.model.name, np.asarray(cc.params), tuple(recmap.size[j]), sigma_mm[j])
        cam.append({"c": b["c"], "xp": b["xp"], "yp": b["yp"], "ap": b["ap"], "model": cc.model.name,
                    "names": b["names"], "ap_model": b["ap_model"], "params": np.array(cc.params, float)})
    res = np.full((k, 2), np.nan)
    obs = block.observations
    for i in np.flatnonzero(recmap.image_id > 0):
        rows = np.flatnonzero((obs.photo == i) & (recmap.obs_point2D >= 0))
        if rows.size == 0:
            continue
        im = rec.images[int(recmap.image_id[i])]
        camera = rec.cameras[im.camera_id]
        cfw = im.cam_from_world()
        pc = XYZ[obs.point[rows]] @ cfw.rotation.matrix().T + cfw.translation
        uv = np.asarray(camera.img_from_cam(pc, check_cheirality=False), float).reshape(-1, 2)
        kp = np.array([im.points2D[int(t)].xy for t in recmap.obs_point2D[rows]], float).reshape(-1, 2)
        j = block.photos.camera[i]
        size = recmap.size[j]
        res[rows] = (mm_from_pixels(kp, size, sigma_mm[j], "colmap")
                     - mm_from_pixels(uv, size, sigma_mm[j], "colmap"))
    out = {"X0": X0, "opk": opk, "XYZ": XYZ, "cam": cam, "residuals": res}
    if recmap.rig_sensors is not None:
        out["sensor"] = _read_sensors(rec, recmap)
    return out


def _read_sensors(rec, recmap: RecMap) -> np.ndarray:
    """(S, 6) each rig sensor's pose in its rig as baarda writes it (centre ``−F Rᵀ t``, ω φ κ of
    ``F R F``; the reference sensor 0; nan where pycolmap has none), from the solved rigs."""
    from baarda.pipeline.geometry import opk_from_rotation

    rs = recmap.rig_sensors
    F = np.diag([1.0, -1.0, -1.0])
    out = np.full((len(rs), 6), np.nan)
    by_cam = {}
    for rig in rec.rigs.values():
        for sid, pose in rig.non_ref_sensors.items():
            by_cam[int(sid.id)] = pose
    for i in range(len(rs)):
        if rs.reference[i]:
            out[i] = 0.0
            continue
        pose = by_cam.get(int(recmap.camera_id[rs.camera[i]]))
        if pose is None:
            continue
        R = np.asarray(pose.rotation.matrix(), float)
        out[i, :3] = -F @ R.T @ np.asarray(pose.translation, float)
        out[i, 3:] = opk_from_rotation(F @ R @ F)
    return out


def block_with_solution(block, sol: dict):
    """``block`` with pycolmap's cameras (brown), poses and points (where it has them)."""
    cams = block.cameras
    c, xp, yp = np.array(cams.c, float), np.array(cams.xp, float), np.array(cams.yp, float)
    ap = np.array(cams.ap, float)
    for j, cj in enumerate(sol["cam"]):
        if cj is None:
            continue
        c[j], xp[j], yp[j] = cj["c"], cj["xp"], cj["yp"]
        if str(cams.ap_model[j]) in ("brown", cj.get("ap_model")):
            p = min(ap.shape[1], len(cj["ap"]))
            ap[j, :p] = cj["ap"][:p]
    ph, pts = block.photos, block.points
    ok_ph = np.isfinite(sol["X0"]).all(axis=1)
    ok_pt = np.isfinite(sol["XYZ"]).all(axis=1)
    return block.replace(cameras=cams.replace(c=c, xp=xp, yp=yp, ap=ap),
                         photos=ph.replace(X0=np.where(ok_ph[:, None], sol["X0"], ph.X0),
                                           opk=np.where(ok_ph[:, None], sol["opk"], ph.opk)),
                         points=pts.replace(XYZ=np.where(ok_pt[:, None], sol["XYZ"], pts.XYZ)))


# --------------------------------------------------------------------------------------------
# covariance: pycolmap's tangent spaces → baarda's parameters


def pose_covariance_baarda(cov_tangent: np.ndarray, R_cv: np.ndarray, t: np.ndarray, h: float = 1e-7) -> np.ndarray:
    """(6, 6) covariance of ``(X0, Y0, Z0, ω, φ, κ)`` from pycolmap's cam_from_world covariance.

    pycolmap orders the tangent space [rotation δ (3), translation (3)]; Ceres'
    ``EigenQuaternionManifold`` perturbs the rotation on the left with the quaternion
    ``(cos|δ|, sin|δ| δ/|δ|)`` — a rotation by ``2δ``: ``R' = exp([2δ]×) R``; ``t' = t + dt``.
    The Jacobian to baarda's parameters is taken by central differences (step ``h``).
    """
    R_cv = np.asarray(R_cv, float)
    t = np.asarray(t, float)

    def f(z):
        R = rotation_from_rotvec(2.0 * z[:3])[0] @ R_cv
        X0, opk = pose_from_cv(R, t + z[3:])
        return np.concatenate([X0, opk])

    J = np.zeros((6, 6))
    for a in range(6):
        e = np.zeros(6)
        e[a] = h
        d = f(e) - f(-e)
        d[3:] = (d[3:] + np.pi) % (2 * np.pi) - np.pi
        J[:, a] = d / (2 * h)
    return J @ cov_tangent @ J.T


def camera_covariance_baarda(cov_params: np.ndarray, model: str, params: np.ndarray, free_idx: np.ndarray,
                             size, pitch: float, names: list, h: float = 1e-7) -> np.ndarray:
    """Covariance of baarda's ``names`` (from c, xp, yp, K1 … B2) from pycolmap's covariance of the
    free COLMAP parameters ``params[free_idx]`` (central differences through camera_from_colmap)."""
    order = ["c", "xp", "yp", *camera_from_colmap(model, params, size, pitch)["names"]]
    pick = [order.index(n) for n in names]

    def f(p):
        b = camera_from_colmap(model, p, size, pitch)
        return np.concatenate([[b["c"], b["xp"], b["yp"]], b["ap"]])[pick]

    J = np.zeros((len(names), len(free_idx)))
    for a, i in enumerate(free_idx):
        step = h * max(1.0, abs(params[i]))
        pp, pm = params.copy(), params.copy()
        pp[i] += step
        pm[i] -= step
        J[:, a] = (f(pp) - f(pm)) / (2 * step)
    return J @ cov_params @ J.T


def estimate_covariance(rec, adjuster, recmap: RecMap, plan: CrossCheckPlan, block) -> dict:
    """pycolmap's covariance (σ = 1 pycolmap pixel, i.e. σ0 = 1) of poses and refined intrinsics,
    in baarda's parameters.  Returns ``{"cov_eo": (m, 6, 6) nan where unavailable, "cov_cameras":
    {j: (names, C)}, "seconds"}`` or ``{"error": text}``."""
    import pycolmap

    t0 = time.perf_counter()
    if block.rigs:
        return {"error": "pycolmap 4.2's covariance estimation takes no rigs (it checks that every image is its "
                         "frame's reference); compared without covariances", "seconds": 0.0}
    opts = pycolmap.BACovarianceOptions()
    try:
        cov = pycolmap.estimate_ba_covariance(opts, rec, adjuster)
    except Exception as e:   # pycolmap raises on rank-deficient problems
        return {"error": f"{type(e).__name__}: {e}", "seconds": time.perf_counter() - t0}
    if cov is None:
        return {"error": "pycolmap's covariance estimation failed (returned None)", "seconds": time.perf_counter() - t0}
    m = len(block.photos)
    cov_eo = np.full((m, 6, 6), np.nan)
    for i in np.flatnonzero(plan.photo_variable & (recmap.image_id > 0)):
        iid = int(recmap.image_id[i])
        C = cov.get_cam_cov_from_world(iid)
        if C is None or np.asarray(C).shape != (6, 6):
            continue
        cfw = rec.images[iid].cam_from_world()
        cov_eo[i] = pose_covariance_baarda(np.asarray(C), cfw.rotation.matrix(), cfw.translation)
    cams = {}
    for p in plan.cameras:
        if not p.refined:
            continue
        cc = rec.cameras[int(recmap.camera_id[p.index])]
        free = []
        if plan.refine["focal"]:
            free += list(cc.focal_length_idxs())
        if plan.refine["principal_point"]:
            free += list(cc.principal_point_idxs())
        if plan.refine["extra"]:
            free += list(cc.extra_params_idxs())
        free = np.array(sorted(free), int)
        C = cov.get_other_params_cov(cc.params)
        if C is None or np.asarray(C).shape != (free.size, free.size):
            continue
        names = [n for n, g in _param_groups(cc.model.name) if p.groups.get(g)]
        Cb = camera_covariance_baarda(np.asarray(C), cc.model.name, np.array(cc.params, float), free,
                                      tuple(recmap.size[p.index]), plan.sigma_mm[p.index], names)
        cams[p.index] = (names, Cb)
    return {"cov_eo": cov_eo, "cov_cameras": cams, "seconds": time.perf_counter() - t0}


def _param_groups(model: str):
    from .plan import _groups

    return [(n, g) for g, members in _groups(model).items() for n in members]
