"""OpenCV helpers on planar-target detections: start values and the ``cv2.calibrateCamera`` reference.

Everything here works in OpenCV pixels (``"opencv"`` convention) and OpenCV's board frame; results
are converted to baarda's conventions with :mod:`baarda.pipeline.camera.convert` and
:data:`baarda.plugins.targets.boards.F_BOARD`.
"""

from __future__ import annotations

import numpy as np

from baarda.pipeline.geometry.image import mm_from_pixels, pixels_from_mm
from baarda.pipeline.geometry import opk_from_rotation
from baarda.pipeline.geometry.pose import pose_from_cv
from baarda.pipeline.camera.convert import brown_from_opencv

from .boards import F_BOARD


def initial_focal_px(object_xyz: list[np.ndarray], uv: list[np.ndarray], size: tuple[int, int]) -> float | None:
    """Focal length (pixels) from the homographies of planar views (:func:`cv2.initCameraMatrix2D`).

    ``object_xyz`` in baarda's board frame (Z = 0); needs at least one view with ≥ 4 points.
    Returns None when OpenCV cannot estimate it.
    """
    import cv2

    views = [(np.asarray(X, np.float32) @ F_BOARD.astype(np.float32), np.asarray(p, np.float32))
             for X, p in zip(object_xyz, uv) if len(X) >= 4]
    if not views:
        return None
    try:
        K = cv2.initCameraMatrix2D([v[0] for v in views], [v[1] for v in views], tuple(int(s) for s in size))
    except cv2.error:
        return None
    f = float(np.sqrt(K[0, 0] * K[1, 1]))
    return f if np.isfinite(f) and f > 0 else None


def resect(object_xyz: np.ndarray, uv: np.ndarray, f_px: float, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray] | None:
    """Approximate ``(X0, opk)`` (baarda) of one photo by :func:`cv2.solvePnP` (no distortion,
    principal point at the image centre).  None when it fails."""
    import cv2

    X = np.asarray(object_xyz, float)
    if len(X) < 4:
        return None
    w, h = size
    K = np.array([[f_px, 0, (w - 1) / 2], [0, f_px, (h - 1) / 2], [0, 0, 1]], float)
    try:
        ok, rvec, tvec = cv2.solvePnP(X, np.asarray(uv, float), K, None)
    except cv2.error:
        return None
    if not ok:
        return None
    R, _ = cv2.Rodrigues(rvec)
    return pose_from_cv(R, tvec.ravel())


def opencv_flags(free) -> tuple[int, bool, list[str]]:
    """``cv2.calibrateCamera`` flags that free the same parameters as baarda's ``free`` interior
    parameters (names of ``c, xp, yp`` and the brown APs ``K1 K2 K3 P1 P2 B1 B2``): a like-for-like
    reference.  Returns ``(flags, fix_aspect, notes)``; fx = fy (``fix_aspect``) unless ``B1`` (affinity)
    is free; ``notes`` say what OpenCV cannot match (one of P1/P2 alone, B2 shear)."""
    import cv2

    free = set(free)
    flags, notes = 0, []
    if "c" not in free:
        flags |= cv2.CALIB_FIX_FOCAL_LENGTH
    if "xp" not in free or "yp" not in free:
        flags |= cv2.CALIB_FIX_PRINCIPAL_POINT
        if ("xp" in free) != ("yp" in free):
            notes.append("OpenCV fixes both coordinates of the principal point or neither: both fixed")
    for k, f in (("K1", cv2.CALIB_FIX_K1), ("K2", cv2.CALIB_FIX_K2), ("K3", cv2.CALIB_FIX_K3)):
        if k not in free:
            flags |= f
    if "P1" not in free and "P2" not in free:
        flags |= cv2.CALIB_ZERO_TANGENT_DIST
    elif ("P1" in free) != ("P2" in free):
        notes.append("OpenCV frees both tangential terms or neither: both free")
    if "B2" in free:
        notes.append("OpenCV has no shear (B2): held at 0")
    return flags, "B1" not in free, notes


