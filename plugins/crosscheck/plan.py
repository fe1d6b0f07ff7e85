"""Which parts of a baarda bundle pycolmap can reproduce exactly, and how (pure bookkeeping).

pycolmap 4.2.1 (without ``pyceres``) offers: per camera one COLMAP model; three *global*
switches for the intrinsics (focal length(s), principal point, all extra parameters); per camera
"intrinsics constant"; per frame "pose constant"; per 3-D point "constant"; and one unweighted
cost ½ Σ ‖r‖² in pixels.  It has no weighted constraints (priors), no partly fixed points or
poses, no distances and no inner constraints.

The plan maps a converged :class:`baarda.pipeline.adjustment.BundleResult` onto that:

* cameras (``mode``):
  ``"refine"`` — a COLMAP model holds the AP model exactly and its parameter groups are free or
  fixed exactly as in baarda (the intrinsics are compared);
  ``"constant"`` — the camera can be written exactly, but its free/fixed pattern cannot be
  reproduced (or differs from the global pattern of the other cameras): the intrinsics are
  held at baarda's adjusted values;
  ``"corrected"`` — no COLMAP model holds the AP model (Ebner, AICON's balanced radial with
  affinity, brown with B2 or B1 together with distortion): each observation is corrected by
  baarda's adjusted distortion at baarda's adjusted ideal image point, the camera is a constant
  pinhole (c, xp, yp) — first-order equivalent only.
* everything baarda adjusts with terms pycolmap lacks (weighted or partly fixed control points,
  points of distances, weighted or partly fixed exterior orientations, weighted intrinsics) is
  **held at baarda's adjusted values**.  Holding parameters at their values in the optimum
  leaves the optimum of the others unchanged (the restricted problem's gradient vanishes
  there), so the remaining quantities still have to agree exactly.
* a free network (inner constraints) gets its gauge the same way: two photos held at baarda's
  adjusted poses.
* weights: pycolmap's pixel of camera j is chosen as the a-priori σ_j (mm) of the camera's
  observations, so that its cost ½ Σ ‖r‖² equals baarda's ½ vᵀPv / σ0² — exact when every
  active observation of a camera has the covariance σ_j² I.  Otherwise σ_j is the RMS σ and
  the weights are not equivalent.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from baarda.pipeline.camera.convert import BROWN, FREE_BROWN, UnsupportedCamera, colmap_from_brown
from baarda.pipeline.camera.ray_models import COLMAP_RAY_MODELS

__all__ = ["CameraPlan", "CrossCheckPlan", "plan_crosscheck", "behind_camera", "MODEL_ORDER", "brown_vector"]

MODEL_ORDER = ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "PINHOLE", "OPENCV", "FULL_OPENCV")
"""COLMAP models tried for a camera, simplest first."""

DISTORTION = ("K1", "K2", "K3", "P1", "P2")


def brown_vector(cameras, j: int) -> np.ndarray | None:
    """The brown parameters (7,) of camera ``j`` (zeros for ``"none"``), None for other AP models."""
    model = str(cameras.ap_model[j])
    if model == "none":
        return np.zeros(len(BROWN))
    if model == "brown":
        ap = np.asarray(cameras.ap[j], float)
        return np.concatenate([ap, np.zeros(max(0, len(BROWN) - ap.size))])[:len(BROWN)]
    return None


@dataclass
class CameraPlan:
    """How camera ``index`` enters pycolmap."""

    index: int
    id: str
    mode: str                       # "refine" | "constant" | "corrected" | "unused"
    colmap_model: str
    groups: dict = field(default_factory=dict)   # focal / principal_point / extra -> True, False or None (empty)
    note: str = ""

    @property
    def refined(self) -> bool:
        return self.mode == "refine" and any(v for v in self.groups.values())


@dataclass
class CrossCheckPlan:
    """The mapping of one baarda adjustment onto pycolmap (see the module docstring)."""

    cameras: list
    refine: dict                     # global pycolmap switches: focal / principal_point / extra
    sigma_mm: np.ndarray             # (K,) pycolmap's pixel of each camera = a-priori σ (mm)
    weights_equivalent: bool
    obs_used: np.ndarray             # (k,) observations in pycolmap (baarda's used observations)
    point_variable: np.ndarray       # (n,) bool, adjusted by pycolmap from the start values
    point_constant: np.ndarray       # (n,) bool, constant (fixed in baarda, or held)
    point_held: np.ndarray           # (n,) bool, held at baarda's adjusted values (subset of constant)
    photo_variable: np.ndarray       # (m,)
    photo_constant: np.ndarray       # (m,)
    photo_held: np.ndarray           # (m,)
    datum: str
    datum_equivalent: bool = True
    behind: np.ndarray | None = None   # (k,) observations of points behind their camera (COLMAP: zero residual)
    notes: list = field(default_factory=list)
    sensor_constant: np.ndarray | None = None   # (S,) rig sensors held constant (fixed, or held; docs/rigs.md)
    sensor_held: np.ndarray | None = None       # (S,) held at baarda's adjusted pose (weighted in baarda)

    @property
    def exact(self) -> bool:
        """Points, poses and residuals must agree to rounding (weights equal, no corrected camera)."""
        return (self.weights_equivalent and self.datum_equivalent
                and (self.behind is None or not self.behind.any())
                and not any(c.mode == "corrected" for c in self.cameras))

    @property
    def covariance_comparable(self) -> bool:
        """pycolmap's marginal pose/intrinsics covariances are baarda's: same problem, same gauge."""
        return (self.exact and self.datum == "control" and not self.point_held.any()
                and not self.photo_held.any() and all(c.mode in ("refine", "unused") for c in self.cameras)
                and self.sensor_constant is None)


def _status(sigma: float) -> str:
    return "fixed" if sigma == 0 else ("free" if np.isinf(sigma) else "weighted")


def _ray_classes() -> dict:
    """baarda ray-model name → its class (COLMAP's fisheye, FOV, EUCM, division, equirectangular models)."""
    return {cls.name: cls for cls in COLMAP_RAY_MODELS.values()}


def _groups(model: str) -> dict:
    if model in COLMAP_RAY_MODELS:                 # a ray model: COLMAP's own parameters (docs/camera-models.md)
        cls = COLMAP_RAY_MODELS[model]
        if model == "EQUIRECTANGULAR":
            return {"focal": (), "principal_point": (), "extra": ()}
        return {"focal": ("c", "B1") if cls.focal2 else ("c",), "principal_point": ("xp", "yp"),
                "extra": tuple(cls.extra)}
    focal = ("c", "B1") if "B1" in FREE_BROWN[model] else ("c",)
    extra = tuple(n for n in BROWN if n in FREE_BROWN[model] and n != "B1")
    return {"focal": focal, "principal_point": ("xp", "yp"), "extra": extra}


def _refine_model(status: dict, active: set) -> tuple[str, dict] | None:
    """The simplest COLMAP model whose parameter groups reproduce baarda's free/fixed pattern."""
    for model in MODEL_ORDER:
        holds = set(FREE_BROWN[model])
        if not active <= holds:
            continue
        if "B1" in active and active & set(DISTORTION):
            continue            # OPENCV's fx ≠ fy scales the distortion too: not brown's B1
        flags, ok = {}, True
        for g, members in _groups(model).items():
            st = {status.get(n, "fixed") for n in members}
            if len(st) > 1 or "weighted" in st:
                ok = False
                break
            flags[g] = (st == {"free"}) if members else None
        if ok and model == "FULL_OPENCV" and flags["extra"]:
            ok = False          # refining FULL_OPENCV's extras frees k4 … k6 too (rational model)
        if ok:
            return model, flags
    return None


def _camera_plan(j, cams, result, names, ap_start, ap_adj, used) -> CameraPlan:
    cid = str(cams.ids[j])
    if not used:
        return CameraPlan(j, cid, "unused", "SIMPLE_PINHOLE", note="no observation in the adjustment")
    model = str(cams.ap_model[j])
    if model in _ray_classes():
        return _ray_camera_plan(j, cid, result, names, _ray_classes()[model].colmap)
    if ap_start is None or ap_adj is None:
        return CameraPlan(j, cid, "corrected", "SIMPLE_PINHOLE",
                          note=f"AP model '{model}' has no COLMAP counterpart: observations corrected by baarda's "
                               "adjusted distortion, c, xp, yp held (first-order comparison)")
    status = {n: _status(result.camera_sigma[j, t]) for t, n in enumerate(names)}
    if model == "none":
        status.update({n: "fixed" for n in BROWN})
    active = {n for t, n in enumerate(BROWN)
              if status.get(n) != "fixed" or ap_start[t] != 0.0 or ap_adj[t] != 0.0}
    found = _refine_model(status, active)
    if found is not None:
        return CameraPlan(j, cid, "refine", found[0], groups=found[1])
    free = [n for n in names if status.get(n) != "fixed"]
    why = (f"free parameters {', '.join(free) or 'none'} (non-zero or free: {', '.join(sorted(active)) or 'none'}) "
           "cannot be reproduced by COLMAP's refine switches")
    try:
        size = (1000, 1000)
        cmodel, _ = colmap_from_brown(result.block_in.cameras.c[j], 0.0, 0.0, ap_adj, size, 1.0, "auto")
    except (UnsupportedCamera, ValueError) as e:
        return CameraPlan(j, cid, "corrected", "SIMPLE_PINHOLE",
                          note=f"{why}, and the adjusted camera has no exact COLMAP model ({e}): observations "
                               "corrected by baarda's adjusted distortion, c, xp, yp held (first-order comparison)")
    return CameraPlan(j, cid, "constant", cmodel, note=f"{why}: intrinsics held at baarda's adjusted values")


def _ray_camera_plan(j, cid, result, names, colmap_model) -> CameraPlan:
    """A camera with a COLMAP ray model: refined when each of COLMAP's parameter groups (focal
    length(s), principal point, extra parameters) is wholly free or wholly fixed in baarda, else held."""
    status = {n: _status(result.camera_sigma[j, t]) for t, n in enumerate(names)}
    flags, ok = {}, True
    for g, members in _groups(colmap_model).items():
        st = {status.get(n, "fixed") for n in members}
        if len(st) > 1 or "weighted" in st:
            ok = False
            break
        flags[g] = (st == {"free"}) if members else None
    if colmap_model == "EQUIRECTANGULAR" and any(s != "fixed" for s in status.values()):
        ok = False
    if ok:
        return CameraPlan(j, cid, "refine", colmap_model, groups=flags)
    free = [n for n in names if status.get(n) != "fixed"]
    return CameraPlan(j, cid, "constant", colmap_model,
                      note=f"free parameters {', '.join(free) or 'none'} cannot be reproduced by COLMAP's refine "
                           "switches: intrinsics held at baarda's adjusted values")


def _merge_global(plans: list) -> dict:
    """Global refine switches from the cameras that refine something; demote incompatible ones."""
    glob: dict = {"focal": None, "principal_point": None, "extra": None}
    for p in plans:
        if not p.refined:
            continue
        clash = [g for g, v in p.groups.items() if v is not None and glob[g] is not None and glob[g] != v]
        if clash:
            p.mode = "constant"
            p.note = (f"its refine pattern ({', '.join(f'{g}={p.groups[g]}' for g in clash)}) differs from the other "
                      "cameras' and pycolmap's switches are global: intrinsics held at baarda's adjusted values")
            continue
        for g, v in p.groups.items():
            if v is not None:
                glob[g] = v
    return {g: bool(v) for g, v in glob.items()}


def _weights(block, result) -> tuple[np.ndarray, bool, list]:
    """pycolmap pixel (σ, mm) per camera and whether baarda's weights are reproduced exactly."""
    obs = block.observations
    oi = result.observation_order
    cam = block.photos.camera[obs.photo[oi]]
    cov = obs.cov[oi]
    K = len(block.cameras)
    sig = np.full(K, np.nan)
    notes = []
    exact = True
    single = ~result.row_active[oi].all(axis=1)
    if single.any():
        exact = False
        notes.append(f"{int(single.sum())} observation(s) with one coordinate switched off enter pycolmap with both")
    for j in range(K):
        sel = cam == j
        if not sel.any():
            continue
        sx, sy, sxy = cov[sel, 0, 0], cov[sel, 1, 1], cov[sel, 0, 1]
        s2 = 0.5 * (sx + sy)
        sig[j] = float(np.sqrt(np.mean(s2)))
        iso = np.allclose(sx, sy, rtol=1e-9, atol=0) and np.all(sxy == 0)
        equal = np.allclose(s2, s2[0], rtol=1e-9, atol=0)
        if not (iso and equal):
            exact = False
            notes.append(f"camera {block.cameras.ids[j]}: observations are not weighted σ² I with one σ "
                         f"(pycolmap uses the RMS σ = {sig[j] * 1e3:.4g} µm for all): weights not equivalent")
    return sig, exact, notes


def behind_camera(result) -> np.ndarray:
    """(k,) bool: used observations whose point lies behind the camera in baarda's solution
    (``W >= 0``; baarda's image-space z points back out of the lens)."""
    from baarda.pipeline.adjustment import project_observations

    st = result.state
    obs = result.block_in.observations
    out = np.zeros(len(obs), bool)
    oi = np.flatnonzero(result.obs_active)
    if oi.size:
        pr = project_observations(obs.photo[oi], obs.point[oi], st.XYZ, st.X0, st.opk, result.block_in.photos.camera,
                                  st.cam_params, result.block_in.cameras.ap_model, result.camera_meta, jacobians=False)
        out[oi] = ~(pr.W < 0)
    return out


def plan_crosscheck(result) -> CrossCheckPlan:
    """The plan for a converged bundle (:class:`baarda.pipeline.adjustment.BundleResult`)."""
    block = result.block_in
    cams, photos, points = block.cameras, block.photos, block.points
    adj_cams = result.block.cameras
    notes = []
    plans = []
    for j in range(len(cams)):
        names = result.cam_param_names[j]
        plans.append(_camera_plan(j, cams, result, names, brown_vector(cams, j), brown_vector(adj_cams, j),
                                  bool(result.camera_used[j])))
    refine = _merge_global(plans)
    sigma, w_exact, w_notes = _weights(block, result)
    notes += w_notes

    # points: fixed control stays constant; free ones are variable; everything else is held
    used_pt = result.point_used.copy()
    fixed_pt = used_pt & (points.sigma == 0).all(axis=1)
    in_dist = np.zeros(len(points), bool)
    for ends in result.distance_points:
        in_dist[ends] = True
    free_pt = used_pt & np.isinf(points.sigma).all(axis=1) & ~in_dist
    held_pt = used_pt & ~fixed_pt & ~free_pt
    if held_pt.any():
        notes.append(f"{int(held_pt.sum())} point(s) with weighted or partly fixed coordinates or in a distance "
                     "held at baarda's adjusted values (pycolmap has no priors, partial fixing or distances)")
    used_ph = result.photo_used.copy()
    fixed_ph = used_ph & (photos.sigma_eo == 0).all(axis=1)
    free_ph = used_ph & np.isinf(photos.sigma_eo).all(axis=1)
    held_ph = used_ph & ~fixed_ph & ~free_ph
    if held_ph.any():
        notes.append(f"{int(held_ph.sum())} photo(s) with weighted or partly fixed exterior orientation held at "
                     "baarda's adjusted values")
    gnss = np.zeros(len(photos), bool)
    gnss[np.asarray(block.gnss.photo, int)] = True
    gnss &= used_ph & ~fixed_ph & ~held_ph
    if gnss.any():                    # antenna observations pull on the pose: hold it where baarda put it
        free_ph &= ~gnss
        held_ph |= gnss
        notes.append(f"{int(gnss.sum())} photo(s) with GNSS antenna observations held at baarda's adjusted poses "
                     "(pycolmap has no antenna observations)")
    behind = behind_camera(result)
    if behind.any():
        notes.append(f"{int(behind.sum())} observation(s) of points behind their camera (first: photo "
                     f"{photos.ids[block.observations.photo[np.argmax(behind)]]}, point "
                     f"{points.ids[block.observations.point[np.argmax(behind)]]}): COLMAP gives them a zero residual, "
                     "baarda's collinearity fits them — not equivalent; switch them off (they are gross errors)")
    datum = result.settings.datum
    datum_ok = True
    if datum == "free":
        constrained = ((used_pt & ~np.isinf(points.sigma).all(axis=1)).any()
                       or (used_ph & ~np.isinf(photos.sigma_eo).all(axis=1)).any())
        if constrained:
            datum_ok = False
            notes.append("free network (inner constraints) on a block that also has fixed or weighted control or "
                         "orientations: baarda's inner constraints then constrain the shape beyond the gauge, "
                         "which pycolmap cannot reproduce (use datum 'control', or make every point a tie point)")
    struct = result.rig
    sensor_constant = sensor_held = None
    if struct is not None:             # rigs: frames and sensor poses (docs/rigs.md)
        rs = block.rigs.sensors
        fixed_s = (rs.sigma == 0).all(axis=1)
        free_s = np.isinf(rs.sigma).all(axis=1) & ~rs.reference
        sensor_held = ~fixed_s & ~free_s
        sensor_constant = fixed_s | sensor_held
        if sensor_held.any():
            notes.append(f"{int(sensor_held.sum())} rig sensor pose(s) weighted or partly fixed in baarda held at "
                         "baarda's adjusted values (pycolmap has no priors)")
        notes.append(f"rigs: {struct.n_frames} frames (one rig_from_world each), {int(free_s.sum())} estimated "
                     "sensor_from_rig pose(s): pycolmap's bundle adjustment with rig constraints")
    if datum == "free" and datum_ok:
        idx = np.flatnonzero(free_ph)
        if struct is not None:         # the gauge on frames: photos that carry a frame's pose (or no frame)
            idx = idx[(struct.photo_frame[idx] < 0) | np.isin(idx, struct.frame_ref_photo)]
        if idx.size >= 2:
            first = idx[0]
            far = idx[np.argmax(np.linalg.norm(result.state.X0[idx] - result.state.X0[first], axis=1))]
            free_ph[[first, far]] = False
            held_ph[[first, far]] = True
            notes.append(f"free network: photos {photos.ids[first]} and {photos.ids[far]} held at baarda's adjusted "
                         "poses as the gauge (pycolmap has no inner constraints); the rest is gauge-free")
    for p in plans:
        if p.note and p.mode != "unused":
            notes.append(f"camera {p.id} ({p.colmap_model}, {p.mode}): {p.note}")
    return CrossCheckPlan(cameras=plans, refine=refine, sigma_mm=sigma, weights_equivalent=w_exact,
                          obs_used=result.obs_active.copy(), point_variable=free_pt,
                          point_constant=fixed_pt | held_pt, point_held=held_pt, photo_variable=free_ph,
                          photo_constant=fixed_ph | held_ph, photo_held=held_ph, datum=datum, datum_equivalent=datum_ok,
                          behind=behind, notes=notes, sensor_constant=sensor_constant, sensor_held=sensor_held)
