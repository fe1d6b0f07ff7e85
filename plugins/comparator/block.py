"""Turn a parsed comparator file into a :class:`baarda.pipeline.model.Block`.

Interior orientation (fiducial mode) is computed per photo by :mod:`.interior`; the tolerance
check returns the offending fiducials and leaves the decision (fail or warn) to the stage.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from baarda.pipeline.api import Block, InputError
from baarda.pipeline.model import Cameras, Observations, Pairs, Photos, Points, SourceInfo

from .interior import FIDUCIAL_COND_MAX, MIN_FIDUCIALS, InteriorFit, fiducial_spread_ratio, fit_interior
from .parser import ComparatorFile

DEFAULT_SIGMA_MM = 0.005
"""A-priori σ of one measured coordinate when the file has no ``sigma`` line (5 µm)."""

IMPLICIT_CAMERA = "camera"
"""Id of the camera created for a photo-mode file that declares none (c and format unknown)."""


@dataclass(frozen=True)
class InteriorResult:
    """Interior orientation of one photo: the fit, and which fiducial (and line) each row is."""

    photo: str
    fit: InteriorFit
    fiducials: tuple[str, ...]
    lines: tuple[int, ...]
    photo_line: int
    calibrated: np.ndarray
    """(n, 2) calibrated fiducial coordinates, mm (the fit's observations)."""

    def report(self, unit_um: float = 1000.0) -> dict:
        """JSON-friendly summary; residuals in µm."""
        return {
            "photo": self.photo, "transform": self.fit.kind, "fiducials": list(self.fiducials),
            "dof": self.fit.dof,
            "sigma0_hat_um": None if math.isnan(self.fit.sigma0_hat) else self.fit.sigma0_hat * unit_um,
            "residuals_um": {f: [float(v[0] * unit_um), float(v[1] * unit_um)]
                             for f, v in zip(self.fiducials, self.fit.residuals)},
            "parameters": self.fit.parameters,
        }


@dataclass(frozen=True)
class ToleranceViolation:
    photo: str
    fiducial: str
    residual_mm: float
    line: int

    def message(self, tolerance_mm: float, kind: str, sigma0_hat_mm: float) -> str:
        s0 = "no redundancy" if math.isnan(sigma0_hat_mm) else f"σ̂0 = {sigma0_hat_mm * 1000:.1f} µm"
        return (f"photo {self.photo}: fiducial {self.fiducial} misses the {kind} interior orientation "
                f"by {self.residual_mm * 1000:.1f} µm, more than the tolerance of {tolerance_mm * 1000:.1f} µm "
                f"({s0}); check its measurement or the camera's calibrated fiducial coordinates")


def interior_orientation(parsed: ComparatorFile, transform: str | None = None) -> dict[str, InteriorResult]:
    """Fit every photo's interior orientation (fiducial mode; empty dict in photo mode)."""
    if parsed.mode != "fiducial":
        return {}
    kind = transform or parsed.transform
    out = {}
    for ph in parsed.photos.values():
        cam = parsed.cameras[ph.camera] if ph.camera else next(iter(parsed.cameras.values()))
        ids = tuple(ph.fids)
        need = MIN_FIDUCIALS[kind]
        if len(ids) < need:
            raise InputError(f"photo {ph.id!r} has {len(ids)} measured fiducial(s); the {kind} interior "
                             f"orientation needs at least {need}", parsed.path, ph.line, "fid")
        XY = np.array([[ph.fids[f].x, ph.fids[f].y] for f in ids]) * parsed.unit_mm
        xy = np.array([[cam.fiducials[f].x, cam.fiducials[f].y] for f in ids])
        if kind == "affine" and (ratio := fiducial_spread_ratio(XY)) > FIDUCIAL_COND_MAX:
            lines = ", ".join(str(ph.fids[f].line) for f in ids)
            raise InputError(f"photo {ph.id!r}: the fiducials {', '.join(ids)} (lines {lines}) lie nearly on one line "
                             f"(principal spreads in the ratio {ratio:.3g} : 1, more than {FIDUCIAL_COND_MAX:g}): "
                             "they cannot determine the affine interior orientation", parsed.path,
                             ph.fids[ids[0]].line, "fid")
        try:
            fit = fit_interior(XY, xy, kind)
        except ValueError as e:
            raise InputError(f"photo {ph.id!r}: {e}", parsed.path, ph.line, "fid") from None
        out[ph.id] = InteriorResult(ph.id, fit, ids, tuple(ph.fids[f].line for f in ids), ph.line, xy)
    return out


def tolerance_violations(results: dict[str, InteriorResult], tolerance_mm: float) -> list[ToleranceViolation]:
    """Fiducials whose residual vector is longer than ``tolerance_mm`` (largest first per photo)."""
    out = []
    for res in results.values():
        norms = res.fit.residual_norm
        for k in np.argsort(-norms):
            if norms[k] > tolerance_mm:
                out.append(ToleranceViolation(res.photo, res.fiducials[k], float(norms[k]), res.lines[k]))
    return out


def build_block(parsed: ComparatorFile, interior: dict[str, InteriorResult]) -> Block:
    """The block: cameras, photos, points, observations (mm, image system) and pairs.

    Observation covariance: the file's ``sigma`` (or a point's own ``sx sy``) in comparator units,
    converted to mm and, in fiducial mode, propagated through the linear part ``M`` of the
    photo's interior orientation (``cov = M Σ Mᵀ``).
    """
    u = parsed.unit_mm
    # cameras
    if parsed.cameras:
        cams = list(parsed.cameras.values())
        cameras = Cameras.make([c.id for c in cams], [c.c for c in cams], [c.xp for c in cams],
                               [c.yp for c in cams], format_mm=[c.format_mm for c in cams])
        cam_index = {c.id: i for i, c in enumerate(cams)}
    else:
        cameras = Cameras.make([IMPLICIT_CAMERA], [math.nan])
        cam_index = {IMPLICIT_CAMERA: 0}
    photos_l = list(parsed.photos.values())
    cam_of = [cam_index[p.camera] if p.camera else 0 for p in photos_l]
    photos = Photos.make([p.id for p in photos_l], camera=cam_of)
    # points: declared object points first, then measured-only ones (tie, unknown XYZ)
    ids = list(parsed.points)
    seen = set(ids)
    for p in photos_l:
        for pid in p.pts:
            if pid not in seen:
                seen.add(pid)
                ids.append(pid)
    roles, xyz, sig = [], [], []
    for pid in ids:
        rec = parsed.points.get(pid)
        roles.append(rec.role if rec else "tie")
        xyz.append(rec.XYZ if rec else (math.nan,) * 3)
        sig.append(rec.sigma if rec else None)
    points = Points.make(ids, np.array(xyz, float).reshape(-1, 3), roles)
    if any(s is not None for s in sig):
        sigma = points.sigma.copy()
        for i, s in enumerate(sig):
            if s is not None:
                sigma[i] = s
        points = points.replace(sigma=sigma)
    point_index = {pid: i for i, pid in enumerate(ids)}
    # observations
    default_sigma = parsed.sigma if parsed.sigma is not None else (DEFAULT_SIGMA_MM / u,) * 2
    o_photo, o_point, o_xy, o_cov, lines = [], [], [], [], {}
    for i, p in enumerate(photos_l):
        if not p.pts:
            continue
        XY = np.array([[m.x, m.y] for m in p.pts.values()]) * u
        sx = np.array([(m.sigma or default_sigma) for m in p.pts.values()]) * u
        cov = np.zeros((len(XY), 2, 2))
        cov[:, 0, 0], cov[:, 1, 1] = sx[:, 0] ** 2, sx[:, 1] ** 2
        if p.id in interior:
            fit = interior[p.id].fit
            XY = fit.apply(XY)
            cov = fit.M @ cov @ fit.M.T
        for m in p.pts.values():
            lines[(i, point_index[m.id])] = (str(parsed.path), m.line)
        o_photo += [i] * len(XY)
        o_point += [point_index[m] for m in p.pts]
        o_xy.append(XY)
        o_cov.append(cov)
    obs = Observations.make(o_photo, o_point, np.concatenate(o_xy) if o_xy else np.zeros((0, 2)),
                            cov=np.concatenate(o_cov) if o_cov else np.zeros((0, 2, 2)))
    photo_index = {p.id: i for i, p in enumerate(photos_l)}
    pairs = Pairs(left=np.array([photo_index[p.left] for p in parsed.pairs], int),
                  right=np.array([photo_index[p.right] for p in parsed.pairs], int))
    meta = {"comparator": {
        "mode": parsed.mode, "unit": parsed.unit,
        "transform": next(iter(interior.values())).fit.kind if interior else None,
        "photo_lines": {p.id: (str(parsed.path), p.line) for p in photos_l},
        "interior_orientation": {k: r.report() for k, r in interior.items()},
    }}
    source = SourceInfo(path=str(parsed.path), format="baarda-comparator", lines=lines,
                        pair_lines=[(str(parsed.path), p.line) for p in parsed.pairs])
    return Block(cameras=cameras, photos=photos, points=points, observations=obs, pairs=pairs,
                 object_unit=parsed.object_unit, meta=meta, source=source)
