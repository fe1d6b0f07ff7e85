"""Public entry point of the bundle numerics: :func:`adjust` → :class:`BundleResult`."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import numpy as np

from baarda.pipeline.accuracy import CheckPoints
from baarda.pipeline.model import Block
from baarda.pipeline.stats.robust import scale_covariance
from baarda.pipeline.stats.snapshot import GroupBlocks, Snapshot

from ..camera import get_ap_model
from .collinearity import EO_NAMES, project_observations
from .initial import initial_values
from .lm import final_system, solve_bundle
from .precision import Cofactors, reliability_rows
from .problem import BundleProblem
from .records import Convergence, Timings
from .rig import photo_transform
from .route import Route
from .settings import BundleSettings, BundleState
from ..threads import single_blas

__all__ = ["adjust", "BundleResult", "padded_ap", "result_of"]


def padded_ap(cameras) -> tuple[np.ndarray, np.ndarray]:
    """``(ap, sigma_ap)`` copies widened to the largest parameter count of the cameras' models;
    added columns get the model's default sigma (0 beyond a camera's own parameter count)."""
    models = [get_ap_model(m) for m in cameras.ap_model.tolist()]
    p = max([m.n_params for m in models] + [cameras.ap.shape[1]])
    k = len(cameras)
    ap = np.zeros((k, p))
    sig = np.zeros((k, p))
    w = cameras.ap.shape[1]
    ap[:, :w] = cameras.ap
    sig[:, :w] = cameras.sigma_ap
    for j, m in enumerate(models):
        if m.n_params > w:
            sig[j, w:m.n_params] = np.asarray(m.default_sigma, float)[w:]
    return ap, sig


@dataclass(eq=False)
class BundleResult:
    """Everything a converged bundle adjustment produced (pure data + :meth:`refit`).

    Parameters are in the block's units (image mm, object ``object_unit``, angles rad).
    Covariances are a-posteriori (``σ̂0² Q``) unless ``dof == 0`` or ``settings.variance ==
    "a-priori"`` (then ``σ0² Q``).
    """

    block_in: Block
    settings: BundleSettings
    state: BundleState
    problem: BundleProblem = field(repr=False)
    sigma0: float
    vtpv: float
    dof: int
    iterations: int
    history: Convergence             # the iterations (iteration 0 the start)
    residuals: np.ndarray            # (k_all, 2) observed − computed for every observation (inactive too)
    obs_active: np.ndarray           # (k_all,) bool, observations used
    row_active: np.ndarray           # (k_all, 2) bool
    snapshot: Snapshot | None
    cam_param_names: list            # per camera: ["c", "xp", "yp", *ap names]
    cov_cameras: list                # per camera: (3+p, 3+p) covariance (zeros for fixed)
    cov_eo: np.ndarray               # (m, 6, 6)
    cov_points: np.ndarray           # (n, 3, 3) (nan for points not in the adjustment)
    redundancy: np.ndarray           # (k_all, 2) r_i = (Qvv P)_ii (0 inactive)
    PQvvP: np.ndarray                # (k_all, 2, 2) blocks of P Qvv P
    check: CheckPoints               # check points: role 'check' with surveyed coordinates
    timings: Timings
    warnings: list
    Qx: np.ndarray | None = field(default=None, repr=False)   # cofactors of the global unknowns (dense route)
    cofactors: Cofactors | None = field(default=None, repr=False)   # DenseCofactors / SparseCofactors
    route: Route | None = field(default=None, repr=False)      # the solver route the adjustment used
    # the precision's (linearisation, factored reduced system) at the solution, kept for the first
    # external reliability computation (which takes it and drops it: see reliability._system)
    final_system: tuple | None = field(default=None, repr=False)

    def __getstate__(self):
        """Pickled (Dask, multiprocessing) without ``final_system``: a cache, rebuilt where needed."""
        return {**self.__dict__, "final_system": None}

    # -- derived -------------------------------------------------------------------------------
    @property
    def sigma0_hat(self) -> float:
        return float(np.sqrt(self.vtpv / self.dof)) if self.dof > 0 else float("nan")

    @property
    def variance_factor(self) -> float:
        return variance_factor(self.vtpv, self.dof, self.settings)

    @property
    def block(self) -> Block:
        """The input block with adjusted camera parameters, orientations and coordinates."""
        b = self.block_in
        cams = b.cameras
        st = self.state
        ap, sig = padded_ap(cams)
        for j, m in enumerate(self.problem.models):
            ap[j, :m.n_params] = st.cam_params[j, 3:3 + m.n_params]
        new_cams = cams.replace(c=st.cam_params[:, 0], xp=st.cam_params[:, 1], yp=st.cam_params[:, 2],
                                ap=ap, sigma_ap=sig)
        used = self.problem.point_used
        XYZ = np.where(used[:, None], st.XYZ, b.points.XYZ)
        ph_used = self.problem.photo_used
        if getattr(self.problem, "rig", None) is not None and st.sensor is not None:
            rs = b.rigs.sensors              # the adjusted sensor poses written back (docs/rigs.md)
            b = b.replace(rigs=b.rigs.replace(sensors=rs.replace(centre=st.sensor[:, :3], opk=st.sensor[:, 3:])))
        return b.replace(cameras=new_cams,
                         photos=b.photos.replace(X0=np.where(ph_used[:, None], st.X0, b.photos.X0),
                                                 opk=np.where(ph_used[:, None], st.opk, b.photos.opk)),
                         points=b.points.replace(XYZ=XYZ))

    def camera_table(self, j: int) -> list[dict]:
        """Each parameter of camera ``j``: name, value, sigma, status (free/weighted/fixed)."""
        prob = self.problem
        out = []
        for t, name in enumerate(self.cam_param_names[j]):
            s = prob.cam_sigma[j, t]
            status = "fixed" if s == 0 else ("free" if np.isinf(s) else "weighted")
            sd = float(np.sqrt(max(self.cov_cameras[j][t, t], 0.0)))
            out.append({"camera": str(self.block_in.cameras.ids[j]), "parameter": name,
                        "value": float(self.state.cam_params[j, t]), "sigma": sd if status != "fixed" else 0.0,
                        "status": status, "apriori_sigma": float(s)})
        return out

    def correlation_camera(self, j: int) -> np.ndarray:
        C = self.cov_cameras[j]
        d = np.sqrt(np.clip(np.diag(C), 0, None))
        with np.errstate(invalid="ignore", divide="ignore"):
            R = C / np.outer(d, d)
        R[~np.isfinite(R)] = 0.0
        np.fill_diagonal(R, np.where(d > 0, 1.0, 0.0))
        return R

    def eo_sigmas(self) -> np.ndarray:
        return np.sqrt(np.clip(np.einsum("mii->mi", self.cov_eo), 0, None))

    def point_sigmas(self) -> np.ndarray:
        return np.sqrt(np.clip(np.einsum("nii->ni", self.cov_points), 0, None))

    def obs_rows(self) -> np.ndarray:
        """(2k, 2): scalar snapshot row → (observation index, coordinate 0 = x / 1 = y)."""
        k = len(self.residuals)
        return np.column_stack([np.repeat(np.arange(k), 2), np.tile([0, 1], k)])

    def refit(self, active: np.ndarray) -> Snapshot:
        """Adjust again with only the scalar rows ``active`` (2 per observation: x, y); the start is
        this solution.  Satisfies :class:`baarda.pipeline.stats.snapshot.Refittable`.

        Returns the new adjustment's snapshot; the new :class:`BundleResult` itself is
        ``snapshot.meta["result"]`` (see :func:`result_of`).  This result is never changed."""
        res = adjust(self.block_in, self.settings, row_active=np.asarray(active, bool).reshape(-1, 2),
                     start=self.state, compute_initial=False)
        snap = res.snapshot
        if snap is None:
            return snap
        return dataclasses.replace(snap, meta={**snap.meta, "result": res})

    def weighted_refit(self, *, redundancy: bool = False):
        """``(refit(weights), how)`` for :func:`baarda.pipeline.stats.weighted_refit`: each image
        point's covariance scaled by its rows' robust weights (:func:`~baarda.pipeline.stats.scale_covariance`),
        adjusted again from this solution (no covariances; with ``redundancy`` the redundancy
        numbers too, ``.r``).  ``refit(w)`` returns ``v`` (2k,), ``r``, the new ``result`` and its
        ``block``; this result is never changed."""
        block = self.block_in
        obs = block.observations
        row_active = np.asarray(self.row_active, bool)
        settings, state = self.settings, self.state

        def refit(weights):
            cov = scale_covariance(obs.cov, weights)
            b = block.replace(observations=obs.replace(cov=cov))
            res = adjust(b, settings, row_active=row_active, start=state, compute_initial=False,
                         covariance=redundancy)
            v = np.where(row_active, np.nan_to_num(res.residuals), 0.0).reshape(-1)
            return SimpleNamespace(v=v, r=res.redundancy.reshape(-1), result=res, block=b)

        return refit, "bundle, adjusted again from its solution"

    def cofactor_columns(self, cols) -> np.ndarray:
        """Columns ``cols`` of the cofactor matrix of the global unknowns (n_g, len(cols)), either
        route (the sparse route solves for them)."""
        return self.cofactors.columns(cols)

    def cofactor_diagonal(self) -> np.ndarray:
        """Diagonal of the cofactor matrix of the global unknowns (n_g,)."""
        return self.cofactors.diagonal()

    @property
    def rig(self):
        """The block's rigs as index arrays (:class:`~.rig.RigStructure`: frames, the reference photo
        of each, each photo's frame and sensor), None without rigs (docs/rigs.md)."""
        return getattr(self.problem, "rig", None)

    @property
    def solver_route(self) -> str:
        """How the reduced camera system was solved: ``"dense"`` or ``"sparse"``."""
        return self.route.name

    @property
    def point_used(self) -> np.ndarray:
        """(n,) bool: points that took part (observed, or on a scale bar)."""
        return self.problem.point_used

    @property
    def photo_used(self) -> np.ndarray:
        """(m,) bool: photos with at least one active observation."""
        return self.problem.photo_used

    @property
    def camera_used(self) -> np.ndarray:
        """(K,) bool: cameras of the photos used."""
        return self.problem.cam_used

    @property
    def camera_sigma(self) -> np.ndarray:
        """(K, 3 + p) a-priori σ of ``[c, xp, yp, ap…]``: 0 fixed, inf free, else weighted."""
        return self.problem.cam_sigma

    @property
    def camera_meta(self) -> list:
        """AP-model meta per camera (``b`` of ebner12, ``r0`` of aicon …) as the adjustment used it."""
        return self.problem.meta

    @property
    def camera_free(self) -> np.ndarray:
        """(K, 3 + p) bool: camera parameters that were unknowns."""
        return self.problem.g_cam >= 0

    @property
    def observation_order(self) -> np.ndarray:
        """Indices of the active observations in the order the adjustment holds them."""
        return self.problem.oi

    @property
    def distances(self) -> tuple:
        """The scale bars (:class:`Distance`) the adjustment used: the settings' and the block's."""
        return self.problem.distances

    @property
    def distance_points(self) -> tuple[np.ndarray, np.ndarray]:
        """Point indices of the scale bars' ends ``(a, b)``."""
        return self.problem.dist_a, self.problem.dist_b

    @property
    def n_unknowns(self) -> int:
        return self.problem.n_unknowns

    @property
    def n_observation_rows(self) -> int:
        """Active image-coordinate rows."""
        return self.problem.n_obs_rows

    @property
    def n_weighted_constraints(self) -> int:
        return len(self.problem.prior_g_idx) + len(self.problem.prior_p_idx)

    @property
    def n_datum_constraints(self) -> int:
        """Inner constraints of a free network (0 with a control datum)."""
        return self.problem.n_c

    @property
    def ap_models(self) -> list:
        """The AP model object of each camera."""
        return self.problem.models

    def summary(self) -> dict:
        return {"sigma0_hat": self.sigma0_hat, "vtpv": self.vtpv, "dof": self.dof, "iterations": self.iterations,
                "observations": int(self.obs_active.sum()), "unknowns": self.problem.n_unknowns,
                "check_points": self.check.summary(), "timings": self.timings.summary()}


