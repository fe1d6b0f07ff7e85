"""The whole bundle workflow as one function: :func:`adjust_block` (``docs/library.md``).

What the ``bundle`` stage does, callable from Python without the runner::

    from baarda.pipeline.api import adjust, BundleConfig
    report = adjust(block, BundleConfig(datum="free", tests=StatTestsConfig(blunders="data-snooping")))
    report.result.sigma0_hat, report.global_test.rejected, report.flagged_observations

:class:`BundleConfig` is the one schema of the bundle's options: the stage's option table
(``[[stage]] use = "bundle"``, nested tables ``solver``, ``tests``, ``robust``,
``variance_components``, ``ap_selection``, ``output``) and the library's argument.  Ranges are declared
on the fields (``option(..., ge=…)``, checked by :func:`baarda.pipeline.options.parse_options` and, for a
config built in Python, by ``__post_init__``); ``__post_init__`` adds only the rules between fields.

:func:`adjust_block` configures the block (camera models, parameter status, a-priori σ), adjusts it,
and runs what the config asks for — AP selection, variance components, robust weights, iterated data
snooping, data snooping, the global and the joint 2-D test, external reliability, the covariance of
chosen parameters, the GNSS antennas' tests — and returns a frozen :class:`BundleReport`.  It never
changes its inputs nor the results it obtains.  Progress goes to an optional callback ``progress(message)``;
the iterations to :data:`~baarda.pipeline.adjustment.ITERATION_CALLBACK`.
"""

from __future__ import annotations

import dataclasses
import difflib
import re
from typing import Callable, ClassVar, Literal

import numpy as np

from baarda.pipeline import stats
from baarda.pipeline.camera import ap_model_names, get_ap_model
from baarda.pipeline.errors import AdjustmentError, InputError
from baarda.pipeline.model import Block
from baarda.pipeline.options import REQUIRED, check_bounds, option
from baarda.pipeline.stats.critical import delta0 as _delta0

from .adjust import BundleResult, adjust, padded_ap, result_of
from .apselect import APSelection, select_aps
from .corrected import check_models
from .eccentricity import Eccentricity, eccentricity_corrections
from .memory import release_freed
from .rig import rig_structure
from .reliability import GlobalRowStats, OwnEffects, global_rows, own_effects, parameter_covariance
from .settings import BundleSettings, Distance
from ..threads import single_blas
from .variance import VarianceComponents, estimate_components

EO_LABELS = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
"""The components of a photo's orientation as ``covariance_of`` names them."""


@dataclasses.dataclass(frozen=True)
class ScaleBar:
    """One scale bar: a measured distance between two object points."""

    from_: str | int = option(REQUIRED, "id of the point at one end", key="from")
    to: str | int = option(REQUIRED, "id of the point at the other end")
    distance: float = option(REQUIRED, "measured distance (object units)", gt=0.0)
    sigma: float = option(REQUIRED, "its standard deviation (object units)", gt=0.0)

    def __post_init__(self):
        check_bounds(self)


@dataclasses.dataclass(frozen=True)
class SolverConfig:
    """``[bundle.solver]``: the iteration and the linear algebra."""

    max_iter: int = option(30, "maximum number of iterations", ge=1)
    tol_obs: float = option(1e-5, "converged when a correction moves no observation by more than this × its σ",
                            gt=0.0)
    tol_rel: float = option(1e-12, "... or when vᵀPv changes by less than this fraction", gt=0.0)
    damping: bool = option(True, "Levenberg–Marquardt damping when a Gauss–Newton step does not reduce vᵀPv")
    solver: Literal["auto", "dense", "sparse"] = option(
        "auto", "reduced camera system: dense Cholesky, or sparse (METIS ordering, supernodal Cholesky, selected "
                "inversion) for large blocks; auto chooses by size and fill (docs/bundle.md)")
    covariance: bool = option(True, "compute covariances, redundancy numbers and w-tests")

    def __post_init__(self):
        check_bounds(self)


@dataclasses.dataclass(frozen=True)
class StatTestsConfig(stats.SnoopingConfig):
    """``[bundle.tests]``: the tests of the observations and the blunder handling (``alpha0``, ``beta0``,
    ``max_rejections``, ``ids_stop`` declared once in :class:`baarda.pipeline.stats.SnoopingConfig`,
    shared with blunder-rejection)."""

    blunders: Literal["none", "data-snooping", "ids"] = option(
        "none", "blunder handling inside the bundle: none, data snooping (flag), iterated data snooping (reject)")


RobustConfig = stats.RobustConfig
"""``[bundle.robust]``: robust estimation by IRLS, the statistics library's group (docs/statistics.md)."""


