"""Settings, state and scale bars of the bundle adjustment (``docs/bundle.md``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal, Mapping

import numpy as np

from baarda.pipeline.errors import InputError
from baarda.pipeline.model import Block

__all__ = ["Distance", "BundleSettings", "BundleState", "camera_meta"]


@dataclass(frozen=True)
class Distance:
    """A measured distance between two object points (scale bar), object units."""

    a: str
    b: str
    distance: float
    sigma: float


@dataclass(frozen=True)
class BundleSettings:
    """Numerical settings of :func:`solve_bundle` (the stage maps its options onto these)."""

    datum: Literal["control", "free"] = "control"
    datum_points: tuple[str, ...] | None = None
    """free network: ids of the points that carry the inner constraints (None = every tie and
    check point that is observed)."""
    datum_centres: bool = False
    """free network: put the inner constraints on the projection centres instead of points."""
    sigma0: float = 1.0
    variance: Literal["a-posteriori", "a-priori"] = "a-posteriori"
    """covariances as ``σ̂0² Q`` (a-posteriori, the default) or ``σ0² Q`` (a-priori: network design at
    error-free observations, where σ̂0 = 0; ``docs/design.md``)."""
    max_iter: int = 30
    tol_obs: float = 1e-5
    """converged when the last correction moves no observation by more than tol_obs × its σ."""
    tol_rel: float = 1e-12
    """... or when vᵀPv changes by less than this fraction."""
    damping: bool = True
    """Levenberg–Marquardt damping when a Gauss–Newton step does not reduce vᵀPv."""
    distances: tuple[Distance, ...] = ()
    on_weak: Literal["error", "drop"] = "error"
    """photos with < 3 points / points in < 2 photos: raise, or drop them with a warning."""
    ap_meta: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    """camera id -> AP-model meta overrides (``b`` for ebner12, ``r0`` for aicon)."""
    covariance: bool = True
    threads: int = 1
    """Python threads for the work that can share them: the dense route's photo-pair products of the
    Schur complement and the per-photo sums (compiled kernels that release the GIL), on either
    route; the sparse route's factorisation and selected inversion run on one thread (subtrees on
    threads were measured not to pay).  BLAS runs one thread inside the adjustment whoever calls it
    (:mod:`.threads`: the adjustment limits it itself with threadpoolctl and restores the caller's
    setting afterwards); results do not depend on ``threads``."""
    solver: Literal["auto", "dense", "sparse"] = "auto"
    """reduced camera system: dense Cholesky, or the sparse supernodal factorisation with selected
    inversion (``docs/bundle.md``, "Sparse route"); ``auto`` chooses by size and fill."""
    residual: Literal["measured", "corrected"] = "measured"
    """image residuals of backward-model cameras (``brown-backward``): of the measured marks
    (baarda's) or DBAT's, the corrected mark minus the ideal projection (:mod:`.corrected`)."""


@dataclass
class BundleState:
    """The parameters of one iterate (all arrays copies, never views of the block)."""

    cam_params: np.ndarray  # (K, 3 + p)  c, xp, yp, ap...
    X0: np.ndarray          # (m, 3)
    opk: np.ndarray         # (m, 3)
    XYZ: np.ndarray         # (n, 3)
    frame: np.ndarray | None = None    # (F, 6) the frames' poses X0, ω φ κ (rigs only; docs/rigs.md)
    sensor: np.ndarray | None = None   # (S, 6) the sensors' poses in their rig (rigs only)

    def copy(self) -> "BundleState":
        return BundleState(self.cam_params.copy(), self.X0.copy(), self.opk.copy(), self.XYZ.copy(),
                           None if self.frame is None else self.frame.copy(),
                           None if self.sensor is None else self.sensor.copy())


def check_unique(ids, what: str) -> None:
    """InputError naming the first id that occurs twice."""
    ids = np.asarray(ids, str)
    u, inv, cnt = np.unique(ids, return_inverse=True, return_counts=True)
    if (cnt > 1).any():
        bad = u[np.argmax(cnt > 1)]
        rows = np.flatnonzero(ids == bad) + 1
        raise InputError(f"duplicate {what} id {str(bad)!r} (rows {', '.join(map(str, rows))}); ids must be unique",
                         field=f"{what} id")


def camera_meta(block: Block, settings: BundleSettings) -> list[dict]:
    """AP-model meta per camera: block.ap_meta[id] updated by settings.ap_meta[id];
    ebner12 without ``b`` gets ``b = 0.4 × format width`` (the base of 60 % forward overlap)."""
    cams = block.cameras
    base = block.ap_meta
    out = []
    for j, cid in enumerate(cams.ids.tolist()):
        m = dict(base.get(cid, {}))
        m.update(settings.ap_meta.get(cid, {}))
        if cams.ap_model[j] == "ebner12" and m.get("b") is None:
            w = float(cams.format_mm[j, 0])
            if np.isfinite(w) and w > 0:
                m["b"] = 0.4 * w
        out.append(m)
    return out


def block_distances(block: Block) -> list[Distance]:
    """Scale bars stored with the block (``block.scale_bars``) as :class:`Distance`."""
    return [Distance(a, b, d, s) for a, b, d, s in block.scale_bars.rows()]