def result_of(snapshot: Snapshot | None, default: "BundleResult") -> "BundleResult":
    """The :class:`BundleResult` behind a snapshot returned by :meth:`BundleResult.refit` (else ``default``)."""
    if snapshot is None:
        return default
    return snapshot.meta.get("result", default)


@single_blas
def adjust(block: Block, settings: BundleSettings | None = None, *, row_active=None, obs_active=None,
           start: BundleState | None = None, compute_initial: bool = True, covariance: bool | None = None
           ) -> BundleResult:
    """Self-calibrating bundle adjustment of ``block``.

    Parameters
    ----------
    block : the photogrammetric block (``baarda.pipeline.model.Block``); never modified.
    settings : :class:`BundleSettings` (datum, convergence, distances, AP meta …).
    row_active : optional (k, 2) bool — scalar rows used (refit / data snooping); an observation
        with neither row active is left out.
    obs_active : optional (k,) bool replacing ``block.observations.active``.
    start : optional start state (e.g. a previous solution).
    compute_initial : compute missing orientations/coordinates by resection/intersection.

    Raises
    ------
    AdjustmentError : singular system (names the missing datum or parameter), no convergence
        (``.state`` holds the last iterate), undeterminable photos/points.
    InputError : duplicate ids, invalid covariances, unknown AP model.
    """
    settings = settings or BundleSettings()
    t0 = time.perf_counter()
    work = block
    if start is None and compute_initial:
        ph, pt = block.photos, block.points
        need = (~ph.has_orientation).any() or (~np.isfinite(pt.XYZ).all(axis=1)).any()
        if need:
            work = initial_values(block, ap_meta=settings.ap_meta)
    t_init = time.perf_counter() - t0
    t_prob = time.perf_counter()
    prob = BundleProblem(block, settings, obs_active=obs_active, row_active=row_active)
    t_prob = time.perf_counter() - t_prob
    st0 = start if start is not None else prob.initial_state(work)
    prob, st, info = solve_bundle(block, settings, start=st0, problem=prob, final=False)
    t1 = time.perf_counter()
    want_cov = settings.covariance if covariance is None else covariance
    k_all = len(block.observations)
    v_all = block.observations.xy - _project_all(prob, st)
    dof = prob.dof
    vtpv = info.vtpv
    var = variance_factor(vtpv, dof, settings)
    P = 3 + prob.pmax
    names = [["c", "xp", "yp"] + list(m.params) for m in prob.models]
    cov_cams = [np.zeros((len(nm), len(nm))) for nm in names]
    cov_eo = np.zeros((prob.m, 6, 6))
    cov_pts = np.full((prob.n, 3, 3), np.nan)
    red_all = np.zeros((k_all, 2))
    PQ_all = np.zeros((k_all, 2, 2))
    snapshot = None
    Qx = None
    cofactors = None
    system = None
    if want_cov:
        route = info.route
        lin, red = final_system(prob, route, st, info.proj)     # the precision's normal equations
        pre = route.precision(prob, lin, red, st)
        system = (lin, red)
        Qx = pre.Qx
        cofactors = pre.cofactors
        cov_cams = [var * Q for Q in pre.Q_cam]
        cov_eo = var * pre.Q_eo
        if prob.rig is not None:
            cov_eo = cov_eo + var * _rig_photo_cofactors(prob, st, pre.cofactors)
        cov_pts[~prob.point_used] = np.nan
        cov_pts[prob.point_used] = 0.0
        if prob.n_e:
            cov_pts[prob.elim_points] = var * pre.Qpp
        gp = np.flatnonzero((prob.g_pt >= 0).any(axis=1))
        if gp.size:
            cov_pts[gp] = var * pre.Q_gpt[gp]
        r, PQ = reliability_rows(prob, pre.H)
        red_all[prob.oi] = r
        PQ_all[prob.oi] = PQ
        # predicted residuals of the rows left out (for tests of removed observations)
        out_rows = ~prob.row_active & np.isfinite(v_all)
        sv_pred = np.full((k_all, 2), np.nan)
        out_obs = np.flatnonzero(out_rows.any(axis=1))
        if out_obs.size:
            aq = route.predicted_variance(prob, st, red, pre, out_obs)
            var_l = np.einsum("kii->ki", block.observations.cov[out_obs])
            sv_pred[out_obs] = np.sqrt(var_l + settings.sigma0 ** 2 * aq)
        sv_pred[~out_rows] = np.nan
        snapshot = _snapshot(block, prob, v_all, red_all, PQ_all, vtpv, dof, settings.sigma0, sv_pred)
    timings = dataclasses.replace(info.timings, setup=info.timings.setup + t_prob,   # building the problem is set-up too
                                  initial_values=t_init, covariance=time.perf_counter() - t1,
                                  total=time.perf_counter() - t0)
    # check points: role 'check' with surveyed coordinates, adjusted as tie points
    pts = block.points
    chk = np.flatnonzero((pts.role == "check") & prob.point_used & np.isfinite(pts.XYZ).all(axis=1))
    check = CheckPoints.of(pts.ids[chk], st.XYZ[chk], pts.XYZ[chk])
    return BundleResult(block_in=block, settings=settings, state=st, problem=prob, sigma0=settings.sigma0,
                        vtpv=vtpv, dof=dof, iterations=info.iterations, history=info.history,
                        residuals=v_all, obs_active=prob.obs_active.copy(), row_active=prob.row_active.copy(),
                        snapshot=snapshot, cam_param_names=names, cov_cameras=cov_cams, cov_eo=cov_eo,
                        cov_points=cov_pts, redundancy=red_all, PQvvP=PQ_all, check=check, timings=timings,
                        warnings=list(prob.warnings), Qx=Qx, cofactors=cofactors, route=info.route,
                        final_system=system)


