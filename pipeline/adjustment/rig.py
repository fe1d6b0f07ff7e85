"""Camera rigs in the bundle: frames (one rig pose per group of photos) and the sensors' poses in the
rig (``docs/rigs.md``).

A rig is a set of cameras (sensors) fixed to each other; one of them, the reference sensor, defines
the rig frame (its image-space frame: x right, y up, z back out of the lens).  A frame is one
exposure of the rig: its photos share one pose ``rig_from_world`` (``X0_f``, ``R_f``), and the
photo of sensor ``s`` has the pose

    R_cam_from_world = R_s · R_f,        X0 = X0_f + R_fᵀ · c_s

with ``R_s = R_sensor_from_rig(ω_s, φ_s, κ_s)`` and ``c_s`` the sensor's projection centre in the
rig frame (object unit).  The reference sensor has ``R_s = I``, ``c_s = 0``.  The unknowns of the
bundle are then the frames' poses (6 each) and the poses of the non-reference sensors (6 each, fixed,
weighted or estimated) instead of every photo's orientation; a photo in no frame keeps its own 6
unknowns exactly as without rigs.

The image Jacobians follow from the photo's by the chain rule on left perturbations of its
rotation, ``∂xy/∂δ = −J_X Rᵀ [d]×`` (``J_X`` the point Jacobian, ``d = R (X − X0)``)::

    ∂xy/∂X0_f = −J_X             ∂xy/∂θ_f,a = ∂xy/∂δ · (R_s s_f,a) − J_X (∂R_f/∂θ_a)ᵀ c_s
    ∂xy/∂c_s  = −J_X R_fᵀ        ∂xy/∂θ_s,a = ∂xy/∂δ · s_s,a

(``s_·,a`` the axial vector of ``∂R/∂θ_a Rᵀ``).  Pure numerics: arrays in, arrays out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from baarda.pipeline.errors import InputError
from baarda.pipeline.stats.congruence import lambda0_multi
from baarda.pipeline.geometry import opk_from_rotation_many, rotation_and_derivatives, rotation_from_opk_many

from .collinearity import Projection, Projector, bmm

__all__ = ["RigStructure", "rig_structure", "rig_parameter_names", "photo_columns", "compose_photos", "initial_rig_state", "RigProjector",
           "photo_transform", "RigResult", "SensorResult", "rig_result", "SENSOR_NAMES"]

EO_PARAMS = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
SENSOR_NAMES = ("X", "Y", "Z", "omega", "phi", "kappa")
"""The six parameters of a sensor's pose in the rig: its projection centre in the rig frame and
ω, φ, κ of ``R_sensor_from_rig``."""


# -- structure ------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class RigStructure:
    """Frames and sensors of a block's rigs as index arrays.

    ``frame_ids`` (F,) the frames; ``frame_ref_photo`` (F,) the photo of the rig's reference sensor
    in each frame (the frame's pose is that photo's); ``frame_sensor`` (F,) its rig's reference row;
    ``photo_frame`` (m,) the frame of each photo (−1: in no frame), ``photo_sensor`` (m,) its row in
    ``block.rigs.sensors`` (−1: in no frame)."""

    frame_ids: np.ndarray
    frame_ref_photo: np.ndarray
    photo_frame: np.ndarray
    photo_sensor: np.ndarray

    @property
    def n_frames(self) -> int:
        return len(self.frame_ids)


def _err(msg, path, line, field):
    return InputError(msg, path=path, line=int(line) or None if path else None, field=field)


def rig_structure(block) -> RigStructure | None:
    """The :class:`RigStructure` of ``block.rigs`` (None without rigs), or an :class:`InputError`
    naming the rig table's or the frame table's file, line and field: a camera in two rigs, a rig
    without exactly one reference sensor, a photo whose camera is in no rig, a photo in two frames,
    a frame with photos of two rigs or two photos of one sensor, a frame without the reference
    sensor's photo."""
    rigs = block.rigs
    if not rigs:
        return None
    rs, fm = rigs.sensors, rigs.frames
    spath, fpath = rigs.path, rigs.frames_path or rigs.path
    cam_ids, ph_ids = block.cameras.ids, block.photos.ids
    row_of_cam = {}
    for i in range(len(rs)):
        j = int(rs.camera[i])
        if j in row_of_cam:
            raise _err(f"camera {str(cam_ids[j])!r} is a sensor of rig {str(rs.rig[row_of_cam[j]])!r} already "
                       "(a camera belongs to one rig)", spath, rs.line[i], "camera")
        row_of_cam[j] = i
    for rig in dict.fromkeys(rs.rig.tolist()):
        rows = np.flatnonzero(rs.rig == rig)
        nref = int(rs.reference[rows].sum())
        if nref != 1:
            raise _err(f"rig {rig!r} has {nref} reference sensors; it needs exactly one (reference = yes)", spath,
                       rs.line[rows[0]], "reference")
        ref = rows[rs.reference[rows]][0]
        if np.any(rs.centre[ref] != 0) or np.any(rs.opk[ref] != 0):
            raise _err(f"rig {rig!r}: the reference sensor's pose is the rig frame (0 0 0, 0° 0° 0°)", spath,
                       rs.line[ref], "X")
    m = len(ph_ids)
    photo_frame = np.full(m, -1)
    photo_sensor = np.full(m, -1)
    photo_line = np.zeros(m, int)
    frame_ids = list(dict.fromkeys(fm.frame.tolist()))
    fidx = {f: i for i, f in enumerate(frame_ids)}
    for r in range(len(fm)):
        p, ln = int(fm.photo[r]), fm.line[r]
        if photo_frame[p] >= 0:
            raise _err(f"photo {str(ph_ids[p])!r} is in frame {frame_ids[photo_frame[p]]!r} already (line "
                       f"{photo_line[p]}); a photo belongs to one frame", fpath, ln, "photo")
        cam = int(block.photos.camera[p])
        if cam not in row_of_cam:
            raise _err(f"photo {str(ph_ids[p])!r}: its camera {str(cam_ids[cam])!r} is a sensor of no rig", fpath, ln,
                       "photo")
        photo_frame[p] = fidx[str(fm.frame[r])]
        photo_sensor[p] = row_of_cam[cam]
        photo_line[p] = ln
    ref_photo = np.full(len(frame_ids), -1)
    for f, fid in enumerate(frame_ids):
        members = np.flatnonzero(photo_frame == f)
        rows = photo_sensor[members]
        rig_names = set(rs.rig[rows].tolist())
        first_line = int(photo_line[members].min())
        if len(rig_names) > 1:
            raise _err(f"frame {fid!r} has photos of rigs {sorted(rig_names)}; a frame is one pose of one rig", fpath,
                       first_line, "frame")
        u, cnt = np.unique(rows, return_counts=True)
        if (cnt > 1).any():
            dup = int(u[np.argmax(cnt > 1)])
            raise _err(f"frame {fid!r} has two photos of camera {str(cam_ids[rs.camera[dup]])!r}", fpath, first_line,
                       "frame")
        refs = members[rs.reference[rows]]
        if not len(refs):
            rig = next(iter(rig_names))
            ref_cam = str(cam_ids[rs.camera[(rs.rig == rig) & rs.reference][0]])
            raise _err(f"frame {fid!r} has no photo of rig {rig!r}'s reference sensor (camera {ref_cam!r}); the frame's "
                       "pose is that photo's", fpath, first_line, "frame")
        ref_photo[f] = refs[0]
    return RigStructure(np.array(frame_ids, dtype=str), ref_photo, photo_frame, photo_sensor)


