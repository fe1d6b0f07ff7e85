"""Self-calibrating bundle block adjustment: Gauss–Newton / Levenberg–Marquardt on sparse normal
equations with the object points eliminated (Schur complement).

Unknowns
    global (the "reduced camera system"): free camera parameters ``[c, xp, yp, ap…]`` per
    camera, free exterior orientation ``[X0, Y0, Z0, ω, φ, κ]`` per photo, and the coordinates of
    the few object points that couple to other points (scale bars);
    eliminated: every other object point (3×3 blocks).
Observations
    image points (2×2 weight ``P = σ0² Σ⁻¹`` each, x/y may be correlated), weighted constraints on
    any unknown (``0 < σ < inf``), distances between object points (scale bars).
Datum
    ``"control"``: by control points / weighted constraints — the reduced system must be regular;
    ``"free"``: inner constraints (minimum norm) on the chosen points or on the projection
    centres, appended as Lagrange rows to the reduced system; the scale comes from a distance when
    one is given.

Everything is vectorised over observations; the reduced system is dense (``cho_factor`` /
``lu_factor``).  See ``docs/bundle.md``.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any, Literal, Mapping, Sequence

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from baarda.pipeline.errors import AdjustmentError, InputError
from baarda.pipeline.model import Block

from ..camera.models import get_ap_model
from .collinearity import EO_NAMES, IOP_NAMES, Projector, bmm, bmv

__all__ = ["Distance", "BundleSettings", "BundleState", "BundleProblem", "solve_bundle"]


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


@dataclass
class BundleState:
    """The parameters of one iterate (all arrays copies, never views of the block)."""

    cam_params: np.ndarray  # (K, 3 + p)  c, xp, yp, ap...
    X0: np.ndarray          # (m, 3)
    opk: np.ndarray         # (m, 3)
    XYZ: np.ndarray         # (n, 3)

    def copy(self) -> "BundleState":
        return BundleState(self.cam_params.copy(), self.X0.copy(), self.opk.copy(), self.XYZ.copy())


def _dup(ids, what):
    ids = np.asarray(ids, str)
    u, inv, cnt = np.unique(ids, return_inverse=True, return_counts=True)
    if (cnt > 1).any():
        bad = u[np.argmax(cnt > 1)]
        rows = np.flatnonzero(ids == bad) + 1
        raise InputError(f"duplicate {what} id {str(bad)!r} (rows {', '.join(map(str, rows))}); ids must be unique",
                         field=f"{what} id")


def camera_meta(block: Block, settings: BundleSettings) -> list[dict]:
    """AP-model meta per camera: block.meta['ap_meta'][id] updated by settings.ap_meta[id];
    ebner12 without ``b`` gets ``b = 0.4 × format width`` (the base of 60 % forward overlap)."""
    cams = block.cameras
    base = block.meta.get("ap_meta", {}) if isinstance(block.meta, dict) else {}
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


class BundleProblem:
    """Index bookkeeping of one adjustment: which parameters are unknown, observed or fixed,
    where every unknown sits in the global vector, the whitening of each observation.

    Built once per (block, active set, settings); the iteration only changes the state.
    """

    def __init__(self, block: Block, settings: BundleSettings, obs_active: np.ndarray | None = None,
                 row_active: np.ndarray | None = None):
        self.block = block
        self.settings = settings
        cams, photos, points, obs = block.cameras, block.photos, block.points, block.observations
        _dup(cams.ids, "camera")
        _dup(photos.ids, "photo")
        _dup(points.ids, "point")
        K, m, n = len(cams), len(photos), len(points)
        self.K, self.m, self.n = K, m, n
        try:
            self.models = [get_ap_model(name) for name in cams.ap_model.tolist()]
        except KeyError as e:
            raise InputError(str(e.args[0]), field="ap_model") from None
        self.pmax = max([mdl.n_params for mdl in self.models] + [0])
        self.meta = camera_meta(block, settings)
        for j, mdl in enumerate(self.models):
            if mdl.name == "ebner12" and self.meta[j].get("b") is None:
                raise InputError(f"camera {str(cams.ids[j])!r}: ebner12 needs the image base b (mm): set option "
                                 "'ebner_b' or give the camera's format", field="ebner_b")
        P = 3 + self.pmax
        cp0 = np.zeros((K, P))
        cp0[:, 0], cp0[:, 1], cp0[:, 2] = cams.c, cams.xp, cams.yp
        csig = np.zeros((K, P))
        csig[:, :3] = cams.sigma_iop
        for j, mdl in enumerate(self.models):
            p = mdl.n_params
            given = min(p, cams.ap.shape[1])
            cp0[j, 3:3 + given] = cams.ap[j, :given]
            csig[j, 3:3 + given] = cams.sigma_ap[j, :given]
            csig[j, 3 + given:3 + p] = np.asarray(mdl.default_sigma, float)[given:p]
        self.cam_params0 = cp0
        self.cam_sigma = csig

        # ---- which observations, photos, points take part ------------------------------------
        act = np.asarray(obs.active, bool).copy() if obs_active is None else np.asarray(obs_active, bool).copy()
        if row_active is not None:
            ra = np.asarray(row_active, bool).reshape(-1, 2)
            act &= ra.any(axis=1)
            self.row_active = ra & act[:, None]
        else:
            self.row_active = np.repeat(act[:, None], 2, axis=1)
        dist = tuple(settings.distances) + tuple(_block_distances(block))
        self.distances = dist
        self.dist_a = points.index_of([d.a for d in dist]) if dist else np.zeros(0, int)
        self.dist_b = points.index_of([d.b for d in dist]) if dist else np.zeros(0, int)
        self.dist_l = np.array([d.distance for d in dist], float)
        self.dist_s = np.array([d.sigma for d in dist], float)
        if (self.dist_s <= 0).any() or not np.isfinite(self.dist_s).all():
            raise InputError("a distance (scale bar) needs a positive, finite sigma", field="sigma")
        self.warnings: list[str] = []
        act = self._check_weak(act)
        self.obs_active = act
        self.row_active &= act[:, None]
        oi = np.flatnonzero(act)
        oi = oi[np.argsort(obs.photo[oi], kind="stable")]     # photo segments are contiguous
        self.oi = oi
        self.obs_photo = obs.photo[oi]
        self.obs_point = obs.point[oi]
        self.obs_cam = photos.camera[self.obs_photo]
        self.l = obs.xy[oi].copy()
        self.photo_used = np.zeros(m, bool)
        self.photo_used[self.obs_photo] = True
        self.point_used = np.zeros(n, bool)
        self.point_used[self.obs_point] = True
        self.point_used[self.dist_a] = True
        self.point_used[self.dist_b] = True
        self.cam_used = np.zeros(K, bool)
        self.cam_used[photos.camera[self.photo_used]] = True

        # ---- whitening: e = L (l − f), LᵀL = P = σ0² Σ⁻¹ (rows switched off get weight 0) -----
        cov = obs.cov[oi]
        s0 = settings.sigma0
        ra = self.row_active[oi]
        L = np.zeros((len(oi), 2, 2))
        both = ra.all(axis=1)
        if both.any():
            Pm = s0 * s0 * np.linalg.inv(cov[both])
            try:
                Lc = np.linalg.cholesky(Pm)
            except np.linalg.LinAlgError:
                bad = oi[both][np.argmin(np.linalg.det(cov[both]))]
                raise InputError(f"observation {bad + 1} (photo {str(photos.ids[obs.photo[bad]])!r}, point "
                                 f"{str(points.ids[obs.point[bad]])!r}) has a covariance that is not positive definite",
                                 field="cov") from None
            L[both] = np.transpose(Lc, (0, 2, 1))
        for r in (0, 1):
            only = ra[:, r] & ~ra[:, 1 - r]
            L[only, r, r] = s0 / np.sqrt(cov[only, r, r])
        if not np.isfinite(L).all():
            raise InputError("an image observation has a zero or invalid variance", field="cov")
        self.L = L
        self.L_diag = bool(np.all(L[:, 0, 1] == 0) and np.all(L[:, 1, 0] == 0))

        # ---- global unknowns ---------------------------------------------------------------------
        nx = 0
        self.g_cam = np.full((K, P), -1)
        free_c = (csig != 0) & self.cam_used[:, None]
        for j, mdl in enumerate(self.models):
            free_c[j, 3 + mdl.n_params:] = False
        cnt = int(free_c.sum())
        self.g_cam[free_c] = np.arange(nx, nx + cnt)
        nx += cnt
        self.g_eo = np.full((m, 6), -1)
        free_e = (photos.sigma_eo != 0) & self.photo_used[:, None]
        cnt = int(free_e.sum())
        self.g_eo[free_e] = np.arange(nx, nx + cnt)
        nx += cnt
        pt_free = (points.sigma != 0) & self.point_used[:, None]
        self.pt_free = pt_free
        glob_pts = np.zeros(n, bool)
        glob_pts[self.dist_a] = True
        glob_pts[self.dist_b] = True
        self.g_pt = np.full((n, 3), -1)
        gp_free = pt_free & glob_pts[:, None]
        cnt = int(gp_free.sum())
        self.g_pt[gp_free] = np.arange(nx, nx + cnt)
        nx += cnt
        self.n_g = nx
        elim = self.point_used & ~glob_pts & pt_free.any(axis=1)
        self.elim_points = np.flatnonzero(elim)
        self.n_e = len(self.elim_points)
        self.elim_of = np.full(n, -1)
        self.elim_of[self.elim_points] = np.arange(self.n_e)
        self.elim_free = pt_free[self.elim_points]                    # (n_e, 3)
        self.n_unknowns = self.n_g + int(self.elim_free.sum())

        # per-observation column layout: [cam (P) | eo (6) | global point (3)], dummy = n_g
        groups = []
        if (self.g_cam[self.obs_cam] >= 0).any():
            groups.append(("cam", P))
        groups.append(("eo", 6))
        if (self.g_pt[self.obs_point] >= 0).any():
            groups.append(("pt", 3))
        self.col_groups = groups
        cols = []
        for name, _ in groups:
            cols.append({"cam": self.g_cam[self.obs_cam], "eo": self.g_eo[self.obs_photo],
                         "pt": self.g_pt[self.obs_point]}[name])
        cidx = np.concatenate(cols, axis=1) if cols else np.zeros((len(oi), 0), int)
        # drop columns that no observation uses (parameters fixed everywhere)
        keep = (cidx >= 0).any(axis=0)
        n_ph_cols = sum(w for name, w in groups if name != "pt")
        self.col_keep = np.flatnonzero(keep)
        cidx = cidx[:, keep]
        self.col_mask = cidx >= 0
        cidx = np.where(self.col_mask, cidx, self.n_g)
        self.cidx = cidx
        self.q = cidx.shape[1]
        self.q_ph = int(keep[:n_ph_cols].sum())                          # photo-constant columns
        # photo segments of the (photo-sorted) observations
        ph_sorted = self.obs_photo
        starts = np.flatnonzero(np.r_[True, ph_sorted[1:] != ph_sorted[:-1]]) if len(oi) else np.zeros(0, int)
        self.seg_start = starts
        self.seg_end = np.r_[starts[1:], len(oi)].astype(int)
        self.gp_obs = np.flatnonzero((cidx[:, self.q_ph:] < self.n_g).any(axis=1)) if self.q > self.q_ph \
            else np.zeros(0, int)
        pidx = self.elim_of[self.obs_point]
        self.obs_elim = pidx >= 0
        self.pidx = np.where(self.obs_elim, pidx, self.n_e)
        self.pt_mask = np.zeros((len(oi), 3), bool)
        self.pt_mask[self.obs_elim] = self.elim_free[pidx[self.obs_elim]]
        ng1 = self.n_g + 1
        gc = cidx[self.gp_obs]
        self.flatU_gp = (gc[:, :, None] * ng1 + gc[:, None, :]).ravel()

        # ---- weighted constraints (priors) -------------------------------------------------------
        self._setup_priors()
        # ---- datum -------------------------------------------------------------------------------
        self._setup_datum()
        self.n_obs_rows = int(self.row_active[oi].sum())
        self.dof = (self.n_obs_rows + len(self.prior_g_idx) + len(self.prior_p_idx) + len(self.dist_l)
                    + self.n_c - self.n_unknowns)
        self._setup_iteration()

    def _setup_iteration(self):
        """What every iteration reuses: the projector (camera of each observation, AP-model groups),
        the Jacobian columns that feed ``cidx``, the photo segments' columns, the observation →
        point summation matrix."""
        P = 3 + self.pmax
        sel = {"cam": np.zeros(0, int), "eo": np.zeros(0, int), "pt": np.zeros(0, int)}
        off = 0
        for name, w in self.col_groups:
            sel[name] = self.col_keep[(self.col_keep >= off) & (self.col_keep < off + w)] - off
            off += w
        self.jac_cols = (sel["cam"], sel["eo"], sel["pt"])
        photos = self.block.photos
        self.projector = Projector(self.obs_photo, self.obs_point, photos.camera, self.block.cameras.ap_model,
                                   self.meta, cam_cols=sel["cam"])
        self.col_mask_all = bool(self.col_mask.all())
        self.pt_mask_all = bool(self.pt_mask.all())
        self.L_rows = np.stack([self.L[:, 0, 0], self.L[:, 1, 1]], axis=1)[:, :, None]
        self.seg_len = (self.seg_end - self.seg_start).astype(np.intp)
        self.seg_cols = self.cidx[self.seg_start, :self.q_ph]                # (n_seg, q_ph)
        k = len(self.oi)
        # Σ over the observations of each eliminated point (row n_e: observations of no such point)
        self.obs_to_point = sp.csr_matrix((np.ones(k), (self.pidx, np.arange(k))), shape=(self.n_e + 1, k))
        self.datum_on_elim = bool(self.n_c and len(self.datum_elim))

    # ------------------------------------------------------------------------------------------
    def _check_weak(self, act):
        """Photos with < 3 observed points and free points in < 2 photos: error or drop."""
        blk = self.block
        obs, photos, points = blk.observations, blk.photos, blk.points
        for _ in range(100):
            oi = np.flatnonzero(act)
            # duplicate (photo, point) pairs
            key = obs.photo[oi].astype(np.int64) * (len(points) + 1) + obs.point[oi]
            u, cnt = np.unique(key, return_counts=True)
            if (cnt > 1).any():
                k = u[np.argmax(cnt > 1)]
                ph, pt = divmod(int(k), len(points) + 1)
                raise InputError(f"point {str(points.ids[pt])!r} is measured twice in photo {str(photos.ids[ph])!r}; "
                                 "keep one measurement (or switch one off)", field="observations")
            n_pts_photo = np.bincount(obs.photo[oi], minlength=len(photos))
            eo_free = (photos.sigma_eo != 0).any(axis=1)
            weak_ph = np.flatnonzero((n_pts_photo > 0) & (n_pts_photo < 3) & eo_free)
            rays = np.bincount(obs.point[oi], minlength=len(points))
            indist = np.zeros(len(points), bool)
            indist[self.dist_a] = True
            indist[self.dist_b] = True
            free_all = np.isinf(points.sigma).all(axis=1)
            weak_pt = np.flatnonzero((rays == 1) & free_all & ~indist)
            if weak_ph.size == 0 and weak_pt.size == 0:
                return act
            if self.settings.on_weak == "error":
                if weak_ph.size:
                    i = weak_ph[0]
                    raise AdjustmentError(
                        f"photo {str(photos.ids[i])!r} has only {n_pts_photo[i]} observed point(s); its orientation needs "
                        "at least 3 (better 4 or more) — add points, fix its orientation, or set on_weak = 'drop'")
                p = weak_pt[0]
                ph = obs.photo[oi][obs.point[oi] == p][0]
                raise AdjustmentError(
                    f"point {str(points.ids[p])!r} is observed in only one photo ({str(photos.ids[ph])!r}) and has no control: "
                    "it cannot be determined — add a measurement in another photo, remove it, or set on_weak = 'drop'")
            drop = np.isin(obs.photo, weak_ph) | np.isin(obs.point, weak_pt)
            for i in weak_ph:
                self.warnings.append(f"photo {str(photos.ids[i])!r} dropped: only {n_pts_photo[i]} observed point(s)")
            for p in weak_pt:
                self.warnings.append(f"point {str(points.ids[p])!r} dropped: observed in only one photo")
            act = act & ~drop
        return act  # pragma: no cover

    def _setup_priors(self):
        blk = self.block
        gi, w, given, ang = [], [], [], []
        s0 = self.settings.sigma0
        # cameras
        m = (self.g_cam >= 0) & np.isfinite(self.cam_sigma) & (self.cam_sigma > 0)
        gi.append(self.g_cam[m]); w.append((s0 / self.cam_sigma[m]) ** 2); given.append(self.cam_params0[m])
        ang.append(np.zeros(int(m.sum()), bool))
        # exterior orientation
        se = blk.photos.sigma_eo
        m = (self.g_eo >= 0) & np.isfinite(se) & (se > 0)
        val = np.concatenate([blk.photos.X0, blk.photos.opk], axis=1)
        if np.isnan(val[m]).any():
            raise InputError("an exterior-orientation element has an a-priori sigma but no value", field="sigma_eo")
        gi.append(self.g_eo[m]); w.append((s0 / se[m]) ** 2); given.append(val[m])
        ang.append(np.broadcast_to(np.arange(6) >= 3, se.shape)[m])
        # global points
        ps = blk.points.sigma
        m = (self.g_pt >= 0) & np.isfinite(ps) & (ps > 0)
        gi.append(self.g_pt[m]); w.append((s0 / ps[m]) ** 2); given.append(blk.points.XYZ[m])
        ang.append(np.zeros(int(m.sum()), bool))
        self.prior_g_idx = np.concatenate(gi).astype(int)
        self.prior_g_w = np.concatenate(w)
        self.prior_g_val = np.concatenate(given)
        self.prior_g_ang = np.concatenate(ang)
        # eliminated points
        ep = self.elim_points
        s = ps[ep]
        m = self.elim_free & np.isfinite(s) & (s > 0)
        pe, pc = np.nonzero(m)
        self.prior_p_idx = pe
        self.prior_p_coord = pc
        self.prior_p_w = (s0 / s[m]) ** 2
        self.prior_p_val = blk.points.XYZ[ep][m]
        if np.isnan(self.prior_p_val).any() or np.isnan(self.prior_g_val).any():
            raise InputError("a control point has an a-priori sigma but no coordinate", field="XYZ")

    def _setup_datum(self):
        st = self.settings
        self.n_c = 0
        self.datum_elim = np.zeros(0, int)
        self.datum_glob_pts = np.zeros(0, int)
        self.datum_photos = np.zeros(0, int)
        if st.datum != "free":
            return
        self.scale_free = len(self.dist_l) == 0
        self.n_c = 7 if self.scale_free else 6
        pts = self.block.points
        if st.datum_centres:
            self.datum_photos = np.flatnonzero(self.photo_used & (self.g_eo[:, :3] >= 0).all(axis=1))
            if len(self.datum_photos) < 3:
                raise AdjustmentError("free network on projection centres needs at least 3 photos with free positions")
            return
        if st.datum_points is None:
            sel = self.point_used & np.isin(pts.role, ("tie", "check"))
        else:
            sel = np.zeros(self.n, bool)
            sel[pts.index_of(list(st.datum_points))] = True
            unused = sel & ~self.point_used
            if unused.any():
                raise InputError(f"datum point {str(pts.ids[np.argmax(unused)])!r} is not observed", field="datum_points")
        sel &= self.pt_free.all(axis=1)
        if sel.sum() < 3:
            raise AdjustmentError("free network: the inner constraints need at least 3 observed points with free "
                                  "coordinates (option datum_points)")
        self.datum_elim = self.elim_of[sel & (self.elim_of >= 0)]
        self.datum_glob_pts = np.flatnonzero(sel & (self.g_pt >= 0).all(axis=1))

    # ------------------------------------------------------------------------------------------
    def initial_state(self, block: Block | None = None) -> BundleState:
        b = block or self.block
        return BundleState(self.cam_params0.copy(), np.array(b.photos.X0, float),
                           np.array(b.photos.opk, float), np.array(b.points.XYZ, float))

    def global_vector(self, st: BundleState) -> np.ndarray:
        x = np.zeros(self.n_g)
        m = self.g_cam >= 0
        x[self.g_cam[m]] = st.cam_params[m]
        eo = np.concatenate([st.X0, st.opk], axis=1)
        m = self.g_eo >= 0
        x[self.g_eo[m]] = eo[m]
        m = self.g_pt >= 0
        x[self.g_pt[m]] = st.XYZ[m]
        return x

    def apply(self, st: BundleState, dx_g: np.ndarray, dp: np.ndarray) -> BundleState:
        out = st.copy()
        m = self.g_cam >= 0
        out.cam_params[m] += dx_g[self.g_cam[m]]
        m = self.g_eo >= 0
        eo = np.concatenate([out.X0, out.opk], axis=1)
        eo[m] += dx_g[self.g_eo[m]]
        out.X0, out.opk = eo[:, :3].copy(), eo[:, 3:].copy()
        m = self.g_pt >= 0
        out.XYZ[m] += dx_g[self.g_pt[m]]
        if self.n_e:
            out.XYZ[self.elim_points] += np.where(self.elim_free, dp, 0.0)
        return out

    # ------------------------------------------------------------------------------------------
    def project(self, st: BundleState, jacobians: bool):
        pr = self.projector.project(st.XYZ, st.X0, st.opk, st.cam_params)
        return self.projector.jacobians(pr) if jacobians else pr

    def residual_parts(self, st: BundleState, proj=None):
        """Whitened image residuals e (k, 2), prior residuals (global, points), distances."""
        proj = proj or self.project(st, False)
        v = self.l - proj.xy
        e = bmv(self.L, v)
        xg = self.global_vector(st)
        dg = self.prior_g_val - xg[self.prior_g_idx]
        dg = np.where(self.prior_g_ang, _wrap(dg), dg)
        dpv = self.prior_p_val - st.XYZ[self.elim_points[self.prior_p_idx], self.prior_p_coord]
        dd = self.dist_l - np.linalg.norm(st.XYZ[self.dist_a] - st.XYZ[self.dist_b], axis=1)
        return v, e, dg, dpv, dd, proj

    def cost(self, st: BundleState, parts=None) -> float:
        v, e, dg, dpv, dd, _ = parts or self.residual_parts(st)
        s0 = self.settings.sigma0
        return float(np.sum(e * e) + np.sum(self.prior_g_w * dg * dg) + np.sum(self.prior_p_w * dpv * dpv)
                     + np.sum((s0 * dd / self.dist_s) ** 2)) if len(e) or len(dg) else 0.0

    # ------------------------------------------------------------------------------------------
    def linearize(self, st: BundleState, proj=None):
        """Whitened Jacobians and normal-equation pieces at ``st``.

        ``proj``: the projection of ``st`` already computed (the accepted trial step's), so the
        residuals are not evaluated twice; its Jacobians are added here."""
        t0 = time.perf_counter()
        if proj is None or proj._d is None:
            proj = self.project(st, False)
        if proj.J_eo is None:
            self.projector.jacobians(proj)
        parts = self.residual_parts(st, proj)
        v, e, dg, dpv, dd, _ = parts
        k = len(e)
        sc, se, spt = self.jac_cols
        Jc = np.empty((k, 2, self.q))
        a, b = len(sc), len(sc) + len(se)
        Jc[:, :, :a] = proj.J_cam
        Jc[:, :, a:b] = proj.J_eo if len(se) == 6 else proj.J_eo[:, :, se]
        Jc[:, :, b:] = proj.J_point[:, :, spt]
        Jc = self.whiten(Jc, out=Jc)
        if not self.col_mask_all:
            Jc *= self.col_mask[:, None, :]
        Jp = self.whiten(proj.J_point)
        if not self.pt_mask_all:
            Jp *= self.pt_mask[:, None, :]
        U, g = self.gram_U(Jc, e)
        ng1 = self.n_g + 1
        Vk = Jp[:, 0, :, None] * Jp[:, 0, None, :]
        Vk += Jp[:, 1, :, None] * Jp[:, 1, None, :]
        V = (self.obs_to_point @ Vk.reshape(k, 9))[:-1].reshape(-1, 3, 3)
        Jpe = Jp[:, 0, :] * e[:, 0, None] + Jp[:, 1, :] * e[:, 1, None]
        bp = (self.obs_to_point @ Jpe)[:-1]
        # priors
        np.add.at(U, (self.prior_g_idx, self.prior_g_idx), self.prior_g_w)
        np.add.at(g, self.prior_g_idx, self.prior_g_w * dg)
        if len(self.prior_p_idx):
            np.add.at(V, (self.prior_p_idx, self.prior_p_coord, self.prior_p_coord), self.prior_p_w)
            np.add.at(bp, (self.prior_p_idx, self.prior_p_coord), self.prior_p_w * dpv)
        # distances (all their points are global unknowns)
        if len(self.dist_l):
            s0 = self.settings.sigma0
            diff = st.XYZ[self.dist_a] - st.XYZ[self.dist_b]
            unit = diff / np.linalg.norm(diff, axis=1, keepdims=True)
            wd = s0 / self.dist_s
            cols = np.concatenate([self.g_pt[self.dist_a], self.g_pt[self.dist_b]], axis=1)
            Jd = np.concatenate([unit, -unit], axis=1) * wd[:, None]
            ok = cols >= 0
            cols = np.where(ok, cols, self.n_g)
            Jd = Jd * ok
            dist_lin = (Jd, cols)
            Uext = np.zeros((ng1, ng1))
            np.add.at(Uext, (cols[:, :, None], cols[:, None, :]), Jd[:, :, None] * Jd[:, None, :])
            U = U + Uext[:-1, :-1]
            gext = np.zeros(ng1)
            np.add.at(gext, cols, Jd * (wd * dd)[:, None])
            g = g + gext[:-1]
        # free coordinates that no observation touches stay fixed
        if self.n_e:
            fixed = ~self.elim_free
            pi, ci = np.nonzero(fixed)
            V[pi, ci, ci] = 1.0
            bp[fixed] = 0.0
        Jd, dcols = dist_lin if len(self.dist_l) else (None, None)
        return dict(U=U, g=g, V=V, bp=bp, Jc=Jc, Jp=Jp, e=e, v=v, parts=parts, proj=proj,
                    Jd=Jd, dcols=dcols, t=time.perf_counter() - t0)

    def whiten(self, J, out=None):
        """``L J`` for (k, 2, c) Jacobians."""
        if self.L_diag:
            return np.multiply(J, self.L_rows, out=out)
        return bmm(self.L, J)

    def gram_U(self, Jc, e=None):
        """``Σ_k Jc_kᵀ Jc_k`` scattered into (n_g, n_g) (and ``Σ_k Jc_kᵀ e_k`` when ``e`` is given):
        per photo with BLAS for the photo-constant columns, by bincount for the few observations
        of global points."""
        ng1 = self.n_g + 1
        Up = np.zeros((ng1, ng1))
        gp = np.zeros(ng1)
        q_ph = self.q_ph
        whole = q_ph == self.q
        for s0, s1, idx in zip(self.seg_start.tolist(), self.seg_end.tolist(), self.seg_cols):
            A = Jc[s0:s1].reshape(-1, q_ph) if whole else Jc[s0:s1, :, :q_ph].reshape(-1, q_ph)
            Up[np.ix_(idx, idx)] += A.T @ A
            if e is not None:
                gp[idx] += A.T @ e[s0:s1].reshape(-1)
        if len(self.gp_obs):
            J = Jc[self.gp_obs]
            outer = bmm(np.transpose(J, (0, 2, 1)), J)
            outer[:, :q_ph, :q_ph] = 0.0          # counted above
            Up += np.bincount(self.flatU_gp, outer.ravel(), minlength=ng1 * ng1).reshape(ng1, ng1)
            if e is not None:
                eg = e[self.gp_obs]
                gv = J[:, 0, q_ph:] * eg[:, 0, None] + J[:, 1, q_ph:] * eg[:, 1, None]
                gp += np.bincount(self.cidx[self.gp_obs, q_ph:].ravel(), gv.ravel(), minlength=ng1)
        if e is None:
            return Up[:-1, :-1]
        return Up[:-1, :-1], gp[:-1]

    def gram_mode(self) -> str:
        """Cheapest way to form ``B Bᵀ`` for this problem (cost model in flops-equivalents)."""
        if getattr(self, "_gram_mode", None) is None:
            n_e = self.n_e
            cnt = np.bincount(self.pidx[self.obs_elim], minlength=n_e).astype(float)
            q = self.q_ph
            n_pairs = float(np.sum(cnt * (cnt - 1) / 2))
            n_seg = len(self.seg_start)
            photo_pairs = min(n_pairs, n_seg * (n_seg - 1) / 2)
            # pairs: one small BLAS product per photo pair (≈ 30 µs-equivalents of overhead each),
            # the gathered blocks and the per-photo diagonal
            pairs = (2 * 3 * q * q / 4 + 2 * 3 * q * 2) * n_pairs + 3e4 * photo_pairs + len(self.oi) * 3 * q * q / 4
            nnz_col = np.minimum(cnt * self.q, self.n_g)
            sparse = 3.0 * float(np.sum(nnz_col ** 2)) * 4.0
            dense = float(self.n_g + self.n_c) ** 2 * 3 * n_e / 10.0 + 3.0 * len(self.oi) * self.q
            dense_bytes = 8.0 * (self.n_g + 1) * 3 * n_e
            pair_bytes = 16.0 * n_pairs + 8.0 * photo_pairs * q * q
            costs = {"sparse": sparse, "pairs": pairs if pair_bytes < 6e8 else np.inf,
                     "dense": dense if dense_bytes < 4e8 else np.inf}
            self._gram_mode = min(costs, key=costs.get)
        return self._gram_mode

    def precision_route(self) -> str:
        """How :func:`baarda.pipeline.adjustment.precision.precision` forms the points' cofactors (cost model in
        flops-equivalents, independent of :meth:`gram_mode`, which chooses the Schur product):
        ``"pairs"`` — per point only the (t q)² block of K⁻¹ its t observations touch (short
        tracks, e.g. aerial blocks, BAL) — or ``"chunks"`` — K⁻¹ B for blocks of points, n_x² per
        point (few points seen by many photos, e.g. close range).  The pairs route gathers the
        blocks of all points of one track length at once; past 2e8 bytes it is not used."""
        if getattr(self, "_precision_route", None) is None:
            cnt = np.bincount(self.pidx[self.obs_elim], minlength=self.n_e).astype(float)
            tq = cnt * self.q
            n_x = self.n_g + self.n_c
            pairs = float(np.sum(4.0 * tq * tq * 3 + 3.0 * tq * self.n_c))
            chunks = 3.0 * n_x * n_x * self.n_e + 3.0 * len(self.oi) * self.q * 3
            lengths, inverse = np.unique(cnt, return_inverse=True) if self.n_e else (np.zeros(0), np.zeros(0, int))
            group_bytes = np.bincount(inverse, 8.0 * tq * tq, minlength=len(lengths)) if self.n_e else np.zeros(1)
            fits = float(group_bytes.max(initial=0.0)) < 2e8
            self._precision_route = "pairs" if fits and pairs < chunks else "chunks"
        return self._precision_route

    def track_groups(self):
        """Observations of each eliminated point grouped by track length: list of
        ``(obs_mat (N_t, t), None)`` (built once)."""
        if getattr(self, "_tracks", None) is None:
            sel = np.flatnonzero(self.obs_elim)
            order = sel[np.argsort(self.pidx[sel], kind="stable")]
            cnt = np.bincount(self.pidx[sel], minlength=self.n_e)
            start = np.r_[0, np.cumsum(cnt)[:-1]]
            groups = []
            for t in np.unique(cnt[cnt > 0]):
                pts = np.flatnonzero(cnt == t)
                groups.append((order[start[pts][:, None] + np.arange(t)], None))
            self._tracks = groups
        return self._tracks

    def pair_plan(self, chunk_pairs: int = 1 << 15):
        """The observation pairs of every eliminated point, grouped by photo pair (built once).

        ``B Bᵀ`` (global part) is ``Σ_photos Y_aᵀ Y_a + Σ_{a<b} (S_ab + S_abᵀ)`` with
        ``S_ab = Σ_{p seen in a and b} B_ap B_bpᵀ``: one BLAS product per photo pair over the
        stacked blocks of their common points.  Returns a dict: ``oa, ob`` (observations of each
        pair, photo of ``oa`` < photo of ``ob``, sorted by photo pair), ``gs, ge`` (pair range of
        each photo pair), ``flat`` / ``flat_diag`` (where the q×q blocks go in the (n_g+1)² matrix),
        ``chunks`` (photo-pair ranges gathered together, ≤ ``chunk_pairs`` pairs unless one photo
        pair alone has more)."""
        if getattr(self, "_pair_plan", None) is None:
            n_seg = len(self.seg_start)
            seg_of = np.repeat(np.arange(n_seg), self.seg_len)
            oa_l, ob_l = [np.zeros(0, np.intp)], [np.zeros(0, np.intp)]
            for obs_mat, _ in self.track_groups():
                t = obs_mat.shape[1]
                if t < 2:
                    continue
                ia, ib = np.triu_indices(t, 1)
                oa_l.append(obs_mat[:, ia].ravel())
                ob_l.append(obs_mat[:, ib].ravel())
            oa, ob = np.concatenate(oa_l), np.concatenate(ob_l)
            sa, sb = seg_of[oa], seg_of[ob]
            swap = sa > sb
            oa, ob = np.where(swap, ob, oa), np.where(swap, oa, ob)
            sa, sb = np.minimum(sa, sb), np.maximum(sa, sb)
            key = sa.astype(np.int64) * n_seg + sb
            o = np.lexsort((oa, key))
            oa, ob, key, sa, sb = oa[o], ob[o], key[o], sa[o], sb[o]
            gs = np.flatnonzero(np.r_[True, key[1:] != key[:-1]]) if len(key) else np.zeros(0, int)
            ge = np.r_[gs[1:], len(key)].astype(int)
            ng1 = self.n_g + 1
            itype = np.int32 if ng1 * ng1 < 2 ** 31 else np.int64
            ra = self.seg_cols[sa[gs]].astype(itype)
            rb = self.seg_cols[sb[gs]].astype(itype)
            flat = (ra[:, :, None] * itype(ng1) + rb[:, None, :]).ravel()
            rd = self.seg_cols.astype(itype)
            flat_diag = (rd[:, :, None] * itype(ng1) + rd[:, None, :]).ravel()
            chunks = []
            g0 = 0
            for g in range(1, len(gs) + 1):
                if g == len(gs) or ge[g] - gs[g0] > chunk_pairs:
                    chunks.append((g0, g))
                    g0 = g
            self._pair_plan = dict(oa=oa, ob=ob, gs=gs.tolist(), ge=ge.tolist(), flat=flat, flat_diag=flat_diag,
                                   chunks=chunks)
        return self._pair_plan

    # ------------------------------------------------------------------------------------------
    def constraint_rows(self, st: BundleState):
        """Inner constraints Gᵀ Δ = 0: (Cg (n_g, n_c), Cp (n_e, 3, n_c))."""
        n_c = self.n_c
        Cg = np.zeros((self.n_g, n_c))
        Cp = np.zeros((self.n_e, 3, n_c))
        if n_c == 0:
            return Cg, Cp
        pos, where = [], []
        if len(self.datum_photos):
            pos.append(st.X0[self.datum_photos])
        if len(self.datum_elim):
            pos.append(st.XYZ[self.elim_points[self.datum_elim]])
        if len(self.datum_glob_pts):
            pos.append(st.XYZ[self.datum_glob_pts])
        allpos = np.concatenate(pos)
        ctr = allpos.mean(axis=0)
        scale = np.sqrt(np.mean(np.sum((allpos - ctr) ** 2, axis=1))) or 1.0

        def G(X):
            Xr = (X - ctr) / scale
            out = np.zeros((len(X), 3, n_c))
            out[:, [0, 1, 2], [0, 1, 2]] = 1.0
            # rotation: ΔX = ε × X → columns of −[X]×
            out[:, 1, 3], out[:, 2, 3] = -Xr[:, 2], Xr[:, 1]
            out[:, 0, 4], out[:, 2, 4] = Xr[:, 2], -Xr[:, 0]
            out[:, 0, 5], out[:, 1, 5] = -Xr[:, 1], Xr[:, 0]
            if n_c == 7:
                out[:, :, 6] = Xr
            return out

        if len(self.datum_photos):
            Gx = G(st.X0[self.datum_photos])
            Cg[self.g_eo[self.datum_photos, :3].ravel()] = Gx.reshape(-1, n_c)
        if len(self.datum_glob_pts):
            Gx = G(st.XYZ[self.datum_glob_pts])
            Cg[self.g_pt[self.datum_glob_pts].ravel()] = Gx.reshape(-1, n_c)
        if len(self.datum_elim):
            Cp[self.datum_elim] = G(st.XYZ[self.elim_points[self.datum_elim]])
        return Cg, Cp

    # ------------------------------------------------------------------------------------------
    def reduced_system(self, lin, st: BundleState, lam: float = 0.0):
        """Schur complement: K (n_x, n_x), rhs (n_x,), the factors needed to back-substitute."""
        U, g, V, bp = lin["U"], lin["g"], lin["V"], lin["bp"]
        Jc, Jp = lin["Jc"], lin["Jp"]
        n_g, n_e, n_c = self.n_g, self.n_e, self.n_c
        if lam > 0:
            U = U + lam * np.diag(np.diag(U))
            V = V + lam * np.einsum("pii->pi", V)[:, :, None] * np.eye(3)
        Li = _chol3_inv(V, self)                                   # (n_e, 3, 3) lower, L⁻¹ with V = L Lᵀ
        Li1 = np.concatenate([Li, np.eye(3)[None]], axis=0)        # dummy point for global-point obs
        # B_k = W_k L⁻ᵀ = Jcᵀ (Jp L⁻ᵀ), held transposed: BkT (k, 3, q)
        Jh = bmm(Jp, np.transpose(Li1[self.pidx], (0, 2, 1)))
        BkT = Jh[:, 0, :, None] * Jc[:, 0, None, :]
        BkT += Jh[:, 1, :, None] * Jc[:, 1, None, :]
        Cg, Cp = self.constraint_rows(st)
        n_x = n_g + n_c
        Bc = np.einsum("pac,pba->pcb", Cp, Li) if n_c else None   # (n_e, n_c, 3) = Cpᵀ L⁻ᵀ
        B = _BMatrix(self, BkT, Bc)
        K = np.zeros((n_x, n_x))
        K[:n_g, :n_g] = U
        if n_c:
            K[:n_g, n_g:] = Cg
            K[n_g:, :n_g] = Cg.T
        K -= B.gram()
        z = bmv(Li, bp)                                             # L⁻¹ b_p
        rhs = np.concatenate([g, np.zeros(n_c)]) - (B.matvec(z) if n_e else 0.0)
        return dict(K=K, rhs=rhs, Li=Li, z=z, B=B)

    def back_substitute(self, red, dx):
        """Δp = L⁻ᵀ (z − B_pᵀ Δx) for every eliminated point."""
        if self.n_e == 0:
            return np.zeros((0, 3))
        t = red["z"] - red["B"].rmatvec(dx)
        return bmv(np.transpose(red["Li"], (0, 2, 1)), t)


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def _block_distances(block: Block):
    out = []
    for d in (block.meta.get("distances", []) if isinstance(block.meta, dict) else []):
        if isinstance(d, Distance):
            out.append(d)
        elif isinstance(d, Mapping):
            out.append(Distance(str(d["from"]), str(d["to"]), float(d["distance"]), float(d["sigma"])))
        else:                                   # (id_a, id_b, distance, sigma), e.g. the AICON reader's
            a, b, dist, sig = tuple(d)[:4]
            out.append(Distance(str(a), str(b), float(dist), float(sig)))
    return out


def _chol3(V, prob):
    try:
        return np.linalg.cholesky(V)
    except np.linalg.LinAlgError:
        det = np.linalg.det(V)
        tr = np.einsum("pii->p", V)
        bad = int(np.argmin(det / np.maximum(tr, 1e-300) ** 3))
        pid = str(prob.block.points.ids[prob.elim_points[bad]])
        raise AdjustmentError(f"point {pid!r} cannot be determined: its rays are (nearly) parallel or it is "
                              "seen from one photo only — remove it or add observations") from None


def _chol3_inv(V, prob):
    """``L⁻¹`` of ``V = L Lᵀ`` for every 3×3 block (closed form; LAPACK's error path when a block
    is not positive definite)."""
    a00, a10, a11 = V[:, 0, 0], V[:, 1, 0], V[:, 1, 1]
    a20, a21, a22 = V[:, 2, 0], V[:, 2, 1], V[:, 2, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        l00 = np.sqrt(a00)
        l10 = a10 / l00
        l20 = a20 / l00
        l11 = np.sqrt(a11 - l10 * l10)
        l21 = (a21 - l20 * l10) / l11
        l22 = np.sqrt(a22 - l20 * l20 - l21 * l21)
        i00, i11, i22 = 1.0 / l00, 1.0 / l11, 1.0 / l22
        Li = np.zeros_like(V)
        Li[:, 0, 0], Li[:, 1, 1], Li[:, 2, 2] = i00, i11, i22
        Li[:, 1, 0] = -l10 * i00 * i11
        Li[:, 2, 1] = -l21 * i11 * i22
        Li[:, 2, 0] = (l10 * l21 - l11 * l20) * i00 * i11 * i22
    if not np.isfinite(Li).all():
        return np.linalg.inv(_chol3(V, prob))
    return Li


class _BMatrix:
    """``B = [W V^{-1/2}; Cpᵀ V^{-1/2}]`` (n_x × 3 n_e), held as per-observation blocks, transposed:
    ``BkT`` (k, 3, q) (``Bk`` (k, q, 3) is a view), plus the constraint blocks ``Bc`` (n_e, n_c, 3).

    ``gram() = B Bᵀ`` is computed by the cheapest of three strategies:
    ``dense`` (BLAS on the dense n_g × 3n_e matrix: few points, many photos per point),
    ``pairs`` (one BLAS product per photo pair over the blocks of their common points, see
    :meth:`BundleProblem.pair_plan`: many points with short tracks, e.g. BAL),
    ``sparse`` (scipy CSR product).
    """

    def __init__(self, prob: BundleProblem, BkT, Bc):
        self.prob = prob
        self.BkT, self.Bc = BkT, Bc
        self.n_x = prob.n_g + prob.n_c
        self.mode = prob.gram_mode()

    @property
    def Bk(self):
        return np.swapaxes(self.BkT, 1, 2)

    # -- the Schur product ---------------------------------------------------------------------
    def gram(self):
        prob = self.prob
        n_g, n_e, n_c = prob.n_g, prob.n_e, prob.n_c
        out = np.zeros((self.n_x, self.n_x))
        if n_e == 0:
            return out
        if self.mode == "dense":
            D = self.dense_cols(0, n_e)
            out[:] = D @ D.T
            return out
        ng1 = n_g + 1
        q = prob.q_ph
        X = self.BkT if q == prob.q else np.ascontiguousarray(self.BkT[:, :, :q])
        if self.mode == "pairs":
            pl = prob.pair_plan()
            gs, ge, oa, ob = pl["gs"], pl["ge"], pl["oa"], pl["ob"]
            S = np.empty((len(gs), q, q))
            for g0, g1 in pl["chunks"]:
                p0, p1 = gs[g0], ge[g1 - 1]
                XA = X[oa[p0:p1]]
                XB = X[ob[p0:p1]]
                for g in range(g0, g1):
                    a, b = gs[g] - p0, ge[g] - p0
                    np.matmul(XA[a:b].reshape(-1, q).T, XB[a:b].reshape(-1, q), out=S[g])
            A = np.bincount(pl["flat"], S.ravel(), minlength=ng1 * ng1).reshape(ng1, ng1)
            Dg = np.empty((len(prob.seg_start), q, q))
            for j, (s0, s1) in enumerate(zip(prob.seg_start.tolist(), prob.seg_end.tolist())):
                Y = X[s0:s1].reshape(-1, q)
                np.matmul(Y.T, Y, out=Dg[j])
            A = A + A.T
            A += np.bincount(pl["flat_diag"], Dg.ravel(), minlength=ng1 * ng1).reshape(ng1, ng1)
            out[:n_g, :n_g] = A[:-1, :-1]
        else:
            S = self.sparse()[:n_g]
            out[:n_g, :n_g] = (S @ S.T).toarray()
        if n_c:
            if prob.datum_on_elim:
                # cross terms with the constraint rows, Σ_k B_k Bc_pᵀ, per photo
                BcT1 = np.concatenate([np.swapaxes(self.Bc, 1, 2), np.zeros((1, 3, n_c))], axis=0)
                Z = BcT1[prob.pidx]                                             # (k, 3, n_c)
                cross = np.zeros((ng1, n_c))
                for s0, s1, idx in zip(prob.seg_start.tolist(), prob.seg_end.tolist(), prob.seg_cols):
                    cross[idx] += X[s0:s1].reshape(-1, q).T @ Z[s0:s1].reshape(-1, n_c)
                out[:n_g, n_g:] = cross[:-1]
                out[n_g:, :n_g] = cross[:-1].T
            Bcf = np.transpose(self.Bc, (1, 0, 2)).reshape(n_c, -1)
            out[n_g:, n_g:] = Bcf @ Bcf.T
        return out

    # -- products with vectors -----------------------------------------------------------------
    def matvec(self, z):
        """``B z`` for z (n_e, 3)."""
        prob = self.prob
        q = prob.q_ph
        z1 = np.vstack([z.reshape(-1, 3), np.zeros((1, 3))])
        y = np.matmul(z1[prob.pidx][:, None, :], self.BkT[:, :, :q])[:, 0, :]     # (k, q)
        ys = np.add.reduceat(y, prob.seg_start, axis=0)                           # per photo
        out = np.zeros(self.n_x)
        out[:prob.n_g] = np.bincount(prob.seg_cols.ravel(), ys.ravel(), minlength=prob.n_g + 1)[:-1]
        if prob.n_c and prob.n_e:
            out[prob.n_g:] = np.einsum("pca,pa->c", self.Bc, z.reshape(-1, 3))
        return out

    def rmatvec(self, x):
        """``Bᵀ x`` as (n_e, 3)."""
        prob = self.prob
        q = prob.q_ph
        xg = np.append(x[:prob.n_g], 0.0)[prob.seg_cols]                     # (n_seg, q)
        xk = np.repeat(xg, prob.seg_len, axis=0)                              # (k, q)
        y = np.matmul(self.BkT[:, :, :q], xk[:, :, None])[:, :, 0]           # (k, 3)
        out = (prob.obs_to_point @ y)[:-1]
        if prob.n_c and prob.n_e:
            out += np.einsum("pca,c->pa", self.Bc, x[prob.n_g:])
        return out

    # -- explicit columns ----------------------------------------------------------------------
    def dense_cols(self, p0, p1):
        """Dense ``B[:, 3 p0 : 3 p1]`` (n_x × 3 (p1 − p0))."""
        prob = self.prob
        n_g, n_c = prob.n_g, prob.n_c
        nc = p1 - p0
        sel = (prob.pidx >= p0) & (prob.pidx < p1)
        rows = prob.cidx[sel]
        ncol = 3 * nc
        cols = 3 * (prob.pidx[sel] - p0)
        flat = (rows[:, :, None] * ncol + cols[:, None, None] + np.arange(3)).ravel()
        D = np.bincount(flat, self.Bk[sel].ravel(), minlength=(n_g + 1) * ncol).reshape(n_g + 1, ncol)
        out = np.empty((self.n_x, ncol))
        out[:n_g] = D[:n_g]
        if n_c:
            out[n_g:] = np.transpose(self.Bc[p0:p1], (1, 0, 2)).reshape(n_c, ncol)
        return out

    cols_points = dense_cols

    def sparse(self):
        prob = self.prob
        Bk = self.Bk
        rows = np.broadcast_to(prob.cidx[:, :, None], Bk.shape)
        cols = np.broadcast_to(3 * prob.pidx[:, None, None] + np.arange(3), Bk.shape)
        S = sp.csr_matrix((Bk.ravel(), (rows.ravel(), cols.ravel())), shape=(prob.n_g + 1, 3 * (prob.n_e + 1)))
        return S[:, :3 * prob.n_e]


def solve_bundle(block: Block, settings: BundleSettings | None = None, *, obs_active=None, row_active=None,
                 start: BundleState | None = None, problem: BundleProblem | None = None, final: bool = True):
    """Run the adjustment (see :func:`baarda.pipeline.adjustment.adjust` for the public entry point).

    Returns ``(problem, state, info)``; ``info`` holds the history, timings and — with ``final``
    (the default) — the linearisation and reduced system at the solution (``lin``, ``red``, what
    the precision needs; ``info["proj"]`` is the solution's projection either way).
    """
    settings = settings or BundleSettings()
    t0 = time.perf_counter()
    prob = problem or BundleProblem(block, settings, obs_active=obs_active, row_active=row_active)
    st = (start or prob.initial_state()).copy()
    _check_initial(prob, st)
    parts = prob.residual_parts(st)
    cost = prob.cost(st, parts)
    timings = {"setup": time.perf_counter() - t0, "linearize": 0.0, "solve": 0.0, "residuals": 0.0}
    history = []
    lam = 0.0
    history.append({"iteration": 0, "vtpv": cost, "lambda": 0.0, "max_step_sigma": float("nan")})
    converged = False
    it = 0
    eps_cost = 1e-12 * max(1, prob.n_obs_rows)
    nu = 2.0
    for it in range(1, settings.max_iter + 1):
        lin = prob.linearize(st, parts[-1])            # the accepted step's projection, Jacobians added
        timings["linearize"] += lin["t"]
        while True:
            ts = time.perf_counter()
            red = prob.reduced_system(lin, st, lam)
            dx, fac = _solve_reduced(prob, red, st, diagnose=(it == 1 and lam == 0.0))
            dp = prob.back_substitute(red, dx)
            pred = _pred(prob, lin, dx, dp)        # J̃Δ: change of each observation in units of its σ
            max_step = float(np.max(np.abs(pred))) if pred.size else 0.0
            gain = cost - _linear_cost(prob, lin, pred, dx, dp)
            tr = time.perf_counter()
            timings["solve"] += tr - ts
            new = prob.apply(st, dx[:prob.n_g], dp)
            new_parts = prob.residual_parts(new)
            new_cost = prob.cost(new, new_parts)
            timings["residuals"] += time.perf_counter() - tr
            if not np.isfinite(new_cost):
                new_cost = np.inf
            rho = (cost - new_cost) / gain if gain > 0 else (1.0 if new_cost <= cost else -1.0)
            if gain <= eps_cost and new_cost <= cost + eps_cost:
                break                                 # nothing left to gain: converged
            if new_cost <= cost * (1 + 1e-10) + eps_cost or not settings.damping:
                # accepted: Nielsen's update of the damping
                if lam > 0:
                    lam *= max(1.0 / 3.0, 1.0 - (2.0 * min(rho, 1.0) - 1.0) ** 3)
                    if lam < 1e-7:
                        lam = 0.0
                elif rho < 0.25 and settings.damping:
                    lam = 1e-4                  # Gauss–Newton overshoots: start damping next time
                nu = 2.0
                break
            if lam == 0.0 and max_step < settings.tol_obs:
                new, new_parts, new_cost = st, parts, cost    # at the minimum already
                break
            lam = 1e-4 if lam == 0 else lam * nu
            nu *= 2.0
            if lam > 1e12:
                raise AdjustmentError(
                    f"the adjustment diverges: no damped step reduces vᵀPv (= {cost:.6g}) at iteration {it}; "
                    "check the initial values and the datum", state=st)
        rel = abs(cost - new_cost) / max(cost, 1e-300)
        st, parts, cost = new, new_parts, new_cost
        history.append({"iteration": it, "vtpv": cost, "lambda": lam, "max_step_sigma": max_step})
        if (lam == 0.0 and max_step < settings.tol_obs) or rel < settings.tol_rel or gain <= eps_cost \
                or abs(cost - history[-2]["vtpv"]) <= eps_cost:
            converged = True
            break
    if not converged:
        err = AdjustmentError(
            f"no convergence after {settings.max_iter} iterations: vᵀPv = {cost:.6g}, last correction moved an "
            f"observation by {history[-1]['max_step_sigma']:.3g} σ (threshold {settings.tol_obs:g}); "
            "raise max_iter, check the initial values, or look for gross errors", state=st)
        err.history = history
        raise err
    info = dict(history=history, iterations=it, timings=timings, vtpv=cost, proj=parts[-1])
    if final:
        lin, red = final_system(prob, st, parts[-1])
        info.update(lin=lin, red=red)
    return prob, st, info


def final_system(prob: BundleProblem, st: BundleState, proj=None):
    """Linearisation and undamped reduced system at the solution (for the precision)."""
    lin = prob.linearize(st, proj)
    return lin, prob.reduced_system(lin, st, 0.0)


def _pred(prob, lin, dx, dp) -> np.ndarray:
    """Whitened change J̃Δ of every observation (k, 2)."""
    xk = np.append(dx[:prob.n_g], 0.0)[prob.cidx]                          # (k, q)
    pred = np.matmul(lin["Jc"], xk[:, :, None])[:, :, 0]
    if prob.n_e:
        pk = np.vstack([dp, np.zeros((1, 3))])[prob.pidx]
        pred += np.matmul(lin["Jp"], pk[:, :, None])[:, :, 0]
    return pred


def _linear_cost(prob, lin, pred, dx, dp) -> float:
    """vᵀPv of the linearised model after the step Δ (for the gain ratio of the damping)."""
    v, e, dg, dpv, dd, _ = lin["parts"]
    c = float(np.sum((e - pred) ** 2))
    c += float(np.sum(prob.prior_g_w * (dg - dx[prob.prior_g_idx]) ** 2))
    if len(prob.prior_p_idx):
        c += float(np.sum(prob.prior_p_w * (dpv - dp[prob.prior_p_idx, prob.prior_p_coord]) ** 2))
    if len(prob.dist_l):
        wd = prob.settings.sigma0 / prob.dist_s
        step = (lin["Jd"] * np.append(dx[:prob.n_g], 0.0)[lin["dcols"]]).sum(axis=1)
        c += float(np.sum((wd * dd - step) ** 2))
    return c


def _check_initial(prob: BundleProblem, st: BundleState):
    bad = prob.photo_used & ~np.isfinite(np.concatenate([st.X0, st.opk], axis=1)).all(axis=1)
    if bad.any():
        raise AdjustmentError(f"photo {str(prob.block.photos.ids[np.argmax(bad)])!r} has no initial orientation "
                              "(compute initial values first)")
    bad = prob.point_used & ~np.isfinite(st.XYZ).all(axis=1)
    if bad.any():
        raise AdjustmentError(f"point {str(prob.block.points.ids[np.argmax(bad)])!r} has no initial coordinates "
                              "(compute initial values first)")


def _solve_reduced(prob: BundleProblem, red, st, diagnose=False):
    """Solve K Δ = rhs with Jacobi scaling; on singularity raise a datum / parameter diagnosis.

    Without inner constraints K is positive definite: Cholesky.  With them K is the saddle-point
    matrix ``[[N, C], [Cᵀ, −E]]`` (E = the constraints' share of the eliminated points); it is
    solved through the Cholesky factor of ``M = N + C Cᵀ`` (positive definite when C fixes the
    datum) and an n_c × n_c system — exactly the bordered solution (see :func:`solve_factored`).
    """
    K, rhs = red["K"], red["rhs"]
    n_g, n_c = prob.n_g, prob.n_c
    if n_g == 0:
        return np.zeros(n_c), None
    d = np.sqrt(np.abs(np.diag(K)[:n_g]))
    zero = d == 0
    if zero.any():
        from .diagnose import raise_rank_defect
        raise_rank_defect(prob, red, st)
    s = np.ones(n_g + n_c)
    s[:n_g] = 1.0 / d
    if n_c:
        s[n_g:] = 1.0 / np.maximum(np.linalg.norm(K[:n_g, n_g:] * s[:n_g, None], axis=0), 1e-300)
    Ks = K * s[:, None] * s[None, :]
    try:
        if n_c == 0:
            fac = ("chol", sla.cho_factor(Ks, lower=False, check_finite=False))
            piv = np.diag(fac[1][0]) ** 2
            if piv.min() < 1e-11:
                raise np.linalg.LinAlgError
        else:
            C = Ks[:n_g, n_g:]
            E = -Ks[n_g:, n_g:]
            M = Ks[:n_g, :n_g] + C @ C.T
            cf = sla.cho_factor(M, lower=False, check_finite=False)
            piv = np.diag(cf[0]) ** 2
            if piv.min() < 1e-11 * np.max(np.diag(M)):
                raise np.linalg.LinAlgError
            IE = np.eye(n_c) - E
            Yc = sla.cho_solve(cf, C, check_finite=False)             # M⁻¹ C
            Z = C.T @ Yc @ IE + E
            zf = sla.lu_factor(Z, check_finite=False)
            u = np.abs(np.diag(zf[0]))
            if u.min() < 1e-11 * max(u.max(), 1.0):
                raise np.linalg.LinAlgError
            fac = ("bordered", (cf, C, Yc, IE, zf))
        y = solve_factored(fac, rhs * s)
        if not np.isfinite(y).all():
            raise np.linalg.LinAlgError
    except (np.linalg.LinAlgError, ValueError):
        from .diagnose import raise_rank_defect
        raise_rank_defect(prob, red, st)
    red["factor"] = fac
    red["scale"] = s
    return y * s, fac


def solve_factored(fac, r):
    """Solve with a factorisation of :func:`_solve_reduced` (scaled system); ``r`` (n_x,) or (n_x, j).

    ``bordered``: ``N Δ + C k = b``, ``Cᵀ Δ − E k = r_c``.  Adding C × the second row to the first
    gives ``M Δ + C (I − E) k = b + C r_c`` with ``M = N + C Cᵀ``, so ``Δ = y₀ − M⁻¹C (I − E) k``,
    ``y₀ = M⁻¹ (b + C r_c)``, and the second row becomes
    ``(Cᵀ M⁻¹ C (I − E) + E) k = Cᵀ y₀ − r_c`` (n_c × n_c; the identity at an undamped step).
    """
    kind, f = fac
    if kind == "chol":
        return sla.cho_solve(f, r, check_finite=False)
    if kind == "lu":
        return sla.lu_solve(f, r, check_finite=False)
    cf, C, Yc, IE, zf = f
    n_g = C.shape[0]
    b, rc = r[:n_g], r[n_g:]
    y0 = sla.cho_solve(cf, b + C @ rc, check_finite=False)
    k = sla.lu_solve(zf, C.T @ y0 - rc, check_finite=False)
    return np.concatenate([y0 - Yc @ (IE @ k), k], axis=0)