@dataclasses.dataclass(frozen=True)
class VarianceComponentsConfig:
    """``[bundle.variance_components]``: Förstner's iterated variance components per observation group."""

    mode: Literal["none", "estimate", "apply"] = option(
        "none", "none, estimate and report them (the adjustment keeps the a-priori σ), or apply them (the "
                "adjustment, its tests and data snooping use the re-weighted σ); docs/bundle.md")
    groups: Literal["camera", "photo", "source", "all"] = option(
        "camera", "image coordinates grouped per camera, per photo, per source file, or one group; control, EO "
                  "priors, weighted camera parameters and scale bars are groups of their own")
    photo_groups: dict[str, list[str]] = option(
        {}, "user-defined image groups, name -> photo ids (override groups for those photos)")
    alpha: float = option(0.05, "significance level of each group's test of f = 1 (two-sided)", gt=0.0, lt=1.0)
    iterations: int = option(20, "at most this many re-adjustments", ge=1)

    def __post_init__(self):
        check_bounds(self)


@dataclasses.dataclass(frozen=True)
class APSelectionConfig:
    """``[bundle.ap_selection]``: the paper's selection of additional parameters."""

    enabled: bool = option(False, "select APs: remove |ρ| > rho_max one after another, then t-tests")
    rho_max: float = option(0.75, "correlation limit (the paper's 0.75)", gt=0.0, lt=1.0)
    alpha: float = option(0.05, "significance level of the t-test (two-sided)", gt=0.0, lt=1.0)
    significance: Literal["remove", "report"] = option(
        "remove", "remove insignificant APs one at a time, or only report them")

    def __post_init__(self):
        check_bounds(self)


@dataclasses.dataclass(frozen=True)
class OutputConfig:
    """``[bundle.output]``: what is computed for the report beyond the adjustment."""

    external_reliability: bool = option(
        True, "effect of every coordinate's MDB on its own point and its own photo's orientation "
              "(bundle_observations.csv ext_*, report, results.json; docs/statistics.md)")
    confidence: float = option(
        0.0, "confidence of the points' error ellipsoids, plan ellipses and height intervals in bundle_points.csv "
             "(χ² quantiles with 3, 2, 1 dof); 0 = the 1-σ figures", ge=0.0, lt=1.0)
    covariance_of: list[str] = option(
        [], "parameters whose joint covariance is written to bundle_covariance.csv, e.g. "
            "['photo 001', 'point 17', 'camera cam', 'point 18 Z'] (a photo's X0…kappa, a point's X, Y, Z, a camera's "
            "c, xp, yp, APs, or one component)")
    arrow_scale: float = option(0.0, "scale of residual arrows in the recording (0: automatic)", ge=0.0)

    def __post_init__(self):
        check_bounds(self)


@dataclasses.dataclass(frozen=True)
class EccentricityConfig:
    """``[bundle.eccentricity]``: circular targets (``Block.circles``) corrected for the perspective
    eccentricity of their imaged centres, iterated with the adjustment (docs/targets.md)."""

    enabled: bool = option(
        True, "correct the image observations of circular targets of known diameter (the block's circle table, "
              "e.g. opencv-targets with target = 'circles' and circle_diameter) for the eccentricity of the "
              "ellipse centre at the adjusted orientation, re-adjusting until the corrections settle")
    tol: float = option(0.01, "settled when no correction changes by more than this × the coordinate's a-priori σ",
                        gt=0.0)
    max_rounds: int = option(5, "at most this many re-adjustments with updated corrections", ge=1)
    distortion: Literal["rim", "centre"] = option(
        "rim", "the camera's distortion applied to 64 points of the circle's rim whose fitted conic's centre is "
               "taken (as a detector fits the distorted outline; keeps the distortion's curvature across the "
               "target), or only to the ellipse centre of the closed form (cheaper, exact without distortion; "
               "docs/targets.md)")

    def __post_init__(self):
        check_bounds(self)


@dataclasses.dataclass(frozen=True)
class RigConfig:
    """``[bundle.rig]`` (and the sources' ``rig``): camera rigs from a rig table and a frame table
    (``docs/rigs.md``); empty ``table``: the block's own rigs (a COLMAP model's, a source's)."""

    table: str = option("", "rig table (CSV: rig, camera, reference, status, the sensor's pose in the rig and σ), "
                            "relative to the project file; empty: the rigs the block brings")
    frames: str = option("", "frame table (CSV: frame, photo), relative to the project file")
    frames_from_name: str = option("", "regular expression on the photo id whose first group (or match) names the "
                                       "frame, e.g. '(\\d+)$' (instead of a frame table)")
    alpha: float = option(0.05, "significance level of the test of the rig against its calibration", gt=0.0, lt=1.0)

    def __post_init__(self):
        check_bounds(self)
        if self.frames_from_name:
            try:
                re.compile(self.frames_from_name)
            except re.error as e:
                raise ValueError(f"frames_from_name is not a regular expression: {e}") from None
        if (self.frames or self.frames_from_name) and not self.table:
            raise ValueError("rig.frames / rig.frames_from_name need the rig table (rig.table)")