def rig_parameter_names(prob) -> dict:
    """Global column → readable name of the frames' and sensors' unknowns of a problem with rigs
    (``{}`` without): ``"omega of frame 'F01'"``, ``"X of camera 'right' in rig 'stereo'"``."""
    rig = getattr(prob, "rig", None)
    if rig is None:
        return {}
    out = {}
    rs, cams = prob.block.rigs.sensors, prob.block.cameras
    for f, fid in enumerate(rig.frame_ids.tolist()):
        for t in range(6):
            if prob.g_frame[f, t] >= 0:
                out[int(prob.g_frame[f, t])] = f"{EO_PARAMS[t]} of frame {fid!r}"
    for i in range(len(rs)):
        for t in range(6):
            if prob.g_sensor[i, t] >= 0:
                out[int(prob.g_sensor[i, t])] = (f"{SENSOR_NAMES[t]} of camera {str(cams.ids[rs.camera[i]])!r} in rig "
                                                 f"{str(rs.rig[i])!r}")
    return out


def photo_columns(prob, st, photos) -> tuple[np.ndarray, np.ndarray]:
    """``(cols (N, 12), T (N, 6, 12))``: the global columns (−1 fixed) a photo's orientation depends
    on and the linear map from them to its ``[X0, ω, φ, κ]`` — the photo's own 6 columns and
    ``[I 0]`` for a photo in no frame, its frame's and sensor's 12 and the composition's Jacobian
    for a photo of a rig."""
    photos = np.asarray(photos, int)
    N = len(photos)
    cols = np.full((N, 12), -1)
    T = np.zeros((N, 6, 12))
    cols[:, :6] = prob.g_eo[photos]
    T[:, :, :6] = np.eye(6)
    rig = getattr(prob, "rig", None)
    if rig is None:
        return cols, T
    inf = rig.photo_frame[photos] >= 0
    if inf.any():
        ph = photos[inf]
        cols[inf] = np.concatenate([prob.g_frame[rig.photo_frame[ph]], prob.g_sensor[rig.photo_sensor[ph]]], axis=1)
        T[inf] = photo_transform(rig, st.frame, st.sensor, st.opk)[ph]
    return cols, T