def opencv_calibration(block, camera: int = 0, flags: int = 0, fix_aspect: bool = False, free=None) -> dict:
    """``cv2.calibrateCamera`` on the control-point observations of one camera of a block.

    Uses every photo of the camera with ≥ 6 observations of points with known coordinates (board
    frame, Z = 0); image coordinates are converted back to OpenCV pixels.  Returns the OpenCV result
    (``fx, fy, cx, cy`` px, ``dist`` (k1, k2, p1, p2, k3), ``rms_px`` as OpenCV reports it — the
    RMS over all x and y residual *pairs*, i.e. √(Σ(vx² + vy²)/n_points)), the views used, and
    the same camera in baarda's terms (``c, xp, yp`` mm and brown ``ap``, exact when fx = fy).
    ``fix_aspect`` adds ``CALIB_FIX_ASPECT_RATIO`` with fx/fy = 1: then OpenCV's camera model is
    exactly baarda's brown model with B1 = B2 = 0.  ``free`` (baarda's free interior parameters) sets
    ``flags`` and ``fix_aspect`` by :func:`opencv_flags` instead, so that both estimate the same
    parameters; parameters held fixed keep the block camera's value (``CALIB_USE_INTRINSIC_GUESS``).
    OpenCV runs single-threaded here (``cv2.setNumThreads(1)``), which makes the reference
    reproducible.
    """
    import cv2

    cams, ph, obs, pts = block.cameras, block.photos, block.observations, block.points
    size = tuple(int(v) for v in cams.resolution[camera])
    pitch = float(cams.pixel_mm[camera])
    known = np.isfinite(pts.XYZ).all(axis=1)
    obj, img, used = [], [], []
    for k in np.flatnonzero(ph.camera == camera):
        rows = np.flatnonzero((obs.photo == k) & obs.active & known[obs.point])
        if rows.size < 6:
            continue
        obj.append((pts.XYZ[obs.point[rows]] @ F_BOARD).astype(np.float32))
        img.append(pixels_from_mm(obs.xy[rows], size, pitch, "opencv").astype(np.float32))
        used.append(str(ph.ids[k]))
    if len(obj) < 2:
        raise ValueError(f"camera {cams.ids[camera]}: cv2.calibrateCamera needs ≥ 2 views with ≥ 6 control "
                         f"observations, have {len(obj)}")
    notes: list[str] = []
    if free is not None:
        flags, fix_aspect, notes = opencv_flags(free)
    K0, D0 = None, None
    if fix_aspect:
        flags |= cv2.CALIB_FIX_ASPECT_RATIO
        K0 = np.eye(3)                      # only the ratio fx/fy = 1 is taken from it
    if flags & (cv2.CALIB_FIX_FOCAL_LENGTH | cv2.CALIB_FIX_PRINCIPAL_POINT):
        # held parameters keep the block camera's values: focal length and principal point as guesses
        f = float(cams.c[camera]) / pitch
        cx, cy = pixels_from_mm([float(cams.xp[camera]), float(cams.yp[camera])], size, pitch, "opencv")
        K0 = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1]], float)
        D0 = np.zeros(5)
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, size, K0, D0, flags=flags)
    finally:
        cv2.setNumThreads(threads)
    dist = np.asarray(dist, float).ravel()
    dist = np.concatenate([dist, np.zeros(max(0, 5 - dist.size))])
    k1, k2, p1, p2, k3 = dist[:5]
    c, ap = brown_from_opencv(K[0, 0], K[1, 1], pitch, k1=k1, k2=k2, p1=p1, p2=p2, k3=k3)
    xp, yp = mm_from_pixels([K[0, 2], K[1, 2]], size, pitch, "opencv")
    n_points = sum(len(o) for o in obj)
    return {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2]),
            "dist": dist[:5].tolist(), "rms_px": float(rms), "views": used, "n_points": int(n_points),
            "c_mm": float(c), "xp_mm": float(xp), "yp_mm": float(yp), "brown": ap.tolist(),
            "flags": _flag_names(flags), "notes": notes,
            "rvecs": [np.asarray(r).ravel() for r in rvecs], "tvecs": [np.asarray(t).ravel() for t in tvecs]}


def _flag_names(flags: int) -> list[str]:
    """The ``CALIB_*`` names set in ``flags`` (for the report)."""
    import cv2

    names = ("CALIB_USE_INTRINSIC_GUESS", "CALIB_FIX_ASPECT_RATIO", "CALIB_FIX_FOCAL_LENGTH",
             "CALIB_FIX_PRINCIPAL_POINT", "CALIB_ZERO_TANGENT_DIST", "CALIB_FIX_K1", "CALIB_FIX_K2", "CALIB_FIX_K3")
    return [n for n in names if flags & int(getattr(cv2, n))]