@dataclasses.dataclass(frozen=True)
class BundleConfig:
    """The bundle's options: the ``bundle`` stage's option table and :func:`adjust_block`'s argument."""

    RENAMED: ClassVar[dict[str, str]] = {"image_sigma_scale": "sigma_image_scale"}
    MOVED: ClassVar[dict[str, str]] = {
        "max_iter": "solver.max_iter", "tol_obs": "solver.tol_obs", "tol_rel": "solver.tol_rel",
        "damping": "solver.damping", "solver": "solver.solver", "covariance": "solver.covariance",
        "blunders": "tests.blunders", "alpha0": "tests.alpha0", "beta0": "tests.beta0",
        "max_rejections": "tests.max_rejections", "ids_stop": "tests.ids_stop",
        "robust": "robust.method", "robust_c": "robust.c", "robust_standardise": "robust.standardise",
        "variance_components": "variance_components.mode", "vc_groups": "variance_components.groups",
        "vc_photo_groups": "variance_components.photo_groups", "vc_alpha": "variance_components.alpha",
        "vc_iterations": "variance_components.iterations",
        "ap_selection": "ap_selection.enabled", "rho_max": "ap_selection.rho_max",
        "ap_alpha": "ap_selection.alpha", "ap_significance": "ap_selection.significance",
        "external_reliability": "output.external_reliability", "confidence": "output.confidence",
        "covariance_of": "output.covariance_of", "arrow_scale": "output.arrow_scale",
    }
    """The flat names of the options before they were grouped (flat name → dotted new path)."""

    datum: Literal["control", "free"] = option(
        "control", "datum: by control points / weighted constraints, or a free network with inner constraints")
    datum_points: list[str] = option(
        [], "free network: ids of the points carrying the inner constraints (empty: every tie and check point)")
    datum_on: Literal["points", "centres"] = option(
        "points", "free network: inner constraints on object points or on the projection centres")
    ap_model: str = option("", "AP model of every camera (none, ebner12, brown, aicon, or a registered "
                               "third-party model); empty: as in the block")
    ap_models: dict[str, str] = option({}, "AP model per camera id (overrides ap_model)")
    iop: Literal["block", "free", "fixed"] = option(
        "block", "c, xp, yp: a-priori sigmas from the block, all free, or all fixed")
    aps: Literal["block", "free", "fixed"] = option(
        "block", "additional parameters: sigmas from the block, all free, or all fixed")
    fix: list[str] = option([], "parameter names held fixed in every camera (e.g. ['K3', 'P1', 'P2'])")
    free: list[str] = option([], "parameter names made free in every camera (applied after 'fix')")
    sigma: dict[str, float] = option({}, "parameter name -> a-priori sigma (weighted constraint), every camera",
                                     ge=0.0)
    ebner_b: float = option(0.0, "image base b (mm) of ebner12; 0: 0.4 × format width (60 % overlap)", ge=0.0)
    sigma_eo: list[float] = option(
        [], "weighted constraints on the given exterior orientations: a-priori σ [X0, Y0, Z0 (object units), "
            "ω, φ, κ (degrees)] for every photo whose orientation the block gives (0 fixes); empty: as in the block",
        ge=0.0)
    distances: list[ScaleBar] = option(
        [], "extra scale bars: tables {from, to, distance, sigma} (object units); block scale bars are used too")
    sigma0: float = option(1.0, "a-priori standard deviation of unit weight", gt=0.0)
    variance: Literal["a-posteriori", "a-priori"] = option(
        "a-posteriori", "covariances from σ̂0 (a-posteriori) or σ0 (a-priori: network design, docs/design.md)")
    sigma_image_scale: float = option(
        1.0, "multiply the a-priori σ of every image coordinate by this factor (a variance component, e.g. "
             "σ̂0 of an earlier run on the same weights)", gt=0.0)
    on_weak: Literal["error", "drop"] = option(
        "error", "photos with < 3 points, points in < 2 photos: stop with an error, or drop them with a warning")
    residual: Literal["measured", "corrected"] = option(
        "measured", "image residuals of backward-model cameras (brown-backward): of the measured marks (baarda's), or "
                    "DBAT's — the corrected mark minus the ideal projection, weighted with the mark's σ (docs/dbat.md)")
    solver: SolverConfig = option(SolverConfig(), "the iteration and the linear algebra")
    tests: StatTestsConfig = option(StatTestsConfig(), "tests of the observations, blunder handling")
    robust: RobustConfig = option(
        RobustConfig(), "robust estimation by IRLS, weights on the image coordinates: the adjusted values, σ̂0 and the "
                        "tests are those of the final weighted adjustment, the down-weighted coordinates are listed "
                        "(report, results.json, robust_wx/robust_wy in bundle_observations.csv)")
    variance_components: VarianceComponentsConfig = option(
        VarianceComponentsConfig(), "variance components per observation group")
    ap_selection: APSelectionConfig = option(APSelectionConfig(), "selection of additional parameters")
    output: OutputConfig = option(OutputConfig(), "external reliability, ellipsoids, covariances on demand")
    eccentricity: EccentricityConfig = option(
        EccentricityConfig(), "eccentricity of circular targets' imaged centres (blocks with a circle table only)")
    rig: RigConfig = option(RigConfig(), "camera rigs: sensors' poses in the rig, photos grouped into frames "
                                         "(docs/rigs.md)")

    def __post_init__(self):
        check_bounds(self)
        names = ap_model_names()
        models = [self.ap_model] * bool(self.ap_model) + list(self.ap_models.values())
        for m in models:
            if m not in names:
                raise ValueError(f"unknown AP model {m!r}; registered: {', '.join(names)}")
        known = {"c", "xp", "yp"}
        for m in models:
            known |= set(get_ap_model(m).params)
        # with ap_model given, every camera's model is known here (else it comes with the block: the
        # same check is made by configure_block, so `baarda validate` catches what it can)
        for where, names in (("fix", self.fix), ("free", self.free), ("sigma", list(self.sigma))):
            for name in names:
                if self.ap_model and name not in known:
                    close = difflib.get_close_matches(name, sorted(known), n=1, cutoff=0.5)
                    label = f"sigma.{name}" if where == "sigma" else f"{where}: {name!r}"
                    raise ValueError(f"{label}: not a parameter of the camera model(s) "
                                     f"({', '.join(sorted(known))})"
                                     + (f"; did you mean {close[0]!r}?" if close else ""))
        if self.sigma_eo and len(self.sigma_eo) != 6:
            raise ValueError(f"sigma_eo: expected 6 non-negative numbers [X0, Y0, Z0, ω, φ, κ (deg)], "
                             f"got {self.sigma_eo!r}")
        if self.robust.method != "none" and (self.tests.blunders == "ids" or not self.solver.covariance):
            raise ValueError(f"robust.method = {self.robust.method!r} needs solver.covariance = true and excludes "
                             "tests.blunders = 'ids' (robust weights and rejections are two answers to the same "
                             "question)")
        if self.variance_components.mode != "none" and not self.solver.covariance:
            raise ValueError("variance_components needs the redundancy numbers: set solver.covariance = true")


