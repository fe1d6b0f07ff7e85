"""A small fisheye block: a camera with a ray model inside a room of targets (tests, the bundled
``fixtures/fisheye`` project and the pycolmap cross-check).

Points on the walls, floor and ceiling of a room; stations near its centre, each looking in its own
direction (some up, some rolled by 90°), so that the whole field of the lens is covered — rays up to
``max_angle_deg`` off the axis, beyond 90° for the lenses that reach there.  The geometry is drawn
from ``seed``, the image noise from ``rng``; the projection is the bundle's own (``Projector``).
"""

from __future__ import annotations

import numpy as np

from baarda.pipeline.camera import get_ap_model
from baarda.pipeline.camera.ray_models import field_angle
from baarda.pipeline.geometry import opk_from_rotation
from baarda.pipeline.model import FREE, Block, Cameras, Observations, Photos, Points

__all__ = ["make_fisheye_block", "TRUE_RAY_AP"]

TRUE_RAY_AP = {
    # COLMAP-parameterised models (dimensionless, OpenCV's camera frame); B1 = fx/fy − 1 first
    "simple-fisheye": [],
    "fisheye": [0.004],
    "simple-radial-fisheye": [0.03],
    "radial-fisheye": [0.03, -0.004],
    "opencv-fisheye": [0.003, 0.021, -0.011, 0.004, -0.0007],
    "thin-prism-fisheye": [0.003, 0.02, -0.006, 0.001, -0.0007, 0.001, -0.0002, 0.0009, -0.0006],
    "rad-tan-thin-prism-fisheye": [0.003, 0.021, -0.008, 0.002, -0.0004, 0.0001, -0.00002, 0.0008, -0.0005,
                                   0.0006, -0.0001, -0.0004, 0.00007],
    "fov": [0.003, 0.93],
    "eucm": [0.003, 0.62, 1.07],
    "division": [0.003, -0.17],
    "simple-division": [-0.12],
    "equirectangular": [0.0],
    # photogrammetric projections with brown's terms (mm units, c ≈ 2.7 mm)
    "fisheye-equidistant": [-2.0e-3, 3.0e-4, 0.0, 2.0e-4, -1.5e-4, 1.0e-4, -5.0e-5],
    "fisheye-equisolid": [-2.0e-3, 3.0e-4, 0.0, 2.0e-4, -1.5e-4, 1.0e-4, -5.0e-5],
    "fisheye-stereographic": [-2.0e-3, 3.0e-4, 0.0, 2.0e-4, -1.5e-4, 1.0e-4, -5.0e-5],
    "fisheye-orthographic": [-2.0e-3, 3.0e-4, 0.0, 2.0e-4, -1.5e-4, 1.0e-4, -5.0e-5],
}
"""Parameters of the synthetic cameras (``Cameras.ap`` of each ray model)."""

MAX_ANGLE = {"fisheye-orthographic": 85.0, "eucm": 100.0, "equirectangular": 150.0}
"""Largest field angle (°) observed by default; others 100°."""


def _rotation(view, up_hint, roll):
    z = -np.asarray(view, float) / np.linalg.norm(view)          # the camera looks along −W
    up = up_hint if abs(np.dot(up_hint, z)) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.vstack([x, y, z])
    c, s = np.cos(roll), np.sin(roll)
    return np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]]) @ R