def opencv_stereo(block, free, cals: dict) -> dict:
    """``cv2.stereoCalibrate`` on the detections of a two-camera rig (``block.rigs``: the reference
    sensor is the left camera) — the same photos, the points seen in both photos of a frame, the same
    interior parameters free as baarda's (``free``, :func:`opencv_flags`), started from the
    per-camera ``cv2.calibrateCamera`` results ``cals`` (camera id → :func:`opencv_calibration`).

    Returns OpenCV's ``R``, ``T`` (x_right = R x_left + T, y-down/z-forward frames, object unit),
    the RMS (px), the frames used, and the right camera's pose in the rig as baarda writes it
    (``centre`` = −F Rᵀ T and ``opk`` of F R F, F = diag(1, −1, −1): x right, y up, z back), the
    baseline |T|.  ``ValueError`` when the rig is not two cameras or too few frames see both."""
    import cv2

    rigs = block.rigs
    rs = rigs.sensors
    if len(rs) != 2 or len(set(rs.rig.tolist())) != 1:
        raise ValueError("cv2.stereoCalibrate compares a rig of exactly two cameras")
    left = int(rs.camera[rs.reference][0])
    right = int(rs.camera[~rs.reference][0])
    cams, ph, obs, pts = block.cameras, block.photos, block.observations, block.points
    lid, rid = str(cams.ids[left]), str(cams.ids[right])
    if lid not in cals or rid not in cals:
        raise ValueError("cv2.stereoCalibrate starts from both cameras' cv2.calibrateCamera results")
    size = tuple(int(v) for v in cams.resolution[left])
    if tuple(int(v) for v in cams.resolution[right]) != size:
        raise ValueError("cv2.stereoCalibrate needs both cameras at one image size")
    known = np.isfinite(pts.XYZ).all(axis=1)
    fm = rigs.frames
    obj, img_l, img_r, used = [], [], [], []
    for frame in dict.fromkeys(fm.frame.tolist()):
        members = fm.photo[fm.frame == frame]
        pl = [p for p in members if ph.camera[p] == left]
        pr = [p for p in members if ph.camera[p] == right]
        if not pl or not pr:
            continue
        rows_l = np.flatnonzero((obs.photo == pl[0]) & obs.active & known[obs.point])
        rows_r = np.flatnonzero((obs.photo == pr[0]) & obs.active & known[obs.point])
        common, il, ir = np.intersect1d(obs.point[rows_l], obs.point[rows_r], return_indices=True)
        if len(common) < 6:
            continue
        obj.append((pts.XYZ[common] @ F_BOARD).astype(np.float32))
        img_l.append(pixels_from_mm(obs.xy[rows_l[il]], size, float(cams.pixel_mm[left]), "opencv").astype(np.float32))
        img_r.append(pixels_from_mm(obs.xy[rows_r[ir]], size, float(cams.pixel_mm[right]), "opencv").astype(np.float32))
        used.append(str(frame))
    if len(obj) < 2:
        raise ValueError(f"cv2.stereoCalibrate needs ≥ 2 frames with ≥ 6 points seen by both cameras, have {len(obj)}")

    def km(cal):
        return (np.array([[cal["fx"], 0, cal["cx"]], [0, cal["fy"], cal["cy"]], [0, 0, 1]], float),
                np.asarray(cal["dist"], float))

    K1, D1 = km(cals[lid])
    K2, D2 = km(cals[rid])
    flags, fix_aspect, notes = opencv_flags(free)
    if fix_aspect:
        flags |= cv2.CALIB_FIX_ASPECT_RATIO
    flags |= cv2.CALIB_USE_INTRINSIC_GUESS
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        rms, K1, D1, K2, D2, R, T, _, _ = cv2.stereoCalibrate(obj, img_l, img_r, K1, D1, K2, D2, size, flags=flags,
                                                              criteria=criteria)
    finally:
        cv2.setNumThreads(threads)
    T = np.asarray(T, float).ravel()
    Fl = np.diag([1.0, -1.0, -1.0])
    R_b = Fl @ R @ Fl
    centre = -Fl @ R.T @ T
    return {"R": np.asarray(R).tolist(), "T": T.tolist(), "rms_px": float(rms), "frames": used,
            "left": lid, "right": rid, "centre": centre.tolist(), "opk": opk_from_rotation(R_b).tolist(),
            "baseline": float(np.linalg.norm(T)), "flags": _flag_names(flags), "notes": notes,
            "fx": [float(K1[0, 0]), float(K2[0, 0])]}