# -- the block and the core's settings from the config ---------------------------------------------
def configure_block(block: Block, config: BundleConfig) -> Block:
    """A new block with the config's camera models, parameter status and a-priori σ (the input unchanged)."""
    o = config
    cams = block.cameras
    models = cams.ap_model.copy().astype(object)
    if o.ap_model:
        models[:] = o.ap_model
    for cid, m in o.ap_models.items():
        if cid not in cams.ids:
            raise InputError(f"ap_models: unknown camera {cid!r}", field="ap_models")
        models[list(cams.ids).index(cid)] = m
    changed = models != cams.ap_model
    cams = cams.replace(ap_model=np.array(models, dtype=str))
    ap, sig = padded_ap(cams)
    for j in np.flatnonzero(changed):
        mdl = get_ap_model(models[j])
        ap[j] = 0.0
        sig[j] = 0.0
        sig[j, :mdl.n_params] = np.asarray(mdl.default_sigma, float)
    siop = np.array(cams.sigma_iop, float)
    if o.iop != "block":
        siop[:] = np.inf if o.iop == "free" else 0.0
    for j in range(len(cams)):
        mdl = get_ap_model(cams.ap_model[j])
        p = mdl.n_params
        if o.aps != "block":
            sig[j, :p] = np.inf if o.aps == "free" else 0.0
        names = ["c", "xp", "yp"] + list(mdl.params)
        rules = [(n, 0.0) for n in o.fix] + [(n, np.inf) for n in o.free] + [(n, float(s)) for n, s in o.sigma.items()]
        for name, value in rules:
            if name in names:
                t = names.index(name)
                if t < 3:
                    siop[j, t] = value
                else:
                    sig[j, t - 3] = value
    known = {n for m in set(cams.ap_model.tolist()) for n in ["c", "xp", "yp"] + list(get_ap_model(m).params)}
    for name in list(o.fix) + list(o.free) + list(o.sigma):
        if name not in known:
            raise InputError(f"parameter {name!r} belongs to none of the cameras' models "
                             f"({', '.join(sorted(known))})", field="fix/free/sigma")
    block = block.replace(cameras=cams.replace(ap=ap, sigma_ap=sig, sigma_iop=siop))
    if o.sigma_eo:
        ph = block.photos
        se = np.array(ph.sigma_eo, float)
        to = ph.has_orientation.copy()
        rig = rig_structure(block)
        if rig is not None:               # a rig photo's orientation is its frame's (the reference photo's)
            to &= (rig.photo_frame < 0) | np.isin(np.arange(len(ph)), rig.frame_ref_photo)
        se[to] = np.r_[o.sigma_eo[:3], np.radians(o.sigma_eo[3:])]
        block = block.replace(photos=ph.replace(sigma_eo=se))
    if o.sigma_image_scale != 1.0:
        obs = block.observations
        block = block.replace(observations=obs.replace(cov=obs.cov * o.sigma_image_scale ** 2))
    return block


def bundle_settings(config: BundleConfig, block: Block, threads: int = 1) -> BundleSettings:
    """The core's :class:`BundleSettings` from the config (the one place the config maps onto them)."""
    o, s = config, config.solver
    known = set(block.points.ids.tolist())
    for k, pid in enumerate(o.datum_points):         # an unknown id: the option's mistake, not a KeyError
        if str(pid) not in known:
            raise InputError(f"datum_points[{k}]: no point {str(pid)!r} in the block", field="datum_points")
    for k, d in enumerate(o.distances):
        for end in (d.from_, d.to):
            if str(end) not in known:
                raise InputError(f"distances[{k}]: no point {str(end)!r} in the block", field="distances")
    ap_meta = {cid: {"b": o.ebner_b} for cid in block.cameras.ids.tolist()} if o.ebner_b > 0 else {}
    if o.residual == "corrected":
        check_models(block.cameras.ids.tolist(), [get_ap_model(m) for m in block.cameras.ap_model.tolist()])
    return BundleSettings(
        datum=o.datum, datum_points=tuple(o.datum_points) or None, datum_centres=o.datum_on == "centres",
        sigma0=o.sigma0, variance=o.variance,
        max_iter=s.max_iter, tol_obs=s.tol_obs, tol_rel=s.tol_rel, damping=s.damping,
        distances=tuple(Distance(str(d.from_), str(d.to), d.distance, d.sigma) for d in o.distances),
        on_weak=o.on_weak, ap_meta=ap_meta, covariance=s.covariance, solver=s.solver, threads=threads,
        residual=o.residual)


def check_requests(block: Block, specs, field: str = "output.covariance_of") -> None:
    """Every ``covariance_of`` entry names a photo, point or camera of the block (and a known component of
    a photo or point); an :class:`InputError` naming the option if not (before any adjustment)."""
    tables = {"photo": block.photos, "point": block.points, "camera": block.cameras}
    comps = {"photo": EO_LABELS, "point": ("X", "Y", "Z")}
    for spec in specs:
        parts = str(spec).split()
        msg = None
        if len(parts) < 2 or parts[0] not in tables:
            msg = f"{spec!r}: expected 'photo <id>', 'point <id>' or 'camera <id>' (optionally + a component)"
        else:
            ids = {str(i) for i in tables[parts[0]].ids}
            ident = " ".join(parts[1:])
            if ident not in ids:
                head = " ".join(parts[1:-1])
                if len(parts) > 2 and head in ids:
                    if parts[0] in comps and parts[-1] not in comps[parts[0]]:
                        msg = f"{spec!r}: {parts[0]} components are {', '.join(comps[parts[0]])}"
                else:
                    msg = f"{spec!r}: no {parts[0]} with id {ident!r}"
        if msg:
            raise InputError(msg, field=field)


# -- the report ----------------------------------------------------------------------------------
def _frozen(a) -> np.ndarray:
    out = np.array(a, copy=True)
    out.flags.writeable = False
    return out


@dataclasses.dataclass(frozen=True, eq=False)
class RobustEstimate:
    """The robust estimate of the bundle: the IRLS result, the final weighted adjustment, how it refits."""

    irls: stats.RobustResult
    final: BundleResult
    how: str

    @property
    def downweighted(self) -> np.ndarray:
        return self.irls.downweighted

    def summary(self) -> dict:
        return {"how": self.how, **self.irls.summary()}


@dataclasses.dataclass(frozen=True, eq=False)
class BeforeRejection:
    """The adjustment iterated data snooping started from, and its data snooping."""

    result: BundleResult
    snooping: stats.DataSnoopingResult


