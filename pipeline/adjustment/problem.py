"""The bundle adjustment problem: which parameters are unknown, observed or fixed, where every
unknown sits in the global vector, the whitening of each observation, residuals and vᵀPv.

The normal equations are :mod:`.normal`, the routes :mod:`.route`, their solution :mod:`.factor`,
the iteration :mod:`.lm`.

Unknowns
    global (the "reduced camera system"): free camera parameters ``[c, xp, yp, ap…]`` per
    camera, free exterior orientation ``[X0, Y0, Z0, ω, φ, κ]`` per photo, and the coordinates of
    the few object points that couple to other points (scale bars);
    eliminated: every other object point (3×3 blocks).
Observations
    image points (2×2 weight ``P = σ0² Σ⁻¹`` each, x/y may be correlated), weighted constraints on
    any unknown (``0 < σ < inf``), and observations on global unknowns only (:class:`GlobalRows`):
    distances between object points (scale bars) and GNSS antenna positions
    ``X_antenna + v = X0 + R_cam_from_worldᵀ e`` (lever arm ``e`` in the camera frame).
Datum
    ``"control"``: by control points / weighted constraints — the reduced system must be regular;
    ``"free"``: inner constraints (minimum norm) on the chosen points or on the projection
    centres, appended as Lagrange rows to the reduced system; the scale comes from a distance when
    one is given.

Everything is vectorised over observations.  The column layout of the unknowns is
:class:`~.layout.ColumnLayout`, the normal equations :attr:`BundleProblem.normals`, the reduced
system's route (dense or sparse) :func:`.route.choose_route`'s.  See ``docs/bundle.md``.
"""


from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from baarda.pipeline.errors import AdjustmentError, InputError
from baarda.pipeline.geometry import rotation_and_derivatives
from baarda.pipeline.model import Block

from ..camera import get_ap_model
from .collinearity import Projector, bmv
from .corrected import check_models
from .layout import ColumnLayout
from .normal import NormalEquations
from .rig import RigProjector, compose_photos, initial_rig_state, rig_structure
from .settings import BundleSettings, BundleState, block_distances, camera_meta, check_unique

__all__ = ["BundleProblem", "GlobalRows"]


@dataclass(frozen=True, eq=False)
class GlobalRows:
    """One kind of observation on global unknowns only (no eliminated point takes part): ``G``
    observations of ``r`` scalar rows each, every one touching the ``w`` global columns ``cols``
    (−1 = fixed), whitened by ``L`` (``LᵀL = P = σ0² Σ⁻¹``, (G, r, r)).

    ``kind`` ``"distance"`` (a scale bar: r = 1, the 6 coordinates of its two points) or ``"gnss"``
    (an antenna: r = 3, the photo's 6 orientation unknowns).  ``index`` the observation's row in
    its source (the problem's distances; ``block.gnss``), ``l`` (G, r) the observed values.  The
    normal equations, the predicted cost, the degrees of freedom, vᵀPv, the redundancy numbers and
    the variance components treat every kind alike through the flat whitened rows
    (:meth:`BundleProblem.global_rows_linear`)."""

    kind: str
    r: int
    cols: np.ndarray
    L: np.ndarray
    l: np.ndarray
    index: np.ndarray

    @property
    def n_rows(self) -> int:
        return len(self.cols) * self.r