def make_fisheye_block(model="opencv-fisheye", *, ap=None, c=1.6, xp=0.012, yp=-0.008, n_photos=8,
                       n_points=150, n_control=8, max_angle_deg=None, noise_mm=0.0, sigma_mm=0.0015,
                       pixel_mm=0.003, size=None, rng=None, seed=1, free_iop=True):
    """``(block, truth)``: a fisheye block with camera ``model`` (parameters ``ap``, default
    :data:`TRUE_RAY_AP`), ``truth = dict(X0, opk, XYZ, cam = [c, xp, yp, ap…])``.  Control points
    ("full") are the first ``n_control`` points; observations up to ``max_angle_deg`` off the axis and
    inside the format (``size`` pixels of ``pixel_mm``; default a 1800 × 1800 sensor, 2π c × π c for
    the equirectangular camera); points seen in fewer than two photos are left out."""
    if size is None:
        size = ((int(np.ceil(2 * np.pi * c / pixel_mm)) + 2, int(np.ceil(np.pi * c / pixel_mm)) + 2)
                if model == "equirectangular" else (1800, 1800))
    from baarda.pipeline.adjustment import project_observations

    g = np.random.default_rng(seed)
    rng = rng if rng is not None else np.random.default_rng(seed + 100)
    half = np.array([4.0, 3.0, 1.5])                               # a room 8 m × 6 m × 3 m
    face = g.integers(0, 6, n_points)
    XYZ = g.uniform(-half, half, (n_points, 3))
    axis, sign = face // 2, np.where(face % 2, 1.0, -1.0)
    XYZ[np.arange(n_points), axis] = sign * half[axis]
    views = [[0.6, 0.8, 0.2], [-0.3, 1, 0.3], [-0.6, -0.8, 0.1], [0.3, -1, -0.2], [0.3, 0.9, 1], [0.7, -0.7, 0.4]]
    X0, opk = [], []
    for i in range(n_photos):
        C = g.uniform(-0.6, 0.6, 3) * [1, 1, 0.5]
        R = _rotation(np.array(views[i % len(views)], float) + 0.1 * g.standard_normal(3), np.array([0, 0, 1.0]),
                      roll=(np.pi / 2) * (i % 2) + 0.1 * i)
        X0.append(C)
        opk.append(opk_from_rotation(R))
    X0, opk = np.array(X0), np.array(opk)
    ap = np.asarray(TRUE_RAY_AP[model] if ap is None else ap, float)
    cam = np.r_[c, xp, yp, ap]
    ph = np.repeat(np.arange(n_photos), n_points)
    pt = np.tile(np.arange(n_points), n_photos)
    from baarda.pipeline.geometry import rotation_from_opk_many

    R = rotation_from_opk_many(opk)
    d = np.einsum("kij,kj->ki", R[ph], XYZ[pt] - X0[ph])
    limit = MAX_ANGLE.get(model, 100.0) if max_angle_deg is None else max_angle_deg
    seen = field_angle(d) <= limit
    if model == "equirectangular":     # away from the poles, where the azimuth turns on the spot, and
        # from the seam behind the camera, where it jumps by 2π (residuals are not wrapped)
        seen = (np.abs(np.degrees(np.arctan2(d[:, 1], np.hypot(d[:, 0], d[:, 2])))) < 70.0) \
            & (np.abs(np.degrees(np.arctan2(d[:, 0], -d[:, 2]))) < 160.0)
    ph, pt = ph[seen], pt[seen]
    pr = project_observations(ph, pt, XYZ, X0, opk, np.zeros(n_photos, int), cam[None], [model], [{}],
                              jacobians=False)
    inside = (np.abs(pr.xy) < np.array(size) * pixel_mm / 2).all(axis=1)
    xy = pr.xy + noise_mm * rng.standard_normal(pr.xy.shape)
    ph, pt, xy = ph[inside], pt[inside], xy[inside]
    two = np.bincount(pt, minlength=n_points)[pt] >= 2
    ph, pt, xy = ph[two], pt[two], xy[two]
    p = get_ap_model(model).n_params
    sig_iop = np.full(3, FREE if free_iop else 0.0)
    if model == "equirectangular":
        sig_iop[1] = 0.0              # xp shifts every azimuth: a rotation of each photo about its V axis
    cams = Cameras.make(["fisheye"], c, xp, yp, ap_model=model, ap=ap[None] if p else None,
                        sigma_iop=sig_iop,
                        sigma_ap=np.full((1, p), FREE) if p else None,
                        format_mm=(size[0] * pixel_mm, size[1] * pixel_mm), pixel_mm=pixel_mm, resolution=size)
    photos = Photos.make([f"F{i + 1}" for i in range(n_photos)], 0, X0, opk)
    role = np.array(["tie"] * n_points, dtype=object)
    role[:n_control] = "full"
    points = Points.make([str(1000 + i) for i in range(n_points)], XYZ, role)
    obs = Observations.make(ph, pt, xy, sigma=sigma_mm)
    return Block(cams, photos, points, obs), {"X0": X0, "opk": opk, "XYZ": XYZ, "cam": cam}