# -- poses ------------------------------------------------------------------------------------------
def compose_photos(struct: RigStructure, frame: np.ndarray, sensor: np.ndarray, X0: np.ndarray, opk: np.ndarray):
    """``(X0, opk)`` (m, 3) of every photo: the given ones, with those of the photos in frames
    replaced by the composition of their frame's pose ``frame`` (F, 6) and their sensor's pose
    ``sensor`` (S, 6) (module docstring).  Inputs are not modified."""
    X0, opk = np.array(X0, float), np.array(opk, float)
    ph = np.flatnonzero(struct.photo_frame >= 0)
    if not len(ph):
        return X0, opk
    f, s = struct.photo_frame[ph], struct.photo_sensor[ph]
    Rf = rotation_from_opk_many(frame[f, 3:])
    Rs = rotation_from_opk_many(sensor[s, 3:])
    X0[ph] = frame[f, :3] + np.einsum("pji,pj->pi", Rf, sensor[s, :3])
    new = opk_from_rotation_many(Rs @ Rf)
    old = opk[ph]
    ok = np.isfinite(old).all(axis=1)
    new[ok] = old[ok] + _wrap(new[ok] - old[ok])          # keep the photos' angles continuous
    opk[ph] = new
    return X0, opk


def _mean_rotation(Rs: np.ndarray) -> np.ndarray:
    """The chordal L2 mean of rotations (n, 3, 3)."""
    U, _, Vt = np.linalg.svd(Rs.sum(axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def initial_rig_state(struct: RigStructure, sensors, X0: np.ndarray, opk: np.ndarray):
    """Start values ``(frame (F, 6), sensor (S, 6))``: each frame's pose is its reference photo's
    (``X0``, ``opk``, approximate orientations of every photo); a sensor pose that the rig table
    leaves unknown (nan) is the mean over the frames of the relative orientation of its photo to the
    reference photo (chordal mean of the rotations, mean of the centres)."""
    ref = struct.frame_ref_photo
    frame = np.concatenate([X0[ref], opk[ref]], axis=1)
    sensor = np.concatenate([sensors.centre, sensors.opk], axis=1).astype(float)
    for s in range(len(sensors)):
        if np.isfinite(sensor[s]).all():
            continue
        ph = np.flatnonzero(struct.photo_sensor == s)
        ph = ph[np.isfinite(X0[ph]).all(axis=1) & np.isfinite(opk[ph]).all(axis=1)]
        f = struct.photo_frame[ph]
        ok = np.isfinite(frame[f]).all(axis=1)
        ph, f = ph[ok], f[ok]
        if not len(ph):
            continue                     # no start: the bundle stops with the photo's missing orientation
        Rf = rotation_from_opk_many(frame[f, 3:])
        Rp = rotation_from_opk_many(opk[ph])
        R = _mean_rotation(Rp @ np.transpose(Rf, (0, 2, 1)))
        c = np.einsum("pij,pj->pi", Rf, X0[ph] - frame[f, :3]).mean(axis=0)
        given = sensor[s]
        sensor[s] = np.where(np.isfinite(given), given, np.r_[c, opk_from_rotation_many(R[None])[0]])
    return frame, sensor


def _axial(opk):
    """``(R (n, 3, 3), dR (n, 3, 3, 3), s (n, 3, 3))``: rotations, their derivatives and the axial
    vectors as columns ``s[:, :, a]`` of ``∂R/∂θ_a Rᵀ``."""
    R, dR = rotation_and_derivatives(opk)
    S = np.einsum("naij,nkj->naik", dR, R)
    sv = np.stack([S[:, :, 2, 1], S[:, :, 0, 2], S[:, :, 1, 0]], axis=1)      # (n, 3 comps, 3 angles)
    return R, dR, sv


def photo_transform(struct: RigStructure, frame: np.ndarray, sensor: np.ndarray, photo_opk: np.ndarray):
    """``T (m, 6, 12)``: the change of each photo's ``[X0, ω, φ, κ]`` with its frame's 6 and its
    sensor's 6 parameters (zero for photos in no frame), for the photos' covariances."""
    m = len(struct.photo_frame)
    T = np.zeros((m, 6, 12))
    ph = np.flatnonzero(struct.photo_frame >= 0)
    if not len(ph):
        return T
    f, s = struct.photo_frame[ph], struct.photo_sensor[ph]
    Rf, dRf, sf = _axial(frame[f, 3:])
    Rs, _, ss = _axial(sensor[s, 3:])
    _, _, sp = _axial(photo_opk[ph])
    c = sensor[s, :3]
    T[ph, :3, :3] = np.eye(3)
    T[ph, :3, 3:6] = np.einsum("paji,pj->pia", dRf, c)                # (∂R_f/∂θ_a)ᵀ c_s
    T[ph, :3, 6:9] = np.transpose(Rf, (0, 2, 1))
    Sinv = np.linalg.pinv(sp)                                          # δ_left → d(ω, φ, κ) of the photo
    T[ph, 3:, 3:6] = Sinv @ (Rs @ sf)
    T[ph, 3:, 9:12] = Sinv @ ss
    return T


class RigProjector(Projector):
    """The collinearity equations with the photos' orientations composed of frame and sensor poses:
    :meth:`jacobians` gives ``J_eo`` (k, 2, 12) over the frame's 6 and the sensor's 6 parameters (a
    photo in no frame: its own 6 orientation unknowns in the first six columns, exactly the
    photo's Jacobian, and zeros)."""

    def __init__(self, struct: RigStructure, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.struct = struct
        self.in_frame = struct.photo_frame[self.obs_photo] >= 0 if self.k else np.zeros(0, bool)

    def project(self, XYZ, X0, opk, cam_params, *, R=None, rig=None) -> Projection:
        pr = super().project(XYZ, X0, opk, cam_params, R=R)
        pr._rig = rig
        return pr

    def jacobians(self, pr: Projection, *, dR=None) -> Projection:
        super().jacobians(pr, dR=dR)
        J6 = pr.J_eo
        J = np.zeros((self.k, 2, 12))
        J[:, :, :6] = J6
        obs = np.flatnonzero(self.in_frame)
        rig = getattr(pr, "_rig", None)
        if len(obs) and rig is None:
            raise ValueError("RigProjector.jacobians needs the frame and sensor poses (project(..., rig=...))")
        if len(obs):
            frame, sensor = rig
            st = self.struct
            # per photo in a frame: R_s s_f (columns a), (∂R_f/∂θ_a)ᵀ c_s, R_fᵀ and s_s
            phs = np.unique(self.obs_photo[obs])
            f, s = st.photo_frame[phs], st.photo_sensor[phs]
            _, dRf, sf = _axial(frame[f, 3:])
            Rs, _, ss = _axial(sensor[s, 3:])
            Rf = rotation_from_opk_many(frame[f, 3:])
            A = np.zeros((self.struct.photo_frame.shape[0], 4, 3, 3))
            A[phs, 0] = Rs @ sf
            A[phs, 1] = np.einsum("paji,pj->pia", dRf, sensor[s, :3])
            A[phs, 2] = np.transpose(Rf, (0, 2, 1))
            A[phs, 3] = ss
            ph = self.obs_photo[obs]
            Jx = pr.J_point[obs]                                                  # (o, 2, 3)
            JR = bmm(Jx, np.transpose(pr._R[ph], (0, 2, 1)))                      # J_X Rᵀ
            Jd = np.cross(pr._d[obs][:, None, :], JR)                             # ∂xy/∂δ = −J_X Rᵀ [d]× = d × (J_X Rᵀ)
            Ap = A[ph]
            J[obs, :, :3] = -Jx
            J[obs, :, 3:6] = bmm(Jd, Ap[:, 0]) - bmm(Jx, Ap[:, 1])
            J[obs, :, 6:9] = -bmm(Jx, Ap[:, 2])
            J[obs, :, 9:12] = bmm(Jd, Ap[:, 3])
        pr.J_eo = J
        return pr


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


# -- results --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SensorResult:
    """One sensor of a rig after the bundle (object unit, radians).

    ``value`` (6,) ``[X, Y, Z, ω, φ, κ]`` of the pose in the rig; ``cov`` (6, 6) its covariance
    (a-posteriori as the result's; 0 for fixed); ``status`` per parameter ``fixed``/``weighted``/
    ``estimated``; ``baseline`` |c_s| and ``sigma_baseline``; ``prior`` (6,) the rig table's pose
    (nan none), ``prior_sigma`` (6,) its σ (weighted: the constraint's, estimated: the
    calibration's); ``redundancy`` (6,) of the weighted constraints (nan otherwise), ``w`` (6,) their
    standardised residuals; ``stability`` the test of the estimate against the prior (None without
    one); ``reference``/``d_reference_sigma``: a reference solution and the differences in σ."""

    rig: str
    camera: str
    reference_sensor: bool
    value: np.ndarray
    cov: np.ndarray
    status: tuple
    baseline: float
    sigma_baseline: float
    prior: np.ndarray
    prior_sigma: np.ndarray
    redundancy: np.ndarray
    w: np.ndarray
    stability: dict | None
    reference: np.ndarray
    d_reference_sigma: np.ndarray

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.cov), 0, None))

    @property
    def correlation(self) -> np.ndarray:
        s = self.sigma
        with np.errstate(invalid="ignore", divide="ignore"):
            R = self.cov / np.outer(s, s)
        R[~np.isfinite(R)] = 0.0
        np.fill_diagonal(R, np.where(s > 0, 1.0, 0.0))
        return R


@dataclass(frozen=True)
class RigResult:
    """The rigs of one adjustment: one :class:`SensorResult` per sensor, the frames, the joint test
    of every sensor with a prior (``stability``), and ``reference_name``."""

    sensors: tuple
    n_frames: int
    stability: dict | None
    reference_name: str


def _group_test(d, Q, var0, sigma0_hat2, dof, alpha):
    """``dᵀ Q⁺ d / (h σ²)``: χ²(h)/h with σ0 a priori, F(h, dof) with σ̂0 (h the rank of Q)."""
    w, V = np.linalg.eigh(0.5 * (Q + Q.T))
    keep = w > 1e-12 * max(w.max(initial=0.0), 1e-300)
    h = int(keep.sum())
    if h == 0:
        return None
    z = V[:, keep].T @ d
    q = float(np.sum(z * z / w[keep]))
    T0 = q / (h * var0)
    out = {"h": h, "T": T0, "critical": float(stats.chi2.ppf(1 - alpha, h) / h), "alpha": alpha,
           "p": float(stats.chi2.sf(T0 * h, h)), "distribution": f"chi2({h})/{h}"}
    if dof > 0 and sigma0_hat2 > 0:
        out.update(T_F=q / (h * sigma0_hat2), critical_F=float(stats.f.ppf(1 - alpha, h, dof)),
                   p_F=float(stats.f.sf(q / (h * sigma0_hat2), h, dof)))
    out["stable"] = bool(out["T"] <= out["critical"])
    # the smallest change of each parameter alone the test detects with power 80 %
    # (λ0 of the χ²(h) test; ∇_i = σ0 √(λ0 / (Q⁺)_ii), as the congruence test's MDD)
    lam0 = lambda0_multi(alpha, 0.80, h)
    Qp = (V[:, keep] / w[keep]) @ V[:, keep].T
    with np.errstate(divide="ignore", invalid="ignore"):
        out["mdc"] = np.where(np.diag(Qp) > 0, np.sqrt(var0 * lam0 / np.diag(Qp)), np.nan).tolist()
    out["lambda0"] = lam0
    return out