@dataclasses.dataclass(frozen=True, eq=False)
class ParameterCovariance:
    """The joint a-posteriori covariance of the parameters ``output.covariance_of`` names."""

    names: tuple[str, ...]
    matrix: np.ndarray

    @property
    def sigma(self) -> np.ndarray:
        """The a-posteriori σ of each parameter (the root of the diagonal)."""
        return np.sqrt(np.clip(np.diag(self.matrix), 0, None))

    @property
    def correlation(self) -> np.ndarray:
        """The correlation matrix (0 where a parameter is fixed)."""
        d = self.sigma
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(np.outer(d, d) > 0, self.matrix / np.outer(d, d), 0.0)


@dataclasses.dataclass(frozen=True, eq=False)
class GnssTests:
    """The GNSS antennas as observations: their rows' statistics and data snooping at α0, β0."""

    rows: GlobalRowStats
    snooping: stats.DataSnoopingResult

    @property
    def flagged(self) -> np.ndarray:
        """Per antenna: any of its three coordinates flagged by the w-test."""
        return self.snooping.flagged.reshape(-1, 3).any(axis=1)


@dataclasses.dataclass(frozen=True, eq=False)
class EccentricityRounds:
    """How the eccentricity corrections were iterated with the adjustment.

    ``final`` the corrections the reported adjustment used (applied to ``BundleReport.block``'s
    observations: ``observed − correction``); ``after`` those recomputed at its solution (what one more
    round would use); ``changes`` per round the largest change of a correction in units of the
    coordinate's a-priori σ (round 1: against no correction), ``rms_mm`` the RMS correction of each
    round (mm, over the corrected coordinates); ``settled`` whether the last change was below ``tol``."""

    final: Eccentricity
    after: Eccentricity
    changes: tuple[float, ...]
    rms_mm: tuple[float, ...]
    settled: bool
    tol: float
    sigma_rows: np.ndarray = dataclasses.field(default=None, repr=False)   # (k, 2) a-priori σ of each coordinate

    @property
    def remaining(self) -> float:
        """Largest change (in σ) the reported solution would make to the corrections it used."""
        return _largest_change(self.after.correction, self.final.correction, self.sigma_rows, self.final.applied
                               | self.after.applied)


def _largest_change(a: np.ndarray, b: np.ndarray, sigma: np.ndarray, rows: np.ndarray) -> float:
    if not rows.any():
        return 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.abs(a[rows] - b[rows]) / sigma[rows]
    z = z[np.isfinite(z)]
    return float(z.max()) if z.size else 0.0


@dataclasses.dataclass(frozen=True, eq=False)
class BundleReport:
    """What :func:`adjust_block` found (frozen; its arrays are read-only).

    ``result`` is the final adjustment (after AP selection, applied variance components, robust weights,
    rejections); ``block`` the configured block it adjusted; ``output_block`` the adjusted block a next
    stage reads (rejected observations inactive).  ``decision`` per image point: ``ok``, ``inactive``,
    ``flagged``, ``rejected`` or ``downweighted``; ``rejected_rows`` per coordinate row.  A test or
    procedure the config did not ask for (or that needs covariances) is ``None``.
    """

    config: BundleConfig
    result: BundleResult
    block: Block
    output_block: Block
    decision: np.ndarray
    rejected_rows: np.ndarray
    global_test: stats.GlobalTestResult | None = None
    snooping: stats.DataSnoopingResult | None = None
    joint: stats.JointTestResult | None = None
    ids: stats.IDSResult | None = None
    before_ids: BeforeRejection | None = None
    selection: APSelection | None = None
    vc: VarianceComponents | None = None
    robust: RobustEstimate | None = None
    external: OwnEffects | None = None
    delta0: float = float("nan")
    covariance: ParameterCovariance | None = None
    gnss: GnssTests | None = None
    warnings: tuple[str, ...] = ()
    eccentricity: EccentricityRounds | None = None

    @property
    def sigma0_hat(self) -> float:
        return self.result.sigma0_hat

    @property
    def flagged_observations(self) -> np.ndarray:
        """Indices of the image points (rows of ``block.observations``) flagged or rejected."""
        return np.flatnonzero(np.isin(self.decision, ("flagged", "rejected")))


