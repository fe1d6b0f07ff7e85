"""Simulated digital-camera blocks for the cross-check test and the benchmarks (pure numerics).

Two layouts, both with one digital camera (pixel pitch and resolution known, so every quantity
can be reported in pixels) and white image noise drawn from the ``rng`` argument:

* :func:`simulate_convergent` — close range: photos on a ring around a 3-D point cloud, looking at
  its centre, every other photo rolled by 90° (self-calibration geometry: c, xp, yp and the
  distortion are determinable);
* :func:`simulate_aerial` — a regular block of strips over gently rolling terrain (60 % forward,
  30 % side overlap), control points spread over the block, from a few to 10 000 photos and more.

Memory is O(observations): no photos × points array is built.  A photo looking down on the
terrain takes as candidates only the points of a k-d tree inside its ground footprint; any other
photo (convergent, oblique) takes every point, a chunk of photos at a time.  The observations are
exactly those (and in the order) of projecting every point into every photo
(``tests/synthetic/test_aerial_scale.py``).

Coordinates follow ``docs/conventions.md`` (object unit m, image mm, ω φ κ, y up).  The projection
is the bundle's own collinearity (:func:`baarda.pipeline.adjustment.collinearity.project_observations`), so
the simulated observations are exact for baarda's model up to the added noise.
"""

from __future__ import annotations

import itertools

import numpy as np

from baarda.pipeline.geometry import opk_from_rotation, rotation_from_opk_many
from baarda.pipeline.model import FIXED, FREE, Block, Cameras, Observations, Photos, Points

__all__ = ["simulate_convergent", "simulate_aerial", "perturb_start", "DEFAULT_BROWN"]

DEFAULT_BROWN = (-1.5e-4, 2.0e-7, 0.0, 1.5e-5, -1.0e-5, 0.0, 0.0)
"""A plausible brown distortion for c = 24 mm (K1 mm⁻², K2 mm⁻⁴, K3, P1 mm⁻¹, P2, B1, B2): ≈ 0.3 mm
(80 px) radial and ≈ 6 µm decentring in the corners of a 24 × 16 mm format."""


def _look_at(C, T, roll):
    """``R_cam_from_world`` of a camera at ``C`` looking at ``T`` (z back, y up, rolled by ``roll``)."""
    z = (C - T) / np.linalg.norm(C - T)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    cr, sr = np.cos(roll), np.sin(roll)
    return np.array([[cr, sr, 0], [-sr, cr, 0], [0, 0, 1]]) @ np.vstack([x, y, z])


_PAIRS_PER_CHUNK = 1 << 17
"""Photo–point pairs projected at once (the temporaries of one chunk stay near 50 MB)."""

_FAST_PHOTOS_PER_CHUNK = 128
"""Photos whose candidates come from the terrain index, gathered per chunk."""

_CONE_SLACK = 1.5
"""Candidate rays reach 1.5 × the half format (plus the principal point's offset): a point whose
ideal image position lies beyond cannot be moved into the format by any plausible distortion."""


def _footprints(X0, opk, camera, zmin, zmax):
    """Per photo, a circle (centre (m, 2), radius (m,)) in XY holding every object point with
    ``zmin ≤ Z ≤ zmax`` whose ideal image position lies within the slack-enlarged format, and a
    mask ``ok`` (m,) of the photos for which this holds: the projection centre above ``zmax`` and
    every enlarged corner ray pointing down.  The rays between the two planes Z = zmin and
    Z = zmax form a convex frustum whose vertices are the 8 corner-ray intersections; the circle
    encloses their XY positions (``docs/benchmarks.md``, "Scale")."""
    half = 0.5 * np.asarray(camera["resolution"], float) * camera["pixel_mm"]
    hx = _CONE_SLACK * half[0] + abs(camera["xp"])
    hy = _CONE_SLACK * half[1] + abs(camera["yp"])
    corners = np.array([[sx * hx, sy * hy, -camera["c"]] for sx in (-1, 1) for sy in (-1, 1)])
    R = rotation_from_opk_many(opk)                       # R_cam_from_world, (m, 3, 3)
    d = np.einsum("mji,cj->mci", R, corners)              # world directions X − X0 = Rᵀ p_cam, (m, 4, 3)
    dz = d[:, :, 2]
    ok = np.isfinite(X0).all(axis=1) & np.isfinite(opk).all(axis=1) & (X0[:, 2] > zmax) & (dz < 0).all(axis=1)
    dz = np.where(ok[:, None], dz, -1.0)
    verts = []
    for z in (zmin, zmax):
        t = (z - X0[:, 2])[:, None] / dz                  # (m, 4), positive where ok
        verts.append(X0[:, None, :2] + t[:, :, None] * d[:, :, :2])
    verts = np.concatenate(verts, axis=1)                 # (m, 8, 2)
    centre = verts.mean(axis=1)
    radius = np.linalg.norm(verts - centre[:, None, :], axis=2).max(axis=1)
    radius = radius * (1 + 1e-9) + 1e-9 * (np.abs(centre).max(axis=1) + 1.0)
    ok &= np.isfinite(centre).all(axis=1) & np.isfinite(radius)
    return np.where(ok[:, None], centre, 0.0), np.where(ok, radius, 0.0), ok


