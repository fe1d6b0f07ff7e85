"""Pre-analysis numerics: a planned network as a block of error-free observations, its noisy
realisations, and the comparison of realised with predicted precision (``docs/design.md``).

Pure numerics: arrays and blocks in, arrays and blocks out, randomness only through ``rng``.  The
projection is the bundle's own collinearity (:func:`baarda.pipeline.adjustment.project_observations`),
so the planned observations are exactly what the adjustment computes at the planned parameters.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats as sps

from baarda.pipeline.adjustment import BundleSettings, BundleState, adjust, camera_meta, project_observations
from baarda.pipeline.camera import get_ap_model
from baarda.pipeline.api import Block
from baarda.pipeline.model import FIXED, FREE, Cameras, Observations, Photos, Points

__all__ = ["PlannedCamera", "plan_block", "realise", "realisation_errors", "truth_state", "ratio_test",
           "RatioTest", "joint_test"]


@dataclass(frozen=True)
class PlannedCamera:
    """The planned camera: principal distance, pixel pitch and format, AP model, parameter status."""

    c: float                           # mm
    pixel_mm: float
    resolution: tuple[int, int]        # pixels (width, height)
    ap_model: str = "none"
    xp: float = 0.0
    yp: float = 0.0
    ap: dict | None = None             # AP name -> planned value (default 0)
    free: tuple[str, ...] = ()         # parameter names estimated without constraint
    sigma: dict | None = None          # parameter name -> a-priori σ (weighted constraint)
    ap_meta: dict | None = None        # AP-model meta (``b`` of ebner12, ``r0`` of aicon)

    def names(self) -> list[str]:
        return ["c", "xp", "yp"] + list(get_ap_model(self.ap_model).params)

    def cameras(self, cid: str = "cam") -> Cameras:
        names = self.names()
        p = len(names) - 3
        ap = np.zeros(p)
        for k, v in (self.ap or {}).items():
            ap[names.index(k) - 3] = v
        sig = np.full(3 + p, FIXED)
        for k in self.free:
            sig[names.index(k)] = FREE
        for k, v in (self.sigma or {}).items():
            sig[names.index(k)] = v
        w, h = self.resolution
        return Cameras.make([cid], self.c, self.xp, self.yp, ap_model=self.ap_model,
                            ap=ap[None] if p else None, sigma_iop=sig[:3], sigma_ap=sig[None, 3:] if p else None,
                            format_mm=(w * self.pixel_mm, h * self.pixel_mm), pixel_mm=self.pixel_mm,
                            resolution=(w, h))


def plan_block(camera: PlannedCamera, station_ids, X0, opk, target_ids, XYZ, role, *, sigma_image_mm: float,
               sigma_control: float = 0.0, margin_mm: float = 0.0, object_unit: str = "m") -> Block:
    """The planned network as a block whose observations are the exact projections.

    Every target is observed in every station where it lies in front of the camera and inside the
    format less ``margin_mm``.  ``sigma_image_mm``: a-priori σ of each image coordinate;
    ``sigma_control``: a-priori σ of each control coordinate (object units; 0 = fixed control).
    """
    X0 = np.asarray(X0, float)
    opk = np.asarray(opk, float)
    XYZ = np.asarray(XYZ, float)
    role = np.asarray(role, str)
    cams = camera.cameras()
    m, n = len(X0), len(XYZ)
    ph = np.repeat(np.arange(m), n)
    pt = np.tile(np.arange(n), m)
    sig = np.full((n, 3), FREE)
    ctrl = sigma_control if sigma_control > 0 else FIXED
    sig[role == "full"] = ctrl
    sig[role == "xy", :2] = ctrl
    sig[role == "z", 2] = ctrl
    points = Points.make(list(map(str, target_ids)), XYZ, role, sigma=sig)
    photos = Photos.make(list(map(str, station_ids)), 0, X0, opk)
    empty = Block(cams, photos, points, Observations.make(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2))),
                  object_unit=object_unit, meta={"design": True}, ap_meta={"cam": dict(camera.ap_meta or {})})
    meta = camera_meta(empty, BundleSettings())
    params = np.r_[cams.c[0], cams.xp[0], cams.yp[0], cams.ap[0]][None]
    pr = project_observations(ph, pt, XYZ, X0, opk, np.zeros(m, int), params, [camera.ap_model], meta,
                              jacobians=False)
    half = np.asarray(cams.format_mm[0]) / 2.0 - margin_mm
    seen = (pr.W < 0) & (np.abs(pr.xy[:, 0]) <= half[0]) & (np.abs(pr.xy[:, 1]) <= half[1])
    obs = Observations.make(ph[seen], pt[seen], pr.xy[seen], sigma=sigma_image_mm)
    return empty.replace(observations=obs)


def truth_state(block: Block) -> BundleState:
    """The planned parameters (those of the error-free block) as a bundle state."""
    cams = block.cameras
    return BundleState(cam_params=np.column_stack([cams.c, cams.xp, cams.yp, cams.ap]),
                       X0=np.array(block.photos.X0, float), opk=np.array(block.photos.opk, float),
                       XYZ=np.array(block.points.XYZ, float))


def realise(block: Block, rng: np.random.Generator) -> Block:
    """One measurement of the planned network: each image coordinate pair plus N(0, its covariance),
    each weighted control coordinate plus N(0, its σ); fixed control and tie points unchanged."""
    obs = block.observations
    L = np.linalg.cholesky(obs.cov)
    xy = obs.xy + np.einsum("kij,kj->ki", L, rng.standard_normal(obs.xy.shape))
    pts = block.points
    s = np.asarray(pts.sigma, float)
    weighted = np.isfinite(s) & (s > 0)
    XYZ = pts.XYZ + np.where(weighted, s, 0.0) * rng.standard_normal(pts.XYZ.shape)
    return block.replace(observations=obs.replace(xy=xy), points=pts.replace(XYZ=XYZ))


def realisation_errors(block: Block, settings: BundleSettings, rng: np.random.Generator) -> dict:
    """Adjust one realisation (started at the plan) and return its estimation errors: ``XYZ`` (n, 3),
    ``cam`` (K, 3 + p) camera parameters, ``X0`` (m, 3), ``opk`` (m, 3), estimated minus planned, and
    its ``sigma0_hat`` and ``vtpv``, ``dof`` (for the closed-form link to the prediction)."""
    truth = truth_state(block)
    noisy = realise(block, rng)
    res = adjust(noisy, settings, start=truth.copy(), covariance=False)
    st = res.state
    p = st.cam_params.shape[1]
    return {"XYZ": st.XYZ - truth.XYZ, "cam": st.cam_params - truth.cam_params[:, :p],
            "X0": st.X0 - truth.X0, "opk": st.opk - truth.opk,
            "sigma0_hat": res.sigma0_hat, "vtpv": res.vtpv, "dof": res.dof, "iterations": res.iterations}


@dataclass(frozen=True)
class RatioTest:
    """Realised against predicted σ per component: ``ratio = s / σ`` with ``s² = Σ e² / N`` (errors
    from the planned values, so N degrees of freedom); under the prediction ``N s² / σ² ~ χ²(N)``."""

    ratio: np.ndarray        # (q,)
    lower: float             # acceptance interval of the ratio at level alpha (two-sided)
    upper: float
    rejected: np.ndarray     # (q,) bool
    n: int
    alpha: float
    pooled_ratio: float      # sqrt(mean of ratio²)
    pooled_p: float          # two-sided p of the pooled statistic (components treated as independent)


def ratio_test(errors: np.ndarray, sigma: np.ndarray, alpha: float = 0.05) -> RatioTest:
    """Test realised errors ``(N, q)`` against predicted σ ``(q,)`` (see :class:`RatioTest`).  The
    pooled statistic Σ N s²/σ² treats the q components as independent, which they are not (points of
    one network are correlated): its p is indicative, the per-component tests are exact."""
    e = np.asarray(errors, float)
    sigma = np.asarray(sigma, float)
    N = e.shape[0]
    s2 = np.mean(e ** 2, axis=0)
    ratio = np.sqrt(s2) / sigma
    lo = np.sqrt(sps.chi2.ppf(alpha / 2, N) / N)
    hi = np.sqrt(sps.chi2.ppf(1 - alpha / 2, N) / N)
    rej = (ratio < lo) | (ratio > hi)
    q = ratio.size
    T = float(N * np.sum(ratio ** 2))
    cdf = sps.chi2.cdf(T, N * q) if q else 0.5
    return RatioTest(ratio=ratio, lower=float(lo), upper=float(hi), rejected=rej, n=N, alpha=alpha,
                     pooled_ratio=float(np.sqrt(np.mean(ratio ** 2))) if q else float("nan"),
                     pooled_p=float(2 * min(cdf, 1 - cdf)))


def joint_test(errors: np.ndarray, cov: np.ndarray, rcond: float = 1e-10) -> dict:
    """The exact joint test of realised errors ``(N, q)`` against the predicted joint covariance
    ``(q, q)``: per realisation ``d = eᵀ C⁺ e ~ χ²(k)``, ``k`` the rank of ``C`` (``q`` unless a free
    network's datum makes it singular), and ``Σ d ~ χ²(N k)`` over the N independent realisations.
    Returns the mean ``d / k`` (1 expected), the statistic, its degrees of freedom, the two-sided p
    and the rank."""
    e = np.asarray(errors, float)
    N, q = e.shape
    C = np.asarray(cov, float)
    s = np.sqrt(np.clip(np.diag(C), 0, None))
    s[s == 0] = 1.0
    lam, U = np.linalg.eigh(C / np.outer(s, s))           # scaled to correlations: rank by rcond
    keep = lam > rcond * lam.max()
    k = int(keep.sum())
    z = (U[:, keep].T @ (e / s).T) / np.sqrt(lam[keep])[:, None]    # whitened errors (k, N)
    d = np.sum(z ** 2, axis=0)
    T = float(d.sum())
    cdf = sps.chi2.cdf(T, N * k)
    return {"normalised": float(T / (N * k)), "statistic": T, "dof": N * k, "p": float(2 * min(cdf, 1 - cdf)),
            "rank": k, "per_realisation": d / k}