@single_blas
def adjust_block(block: Block, config: BundleConfig | None = None, *,
                 progress: Callable[[str], None] | None = None, threads: int = 1) -> BundleReport:
    """Run the bundle workflow on ``block`` as ``config`` asks; a frozen :class:`BundleReport`.

    ``progress(message)`` is told what starts (the adjustment, variance components, robust estimation);
    ``threads`` is the adjustment's own Python threads (``BundleSettings.threads``); BLAS runs one
    thread for the duration, whoever calls (:mod:`.threads`).  Raises :class:`InputError` for options that do not
    fit the block (its ``field`` the option's dotted name) and :class:`AdjustmentError` when an
    adjustment fails (its ``state`` the last iterate, its ``block`` the configured block).
    """
    config = BundleConfig() if config is None else config
    say = progress or (lambda message: None)
    o = config
    raw = block
    ecc = None
    if o.eccentricity.enabled and block.circles is not None and len(block.circles):
        block, ecc = _eccentricity_rounds(block, o, say, threads)
    configured = configure_block(block, o)
    check_requests(configured, o.output.covariance_of)
    settings = bundle_settings(o, configured, threads)
    say(f"adjusting {len(configured.photos)} photos, {len(configured.points)} points, "
        f"{int(configured.observations.active.sum())} observations")
    warnings: list[str] = []
    selection = vc = robust = None
    try:
        res = adjust(configured, settings, covariance=o.solver.covariance)
        if o.ap_selection.enabled:
            a = o.ap_selection
            selection = select_aps(configured, settings, rho_max=a.rho_max, alpha=a.alpha,
                                   significance=a.significance, result=res)
            res = selection.result
        if o.variance_components.mode != "none":
            say("variance components")
            vc = _variance_components(res, o.variance_components)   # on the block and settings as they stand
            if o.variance_components.mode == "apply":
                res, configured = vc.result, vc.block
        if o.robust.method != "none":
            say(f"robust estimation ({o.robust.method})")
            robust = _robust(configured, res, o.robust, warnings)
            res = robust.final
    except AdjustmentError as e:
        raise _with_block(e, configured) from e
    release_freed()                  # the solve's freed pages back to the system before the tests
    warnings += [str(w) for w in res.warnings]
    snap = res.snapshot
    t = o.tests
    decision = np.array(["ok"] * len(configured.observations), dtype=object)
    decision[~configured.observations.active] = "inactive"
    if robust is not None:
        decision[np.unique(robust.downweighted // 2)] = "downweighted"
    rejected_rows = np.zeros(2 * len(configured.observations), bool)
    gt = ds = joint = ids = before = None
    if snap is not None:
        gt = stats.global_test(snap, alpha=t.alpha_global, alpha0=t.alpha0, beta0=t.beta0)
        if t.blunders == "ids":
            try:
                ids = stats.iterated_data_snooping(res, snap, alpha0=t.alpha0, beta0=t.beta0,
                                                   max_iter=t.max_rejections, stop=t.ids_stop)
            except AdjustmentError as e:
                raise _with_block(e, configured) from e
            if ids.removed:
                before = BeforeRejection(res, stats.data_snooping(snap, alpha0=t.alpha0, beta0=t.beta0))
                rejected_rows[ids.removed] = True
                res = result_of(ids.snapshot, res)
                snap = res.snapshot
                gt = stats.global_test(snap, alpha=t.alpha_global, alpha0=t.alpha0, beta0=t.beta0)
        ds = stats.data_snooping(snap, alpha0=t.alpha0, beta0=t.beta0)
        try:
            joint = stats.joint_test_2d(snap, alpha=t.alpha0)
        except ValueError:
            joint = None
        # flagged: the w-test exceeded K, the point is kept (whatever `blunders` says; docs/statistics.md);
        # a point robust estimation down-weighted stays "downweighted" (what was done to it)
        hit = np.unique(np.flatnonzero(ds.flagged) // 2)
        decision[hit[decision[hit] == "ok"]] = "flagged"
        decision[np.unique(np.flatnonzero(rejected_rows) // 2)] = "rejected"
    d0 = _delta0(t.alpha0, t.beta0)
    external = own_effects(res, d0) if snap is not None and o.output.external_reliability else None
    release_freed()                  # and external reliability's (the final system, its effects per track)
    covariance = None
    if snap is not None and o.output.covariance_of:
        try:
            names, C = parameter_covariance(res, o.output.covariance_of)
        except KeyError as e:
            raise InputError(str(e.args[0]), field="output.covariance_of") from None
        covariance = ParameterCovariance(tuple(names), _frozen(C))
    gnss = None
    if snap is not None and len(res.block_in.gnss):
        gs = global_rows(res).get("gnss")
        if gs is not None:
            gnss = GnssTests(gs, stats.data_snooping(gs.snapshot, alpha0=t.alpha0, beta0=t.beta0))
    out_block = res.block
    if robust is not None:   # the robust weights are the estimator's, not the block's a-priori σ
        out_block = out_block.replace(observations=out_block.observations.replace(cov=configured.observations.cov))
    if ecc is not None:      # the output keeps the measured centres: a later bundle corrects them again
        out_block = out_block.replace(observations=out_block.observations.replace(xy=raw.observations.xy))
        after = eccentricity_corrections(res.block, res.settings, o.eccentricity.distortion)
        ecc = dataclasses.replace(ecc, after=after)
    res.problem.release_normals()    # nothing below solves again (a later use rebuilds them)
    if rejected_rows.any():
        act = out_block.observations.active.copy()
        act[np.unique(np.flatnonzero(rejected_rows) // 2)] = False
        out_block = out_block.replace(observations=out_block.observations.replace(active=act))
    return BundleReport(config=o, result=res, block=configured, output_block=out_block, decision=_frozen(decision),
                        rejected_rows=_frozen(rejected_rows), global_test=gt, snooping=ds, joint=joint, ids=ids,
                        before_ids=before, selection=selection, vc=vc, robust=robust, external=external, delta0=d0,
                        covariance=covariance, gnss=gnss, warnings=tuple(warnings), eccentricity=ecc)


def _eccentricity_rounds(block: Block, o: BundleConfig, say, threads: int) -> tuple[Block, EccentricityRounds]:
    """Adjust, compute the eccentricity corrections at the solution, adjust the corrected observations
    (from the previous solution), until no correction changes by more than ``tol`` σ or ``max_rounds``
    re-adjustments are done.  Returns the block with corrected observations (for the workflow's final
    adjustment) and the rounds.  The core adjustment only: no tests, no rejections in the rounds."""
    e = o.eccentricity
    configured = configure_block(block, o)
    settings = bundle_settings(o, configured, threads)
    obs = configured.observations
    sigma = np.sqrt(np.einsum("kii->ki", obs.cov))
    rows = obs.active[:, None] & np.ones((1, 2), bool)
    corr = np.zeros((len(obs), 2))
    current = None
    changes, rms = [], []
    res = None
    settled = False
    try:
        for r in range(e.max_rounds + 1):
            say(f"eccentricity of circular targets: round {r}")
            work = configured.replace(observations=obs.replace(xy=obs.xy - corr))
            res = adjust(work, settings, covariance=False, **({} if res is None else {"start": res.state}))
            new = eccentricity_corrections(res.block, settings, e.distortion)
            use = rows & new.applied[:, None]
            changes.append(_largest_change(new.correction, corr, sigma, use | (rows & (corr != 0))))
            rms.append(float(np.sqrt(np.mean(new.correction[use] ** 2))) if use.any() else 0.0)
            corr, current = np.array(new.correction), new
            if changes[-1] < e.tol:
                settled = True
                break
    except AdjustmentError as err:
        raise _with_block(err, configured) from err
    out = block.replace(observations=block.observations.replace(xy=block.observations.xy - corr))
    return out, EccentricityRounds(final=current, after=current, changes=tuple(changes), rms_mm=tuple(rms),
                                   settled=settled, tol=e.tol, sigma_rows=_frozen(sigma))


def _with_block(err: AdjustmentError, block: Block) -> AdjustmentError:
    """A copy of ``err`` (message, state, history) that also carries the configured block."""
    new = AdjustmentError(str(err), state=err.state, history=err.history)
    new.block = block
    return new


def _variance_components(res: BundleResult, v: VarianceComponentsConfig) -> VarianceComponents:
    try:
        return estimate_components(res.block_in, res.settings, image_groups=v.groups, photo_groups=v.photo_groups,
                                   first=res, max_iter=v.iterations, alpha=v.alpha, covariance=True)
    except KeyError as e:
        raise InputError(f"variance_components.photo_groups: unknown photo {e}",
                         field="variance_components.photo_groups") from None


def _robust(block: Block, res: BundleResult, r: RobustConfig, warnings: list) -> RobustEstimate:
    """IRLS on the bundle (stats.irls); the final adjustment with the final weights and covariances."""
    refit, how = stats.weighted_refit(res, redundancy=r.standardise == "current")
    rob = stats.irls(refit, res.snapshot, r.method, r.c or None, standardise=r.standardise, max_iter=100)
    if not rob.converged:
        warnings.append(f"robust estimation ({r.method}) did not converge in {rob.iterations} iterations "
                        f"(largest weight change {rob.history[-1]['max_dw']:.3g})")
    if rob.iterations == 0:
        return RobustEstimate(rob, res, how)
    obs = block.observations
    b = block.replace(observations=obs.replace(cov=stats.scale_covariance(obs.cov, np.maximum(rob.weights, 1e-8))))
    final = adjust(b, res.settings, row_active=res.row_active, start=rob.fit.result.state, compute_initial=False,
                   covariance=True)
    return RobustEstimate(rob, final, how)