def _rig_photo_cofactors(prob, st, cof) -> np.ndarray:
    """(m, 6, 6) cofactors of the orientations of the photos in frames (their frame's and sensor's
    12 unknowns propagated through the composition; 0 for the other photos)."""
    out = np.zeros((prob.m, 6, 6))
    ph = np.flatnonzero((prob.rig.photo_frame >= 0) & prob.photo_used)
    if not len(ph) or cof is None:
        return out
    cols = np.concatenate([prob.g_frame[prob.rig.photo_frame[ph]], prob.g_sensor[prob.rig.photo_sensor[ph]]], axis=1)
    Q = cof.blocks(np.where(cols >= 0, cols, prob.n_g))
    T = photo_transform(prob.rig, st.frame, st.sensor, st.opk)[ph]
    out[ph] = T @ Q @ np.transpose(T, (0, 2, 1))
    return out


def _project_all(prob: BundleProblem, st: BundleState) -> np.ndarray:
    obs = prob.block.observations
    ok = np.isfinite(st.X0[obs.photo]).all(axis=1) & np.isfinite(st.XYZ[obs.point]).all(axis=1) \
        & np.isfinite(st.opk[obs.photo]).all(axis=1)
    out = np.full((len(obs), 2), np.nan)
    if ok.any():
        pr = project_observations(obs.photo[ok], obs.point[ok], st.XYZ, st.X0, st.opk, prob.block.photos.camera,
                                  st.cam_params, prob.block.cameras.ap_model, prob.meta, jacobians=False,
                                  marks=prob.marks_of(ok))
        out[ok] = pr.xy
    return out


