"""A small normal-case block (the independent-model tests).

Strips of photos with parallel, nearly horizontal axes (ω, φ, κ a few mrad: normal-case
photography with small deviations) looking down −Z at a relief object, 60 % forward overlap.
An ideal central projection (no camera model): independent of the bundle and of the
independent-model code it tests.
"""

from __future__ import annotations

import numpy as np

from baarda.pipeline.geometry import rotation_from_opk
from baarda.pipeline.model import Block, Cameras, Observations, Pairs, Photos, Points

C_MM = 100.0
FORMAT = (120.0, 90.0)


__all__ = ["make_block", "relief", "ideal_projection", "C_MM", "FORMAT"]


def ideal_projection(X, X0, R, c, xp=0.0, yp=0.0):
    """Ideal collinearity ``x = xp − c U/W, y = yp − c V/W`` of points ``X (n, 3)`` seen from ``X0``
    with ``R = R_cam_from_world`` (docs/conventions.md; no additional parameters)."""
    d = (np.asarray(X, float) - np.asarray(X0, float)) @ np.asarray(R, float).T
    return np.column_stack([xp - c * d[:, 0] / d[:, 2], yp - c * d[:, 1] / d[:, 2]])


def relief(X, Y):
    return 0.12 * np.sin(2.1 * X) * np.cos(1.7 * Y) + 0.05 * X


def make_block(n_strips=1, n_photos=4, distance=1.4, noise_mm=0.0, rng=None, seed=3,
               grid=(9, 5), with_pairs=True, angles_mrad=10.0, control="corners",
               sigma_mm=0.004):
    """Returns (block, truth): truth = dict(X0, opk, XYZ).

    The object spans the block's footprint; points are a jittered grid with relief.  Roles:
    ``control="corners"`` puts full control at the four corners and height control in the
    middle of each long edge, check points every 4th remaining point, the rest tie points.
    """
    g = np.random.default_rng(seed)
    base = 0.4 * distance * FORMAT[0] / C_MM  # 60 % overlap
    foot_x = distance * FORMAT[0] / C_MM
    foot_y = distance * FORMAT[1] / C_MM
    side = 0.4 * foot_y
    X0, opk, ids = [], [], []
    for s in range(n_strips):
        for i in range(n_photos):
            X0.append([i * base, s * side, distance + 0.02 * g.standard_normal()])
            opk.append(angles_mrad * 1e-3 * g.standard_normal(3))
            ids.append(f"{s + 1}{i + 1}")
    X0, opk = np.array(X0), np.array(opk)
    # the stereo coverage (every point lies in at least one model)
    x_lo, x_hi = base - 0.4 * foot_x, (n_photos - 2) * base + 0.4 * foot_x
    y_lo, y_hi = (n_strips - 1) * side - 0.4 * foot_y, 0.4 * foot_y
    gx, gy = np.meshgrid(np.linspace(x_lo, x_hi, grid[0] + (n_photos - 2) * 2),
                         np.linspace(y_lo, y_hi, grid[1] + (n_strips - 1) * 2))
    XY = np.column_stack([gx.ravel(), gy.ravel()]) + g.uniform(-0.02, 0.02, (gx.size, 2))
    XYZ = np.column_stack([XY, relief(XY[:, 0], XY[:, 1])])
    n = XYZ.shape[0]
    ph, pt, xy = [], [], []
    for j in range(len(ids)):
        p = ideal_projection(XYZ, X0[j], rotation_from_opk(*opk[j]), C_MM)
        inside = (np.abs(p[:, 0]) < FORMAT[0] / 2) & (np.abs(p[:, 1]) < FORMAT[1] / 2)
        ph += [j] * int(inside.sum())
        pt += np.flatnonzero(inside).tolist()
        xy.append(p[inside])
    xy = np.vstack(xy)
    if noise_mm:
        rng = rng if rng is not None else np.random.default_rng(seed + 1)
        xy = xy + noise_mm * rng.standard_normal(xy.shape)
    role = np.array(["tie"] * n, dtype=object)
    if control == "corners":
        corners = [np.argmin(XY[:, 0] + XY[:, 1]), np.argmin(-XY[:, 0] + XY[:, 1]),
                   np.argmin(XY[:, 0] - XY[:, 1]), np.argmin(-XY[:, 0] - XY[:, 1])]
        role[corners] = "full"
        xm = 0.5 * (x_lo + x_hi)
        for yy in (y_lo, y_hi):
            role[np.argmin((XY[:, 0] - xm) ** 2 + (XY[:, 1] - yy) ** 2)] = "z"
        rest = np.flatnonzero(role == "tie")
        role[rest[::4]] = "check"
    points = Points.make([f"{100 + i}" for i in range(n)], XYZ, role.astype(str))
    cams = Cameras.make(["cam"], C_MM, format_mm=FORMAT)
    photos = Photos.make(ids, 0, X0, opk)
    obs = Observations.make(ph, pt, xy, sigma=sigma_mm)
    pairs = Pairs(left=np.zeros(0, int), right=np.zeros(0, int))
    if with_pairs:
        L, R = [], []
        for s in range(n_strips):
            for i in range(n_photos - 1):
                L.append(s * n_photos + i)
                R.append(s * n_photos + i + 1)
        pairs = Pairs(left=np.array(L), right=np.array(R))
    return Block(cams, photos, points, obs, pairs=pairs), {"X0": X0, "opk": opk, "XYZ": XYZ}
