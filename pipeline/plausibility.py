"""Checks every block a source produces, whatever the reader: what no adjustment can use.

A reader checks its own format (and names the line); :func:`check_block` then checks the block it
built, so that no reader — built in or a plug-in — can pass on a silent wrong result:

* errors (:class:`InputError`, naming the source file): non-finite image coordinates or sigmas,
  a negative or NaN point sigma (0 is fixed, inf unknown),
  infinite coordinates or orientations (NaN means "unknown" there), a principal distance (NaN: to be
  found), pixel
  pitch (NaN: a film camera) or resolution that is not positive, an a-priori covariance that is not positive definite,
  duplicate camera / photo / point ids, the same point measured twice in one photo, a stereo pair
  listed twice (``L R`` and ``R L`` count the observations twice), image coordinates *far* outside
  the format (more than :data:`FAR` format sizes from the principal point: a misplaced decimal
  point or a unit mistake, never a real measurement; :data:`FAR_SPREAD` median spreads where neither
  format nor principal distance is known);
* warnings: image coordinates outside the format (by more than 10 %); photos without an active
  measurement (an AICON image whose measurements are all disabled), which no adjustment can use.

The runner applies it to the ``block`` of every stage that reads none (a source) and ``baarda
validate`` to the block a source's ``validate`` hook returns.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from .errors import InputError
from .model import Block

FAR = 10.0
"""Image coordinates farther than this many format sizes (or principal distances, where the format
is unknown) from the principal point are an error."""

FAR_SPREAD = 1000.0
"""Where neither format nor principal distance is known: image coordinates farther from the median
than this many times the camera's median spread are an error."""


def _first_duplicate(ids) -> str | None:
    seen = set()
    for i in ids:
        if i in seen:
            return str(i)
        seen.add(i)
    return None


