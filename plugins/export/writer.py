"""Adjusted points with their precision, in the user's CRS, as PLY and CSV — numerics and writers.

:func:`export_points` converts the block's local coordinates and point covariances to the user's
CRS (``J C Jᵀ`` with the Jacobian of the local → CRS conversion, :meth:`LocalFrame.jacobian`);
:func:`write_ply` and :func:`write_csv` write them.  Format: ``docs/export.md``.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baarda.pipeline.crs import crs_label


@dataclass(frozen=True)
class PointExport:
    """What is written: ``ids``, ``role``, ``xyz (n, 3)`` in the output CRS, ``sigma (n, 3)``
    (units of the CRS's axes; metres east/north/up for a geographic CRS), ``local (n, 3)``,
    ``sigma_local (n, 3)``, ``rays (n,)``, ``names`` of the three axes, ``sigma_names``, ``crs``
    text (None: local)."""

    ids: np.ndarray
    role: np.ndarray
    xyz: np.ndarray
    sigma: np.ndarray
    local: np.ndarray
    sigma_local: np.ndarray
    rays: np.ndarray
    names: tuple
    sigma_names: tuple
    crs: str | None
    unit: str


def export_points(block, frame, cov=None, roles=None) -> PointExport:
    """Points of ``block`` with finite coordinates (and role in ``roles``) in ``frame``'s user CRS;
    ``cov (n, 3, 3)`` their covariance in the block's frame (nan/None: σ unknown)."""
    pts = block.points
    keep = np.isfinite(pts.XYZ).all(axis=1)
    if roles:
        keep &= np.isin(pts.role, list(roles))
    idx = np.flatnonzero(keep)
    local = np.array(pts.XYZ[idx], float)
    scale = 1e-3 if block.object_unit == "mm" and not frame.is_identity else 1.0
    C = np.full((len(idx), 3, 3), np.nan) if cov is None else np.array(cov, float)[idx]
    C = C * scale ** 2
    sig_local = np.sqrt(np.clip(np.einsum("kii->ki", C), 0, None))
    xyz = frame.from_local(local * scale) if len(idx) else np.zeros((0, 3))
    names = frame.axis_names()
    if frame.is_identity or names[0] == "lon":
        sigma = sig_local
        sigma_names = ("sX", "sY", "sZ") if frame.is_identity else ("sE_m", "sN_m", "sU_m")
    else:
        J = frame.jacobian(local * scale) if len(idx) else np.zeros((0, 3, 3))
        Cu = J @ C @ np.transpose(J, (0, 2, 1))
        sigma = np.sqrt(np.clip(np.einsum("kii->ki", Cu), 0, None))
        sigma_names = tuple("s" + n for n in names)
    rays = np.bincount(block.observations.point[block.observations.active], minlength=len(pts))[idx]
    return PointExport(ids=pts.ids[idx], role=pts.role[idx], xyz=xyz, sigma=sigma, local=local,
                       sigma_local=sig_local, rays=rays, names=names, sigma_names=sigma_names,
                       crs=frame.crs, unit=block.object_unit if frame.is_identity else "m")


def write_ply(path: str | Path, ex: PointExport, *, binary: bool = True) -> Path:
    """``vertex`` elements with ``double x y z`` (the CRS's axes in order) and ``float sx sy sz``;
    the CRS and the point ids in ``comment`` lines are not needed to read the file (plyfile)."""
    from plyfile import PlyData, PlyElement

    v = np.empty(len(ex.ids), dtype=[("x", "f8"), ("y", "f8"), ("z", "f8"), ("sx", "f4"), ("sy", "f4"),
                                      ("sz", "f4"), ("rays", "i4")])
    v["x"], v["y"], v["z"] = ex.xyz.T if len(ex.ids) else (np.zeros(0),) * 3
    v["sx"], v["sy"], v["sz"] = ex.sigma.T if len(ex.ids) else (np.zeros(0),) * 3
    v["rays"] = ex.rays
    comments = ["baarda adjusted points", f"axes {' '.join(ex.names)} sigma {' '.join(ex.sigma_names)}"]
    if ex.crs is not None:
        comments.append("crs " + crs_label(ex.crs))
    path = Path(path)
    PlyData([PlyElement.describe(v, "vertex")], text=not binary, byte_order="<",
            comments=comments).write(str(path))
    return path


def write_csv(path: str | Path, ex: PointExport) -> Path:
    """One row per point: id, role, the three coordinates, their σ, rays, and (with a CRS) the local
    frame's E, N, U; ``# crs:`` comment line first.  Coordinates with 4 decimals more than a
    millimetre (geographic: 1e-10 degree)."""
    path = Path(path)
    geo = ex.names[0] == "lon"
    with path.open("w", newline="", encoding="utf-8") as f:
        if ex.crs is not None:
            f.write(f"# crs: {crs_label(ex.crs)}\n")
        w = csv.writer(f)
        local = ex.crs is not None
        w.writerow(["point", "role", *ex.names, *ex.sigma_names, "rays"] + (["E_local", "N_local", "U_local"]
                                                                             if local else []))
        for k in range(len(ex.ids)):
            c = [f"{v:.12f}" for v in ex.xyz[k]] if geo else [f"{v:.6f}" for v in ex.xyz[k]]
            row = [ex.ids[k], ex.role[k], *c, *(f"{s:.6g}" for s in ex.sigma[k]), int(ex.rays[k])]
            if local:
                row += [f"{v:.6f}" for v in ex.local[k]]
            w.writerow(row)
    return path
