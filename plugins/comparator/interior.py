"""Interior orientation of a comparator photo: machine coordinates → fiducial (image) system.

Pure numerics: arrays in, a small frozen result out; nothing here knows about files or stages.

Two transformations, both fitted by unweighted least squares on the fiducial marks
(machine coordinates converted to mm first, so that the parameters are near unit scale):

* ``affine`` (6 parameters, at least 3 fiducials)::

      x = a0 + a1 X + a2 Y
      y = b0 + b1 X + b2 Y

* ``similarity`` (4 parameters, at least 2 fiducials)::

      x = a X − b Y + tx
      y = b X + a Y + ty

Residuals are **observed minus computed** (docs/conventions.md) with the calibrated fiducial
coordinates as the observations: ``v = xy_calibrated − T(XY_machine)`` in mm of the image system.
``sigma0_hat = √(Σ v² / dof)`` with ``dof = 2 n − u`` is the standard deviation of one fiducial
coordinate (nan when the fiducials give no redundancy).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from baarda.pipeline.geometry.transforms import affine_design, helmert_design

KINDS = {"affine": 6, "similarity": 4}
"""Transformation name → number of parameters."""

FIDUCIAL_COND_MAX = 100.0
"""Largest accepted ratio of the two principal spreads (singular values of the centred machine
coordinates) of the fiducials of an affine interior orientation: beyond it the fiducials lie so close
to one line that the affine transformation across that line is not determined (an InputError)."""

MIN_FIDUCIALS = {"affine": 3, "similarity": 2}
"""Fewest fiducial marks each transformation can be computed from."""


@dataclass(frozen=True, eq=False)
class InteriorFit:
    """Result of :func:`fit_interior`.

    kind : ``"affine"`` or ``"similarity"``.
    M : (2, 2) linear part and t : (2,) shift, so that ``xy = XY_mm @ M.T + t``.
    residuals : (n, 2) mm, calibrated minus transformed fiducial coordinates.
    dof : redundancy ``2 n − u``.
    sigma0_hat : mm, nan when ``dof == 0``.
    """

    kind: str
    M: np.ndarray
    t: np.ndarray
    residuals: np.ndarray
    dof: int
    sigma0_hat: float

    @property
    def parameters(self) -> dict:
        """The transformation's own parameters (for reports)."""
        if self.kind == "similarity":
            a, b = self.M[0, 0], self.M[1, 0]
            return {"a": float(a), "b": float(b), "tx": float(self.t[0]), "ty": float(self.t[1]),
                    "scale": float(np.hypot(a, b)), "rotation_rad": float(np.arctan2(b, a))}
        return {"a0": float(self.t[0]), "a1": float(self.M[0, 0]), "a2": float(self.M[0, 1]),
                "b0": float(self.t[1]), "b1": float(self.M[1, 0]), "b2": float(self.M[1, 1])}

    @property
    def residual_norm(self) -> np.ndarray:
        """(n,) length of each fiducial's residual vector, mm."""
        return np.hypot(self.residuals[:, 0], self.residuals[:, 1])

    def apply(self, XY_mm: np.ndarray) -> np.ndarray:
        """Transform machine coordinates (already in mm), shape (k, 2), into the image system."""
        return np.asarray(XY_mm, float).reshape(-1, 2) @ self.M.T + self.t


def fiducial_spread_ratio(XY_machine_mm: np.ndarray) -> float:
    """Ratio of the larger to the smaller principal spread of the fiducials (inf when collinear):
    the condition of the affine interior orientation's linear part (:data:`FIDUCIAL_COND_MAX`)."""
    XY = np.asarray(XY_machine_mm, float).reshape(-1, 2)
    s = np.linalg.svd(XY - XY.mean(axis=0), compute_uv=False)
    return float(s[0] / s[1]) if len(s) > 1 and s[1] > 0 else float("inf")


def design_rows(kind: str, XY: np.ndarray) -> np.ndarray:
    """Design matrix (2n, u) of the transformation, rows x1, y1, x2, y2, …"""
    if kind == "affine":
        return affine_design(XY)
    if kind == "similarity":
        return helmert_design(XY)
    raise ValueError(f"unknown interior-orientation transformation {kind!r}; expected one of {sorted(KINDS)}")


def fit_interior(XY_machine_mm: np.ndarray, xy_calibrated: np.ndarray, kind: str = "affine") -> InteriorFit:
    """Fit the machine → image transformation on the fiducial marks.

    Parameters
    ----------
    XY_machine_mm : (n, 2) measured machine coordinates of the fiducials, converted to mm.
    xy_calibrated : (n, 2) calibrated fiducial coordinates (camera calibration), mm.
    kind : ``"affine"`` or ``"similarity"``.

    Raises ``ValueError`` when there are fewer fiducials than the transformation needs or the
    fiducials are degenerate (collinear for the affine transformation, coincident for the
    similarity); the caller turns that into a message naming the photo.
    """
    XY = np.asarray(XY_machine_mm, float).reshape(-1, 2)
    xy = np.asarray(xy_calibrated, float).reshape(-1, 2)
    if XY.shape != xy.shape:
        raise ValueError(f"machine and calibrated fiducials differ in shape: {XY.shape} vs {xy.shape}")
    if kind not in KINDS:
        raise ValueError(f"unknown interior-orientation transformation {kind!r}; expected one of {sorted(KINDS)}")
    n = XY.shape[0]
    if n < MIN_FIDUCIALS[kind]:
        raise ValueError(f"{kind} interior orientation needs at least {MIN_FIDUCIALS[kind]} fiducials, got {n}")
    # Reduce to the centroid for conditioning; the shift is restored below.
    c = XY.mean(axis=0)
    A = design_rows(kind, XY - c)
    l = xy.reshape(-1)
    if np.linalg.matrix_rank(A) < A.shape[1]:
        raise ValueError(f"the fiducial marks are degenerate for the {kind} transformation "
                         f"(collinear or coincident)")
    p, *_ = np.linalg.lstsq(A, l, rcond=None)
    if kind == "affine":
        M = np.array([[p[1], p[2]], [p[4], p[5]]])
        t0 = np.array([p[0], p[3]])
    else:
        M = np.array([[p[0], -p[1]], [p[1], p[0]]])
        t0 = np.array([p[2], p[3]])
    t = t0 - M @ c
    v = (l - A @ p).reshape(-1, 2)
    dof = 2 * n - KINDS[kind]
    s0 = float(np.sqrt((v ** 2).sum() / dof)) if dof > 0 else float("nan")
    v.flags.writeable = False
    return InteriorFit(kind=kind, M=M, t=t, residuals=v, dof=dof, sigma0_hat=s0)