def check_block(block: Block, path=None) -> list[str]:
    """Raise :class:`InputError` for what makes ``block`` unusable; return warnings (text)."""
    if path is None:
        path = block.source.path
    cams, ph, pts, obs = block.cameras, block.photos, block.points, block.observations

    lines = block.source.lines     # (photo, point) → (file, line), where a reader knows

    def fail(message, field=None, obs_index=None):
        where, line = path, None
        if obs_index is not None:
            where, line = lines.get((int(obs.photo[obs_index]), int(obs.point[obs_index])), (path, None))
        raise InputError(message, path=where, line=line, field=field)

    for what, ids in (("camera", cams.ids), ("photo", ph.ids), ("point", pts.ids)):
        dup = _first_duplicate(ids.tolist())
        if dup is not None:
            fail(f"{what} id '{dup}' occurs twice", what)
    for name in ("c", "pixel_mm"):           # NaN: not known (c to be found; a film camera's pixels)
        v = np.asarray(getattr(cams, name), float)
        bad = ~(np.isfinite(v) & (v > 0)) & ~np.isnan(v)
        if bad.any():
            k = int(np.argmax(bad))
            fail(f"camera '{cams.ids[k]}': {name} = {v[k]:g} must be a positive finite number", name)
    for name in ("xp", "yp", "ap", "format_mm"):     # NaN: not known, but for the AP values
        v = np.asarray(getattr(cams, name), float).reshape(len(cams), -1)
        bad = (np.isinf(v) | (np.isnan(v) if name == "ap" else False)).any(axis=1)
        if bad.any():
            fail(f"camera '{cams.ids[int(np.argmax(bad))]}': {name} is not finite", name)
    if (np.asarray(cams.format_mm) < 0).any() or (np.asarray(cams.resolution) < 0).any():
        k = int(np.argmax((np.asarray(cams.format_mm) < 0).any(axis=1) | (np.asarray(cams.resolution) < 0).any(axis=1)))
        fail(f"camera '{cams.ids[k]}': a negative image format or resolution", "format")
    for name, arr, ids in (("X0", ph.X0, ph.ids), ("opk", ph.opk, ph.ids), ("XYZ", pts.XYZ, pts.ids)):
        inf = np.isinf(np.asarray(arr, float)).any(axis=1)
        if inf.any():
            fail(f"{'photo' if name != 'XYZ' else 'point'} '{ids[int(np.argmax(inf))]}': {name} is infinite", name)
    sig = np.asarray(pts.sigma, float).reshape(len(pts), -1)          # 0 fixed, inf unknown
    bad = ((sig < 0) | np.isnan(sig)).any(axis=1)
    if bad.any():
        fail(f"point '{pts.ids[int(np.argmax(bad))]}': a-priori sigma must not be negative or NaN", "sigma")

    warnings: list[str] = []
    if len(obs):
        xy, cov = np.asarray(obs.xy, float), np.asarray(obs.cov, float)
        label = lambda k: f"point '{pts.ids[obs.point[k]]}' in photo '{ph.ids[obs.photo[k]]}'"   # noqa: E731
        bad = ~np.isfinite(xy).all(axis=1)
        if bad.any():
            fail(f"{label(int(np.argmax(bad)))}: image coordinates are not finite", "xy", int(np.argmax(bad)))
        a, b, d = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
        bad = ~(np.isfinite(cov).all(axis=(1, 2)) & (a > 0) & (d > 0) & (a * d - b * b > 0))
        if bad.any():
            fail(f"{label(int(np.argmax(bad)))}: the a-priori covariance is not positive definite "
                 "(a sigma that is zero, negative or not finite)", "sigma", int(np.argmax(bad)))
        act = np.flatnonzero(np.asarray(obs.active, bool))               # a switched-off copy is harmless
        key = obs.photo[act].astype(np.int64) * (len(pts) + 1) + obs.point[act]
        _, first, counts = np.unique(key, return_index=True, return_counts=True)
        if (counts > 1).any():
            k = int(act[first[np.argmax(counts > 1)]])
            fail(f"{label(k)} is measured twice (an observation listed twice would count twice)", "observation", k)
        cam = ph.camera[obs.photo]
        fmt = np.nan_to_num(np.asarray(cams.format_mm, float)[cam], nan=0.0)
        size = np.where(fmt.max(axis=1) > 0, fmt.max(axis=1), np.asarray(cams.c, float)[cam])
        centre = np.nan_to_num(np.stack([np.asarray(cams.xp, float)[cam], np.asarray(cams.yp, float)[cam]], axis=1))
        far = np.abs(xy - centre).max(axis=1) > FAR * size        # False where neither size is known (NaN)
        for k in np.unique(cam[~np.isfinite(size)]):              # neither: the spread of the camera's points
            sel = cam == k
            mid = np.median(xy[sel], axis=0)
            spread = np.median(np.abs(xy[sel] - mid))
            if spread > 0:
                far[sel] |= np.abs(xy[sel] - mid).max(axis=1) > FAR_SPREAD * spread
        if far.any():
            k = int(np.argmax(far))
            fail(f"{label(k)}: image coordinates ({xy[k, 0]:.6g}, {xy[k, 1]:.6g}) mm lie {FAR:g} format sizes "
                 f"or more from the principal point (a unit or decimal-point mistake?)", "xy", k)
        has_fmt = (fmt > 0).all(axis=1)
        outside = has_fmt & (np.abs(xy) > 0.55 * fmt).any(axis=1)
        if outside.any():
            k = int(np.argmax(outside))
            warnings.append(f"{int(outside.sum())} image coordinate(s) outside the format (first: {label(k)})")
    if len(obs) and len(ph):
        seen = np.zeros(len(ph), bool)
        seen[obs.photo[np.asarray(obs.active, bool)]] = True
        if not seen.all():
            idle = [str(i) for i in ph.ids[~seen]]
            warnings.append(f"{len(idle)} photo(s) without an active measurement take no part in an adjustment: "
                            + ", ".join(idle[:10]) + (" …" if len(idle) > 10 else ""))
    pairs = Counter(frozenset((int(a), int(b))) for a, b in zip(block.pairs.left, block.pairs.right))
    twice = [p for p, n in pairs.items() if n > 1]
    if twice:
        names = sorted(str(ph.ids[i]) for i in twice[0])
        fail(f"the stereo pair {' '.join(names)} is listed twice (in either order its observations would count "
             "twice)", "pair")
    same = [(a, b) for a, b in zip(block.pairs.left, block.pairs.right) if a == b]
    if same:
        fail(f"a stereo pair names photo '{ph.ids[same[0][0]]}' twice", "pair")
    return warnings
