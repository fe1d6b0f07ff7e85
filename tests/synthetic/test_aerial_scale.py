"""The aerial / convergent simulator at scale (``baarda.pipeline.synthetic.aerial``).

* the observations are exactly those of an independent brute-force projection of every point
  into every photo (photos × points pairs, small blocks only): same rows, same order, same
  coordinates — for vertical, oblique, horizontal and upward-looking photos, pinhole and brown,
  across chunk boundaries;
* a 2 000-photo block builds in memory proportional to its observations (tracemalloc peak
  against the observation arrays, and against a 500-photo block), far below one photos × points
  index array;
* the block is what was asked for: ≈ 150 points per photo, ≈ 60 % forward and ≈ 30 % side
  overlap seen as points shared by neighbouring photos.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from baarda.pipeline.adjustment import project_observations
from baarda.pipeline.geometry import rotation_from_opk
from baarda.pipeline.synthetic import aerial
from baarda.pipeline.synthetic.aerial import DEFAULT_BROWN, simulate_aerial, simulate_convergent

PIXEL = 0.004
RES = (6000, 4000)


def camera(model="none", c=24.0, xp=0.0, yp=0.0):
    ap = np.asarray(DEFAULT_BROWN, float) if model == "brown" else np.zeros(0)
    return {"model": model, "c": c, "xp": xp, "yp": yp, "ap": ap, "pixel_mm": PIXEL, "resolution": RES}


def camera_of(block):
    cams = block.cameras
    model = str(cams.ap_model[0])
    return {"model": model, "c": float(cams.c[0]), "xp": float(cams.xp[0]), "yp": float(cams.yp[0]),
            "ap": np.array(cams.ap[0], float) if model == "brown" else np.zeros(0),
            "pixel_mm": float(cams.pixel_mm[0]), "resolution": tuple(int(v) for v in cams.resolution[0])}


def brute_force(XYZ, X0, opk, cam, margin_px=10):
    """Every point into every photo, photo by photo, points ascending; (photo, point, xy).

    The pinhole case is projected here from the conventions (``p = R (X − X0)``,
    ``x = xp − c U/W``) with :func:`rotation_from_opk`, independently of the bundle's
    collinearity; a brown camera adds the model's distortion through ``project_observations``."""
    m, n = len(X0), len(XYZ)
    ph = np.repeat(np.arange(m), n)
    pt = np.tile(np.arange(n), m)
    if cam["model"] == "none":
        R = np.array([rotation_from_opk(*a) for a in opk])
        d = np.einsum("kij,kj->ki", R[ph], XYZ[pt] - X0[ph])
        W = d[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = np.column_stack([cam["xp"] - cam["c"] * d[:, 0] / W, cam["yp"] - cam["c"] * d[:, 1] / W])
    else:
        cp = np.concatenate([[cam["c"], cam["xp"], cam["yp"]], cam["ap"]])[None]
        pr = project_observations(ph, pt, XYZ, X0, opk, np.zeros(m, int), cp, [cam["model"]], [{}], jacobians=False)
        xy, W = pr.xy, pr.W
    half = 0.5 * np.asarray(cam["resolution"], float) * cam["pixel_mm"] - margin_px * cam["pixel_mm"]
    inside = (W < 0) & (np.abs(xy[:, 0]) < half[0]) & (np.abs(xy[:, 1]) < half[1])
    return ph[inside], pt[inside], xy[inside]


def assert_same(got, ref, tol=1e-12):
    ph, pt, xy = got
    rph, rpt, rxy = ref
    assert ph.shape == rph.shape and np.array_equal(ph, rph)
    assert np.array_equal(pt, rpt)
    assert np.max(np.abs(xy - rxy), initial=0.0) <= tol


def mixed_scene(rng):
    """Terrain points and photos of every kind: vertical (fast path), oblique beyond the
    footprint test, horizontal, looking up, and one below the highest point."""
    XY = rng.uniform(-150, 150, (4000, 2))
    Z = 3 * np.sin(XY[:, 0] / 40) + rng.normal(0, 1, len(XY))
    XYZ = np.column_stack([XY, Z])
    X0, opk = [], []
    for x in (-80, -20, 40, 100):
        for y in (-60, 0, 60):
            X0.append([x, y, 100 + rng.normal(0, 2)])
            opk.append(rng.normal(0, np.deg2rad(2), 3))
    X0 += [[0, -200, 60], [-200, 0, 40], [0, 0, 2.0], [50, 50, -20], [30, -30, 150]]
    opk += [[np.deg2rad(60), 0, 0.3], [0, np.deg2rad(-85), 0], [np.deg2rad(10), 0, 0], [np.pi, 0, 0],
            [0, np.deg2rad(40), 1.0]]
    return XYZ, np.array(X0, float), np.array(opk, float)


@pytest.mark.parametrize("model", ["none", "brown"])
def test_observe_equals_brute_force_on_every_kind_of_photo(model):
    XYZ, X0, opk = mixed_scene(np.random.default_rng(11))
    cam = camera(model, xp=0.05, yp=-0.03)
    _, _, fast = aerial._footprints(X0, opk, cam, XYZ[:, 2].min(), XYZ[:, 2].max())
    assert fast.sum() >= 10 and (~fast).sum() >= 4           # both routes are exercised
    ref = brute_force(XYZ, X0, opk, cam)
    assert len(ref[0]) > 1000
    assert set(np.unique(ref[0])) >= {0, 5, 12}              # vertical and oblique photos see points
    got = aerial._observe(XYZ, X0, opk, cam, np.random.default_rng(5), 0.0)
    assert_same(got, ref)
    # with noise: the same rows in the same order, so the same noise lands on the same observation
    noisy = aerial._observe(XYZ, X0, opk, cam, np.random.default_rng(5), 0.5)
    expected = ref[2] + 0.5 * PIXEL * np.random.default_rng(5).standard_normal((len(ref[0]), 2))
    assert_same(noisy, (ref[0], ref[1], expected))


def test_chunk_boundaries_do_not_change_the_observations(monkeypatch):
    XYZ, X0, opk = mixed_scene(np.random.default_rng(12))
    cam = camera("brown")
    ref = aerial._observe(XYZ, X0, opk, cam, np.random.default_rng(1), 0.3)
    monkeypatch.setattr(aerial, "_PAIRS_PER_CHUNK", 4000)    # one photo per brute-force chunk
    monkeypatch.setattr(aerial, "_FAST_PHOTOS_PER_CHUNK", 2)
    assert_same(aerial._observe(XYZ, X0, opk, cam, np.random.default_rng(1), 0.3), ref, tol=0.0)


@pytest.mark.parametrize("model", ["none", "brown"])
def test_simulated_aerial_block_is_the_brute_force_projection_of_its_truth(model):
    noisy, exact = simulate_aerial(np.random.default_rng(7), n_strips=5, photos_per_strip=8, model=model)
    ph, pt, xy = brute_force(exact.points.XYZ, exact.photos.X0, exact.photos.opk, camera_of(exact))
    obs = exact.observations
    assert_same((obs.photo, obs.point, obs.xy), (ph, pt, xy))
    assert np.array_equal(noisy.observations.photo, ph) and np.array_equal(noisy.observations.point, pt)
    # the noise is 0.5 px white noise
    d = (noisy.observations.xy - xy) / PIXEL
    assert abs(d.std() - 0.5) < 0.02 and abs(d.mean()) < 0.02


def test_simulated_convergent_block_is_the_brute_force_projection_of_its_truth(monkeypatch):
    monkeypatch.setattr(aerial, "_PAIRS_PER_CHUNK", 700)     # several photos per chunk, never all
    noisy, exact = simulate_convergent(np.random.default_rng(3), n_photos=16, n_points=300, model="brown")
    ph, pt, xy = brute_force(exact.points.XYZ, exact.photos.X0, exact.photos.opk, camera_of(exact))
    obs = exact.observations
    assert_same((obs.photo, obs.point, obs.xy), (ph, pt, xy))
    assert len(ph) > 0.7 * 16 * len(exact.points)            # the convergent photos see most points


def _observation_bytes(obs) -> int:
    return sum(getattr(obs, name).nbytes for name in obs._columns)


def _traced(**kw):
    tracemalloc.start()
    try:
        noisy, exact = simulate_aerial(np.random.default_rng(1), **kw)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return noisy, peak


@pytest.fixture(scope="module")
def block_2000():
    noisy, peak = _traced(n_strips=25, photos_per_strip=80)
    return noisy, peak


def test_2000_photo_block_builds_in_memory_proportional_to_its_observations(block_2000):
    noisy, peak = block_2000
    m, n, k = len(noisy.photos), len(noisy.points), len(noisy.observations)
    assert m == 2000 and k > 250_000
    obs_bytes = _observation_bytes(noisy.observations)
    # the two blocks (noisy and exact) hold two observation tables; the rest is one chunk's work
    ratio = peak / obs_bytes
    print(f"\n2000 photos, {n} points, {k} observations: tracemalloc peak {peak / 1e6:.1f} MB = "
          f"{ratio:.2f} × the observation table ({obs_bytes / 1e6:.1f} MB); one photos × points int64 array "
          f"would be {m * n * 8 / 1e9:.2f} GB")
    assert ratio < 8
    assert peak < 0.1 * (m * n * 8)
    # and it grows with the observations, not with photos × points (×16 from 500 to 2 000 photos)
    small, peak_small = _traced(n_strips=10, photos_per_strip=50)
    k_small = len(small.observations)
    assert len(small.photos) == 500
    growth = peak / peak_small
    print(f"500 photos: peak {peak_small / 1e6:.1f} MB; growth ×{growth:.2f} for ×{k / k_small:.2f} observations "
          f"and ×{m * n / (len(small.photos) * len(small.points)):.1f} photo–point pairs")
    assert growth < 1.25 * k / k_small


def test_2000_photo_block_has_the_requested_layout(block_2000):
    noisy, _ = block_2000
    S, P = 25, 80
    obs = noisy.observations
    m = S * P
    per_photo = np.bincount(obs.photo, minlength=m).reshape(S, P)
    interior = per_photo[1:-1, 1:-1]
    assert abs(np.median(per_photo) - 150) < 7.5
    assert abs(interior.mean() - 150) < 5
    # points shared by neighbouring photos: 60 % forward (next photo in the strip) and 30 % side
    # (same position in the next strip); a 10 px margin, 2 % jitter of the base and 1° tilts
    # take about 1.5 points of a percent off the nominal values
    key = obs.point.astype(np.int64) * m + obs.photo
    strip, pos = obs.photo // P, obs.photo % P

    def shared(step, ok):
        both = ok & np.isin(key + step, key)
        return np.bincount(obs.photo[both], minlength=m)

    fwd = shared(1, pos < P - 1).reshape(S, P)[:, :-1] / per_photo[:, :-1]
    side = shared(P, strip < S - 1).reshape(S, P)[:-1, :] / per_photo[:-1, :]
    print(f"\nmedian points per photo {np.median(per_photo):.0f}; forward overlap {fwd.mean():.3f} ± {fwd.std():.3f}; "
          f"side overlap {side.mean():.3f} ± {side.std():.3f}")
    assert abs(fwd.mean() - 0.6) < 0.03
    assert abs(side.mean() - 0.3) < 0.03
    # every observed point is in at least two photos, control points included
    rays = np.bincount(obs.point, minlength=len(noisy.points))
    assert rays.min() >= 2
    assert (noisy.points.role == "full").sum() >= 4 + (S // 4 + 1) * (P // 4)