def rig_result(res, alpha: float = 0.05) -> RigResult | None:
    """The rig part of a :class:`~.adjust.BundleResult` (None without rigs): each sensor's pose with
    σ and correlations, the baseline with its σ, the redundancy numbers and w of weighted
    constraints, the test of each sensor against its prior (weighted: ``v = prior − x̂`` with
    ``Q_v = Σ_prior/σ0² − Q_x̂``; estimated with a calibration ``prior_sigma``: ``d = x̂ − prior``
    with ``Q_d = Q_x̂ + Σ_prior/σ0²``; χ²(h)/h with σ0, F(h, dof) with σ̂0) and one joint test of all
    of them, and the differences to a reference solution in σ."""
    prob = res.problem
    struct = getattr(prob, "rig", None)
    if struct is None:
        return None
    rigs = prob.block.rigs
    rs = rigs.sensors
    st = res.state
    s0 = res.settings.sigma0
    var = res.variance_factor
    g = prob.g_sensor
    S = len(rs)
    Qall = np.zeros((S * 6, S * 6))
    cols = g.reshape(-1)
    free = cols >= 0
    if free.any() and res.cofactors is not None:
        Q = np.asarray(res.cofactor_columns(cols[free]))[cols[free]]
        Qall[np.ix_(free, free)] = 0.5 * (Q + Q.T)
    sensors = []
    tests_d, tests_Q = [], []
    s0h2 = res.sigma0_hat ** 2 if res.dof > 0 else float("nan")
    for i in range(S):
        blk = slice(6 * i, 6 * i + 6)
        Qx = Qall[blk, blk]
        cov = var * Qx
        val = np.array(st.sensor[i], float)
        sig_apriori = rs.sigma[i]
        status = tuple("fixed" if sg == 0 else ("estimated" if np.isinf(sg) else "weighted") for sg in sig_apriori)
        prior = np.r_[rs.centre[i], rs.opk[i]]
        weighted = np.array([t == "weighted" for t in status])
        psig = np.where(weighted, sig_apriori, rs.prior_sigma[i])
        c = val[:3]
        b = float(np.linalg.norm(c))
        u = c / b if b > 0 else np.zeros(3)
        sb = float(np.sqrt(max(u @ cov[:3, :3] @ u, 0.0)))
        red = np.full(6, np.nan)
        w = np.full(6, np.nan)
        stab = None
        if not rs.reference[i]:
            dv = prior - val
            dv[3:] = _wrap(dv[3:])
            if weighted.any():
                p = (s0 / sig_apriori[weighted]) ** 2
                qv = 1.0 / p - np.diag(Qx)[weighted]
                red[weighted] = p * qv
                with np.errstate(invalid="ignore", divide="ignore"):
                    w[weighted] = dv[weighted] / (s0 * np.sqrt(np.clip(qv, 0, None)))
            has = np.isfinite(prior) & np.isfinite(psig) & (psig > 0) & np.array([t != "fixed" for t in status])
            if has.any():
                Sp = np.diag(psig[has] ** 2) / s0 ** 2
                Qs = Qx[np.ix_(has, has)]
                Qd = np.where(weighted[has][:, None] & weighted[has][None, :], Sp - Qs, 0.0) \
                    + np.where(~weighted[has][:, None] & ~weighted[has][None, :], Sp + Qs, 0.0)
                if weighted[has].all() or (~weighted[has]).all():
                    stab = _group_test(dv[has], Qd, s0 ** 2, s0h2, res.dof, alpha)
                    if stab is not None:
                        stab["mode"] = "weighted" if weighted[has].all() else "estimated"
                        stab["parameters"] = [SENSOR_NAMES[t] for t in np.flatnonzero(has)]
                        tests_d.append(dv[has])
                        tests_Q.append(Qd)
        ref = np.r_[rs.ref_centre[i], rs.ref_opk[i]]
        dd = val - ref
        dd[3:] = _wrap(dd[3:])
        sg = np.sqrt(np.clip(np.diag(cov), 0, None))
        with np.errstate(invalid="ignore", divide="ignore"):
            dref = np.where(sg > 0, dd / sg, np.nan)
        sensors.append(SensorResult(str(rs.rig[i]), str(prob.block.cameras.ids[rs.camera[i]]), bool(rs.reference[i]),
                                    val, cov, status, b, sb, prior, psig, red, w, stab, ref, dref))
    joint = None
    if len(tests_d) > 1:
        from scipy.linalg import block_diag
        joint = _group_test(np.concatenate(tests_d), block_diag(*tests_Q), s0 ** 2, s0h2, res.dof, alpha)
    elif len(tests_d) == 1:
        joint = next(s.stability for s in sensors if s.stability is not None)
    return RigResult(tuple(sensors), struct.n_frames, joint, rigs.reference_name)