def variance_factor(vtpv: float, dof: int, settings: BundleSettings) -> float:
    """The factor on the cofactors: ``σ̂0² = vᵀPv / dof``, or ``σ0²`` without redundancy or when
    ``settings.variance == "a-priori"`` (the precision of a planned network)."""
    if dof > 0 and settings.variance != "a-priori":
        return vtpv / dof
    return settings.sigma0 ** 2


def _snapshot(block, prob, v_all, r_all, PQ_all, vtpv, dof, sigma0, sv_pred=None) -> Snapshot:
    obs = block.observations
    k = len(obs)
    act = prob.row_active  # (k, 2) incl. obs-level activity
    v = np.where(act, np.nan_to_num(v_all), 0.0)
    # P v with P = LᵀL on the active rows of each observation
    L = np.zeros((k, 2, 2))
    L[prob.oi] = prob.L
    Pv = np.einsum("kji,kj->ki", L, np.einsum("kij,kj->ki", L, v))
    PQd = np.einsum("kii->ki", PQ_all)
    sig = np.sqrt(np.einsum("kii->ki", obs.cov))
    # "photo <id> point <id> x|y", built with numpy's string ufuncs (no list of 2k Python strings)
    ph = np.strings.add("photo ", block.photos.ids.astype(str)[obs.photo])
    base = np.strings.add(np.strings.add(ph, " point "), block.points.ids.astype(str)[obs.point])
    del ph
    base = np.repeat(base, 2)
    labels = np.strings.add(base, np.tile(np.array([" x", " y"]), k))
    del base                                  # the intermediates gone before the Snapshot's copies
    group = np.repeat(np.arange(k), 2)
    both = np.flatnonzero(act.all(axis=1))
    blocks = GroupBlocks(both, PQ_all[both])         # arrays: no dict of a million views
    return Snapshot(v=v.reshape(-1), Pv=Pv.reshape(-1), PQvvP=PQd.reshape(-1), r=r_all.reshape(-1),
                    sigma_l=sig.reshape(-1), vtpv=float(vtpv), dof=int(dof), sigma0=float(sigma0),
                    active=act.reshape(-1), labels=labels, group=group, PQvvP_blocks=blocks,
                    meta={"source": "bundle", "obs_rows": "row 2i = x, 2i+1 = y of observation i"},
                    v_pred=v_all.reshape(-1), sigma_v_pred=None if sv_pred is None else sv_pred.reshape(-1))
