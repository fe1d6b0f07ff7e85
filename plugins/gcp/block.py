"""Blocks from GCP lists and GNSS projection centres — numerics, no files.

* :func:`gcp_block` — an ODM ``gcp_list.txt`` (already parsed) and a known camera as a block in the
  local frame: photos by name (orientation unknown), the targets as control (or check) points,
  their pixel measurements converted to mm.
* :func:`apply_gnss` — GNSS antenna positions with a per-camera lever arm as observations of the
  bundle (``Block.gnss``; the bundle adjusts ``X_antenna + v = X0 + R_cam_from_worldᵀ · e``).

Conventions: ``docs/conventions.md`` (pixels ↔ mm, rotations), ``docs/crs.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from baarda.pipeline.api import Block, InputError
from baarda.pipeline.geometry import mm_from_pixels, rotation_from_opk_many
from baarda.pipeline.model import FREE, Cameras, Gnss, Observations, Photos, Points, SourceInfo


@dataclass(frozen=True)
class CameraSpec:
    """A camera in pixels: ``width × height``, focal length ``focal_px``, pixel pitch ``pixel_mm``,
    principal point offset ``(cx_px, cy_px)`` from the image centre (x right, y down), OpenSfM's
    radial ``k1, k2`` of normalised coordinates."""

    id: str
    width: int
    height: int
    focal_px: float
    pixel_mm: float
    cx_px: float = 0.0
    cy_px: float = 0.0
    k1: float = 0.0
    k2: float = 0.0

    def cameras(self) -> Cameras:
        p = self.pixel_mm
        c = self.focal_px * p
        ap_model, ap = "none", None
        if self.k1 or self.k2:
            # Brown's Δx = x̄ (K1 r² + K2 r⁴) with r in mm; OpenSfM's r is normalised by the focal length
            ap_model = "brown"
            ap = np.array([[self.k1 / c ** 2, self.k2 / c ** 4, 0, 0, 0, 0, 0]], float)
        return Cameras.make([self.id], c, self.cx_px * p, -self.cy_px * p, ap_model=ap_model, ap=ap,
                            format_mm=[self.width * p, self.height * p], pixel_mm=p,
                            resolution=[self.width, self.height])


def gcp_block(gcp, camera: CameraSpec, frame, *, sigma_px: float = 1.0, sigma_control=(0.02, 0.02, 0.03),
              check=(), min_points: int = 4, check_where: dict | None = None) -> tuple[Block, dict]:
    """The block of a parsed GCP list (:class:`~.reader.GcpList`) in ``frame`` (a
    :class:`~baarda.pipeline.crs.LocalFrame`; object unit m).

    Targets become control points (role ``full``, a-priori σ ``sigma_control`` (E, N, h) metres) or,
    when named in ``check``, check points.  Photos with fewer than ``min_points`` measured control
    targets cannot be resected and are left out with their measurements (``info["dropped_photos"]``);
    none left is an InputError saying so (before a check-list mistake).  ``check_where`` (``path``,
    ``line``): where the check list is written, named when it names a target the list lacks.
    Pixels: ODM's column/row with the origin at the centre of the top-left pixel, y down (OpenCV's
    convention); outside the image is an error naming the line.
    """
    W, H = camera.width, camera.height
    u, v = gcp.pixel[:, 0], gcp.pixel[:, 1]
    bad = np.flatnonzero((u < -0.5) | (u > W - 0.5) | (v < -0.5) | (v > H - 0.5))
    if bad.size:
        k = bad[0]
        fld = "im_x" if not -0.5 <= u[k] <= W - 0.5 else "im_y"
        raise InputError(f"pixel ({u[k]:g}, {v[k]:g}) lies outside the {W} × {H} image of the camera "
                         "(wrong camera size, or a list for resized images?)", path=gcp.path,
                         line=int(gcp.line[k]), field=fld)
    names = list(dict.fromkeys(gcp.name))
    unknown = sorted(set(check) - set(names))
    n_control = {i: 0 for i in dict.fromkeys(gcp.image)}
    for i, n in zip(gcp.image, gcp.name):
        n_control[i] += int(n not in set(check))
    if n_control and max(n_control.values()) < min_points:     # the real reason first, then a check-list mistake
        most = max(n_control.values())
        n_chk = len(set(check) & set(names))
        raise InputError(f"no photo can be resected: a photo needs {min_points} measured control targets (min_points) "
                         f"and the best of the {len(n_control)} photo(s) measures {most}"
                         + (f" ({n_chk} of the list's {len(names)} targets are check points, which do not count)"
                            if n_chk else "")
                         + (f"; the check list also names {', '.join(map(repr, unknown))}, not in this list"
                            if unknown else ""), path=gcp.path, field="image_name")
    if unknown:
        raise InputError(f"check point(s) {', '.join(map(repr, unknown))} not in the GCP list {gcp.path} (its targets: "
                         f"{', '.join(names[:10])}{' …' if len(names) > 10 else ''})", field="check",
                         **(check_where or {}))
    first = {n: k for k, n in reversed(list(enumerate(gcp.name)))}
    geo = np.array([gcp.geo[first[n]] for n in names])
    XYZ = frame.to_local(geo)
    role = np.array(["check" if n in set(check) else "full" for n in names], dtype=object)
    sig = np.where((role == "full")[:, None], np.broadcast_to(np.asarray(sigma_control, float), (len(names), 3)),
                   FREE)
    pt_index = {n: k for k, n in enumerate(names)}
    images = list(dict.fromkeys(gcp.image))
    counts = {i: 0 for i in images}
    for i, n in zip(gcp.image, gcp.name):
        counts[i] += int(n not in set(check))
    keep_images = [i for i in images if counts[i] >= min_points]
    dropped = {i: counts[i] for i in images if counts[i] < min_points}
    if not keep_images:
        raise InputError(f"no photo sees {min_points} control targets (most: {max(counts.values())}); a photo of a "
                         "GCP-only project is resected from its targets", path=gcp.path, field="image_name")
    ph_index = {i: k for k, i in enumerate(keep_images)}
    rows = np.array([k for k, i in enumerate(gcp.image) if i in ph_index], int)
    xy = mm_from_pixels(gcp.pixel[rows], (W, H), camera.pixel_mm, convention="opencv")
    obs = Observations.make([ph_index[gcp.image[k]] for k in rows], [pt_index[gcp.name[k]] for k in rows], xy,
                            sigma=sigma_px * camera.pixel_mm)
    # points seen in no kept photo stay in the block (their coordinates are reported) but have no rays
    points = Points.make(names, XYZ, role.astype(str), sigma=sig)
    photos = Photos.make(keep_images, 0)
    source = SourceInfo(
        path=str(gcp.path), format="gcp_list",
        lines={(int(ph_index[gcp.image[k]]), int(pt_index[gcp.name[k]])): (str(gcp.path), int(gcp.line[k]))
               for k in rows})
    meta = {
        "gcp": {"path": str(gcp.path), "crs": gcp.crs, "user_xyz": geo, "dropped_photos": dropped,
                "measurements": int(len(gcp.image)), "used_measurements": int(len(rows))},
    }
    info = {"targets": len(names), "photos": len(keep_images), "dropped_photos": dropped,
            "measurements": len(gcp.image), "used_measurements": int(len(rows)),
            "control": int((role == "full").sum()), "check": int((role == "check").sum())}
    return Block(camera.cameras(), photos, points, obs, object_unit="m", meta=meta, crs=frame.info(),
                 source=source), info


def apply_gnss(block: Block, photo_ids, X_antenna, sigma, *, lever_arm=None, opk_default=None) -> tuple[Block, dict]:
    """``block`` with GNSS antenna observations of the photos ``photo_ids`` (``block.gnss``).

    ``X_antenna (g, 3)`` antenna positions in the block's object system and unit, ``sigma (g, 3)``
    their standard deviations (or ``(g, 3, 3)`` covariances); ``lever_arm`` ``{camera id: (3,)}``
    the antenna in the camera frame (x right, y up, z back out of the lens; object unit).  The
    bundle adjusts ``X_antenna + v = X0 + R_cam_from_worldᵀ · lever_arm`` as an observation of the
    photo's orientation (``docs/bundle.md``): no reduction with a fixed attitude here.

    Initial values only: a photo without an attitude gets ``opk_default`` (e.g. nadir), and a photo
    without a projection centre but with an attitude gets ``X0 = X_antenna − Rᵀ · lever_arm`` — so
    it needs no resection.  Earlier antenna observations of other photos are kept; a photo named
    again is replaced.  Photo ids the block lacks are skipped (``info["unknown_photos"]``).
    """
    ph = block.photos
    idx = {p: k for k, p in enumerate(ph.ids.tolist())}
    keep = [k for k, p in enumerate(photo_ids) if p in idx]
    missing = [p for p in photo_ids if p not in idx]
    rows = np.array([idx[photo_ids[k]] for k in keep], int)
    Xa = np.asarray(X_antenna, float)[keep].reshape(-1, 3)
    sig = np.asarray(sigma, float)[keep]
    cams = list(block.cameras.ids)
    arms = np.zeros((len(ph), 3))
    for cid, a in (lever_arm or {}).items():
        arms[ph.camera == cams.index(cid)] = np.asarray(a, float)
    arm = arms[rows]
    X0 = np.array(ph.X0, float)
    opk = np.array(ph.opk, float)
    if opk_default is not None:
        no_att = ~np.isfinite(opk[rows]).all(axis=1)
        opk[rows[no_att]] = np.asarray(opk_default, float)
    start = ~np.isfinite(X0[rows]).all(axis=1) & np.isfinite(opk[rows]).all(axis=1)
    if start.any():
        R = rotation_from_opk_many(opk[rows[start]])
        X0[rows[start]] = Xa[start] - np.einsum("kji,kj->ki", R, arm[start])      # X_antenna − Rᵀ e
    new = Gnss.make(rows, Xa, sigma=sig if sig.ndim == 2 else None, cov=sig if sig.ndim == 3 else None, lever_arm=arm)
    old = block.gnss
    if len(old):
        stay = ~np.isin(old.photo, rows)
        new = Gnss(photo=np.r_[old.photo[stay], new.photo], XYZ=np.vstack([old.XYZ[stay], new.XYZ]),
                   cov=np.concatenate([old.cov[stay], new.cov]), lever_arm=np.vstack([old.lever_arm[stay], new.lever_arm]))
    out = block.replace(photos=ph.replace(X0=X0, opk=opk), gnss=new)
    info = {"photos_with_gnss": int(len(rows)), "unknown_photos": missing,
            "lever_arm_nonzero": int((np.abs(arm).sum(axis=1) > 0).sum()),
            "max_lever_arm": float(np.linalg.norm(arm, axis=1).max()) if len(arm) else 0.0,
            "initial_centres": int(start.sum())}
    return out, info
