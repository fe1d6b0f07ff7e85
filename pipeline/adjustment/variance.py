"""Variance component estimation (Förstner's iterated estimator; ``docs/statistics.md``).

The observations fall into groups ``g`` (image coordinates per camera, per photo or in groups a
user defines; control-point coordinates; exterior-orientation priors; weighted camera
parameters; scale bars; GNSS antenna positions), each with an unknown factor ``f_g`` on its a-priori standard deviations.
With the group's share of the weighted square sum ``Ω_g = v_gᵀ P_g v_g`` and of the redundancy
``r_g = Σ_{i∈g} r_i`` (the redundancy numbers ``r_i = (Qvv P)_ii``)::

    σ̂_g² = Ω_g / (r_g σ0²)                        (Förstner 1979)

is the variance factor of the group; the weights are divided by it (``f_g ← f_g σ̂_g``) and the
adjustment repeated until every ``σ̂_g² = 1``.  At that fixed point the estimate is Helmert's (and the
REML one for normal errors); for a single group it is the usual σ̂0².

Two entry points, both pure (arrays and blocks in, new objects out; inputs never modified):

* :func:`linear_components` — the linear Gauss–Markov model ``l = A x + e`` (dense), the
  reference the tests compare with closed forms;
* :func:`estimate_components` — the bundle: :func:`~.adjust.adjust` repeatedly, each time with the
  block's σ scaled by the current factors.

Each group is reported with ``r_g``, ``Ω_g``, the factor ``f_g`` on its σ, an approximate
standard deviation ``σ(f_g) ≈ f_g / √(2 r_g)`` (the χ² variance of ``σ̂_g²`` with ``r_g`` degrees of
freedom, covariances between the groups neglected) and the test of ``H0: f_g = 1`` (the a-priori
σ of the group are right): ``T_g = f_g² ~ χ²(r_g)/r_g``, two-sided at ``alpha``.  A group with
``r_g < min_redundancy`` in the first adjustment (e.g. the one scale bar that fixes a free
network's scale: ``r ≈ 0``) is not estimable; its factor stays 1.  A group whose observations fit
far better than their σ say (priors equal to the truth) has its factor driven towards 0 and its
redundancy with it; the iteration then stops at ``max_iter`` and reports ``converged = False``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import PurePath as Path
from typing import Any, Sequence

import numpy as np
from scipy import stats as sps

from baarda.pipeline.model import Block, ScaleBars

from .adjust import BundleResult, adjust
from .reliability import global_rows
from .settings import BundleSettings, Distance, block_distances

__all__ = ["VarianceGroup", "VarianceComponents", "LinearComponents", "linear_components",
           "estimate_components", "group_parts", "GroupPart", "image_group_labels", "scale_block", "component_test"]


# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GroupPart:
    """One observation group's share of an adjustment (:func:`group_parts`): ``n`` scalar rows,
    ``omega`` (Ω_g = v_gᵀ P_g v_g in the adjustment's weights) and ``redundancy`` (r_g)."""

    name: str
    kind: str                 # image | control | eo | interior | distance | gnss | rig
    n: int
    omega: float
    redundancy: float


@dataclass(frozen=True)
class VarianceGroup:
    """One group's estimate: ``factor`` multiplies the group's a-priori σ."""

    name: str
    kind: str                 # image | control | eo | interior | distance | gnss | rig
    n: int                    # scalar observations (rows)
    redundancy: float         # r_g (last adjustment)
    omega: float              # Ω_g = v_gᵀ P_g v_g in the last adjustment (its weights)
    factor: float             # f_g: estimated σ / a-priori σ (1 when not estimable)
    sigma_factor: float       # ≈ f_g / √(2 r_g)
    T: float                  # f_g², ~ χ²(r_g)/r_g under H0: f_g = 1
    p_value: float            # two-sided
    rejected: bool
    estimable: bool

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass(eq=False)
class VarianceComponents:
    """Result of :func:`estimate_components`."""

    groups: list                          # [VarianceGroup]
    iterations: int                       # re-adjustments after the first
    converged: bool
    history: list                         # per iteration: {group name: σ̂_g² of that adjustment}
    first: BundleResult = field(repr=False)    # the adjustment on the a-priori σ
    result: BundleResult = field(repr=False)   # the adjustment on the estimated σ
    block: Block = field(repr=False)           # the block with the σ scaled by the factors
    settings: BundleSettings = field(repr=False)
    alpha: float = 0.05

    def factors(self) -> dict:
        return {g.name: g.factor for g in self.groups}

    def summary(self) -> dict:
        return {"iterations": self.iterations, "converged": self.converged, "alpha": self.alpha,
                "groups": [g.as_dict() for g in self.groups]}


@dataclass(frozen=True)
class LinearComponents:
    """Result of :func:`linear_components`: variance factors ``s2`` (σ_g² / a-priori σ_g²)."""

    s2: np.ndarray
    redundancy: np.ndarray
    omega: np.ndarray
    x: np.ndarray
    iterations: int
    converged: bool


def component_test(factor: float, r: float, alpha: float) -> tuple[float, float, bool]:
    """``(T, p, rejected)`` for ``H0: factor = 1``: ``T = factor² ~ χ²(r)/r``, two-sided."""
    if not (r > 0 and np.isfinite(factor)):
        return float("nan"), float("nan"), False
    T = float(factor) ** 2
    cdf = float(sps.chi2.cdf(T * r, r))
    p = float(min(1.0, 2 * min(cdf, 1.0 - cdf)))
    return T, p, bool(p < alpha)


# ---------------------------------------------------------------------------------------------
def linear_components(A: np.ndarray, l: np.ndarray, sigma: np.ndarray, groups: np.ndarray, *,
                      max_iter: int = 50, tol: float = 1e-8) -> LinearComponents:
    """Förstner's iterated estimate for ``l = A x + e``, ``e_i ~ N(0, (f_g σ_i)²)``.

    ``sigma`` (n,) a-priori standard deviations, ``groups`` (n,) integer labels 0 … G−1.
    Returns the variance factors ``s2 = f_g²`` (relative to the a-priori σ), the last ``r_g`` and
    ``Ω_g`` and the estimate ``x``.  Pure; dense (for tests and small models)."""
    A = np.asarray(A, float)
    l = np.asarray(l, float)
    sigma = np.asarray(sigma, float)
    groups = np.asarray(groups, int)
    G = int(groups.max()) + 1
    s2 = np.ones(G)
    conv = False
    it = 0
    for it in range(1, max_iter + 1):
        p = 1.0 / (sigma ** 2 * s2[groups])
        N = A.T @ (p[:, None] * A)
        Ninv = np.linalg.inv(N)
        x = Ninv @ (A.T @ (p * l))
        v = l - A @ x
        r = 1.0 - p * np.einsum("ij,jk,ik->i", A, Ninv, A)
        om = np.bincount(groups, p * v * v, minlength=G)
        rg = np.bincount(groups, r, minlength=G)
        est = om / rg
        s2 = s2 * est
        if np.max(np.abs(est - 1.0)) < tol:
            conv = True
            break
    return LinearComponents(s2=s2, redundancy=rg, omega=om, x=x, iterations=it, converged=conv)


# ---------------------------------------------------------------------------------------------
def image_group_labels(block: Block, by: str | Sequence | np.ndarray = "camera",
                       photo_groups: dict | None = None) -> np.ndarray:
    """A group name per observation: ``"all"``, ``"camera"`` (``image camera <id>``), ``"photo"``
    (``image photo <id>``), ``"source"`` (``image source <file name>``: the file a reader took the
    observation from, ``block.source.lines`` (photo, point) → (file, line), else
    ``block.source.path``), or an array of names (one per observation).  ``photo_groups``
    (name → photo ids) overrides the photos it lists (``image <name>``)."""
    obs, photos = block.observations, block.photos
    k = len(obs)
    if isinstance(by, str):
        if by == "all":
            lab = np.full(k, "image", dtype=object)
        elif by == "camera":
            cid = block.cameras.ids.astype(str)[photos.camera[obs.photo]]
            lab = np.array(["image camera " + c for c in cid.tolist()], dtype=object)
        elif by == "photo":
            pid = photos.ids.astype(str)[obs.photo]
            lab = np.array(["image photo " + p for p in pid.tolist()], dtype=object)
        elif by == "source":
            lines = block.source.lines
            default = block.source.path
            lab = np.empty(k, dtype=object)
            for i, (ph, pt) in enumerate(zip(obs.photo.tolist(), obs.point.tolist())):
                src = lines.get((ph, pt), (default,))[0]
                lab[i] = "image source " + (Path(str(src)).name if src is not None else "unknown")
        else:
            raise ValueError(f"image groups by {by!r}: expected all, camera, photo or source")
    else:
        lab = np.asarray(by, dtype=object)
        if lab.shape != (k,):
            raise ValueError(f"image groups: expected one name per observation ({k}), got shape {lab.shape}")
        lab = np.array(["image " + str(s) for s in lab.tolist()], dtype=object)
    for name, ids in (photo_groups or {}).items():
        idx = photos.index_of([str(i) for i in ids])
        lab[np.isin(obs.photo, idx)] = "image " + str(name)
    return lab


def group_parts(result: BundleResult, image_labels: np.ndarray) -> tuple[GroupPart, ...]:
    """A :class:`GroupPart` per group of ``result``: ``name, kind, n, omega`` (Ω_g, in the
    adjustment's weights) and ``redundancy`` (r_g).  Image rows from the result's residuals and redundancy numbers; a prior
    on an unknown ``j`` has ``r = 1 − p_j Q_jj``, a scale bar ``r = 1 − p a Q aᵀ`` (``a`` the
    distance's gradient), a GNSS antenna coordinate ``r = (Qvv P)_ii`` of its 3 × 3 block
    (:func:`~.reliability.global_rows`).  Over all groups ``Σ r_g = dof``."""
    prob = result.problem
    st = result.state
    _, e, dg, dpv, dd, _ = prob.residual_parts(st)
    out: dict[str, list] = {}                      # name → [kind, n, omega, redundancy], summed

    def add(name, kind, n, om, r):
        d = out.setdefault(name, [kind, 0, 0.0, 0.0])
        d[1] += int(n)
        d[2] += float(om)
        d[3] += max(float(r), 0.0)      # a share of 0 computes as ±1e-14

    # image coordinates (observations prob.oi; switched-off rows have zero weight and r = 0)
    oi = prob.oi
    om_obs = np.einsum("ki,ki->k", e, e)
    r_obs = result.redundancy[oi].sum(axis=1)
    n_obs = prob.row_active[oi].sum(axis=1)
    lab = np.asarray(image_labels, dtype=object)[oi]
    for name in dict.fromkeys(lab.tolist()):
        m = lab == name
        add(name, "image", n_obs[m].sum(), om_obs[m].sum(), r_obs[m].sum())
    # priors on global unknowns: interior (camera), eo, control (points on scale bars)
    if len(prob.prior_g_idx):
        qd = result.cofactor_diagonal()[prob.prior_g_idx]
        w = prob.prior_g_w
        kind = np.empty(prob.n_g, dtype=object)
        kind[prob.g_cam[prob.g_cam >= 0]] = "interior"
        kind[prob.g_eo[prob.g_eo >= 0]] = "eo"
        kind[prob.g_pt[prob.g_pt >= 0]] = "control"
        if getattr(prob, "rig", None) is not None:        # rigs: frames' priors are orientations, sensors' their own
            kind[prob.g_frame[prob.g_frame >= 0]] = "eo"
            kind[prob.g_sensor[prob.g_sensor >= 0]] = "rig"
        kk = kind[prob.prior_g_idx]
        for name in ("interior", "eo", "control", "rig"):
            m = kk == name
            if m.any():
                add(name, name, m.sum(), np.sum(w[m] * dg[m] ** 2), np.sum(1.0 - w[m] * qd[m]))
    # priors on eliminated points (control)
    if len(prob.prior_p_idx):
        var = result.variance_factor
        pts = prob.elim_points[prob.prior_p_idx]
        q = result.cov_points[pts, prob.prior_p_coord, prob.prior_p_coord] / var
        w = prob.prior_p_w
        add("control", "control", len(w), np.sum(w * dpv ** 2), np.sum(1.0 - w * q))
    # observations on global unknowns: scale bars, GNSS antennas (whitened residuals dd)
    if prob.n_grow_rows:
        for kind, gs in global_rows(result).items():
            sl = prob.grow_slices[kind]
            name = {"distance": "scale bars", "gnss": "GNSS"}[kind]
            add(name, kind, sl.stop - sl.start, np.sum(dd[sl] ** 2), np.sum(gs.r))
    return tuple(GroupPart(name, *d) for name, d in out.items())


def scale_block(block: Block, settings: BundleSettings, factors: dict, image_labels: np.ndarray
                ) -> tuple[Block, BundleSettings]:
    """The block and settings with every group's a-priori σ multiplied by ``factors[name]``
    (groups not named keep theirs).  The block's scale bars move into the settings."""
    obs = block.observations
    f_obs = np.array([factors.get(str(n), 1.0) for n in np.asarray(image_labels, dtype=object).tolist()], float)
    out = block.replace(observations=obs.replace(cov=obs.cov * (f_obs ** 2)[:, None, None]))

    def scaled(arr, f):
        a = np.array(arr, float)
        m = np.isfinite(a) & (a > 0)
        a[m] *= f
        return a

    if factors.get("control", 1.0) != 1.0:
        out = out.replace(points=out.points.replace(sigma=scaled(out.points.sigma, factors["control"])))
    if factors.get("eo", 1.0) != 1.0:
        out = out.replace(photos=out.photos.replace(sigma_eo=scaled(out.photos.sigma_eo, factors["eo"])))
    if factors.get("interior", 1.0) != 1.0:
        f = factors["interior"]
        out = out.replace(cameras=out.cameras.replace(sigma_iop=scaled(out.cameras.sigma_iop, f),
                                                      sigma_ap=scaled(out.cameras.sigma_ap, f)))
    if factors.get("rig", 1.0) != 1.0 and block.rigs:
        rs = block.rigs.sensors
        out = out.replace(rigs=block.rigs.replace(sensors=rs.replace(sigma=scaled(rs.sigma, factors["rig"]))))
    if factors.get("GNSS", 1.0) != 1.0 and len(block.gnss):
        out = out.replace(gnss=block.gnss.replace(cov=block.gnss.cov * factors["GNSS"] ** 2))
    bars = tuple(settings.distances) + tuple(block_distances(block))
    if bars:
        f = factors.get("scale bars", 1.0)
        out = out.replace(scale_bars=ScaleBars.make())
        settings = dataclasses.replace(settings, distances=tuple(
            Distance(d.a, d.b, d.distance, d.sigma * f) for d in bars))
    return out, settings


def estimate_components(block: Block, settings: BundleSettings | None = None, *,
                        image_groups: str | Sequence | np.ndarray = "camera", photo_groups: dict | None = None,
                        first: BundleResult | None = None, max_iter: int = 20, tol: float = 1e-3,
                        min_redundancy: float = 1.0, alpha: float = 0.05, **adjust_kw: Any) -> VarianceComponents:
    """Förstner's iterated variance components of a bundle (module docstring).

    ``first``: the adjustment of ``block`` on its a-priori σ if already computed (else adjusted
    here).  Each further adjustment starts from the previous solution.  Converged when every
    estimable group's ``σ̂_g²`` is within ``tol`` of 1.  ``adjust_kw`` go to :func:`adjust`."""
    settings = settings or BundleSettings()
    labels = image_group_labels(block, image_groups, photo_groups)
    res0 = first if first is not None else adjust(block, settings, **adjust_kw)
    if res0.snapshot is None:
        raise ValueError("variance components need redundancy numbers: adjust with covariance = true")
    s0sq = settings.sigma0 ** 2
    factors: dict[str, float] = {}
    history = []
    res = res0
    cur_block, cur_settings = block, settings
    converged = False
    it = 0
    estimable = None
    while True:
        parts = group_parts(res, labels)
        if estimable is None:           # decided once, on the a-priori weights
            estimable = {p.name for p in parts if p.redundancy >= min_redundancy and p.omega > 0}
        est = {p.name: p.omega / (p.redundancy * s0sq) for p in parts if p.name in estimable and p.redundancy > 0}
        history.append(est)
        if all(abs(v - 1.0) < tol for v in est.values()):
            converged = True
            break
        if it >= max_iter:
            break
        for name, s2 in est.items():
            factors[name] = factors.get(name, 1.0) * float(np.sqrt(s2))
        cur_block, cur_settings = scale_block(block, settings, factors, labels)
        res = adjust(cur_block, cur_settings, start=res.state, compute_initial=False, **adjust_kw)
        it += 1
    groups = []
    for p in parts:
        ok = p.name in est
        f = factors.get(p.name, 1.0)             # the factor the last adjustment used
        r = p.redundancy
        T, pv, rej = component_test(f, r, alpha) if ok else (float("nan"), float("nan"), False)
        groups.append(VarianceGroup(name=p.name, kind=p.kind, n=p.n, redundancy=r, omega=p.omega,
                                    factor=float(f), sigma_factor=float(f / np.sqrt(2 * r)) if ok else float("nan"),
                                    T=T, p_value=pv, rejected=rej, estimable=ok))
    return VarianceComponents(groups=groups, iterations=it, converged=converged, history=history, first=res0,
                              result=res, block=cur_block, settings=cur_settings, alpha=alpha)