def _candidate_pairs(XYZ, X0, opk, camera):
    """Chunks ``(photo, point)`` of candidate pairs, photo by photo in order and the points of each
    photo ascending (the order of a photos × points enumeration), never more than a chunk at once.

    Photos looking down on the terrain take the points of a k-d tree of the object points' XY
    inside their footprint circle (:func:`_footprints`); any other photo (convergent, oblique,
    below the points) takes every point, in chunks of at most ``_PAIRS_PER_CHUNK`` pairs."""
    from scipy.spatial import cKDTree

    m, n = len(X0), len(XYZ)
    if m == 0 or n == 0:
        return
    centre, radius, fast = _footprints(X0, opk, camera, XYZ[:, 2].min(), XYZ[:, 2].max())
    tree = cKDTree(XYZ[:, :2]) if fast.any() else None
    per_chunk = max(1, _PAIRS_PER_CHUNK // n)
    i = 0
    while i < m:
        j = i + 1
        if fast[i]:
            while j < m and fast[j] and j - i < _FAST_PHOTOS_PER_CHUNK:
                j += 1
            lists = tree.query_ball_point(centre[i:j], radius[i:j], return_sorted=True)
            counts = np.fromiter(map(len, lists), np.intp, j - i)
            pt = np.fromiter(itertools.chain.from_iterable(lists), np.intp, int(counts.sum()))
            ph = np.repeat(np.arange(i, j), counts)
        else:
            while j < m and not fast[j] and j - i < per_chunk:
                j += 1
            ph = np.repeat(np.arange(i, j), n)
            pt = np.tile(np.arange(n), j - i)
        yield i, j, ph, pt
        i = j


def _project_inside(XYZ, X0, opk, camera, margin_px=10):
    """Error-free observations ``(photo, point, xy mm)`` of every point in front of a photo and
    inside its format (less ``margin_px``), photo by photo, points ascending — the same rows a
    projection of every point into every photo would keep, in memory O(observations)."""
    from baarda.pipeline.adjustment import project_observations

    cam = np.column_stack([camera["c"], camera["xp"], camera["yp"], np.atleast_2d(camera["ap"])])
    half = 0.5 * np.asarray(camera["resolution"], float) * camera["pixel_mm"] - margin_px * camera["pixel_mm"]
    phs, pts, xys = [np.zeros(0, np.intp)], [np.zeros(0, np.intp)], [np.zeros((0, 2))]
    for i, j, ph, pt in _candidate_pairs(XYZ, X0, opk, camera):
        if ph.size == 0:
            continue
        pr = project_observations(ph - i, pt, XYZ, X0[i:j], opk[i:j], np.zeros(j - i, int), cam,
                                  [camera["model"]], [{}], jacobians=False)
        inside = (pr.W < 0) & (np.abs(pr.xy[:, 0]) < half[0]) & (np.abs(pr.xy[:, 1]) < half[1])
        phs.append(ph[inside])
        pts.append(pt[inside])
        xys.append(pr.xy[inside])
    return np.concatenate(phs), np.concatenate(pts), np.concatenate(xys)


def _observe(XYZ, X0, opk, camera, rng, noise_px, margin_px=10):
    """Observations (photo, point, xy mm) of every point inside the format, with noise."""
    ph, pt, xy = _project_inside(XYZ, X0, opk, camera, margin_px)
    xy = xy + noise_px * camera["pixel_mm"] * rng.standard_normal((len(ph), 2))
    return ph, pt, xy


def _block(XYZ, X0, opk, camera, ph, pt, xy, sigma_px, control, free_intrinsics, name):
    """The block of observations ``(ph, pt, xy)``; points seen by fewer than two photos left out."""
    rays = np.bincount(pt, minlength=len(XYZ))
    keep_pt = rays >= 2
    new_index = np.cumsum(keep_pt) - 1
    sel = keep_pt[pt]
    ph, pt, xy = ph[sel], new_index[pt[sel]], xy[sel]
    XYZ = XYZ[keep_pt]
    control = np.asarray(control, bool)[keep_pt]
    p = camera["pixel_mm"]
    model = camera["model"]
    ap = np.atleast_2d(camera["ap"]) if model == "brown" else None
    free = set(free_intrinsics)
    sigma_iop = [FREE if k in free else FIXED for k in ("c", "xp", "yp")]
    sigma_ap = None
    if model == "brown":
        names = ("K1", "K2", "K3", "P1", "P2", "B1", "B2")
        sigma_ap = np.array([[FREE if k in free else FIXED for k in names]])
    res = np.asarray(camera["resolution"], int)
    cameras = Cameras.make([name], camera["c"], camera["xp"], camera["yp"], ap_model=model, ap=ap,
                           sigma_iop=sigma_iop, sigma_ap=sigma_ap, format_mm=res * p, pixel_mm=p,
                           resolution=res)
    photos = Photos.make([f"{k + 1:03d}" for k in range(len(X0))], 0, X0, opk)
    role = np.where(control, "full", "tie")
    points = Points.make([f"{j + 1:05d}" for j in range(len(XYZ))], XYZ, role)
    obs = Observations.make(ph, pt, xy, sigma=sigma_px * p)
    return Block(cameras, photos, points, obs, object_unit="m")


def _noisy_and_exact(XYZ, X0, opk, cam, rng, noise_px, sigma_px, control, free_intrinsics):
    """The noisy block and the same block without noise (a-priori σ = ``sigma_px`` or the noise)."""
    s = noise_px if sigma_px is None else sigma_px
    ph, pt, xy = _project_inside(XYZ, X0, opk, cam)
    noisy_xy = xy + noise_px * cam["pixel_mm"] * rng.standard_normal((len(ph), 2))
    noisy = _block(XYZ, X0, opk, cam, ph, pt, noisy_xy, s, control, free_intrinsics, "cam")
    exact = _block(XYZ, X0, opk, cam, ph, pt, xy, s, control, free_intrinsics, "cam")
    return noisy, exact


def _nearest_free(XY, targets):
    """For each target in turn, the index of the nearest point of ``XY`` not taken by an earlier
    target (a k-d tree instead of a targets × points distance table)."""
    from scipy.spatial import cKDTree

    n = len(XY)
    tree = cKDTree(XY)
    taken = np.zeros(n, bool)
    out = []
    for T in targets:
        k = 4
        while True:
            _, idx = tree.query(T, k=min(k, n))
            idx = np.atleast_1d(idx)
            idx = idx[(idx < n) & ~taken[np.minimum(idx, n - 1)]]
            if idx.size or k >= n:
                break
            k *= 4
        if idx.size:
            taken[idx[0]] = True
            out.append(int(idx[0]))
    return np.array(out, dtype=np.intp)


def _camera(model, c, pixel_mm, resolution, xp, yp, ap):
    if model not in ("none", "brown"):
        raise ValueError(f"model must be 'none' or 'brown', got {model!r}")
    ap = np.asarray(DEFAULT_BROWN if ap is None else ap, float) if model == "brown" else np.zeros(0)
    return {"model": model, "c": float(c), "xp": float(xp), "yp": float(yp), "ap": ap,
            "pixel_mm": float(pixel_mm), "resolution": tuple(resolution)}


def simulate_convergent(rng: np.random.Generator, *, n_photos: int = 10, n_points: int = 150,
                        model: str = "none", ap=None, c: float = 24.0, xp: float = 0.06, yp: float = -0.04,
                        pixel_mm: float = 0.004, resolution=(6000, 4000), noise_px: float = 0.5,
                        sigma_px: float | None = None, n_control: int = 8,
                        free_intrinsics=("c", "xp", "yp"), distance: float = 16.0,
                        size=(10.0, 6.0, 3.0)) -> tuple[Block, Block]:
    """A convergent close-range block; returns ``(noisy block, exact block)``.

    The exact block holds the true orientations, coordinates and error-free observations; the
    noisy block the same values as initial values (control points exact, role ``full``, fixed),
    with ``noise_px`` white noise on the image coordinates and a-priori ``sigma_px`` (default:
    the noise).  ``free_intrinsics`` names the unknown camera parameters (``c, xp, yp`` and the
    brown names ``K1 … B2``).  The object is a box of ``size`` metres centred at the origin.
    """
    sx, sy, sz = size
    XYZ = np.column_stack([rng.uniform(-sx / 2, sx / 2, n_points), rng.uniform(-sy / 2, sy / 2, n_points),
                           rng.uniform(-sz / 2, sz / 2, n_points)])
    # control: the points closest to the corners of the box, spread over the object
    corners = np.array([[a * sx / 2, b * sy / 2, s * sz / 2] for a in (-1, 1) for b in (-1, 1) for s in (-1, 1)])
    control = np.zeros(n_points, bool)
    for k in range(min(n_control, n_points)):
        d = np.linalg.norm(XYZ - corners[k % 8] * (1.0 - 0.3 * (k // 8)), axis=1)
        d[control] = np.inf
        control[np.argmin(d)] = True
    X0, opk = [], []
    for i in range(n_photos):
        az = 2 * np.pi * i / n_photos
        C = np.array([distance * np.cos(az), distance * np.sin(az), 0.35 * distance + 0.1 * distance * (i % 3)])
        T = np.array([0.05 * sx * np.cos(3 * az), 0.05 * sy * np.sin(2 * az), 0.0])
        R = _look_at(C, T, (np.pi / 2) * (i % 2) + 0.03 * i)
        X0.append(C)
        opk.append(opk_from_rotation(R))
    X0, opk = np.array(X0), np.array(opk)
    cam = _camera(model, c, pixel_mm, resolution, xp, yp, ap)
    return _noisy_and_exact(XYZ, X0, opk, cam, rng, noise_px, sigma_px, control, free_intrinsics)


def simulate_aerial(rng: np.random.Generator, *, n_strips: int = 20, photos_per_strip: int = 10,
                    height: float = 100.0, points_per_photo: float = 150.0, model: str = "none", ap=None,
                    c: float = 24.0, pixel_mm: float = 0.004, resolution=(6000, 4000), noise_px: float = 0.5,
                    sigma_px: float | None = None, forward_overlap: float = 0.6, side_overlap: float = 0.3,
                    control_spacing: int = 4, free_intrinsics=()) -> tuple[Block, Block]:
    """A regular aerial block: ``n_strips`` × ``photos_per_strip`` vertical photos at ``height`` m.

    The long side of the format is across the flight (strips along Y).  Terrain points are
    uniform over the block with ``points_per_photo`` points per footprint on average, heights
    of a few metres; a control point (role ``full``) near every ``control_spacing``-th photo
    position of every ``control_spacing``-th strip and at the block corners.  Returns
    ``(noisy block, exact block)`` as :func:`simulate_convergent`.
    """
    fmt = np.asarray(resolution, float) * pixel_mm
    scale = height / c
    across, along = fmt[0] * scale, fmt[1] * scale
    base = (1 - forward_overlap) * along
    spacing = (1 - side_overlap) * across
    X0 = np.array([[s * spacing, k * base, height] for s in range(n_strips) for k in range(photos_per_strip)], float)
    X0[:, :2] += rng.normal(0, 0.02 * base, (len(X0), 2))
    X0[:, 2] += rng.normal(0, 0.01 * height, len(X0))
    opk = rng.normal(0, np.deg2rad(1.0), (len(X0), 3))
    lo = X0[:, :2].min(axis=0) - [across / 2, along / 2]
    hi = X0[:, :2].max(axis=0) + [across / 2, along / 2]
    area = np.prod(hi - lo)
    n_points = int(points_per_photo * area / (across * along))
    XY = rng.uniform(lo, hi, (n_points, 2))
    Z = 3.0 * np.sin(XY[:, 0] / 90.0) * np.cos(XY[:, 1] / 70.0) + rng.normal(0, 0.5, n_points)
    XYZ = np.column_stack([XY, Z])
    control = np.zeros(n_points, bool)
    targets = [X0[s * photos_per_strip + k, :2] for s in range(0, n_strips, control_spacing)
               for k in range(0, photos_per_strip, control_spacing)]
    targets += [lo + [across / 2, along / 2], [hi[0] - across / 2, lo[1] + along / 2],
                [lo[0] + across / 2, hi[1] - along / 2], hi - [across / 2, along / 2]]
    control[_nearest_free(XY, np.array(targets, float))] = True
    cam = _camera(model, c, pixel_mm, resolution, 0.0, 0.0, ap)
    return _noisy_and_exact(XYZ, X0, opk, cam, rng, noise_px, sigma_px, control, free_intrinsics)


def perturb_start(block: Block, rng: np.random.Generator, *, position: float = 0.0, angle: float = 0.0,
                  point: float = 0.0, c: float = 0.0, zero_distortion: bool = False) -> Block:
    """A copy with disturbed initial values: projection centres and free points by ``position`` /
    ``point`` (object unit), ω φ κ by ``angle`` (rad), c by ``c`` (mm) when c is free; fixed values
    (sigma 0) are left alone.  ``zero_distortion`` starts free AP values at 0."""
    ph, pts, cams = block.photos, block.points, block.cameras
    X0 = ph.X0 + position * rng.standard_normal(ph.X0.shape) * (ph.sigma_eo[:, :3] != 0)
    opk = ph.opk + angle * rng.standard_normal(ph.opk.shape) * (ph.sigma_eo[:, 3:] != 0)
    XYZ = pts.XYZ + point * rng.standard_normal(pts.XYZ.shape) * (pts.sigma != 0)
    cc = cams.c + c * rng.standard_normal(len(cams)) * (cams.sigma_iop[:, 0] != 0)
    ap = np.where(cams.sigma_ap != 0, 0.0, cams.ap) if zero_distortion else cams.ap
    return block.replace(photos=ph.replace(X0=X0, opk=opk), points=pts.replace(XYZ=XYZ),
                         cameras=cams.replace(c=cc, ap=ap))