class BundleProblem:
    """Index bookkeeping of one adjustment: which parameters are unknown, observed or fixed,
    where every unknown sits in the global vector, the whitening of each observation.

    Built once per (block, active set, settings); the iteration only changes the state.  The
    normal equations are :attr:`normals` (:class:`~.normal.NormalEquations`), the solver route
    :func:`~.route.choose_route`'s.
    """

    def __init__(self, block: Block, settings: BundleSettings, obs_active: np.ndarray | None = None,
                 row_active: np.ndarray | None = None):
        self.block = block
        self.settings = settings
        self.warnings: list[str] = []
        self._check_ids()
        self.rig = rig_structure(block)          # None without rigs (docs/rigs.md)
        self._camera_parameters()
        self._scale_bars()
        self._participants(obs_active, row_active)
        self._whitening()
        self._global_unknowns()
        self._column_layout()
        self._setup_priors()
        self._global_rows()
        self._setup_datum()
        self._degrees_of_freedom()
        self._setup_iteration()

    # ---- set-up steps, in order ----------------------------------------------------------------
    def _check_ids(self):
        """Camera, photo and point ids are unique."""
        b = self.block
        check_unique(b.cameras.ids, "camera")
        check_unique(b.photos.ids, "photo")
        check_unique(b.points.ids, "point")
        self.K, self.m, self.n = len(b.cameras), len(b.photos), len(b.points)

    def _camera_parameters(self):
        """AP model per camera, its meta, start values ``cam_params0`` and a-priori σ ``cam_sigma``
        (``0`` = fixed, ``inf`` = free, else a weighted constraint) of ``[c, xp, yp, ap…]``."""
        cams, K = self.block.cameras, self.K
        try:
            self.models = [get_ap_model(name) for name in cams.ap_model.tolist()]
        except KeyError as e:
            raise InputError(str(e.args[0]), field="ap_model") from None
        self.pmax = max([mdl.n_params for mdl in self.models] + [0])
        self.meta = camera_meta(self.block, self.settings)
        if self.settings.residual == "corrected":
            check_models(cams.ids.tolist(), self.models)
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

    def _scale_bars(self):
        """Distances between object points: the settings' and the block's."""
        points = self.block.points
        dist = tuple(self.settings.distances) + tuple(block_distances(self.block))
        self.distances = dist
        self.dist_a = points.index_of([d.a for d in dist]) if dist else np.zeros(0, int)
        self.dist_b = points.index_of([d.b for d in dist]) if dist else np.zeros(0, int)
        self.dist_l = np.array([d.distance for d in dist], float)
        self.dist_s = np.array([d.sigma for d in dist], float)
        if (self.dist_s <= 0).any() or not np.isfinite(self.dist_s).all():
            raise InputError("a distance (scale bar) needs a positive, finite sigma", field="sigma")

    def _participants(self, obs_active, row_active):
        """Which observations (and x/y rows), photos, points and cameras take part; weak photos and
        points are an error or dropped (``on_weak``).  Observations are sorted by photo, so each
        photo's observations are one contiguous segment."""
        b = self.block
        obs, photos = b.observations, b.photos
        act = np.asarray(obs.active, bool).copy() if obs_active is None else np.asarray(obs_active, bool).copy()
        if row_active is not None:
            ra = np.asarray(row_active, bool).reshape(-1, 2)
            act &= ra.any(axis=1)
            self.row_active = ra & act[:, None]
        else:
            self.row_active = np.repeat(act[:, None], 2, axis=1)
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
        self.photo_used = np.zeros(self.m, bool)
        self.photo_used[self.obs_photo] = True
        self.point_used = np.zeros(self.n, bool)
        self.point_used[self.obs_point] = True
        self.point_used[self.dist_a] = True
        self.point_used[self.dist_b] = True
        self.cam_used = np.zeros(self.K, bool)
        self.cam_used[photos.camera[self.photo_used]] = True

    def _whitening(self):
        """``e = L (l − f)`` with ``LᵀL = P = σ0² Σ⁻¹`` per image point (rows switched off: weight 0)."""
        b, oi = self.block, self.oi
        obs, photos, points = b.observations, b.photos, b.points
        cov = obs.cov[oi]
        s0 = self.settings.sigma0
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

    def _global_unknowns(self):
        """Positions in the global vector: free camera parameters, free exterior orientation, free
        coordinates of points on scale bars; every other used point with a free coordinate is
        eliminated (3×3 blocks)."""
        b = self.block
        photos, points = b.photos, b.points
        K, m, n, P = self.K, self.m, self.n, 3 + self.pmax
        nx = 0
        self.g_cam = np.full((K, P), -1)
        free_c = (self.cam_sigma != 0) & self.cam_used[:, None]
        for j, mdl in enumerate(self.models):
            free_c[j, 3 + mdl.n_params:] = False
        cnt = int(free_c.sum())
        self.g_cam[free_c] = np.arange(nx, nx + cnt)
        nx += cnt
        self.g_eo = np.full((m, 6), -1)
        free_e = (photos.sigma_eo != 0) & self.photo_used[:, None]
        if self.rig is not None:
            free_e &= (self.rig.photo_frame < 0)[:, None]         # a photo in a frame: the frame's and sensor's
        cnt = int(free_e.sum())
        self.g_eo[free_e] = np.arange(nx, nx + cnt)
        nx += cnt
        if self.rig is not None:
            nx = self._rig_unknowns(nx)
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

    def _rig_unknowns(self, nx: int) -> int:
        """Rigs: the pose of every frame with a used photo (free unless its reference photo's
        orientation is fixed) and of every non-reference sensor that is not fixed (``g_frame`` (F, 6),
        ``g_sensor`` (S, 6), −1 fixed); returns the next free column."""
        rig, rs = self.rig, self.block.rigs.sensors
        photos = self.block.photos
        F = rig.n_frames
        fused = np.zeros(F, bool)
        fused[rig.photo_frame[self.photo_used & (rig.photo_frame >= 0)]] = True
        bad = np.flatnonzero((rig.photo_frame >= 0) & ~np.isin(np.arange(self.m), rig.frame_ref_photo)
                             & ~np.isinf(photos.sigma_eo).all(axis=1))
        if len(bad):
            i = int(bad[0])
            raise InputError(f"photo {str(photos.ids[i])!r} is a non-reference sensor's photo of frame "
                             f"{str(rig.frame_ids[rig.photo_frame[i]])!r}: its orientation follows from the frame's and "
                             "the sensor's; give a-priori σ of the orientation on the frame's reference photo",
                             field="sigma_eo")
        self.g_frame = np.full((F, 6), -1)
        free_f = (photos.sigma_eo[rig.frame_ref_photo] != 0) & fused[:, None]
        cnt = int(free_f.sum())
        self.g_frame[free_f] = np.arange(nx, nx + cnt)
        nx += cnt
        sused = np.zeros(len(rs), bool)
        sused[rig.photo_sensor[self.photo_used & (rig.photo_frame >= 0)]] = True
        self.g_sensor = np.full((len(rs), 6), -1)
        free_s = (rs.sigma != 0) & sused[:, None] & ~rs.reference[:, None]
        cnt = int(free_s.sum())
        self.g_sensor[free_s] = np.arange(nx, nx + cnt)
        return nx + cnt

    def eo_columns(self, photo) -> np.ndarray:
        """The orientation columns of observations in photos ``photo``: the photo's 6 (no rig), or
        with rigs 12: the frame's 6 (a photo in no frame: its own) and its sensor's 6 (−1 fixed or
        none) — the columns of the projector's ``J_eo``."""
        photo = np.asarray(photo, int)
        if self.rig is None:
            return self.g_eo[photo]
        rig = self.rig
        f = rig.photo_frame[photo]
        s = rig.photo_sensor[photo]
        cols = np.full((len(photo), 12), -1)
        cols[:, :6] = np.where((f >= 0)[:, None], self.g_frame[np.maximum(f, 0)], self.g_eo[photo])
        cols[:, 6:] = np.where((s >= 0)[:, None], self.g_sensor[np.maximum(s, 0)], -1)
        return cols

    def _column_layout(self):
        """The :class:`~.layout.ColumnLayout` of the observations' Jacobian columns (built once)."""
        self.layout = ColumnLayout.build(self.g_cam[self.obs_cam], self.eo_columns(self.obs_photo), self.g_pt[self.obs_point],
                                         self.obs_photo, self.n_g, self.elim_of[self.obs_point], self.elim_free)

    def _global_rows(self):
        """Observations on global unknowns only, one :class:`GlobalRows` per kind: the scale bars
        (their points are global unknowns) and the GNSS antennas of the photos that take part
        (``block.gnss``; a photo without active image observations has no orientation to observe).
        Flat layout: ``grow_cols`` (R, w) the columns of every scalar row (rows of one observation
        share them; n_g = fixed), ``grow_slices[kind]`` its rows."""
        s0 = self.settings.sigma0
        kinds = []
        if len(self.dist_l):
            cols = np.concatenate([self.g_pt[self.dist_a], self.g_pt[self.dist_b]], axis=1)
            kinds.append(GlobalRows("distance", 1, cols, (s0 / self.dist_s)[:, None, None], self.dist_l[:, None],
                                    np.arange(len(self.dist_l))))
        gn = self.block.gnss
        if len(gn) and self.rig is not None and (self.rig.photo_frame[gn.photo] >= 0).any():
            raise InputError("GNSS antennas on photos of a rig are not supported yet: give them without the rig",
                             field="gnss")
        if len(gn):
            use = np.flatnonzero(self.photo_used[gn.photo])
            cov = gn.cov[use]
            if not np.isfinite(cov).all() or not np.isfinite(gn.XYZ[use]).all() \
                    or not np.isfinite(gn.lever_arm[use]).all():
                raise InputError("a GNSS antenna observation has a missing position, covariance or lever arm",
                                 field="gnss")
            try:
                Lc = np.linalg.cholesky(s0 * s0 * np.linalg.inv(cov)) if len(use) else np.zeros((0, 3, 3))
            except np.linalg.LinAlgError:
                bad = use[np.argmin(np.linalg.eigvalsh(cov)[:, 0])]
                raise InputError(f"the GNSS antenna of photo {str(self.block.photos.ids[gn.photo[bad]])!r} has a "
                                 "covariance that is not positive definite", field="sigma") from None
            kinds.append(GlobalRows("gnss", 3, self.g_eo[gn.photo[use]], np.transpose(Lc, (0, 2, 1)),
                                    gn.XYZ[use], use))
        self.grows = [k for k in kinds if len(k.cols)]
        self.grow_slices = {}
        w = max([k.cols.shape[1] for k in self.grows] + [1])
        cols, off = [], 0
        for k in self.grows:
            c = np.full((len(k.cols), w), -1)
            c[:, :k.cols.shape[1]] = k.cols
            cols.append(np.repeat(c, k.r, axis=0))
            self.grow_slices[k.kind] = slice(off, off + k.n_rows)
            off += k.n_rows
        cols = np.concatenate(cols) if cols else np.zeros((0, w), int)
        self.grow_cols = np.where(cols >= 0, cols, self.n_g)
        self.n_grow_rows = off

    def _degrees_of_freedom(self):
        """Observation rows + weighted constraints + rows on global unknowns (distances, GNSS
        antennas) + datum constraints − unknowns."""
        self.n_obs_rows = int(self.row_active[self.oi].sum())
        self.dof = (self.n_obs_rows + len(self.prior_g_idx) + len(self.prior_p_idx) + self.n_grow_rows
                    + self.n_c - self.n_unknowns)

    def _setup_iteration(self):
        """What every iteration reuses: the projector (camera of each observation, AP-model groups,
        the camera Jacobian's columns that feed the layout)."""
        photos = self.block.photos
        args = (self.obs_photo, self.obs_point, photos.camera, self.block.cameras.ap_model, self.meta)
        kw = {"cam_cols": self.layout.jac_cols[0], "marks": self.marks_of(self.oi)}
        if self.rig is None:
            self.projector = Projector(*args, **kw)
        else:
            self.projector = RigProjector(self.rig, *args, **kw)
        self.datum_on_elim = bool(self.n_c and len(self.datum_elim))

    def marks_of(self, obs_idx):
        """The measured marks of block observations ``obs_idx`` when the residual is DBAT's
        (``settings.residual == "corrected"``, :mod:`.corrected`), else None."""
        if self.settings.residual != "corrected":
            return None
        return self.block.observations.xy[obs_idx]

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
        if self.rig is not None:
            # frames: the reference photo's a-priori orientation; sensors: the rig table's weighted pose
            ref = self.rig.frame_ref_photo
            m = (self.g_frame >= 0) & np.isfinite(se[ref]) & (se[ref] > 0)
            if np.isnan(val[ref][m]).any():
                raise InputError("an exterior-orientation element has an a-priori sigma but no value", field="sigma_eo")
            gi.append(self.g_frame[m]); w.append((s0 / se[ref][m]) ** 2); given.append(val[ref][m])
            ang.append(np.broadcast_to(np.arange(6) >= 3, m.shape)[m])
            rs = blk.rigs.sensors
            ss = rs.sigma
            m = (self.g_sensor >= 0) & np.isfinite(ss) & (ss > 0)
            sval = np.concatenate([rs.centre, rs.opk], axis=1)
            if np.isnan(sval[m]).any():
                i = int(np.argwhere(m & np.isnan(sval))[0, 0])
                raise InputError(f"rig {str(rs.rig[i])!r}, camera {str(blk.cameras.ids[rs.camera[i]])!r}: a weighted "
                                 "sensor pose needs its values", path=blk.rigs.path, line=int(rs.line[i]) or None,
                                 field="X")
            gi.append(self.g_sensor[m]); w.append((s0 / ss[m]) ** 2); given.append(sval[m])
            ang.append(np.broadcast_to(np.arange(6) >= 3, m.shape)[m])
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
        if any(k.kind == "gnss" for k in self.grows):
            # antennas observe position, orientation and scale of the block: inner constraints on top
            # would pull against them (σ̂0 4.6 instead of 1.0 on the test block of docs/bundle.md)
            raise InputError("GNSS antenna observations fix the datum (position, orientation and scale); a free "
                             "network's inner constraints would contradict them: use datum = \"control\"",
                             field="datum")
        self.scale_free = len(self.dist_l) == 0 and not self._rig_gives_scale()
        self.n_c = 7 if self.scale_free else 6
        pts = self.block.points
        if st.datum_centres and self.rig is not None:
            raise InputError("a free network on the projection centres is not available with rigs: put the inner "
                             "constraints on points (datum_on = \"points\")", field="datum_on")
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

    def _rig_gives_scale(self) -> bool:
        """A fixed or weighted sensor centre away from its rig's reference (a known baseline) observes
        the block's scale, as a scale bar does: the free network's inner constraints then leave it."""
        if self.rig is None:
            return False
        rs = self.block.rigs.sensors
        known = np.isfinite(rs.sigma[:, :3]).any(axis=1) & (np.nan_to_num(rs.centre) != 0).any(axis=1)
        return bool((known & ~rs.reference).any())

    @cached_property
    def normals(self) -> NormalEquations:
        """The normal equations of this problem (and what they reuse between iterations)."""
        return NormalEquations(self)

    def release_normals(self) -> None:
        """Drop :attr:`normals` and what it keeps between iterations (photo-pair plan, track groups,
        sparsity pattern, symbolic analysis: 27 MB at 2 000 photos) once the workflow is done with
        them; a later use (effect vectors, a linearised model) builds them again, the same."""
        self.__dict__.pop("normals", None)

    # ------------------------------------------------------------------------------------------
    def initial_state(self, block: Block | None = None) -> BundleState:
        b = block or self.block
        st = BundleState(self.cam_params0.copy(), np.array(b.photos.X0, float),
                         np.array(b.photos.opk, float), np.array(b.points.XYZ, float))
        if self.rig is not None:
            st.frame, st.sensor = initial_rig_state(self.rig, self.block.rigs.sensors, st.X0, st.opk)
            st.X0, st.opk = compose_photos(self.rig, st.frame, st.sensor, st.X0, st.opk)
        return st

    def global_vector(self, st: BundleState) -> np.ndarray:
        x = np.zeros(self.n_g)
        m = self.g_cam >= 0
        x[self.g_cam[m]] = st.cam_params[m]
        eo = np.concatenate([st.X0, st.opk], axis=1)
        m = self.g_eo >= 0
        x[self.g_eo[m]] = eo[m]
        m = self.g_pt >= 0
        x[self.g_pt[m]] = st.XYZ[m]
        if self.rig is not None:
            for g, v in ((self.g_frame, st.frame), (self.g_sensor, st.sensor)):
                m = g >= 0
                x[g[m]] = v[m]
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
        if self.rig is not None:
            for g, v in ((self.g_frame, out.frame), (self.g_sensor, out.sensor)):
                m = g >= 0
                v[m] += dx_g[g[m]]
            out.X0, out.opk = compose_photos(self.rig, out.frame, out.sensor, out.X0, out.opk)
        return out

    # ------------------------------------------------------------------------------------------
    def project_rows(self, st: BundleState, photo, point, marks=None) -> "tuple":
        """``(projection with Jacobians, orientation columns)`` of any observations ``(photo,
        point)`` (e.g. the ones left out of the adjustment): ``J_eo`` over :meth:`eo_columns`.
        ``marks``: their measured marks when the residual is DBAT's (:meth:`marks_of`)."""
        photo, point = np.asarray(photo, int), np.asarray(point, int)
        args = (photo, point, self.block.photos.camera, self.block.cameras.ap_model, self.meta)
        if self.rig is None:
            pj = Projector(*args, marks=marks)
            pr = pj.jacobians(pj.project(st.XYZ, st.X0, st.opk, st.cam_params))
        else:
            pj = RigProjector(self.rig, *args, marks=marks)
            pr = pj.jacobians(pj.project(st.XYZ, st.X0, st.opk, st.cam_params, rig=(st.frame, st.sensor)))
        return pr, self.eo_columns(photo)

    def project(self, st: BundleState, jacobians: bool):
        if self.rig is None:
            pr = self.projector.project(st.XYZ, st.X0, st.opk, st.cam_params)
        else:
            pr = self.projector.project(st.XYZ, st.X0, st.opk, st.cam_params, rig=(st.frame, st.sensor))
        return self.projector.jacobians(pr) if jacobians else pr

    def residual_parts(self, st: BundleState, proj=None):
        """Whitened image residuals e (k, 2), prior residuals (global, points), the whitened
        residuals of the rows on global unknowns (R,) (distances, GNSS antennas: :meth:`global_rows_linear`)."""
        proj = proj or self.project(st, False)
        v = self.l - proj.xy
        e = bmv(self.L, v)
        xg = self.global_vector(st)
        dg = self.prior_g_val - xg[self.prior_g_idx]
        dg = np.where(self.prior_g_ang, _wrap(dg), dg)
        dpv = self.prior_p_val - st.XYZ[self.elim_points[self.prior_p_idx], self.prior_p_coord]
        dd = self.global_rows_linear(st, jacobians=False)[2]
        return v, e, dg, dpv, dd, proj

    def cost(self, st: BundleState, parts=None) -> float:
        v, e, dg, dpv, dd, _ = parts or self.residual_parts(st)
        return float(np.sum(e * e) + np.sum(self.prior_g_w * dg * dg) + np.sum(self.prior_p_w * dpv * dpv)
                     + np.sum(dd * dd)) if len(e) or len(dg) or len(dd) else 0.0

    # ------------------------------------------------------------------------------------------
    def global_rows_eval(self, k: GlobalRows, st: BundleState, jacobians: bool = True):
        """Computed values ``f`` (G, r) of one kind of observation on global unknowns and, with
        ``jacobians``, ``J = ∂f/∂x`` (G, r, w) on its columns (zero on fixed ones), unwhitened.

        distance ``f = |X_a − X_b|``, ``J = [uᵀ, −uᵀ]`` (u the unit vector from b to a);
        gnss ``f = X0 + Rᵀ e`` (``R = R_cam_from_world(ω, φ, κ)``, ``e`` the lever arm in the camera
        frame), ``∂f/∂X0 = I``, ``∂f/∂(ω, φ, κ)_a = (∂R/∂a)ᵀ e``."""
        G = len(k.cols)
        if k.kind == "distance":
            ia, ib = self.dist_a[k.index], self.dist_b[k.index]
            diff = st.XYZ[ia] - st.XYZ[ib]
            d = np.linalg.norm(diff, axis=1)
            if not jacobians:
                return d[:, None], None
            u = diff / d[:, None]
            f, J = d[:, None], np.concatenate([u, -u], axis=1)[:, None, :]
        elif k.kind == "gnss":
            gn = self.block.gnss
            ph = gn.photo[k.index]
            arm = gn.lever_arm[k.index]
            R, dR = rotation_and_derivatives(st.opk[ph])
            f = st.X0[ph] + np.einsum("gji,gj->gi", R, arm)
            if not jacobians:
                return f, None
            J = np.zeros((G, 3, 6))
            J[:, :, :3] = np.eye(3)
            J[:, :, 3:] = np.einsum("gaji,gj->gia", dR, arm)
        else:                                                    # pragma: no cover
            raise ValueError(k.kind)
        return f, J * (k.cols >= 0)[:, None, :]

    def global_rows_linear(self, st: BundleState, jacobians: bool = True):
        """The whitened rows on global unknowns, flat over every kind (``grow_slices``):
        ``(J̃ (R, w), cols (R, w), ẽ (R,))`` with ``ẽ = L (l − f)``, ``J̃ = L J`` (``J̃ = None``
        without ``jacobians``); ``cols`` = ``grow_cols`` (n_g = fixed)."""
        w = self.grow_cols.shape[1]
        Js, es = [], []
        for k in self.grows:
            f, J = self.global_rows_eval(k, st, jacobians)
            es.append(np.einsum("gij,gj->gi", k.L, k.l - f).reshape(-1))
            if jacobians:
                Jw = np.zeros((len(k.cols), k.r, w))
                Jw[:, :, :J.shape[2]] = np.einsum("gij,gjq->giq", k.L, J)
                Js.append(Jw.reshape(-1, w))
        e = np.concatenate(es) if es else np.zeros(0)
        if not jacobians:
            return None, self.grow_cols, e
        J = np.concatenate(Js) if Js else np.zeros((0, w))
        return J, self.grow_cols, e

    # ------------------------------------------------------------------------------------------


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi
