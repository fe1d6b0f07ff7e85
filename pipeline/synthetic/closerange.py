"""A small close-range block with a camera of any built-in AP model (the bundle's tests).

Convergent photos on a cap around a 3-D point cloud, half of them rolled by 90°, so that c, xp,
yp and the additional parameters are determinable (self-calibration geometry).  The geometry is
drawn from ``seed``, the image noise from ``rng``; the projection is the bundle's collinearity.
"""

from __future__ import annotations

__all__ = ["make_block", "with_correlated_noise", "perturb", "look_at", "TRUE_AP", "META"]

import numpy as np

from baarda.pipeline.geometry import opk_from_rotation
from baarda.pipeline.model import FREE, Block, Cameras, Observations, Photos, Points

TRUE_AP = {
    "none": [],
    "brown": [-2.0e-4, 3.0e-7, -1.0e-10, 2.0e-5, -1.5e-5, 1.0e-4, -5.0e-5],
    "aicon": [-1.1e-4, 1.5e-7, 0.0, 5.8e-6, -8.6e-6, -7.0e-5, -3.1e-5],
    "ebner12": [2e-5, -1e-5, 3e-7, -2e-7, 4e-7, 1e-7, 2e-9, -1e-9, 1.5e-9, -2e-9, 1e-11, -1e-11],
}
META = {"none": {}, "brown": {}, "aicon": {"r0": 10.0}, "ebner12": {"b": 12.0}}


def look_at(C, T, roll=0.0):
    z = (C - T) / np.linalg.norm(C - T)
    up = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.vstack([x, y, z])
    c, s = np.cos(roll), np.sin(roll)
    R = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]]) @ R
    return R


def make_block(n_photos=8, n_points=40, model="brown", noise_mm=0.0, rng=None, n_control=6,
               c=25.0, xp=0.05, yp=-0.03, free_iop=True, sigma_mm=0.001, seed=1):
    """Returns (block, truth) with truth = dict(X0, opk, XYZ, cam) (cam = [c, xp, yp, ap...])."""
    from baarda.pipeline.adjustment import project_observations

    g = np.random.default_rng(seed)
    rng = rng if rng is not None else np.random.default_rng(seed + 100)
    XYZ = np.column_stack([g.uniform(-1, 1, n_points), g.uniform(-0.8, 0.8, n_points),
                           g.uniform(-0.4, 0.4, n_points)])
    X0, opk = [], []
    for i in range(n_photos):
        az = 2 * np.pi * i / n_photos
        C = np.array([2.0 * np.sin(az), 1.0 * np.cos(az) + 0.3 * (i % 2), 3.2 + 0.2 * (i % 3)])
        R = look_at(C, np.array([0.1 * np.cos(3 * az), 0.1 * np.sin(2 * az), 0.0]),
                    roll=(np.pi / 2) * (i % 2) + 0.05 * i)
        X0.append(C)
        opk.append(opk_from_rotation(R))
    X0, opk = np.array(X0), np.array(opk)
    ap = np.array(TRUE_AP[model], float)
    cam = np.r_[c, xp, yp, ap]
    meta = META[model]
    ph = np.repeat(np.arange(n_photos), n_points)
    pt = np.tile(np.arange(n_points), n_photos)
    pr = project_observations(ph, pt, XYZ, X0, opk, np.zeros(n_photos, int), cam[None], [model], [meta],
                              jacobians=False)
    assert (pr.W < 0).all()
    inside = (np.abs(pr.xy[:, 0]) < 18) & (np.abs(pr.xy[:, 1]) < 18)
    xy = pr.xy + noise_mm * rng.standard_normal(pr.xy.shape)
    ph, pt, xy = ph[inside], pt[inside], xy[inside]
    p = len(ap)
    cams = Cameras.make(["cam"], c, xp, yp, ap_model=model, ap=ap[None] if p else None,
                        sigma_iop=np.full(3, FREE if free_iop else 0.0),
                        sigma_ap=np.full((1, p), FREE) if p else None, format_mm=(36.0, 24.0))
    photos = Photos.make([f"P{i + 1}" for i in range(n_photos)], 0, X0, opk)
    role = np.array(["tie"] * n_points, dtype=object)
    role[:n_control] = "full"
    points = Points.make([str(100 + i) for i in range(n_points)], XYZ, role)
    obs = Observations.make(ph, pt, xy, sigma=sigma_mm)
    block = Block(cams, photos, points, obs, ap_meta={"cam": dict(meta)})
    return block, {"X0": X0, "opk": opk, "XYZ": XYZ, "cam": cam}


def with_correlated_noise(block, rng, sigma=(0.5e-3, 2e-3), rho=0.8):
    """``block`` with random correlated image covariances (σx, σy uniform in ``sigma`` mm, ρ uniform
    in ±``rho``) and image noise drawn from them."""
    obs = block.observations
    k = len(obs)
    sx, sy = rng.uniform(*sigma, k), rng.uniform(*sigma, k)
    r = rng.uniform(-rho, rho, k)
    cov = np.zeros((k, 2, 2))
    cov[:, 0, 0], cov[:, 1, 1] = sx ** 2, sy ** 2
    cov[:, 0, 1] = cov[:, 1, 0] = r * sx * sy
    noise = np.einsum("kij,kj->ki", np.linalg.cholesky(cov), rng.standard_normal((k, 2)))
    return block.replace(observations=obs.replace(xy=obs.xy + noise, cov=cov))


def perturb(block, rng, dX0=0.05, dang=0.02, dXYZ=0.03, dc=0.2, ap_zero=True):
    ph, pts, cams = block.photos, block.points, block.cameras
    X0 = ph.X0 + dX0 * rng.standard_normal(ph.X0.shape)
    opk = ph.opk + dang * rng.standard_normal(ph.opk.shape)
    XYZ = pts.XYZ.copy()
    tie = pts.role == "tie"
    XYZ[tie] += dXYZ * rng.standard_normal((tie.sum(), 3))
    cams2 = cams.replace(c=cams.c + dc, xp=cams.xp * 0, yp=cams.yp * 0,
                         ap=np.zeros_like(cams.ap) if ap_zero else cams.ap)
    return block.replace(photos=ph.replace(X0=X0, opk=opk), points=pts.replace(XYZ=XYZ), cameras=cams2)
