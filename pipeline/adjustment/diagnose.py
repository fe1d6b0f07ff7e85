"""Rank-defect diagnosis of the reduced normal equations: which datum or parameter is missing.

Called when the (Jacobi-scaled) reduced system is singular.  The null space is found by an
eigen-decomposition; the part of it spanned by the seven similarity motions of the block
(3 translations, 3 rotations, scale) is reported as a missing datum, the rest is traced to the
parameters that dominate the null vectors ("parameter K3 of camera 'P31' cannot be determined
(correlation 0.999 with K2)").
"""

from __future__ import annotations

import numpy as np

from baarda.pipeline.errors import AdjustmentError
from baarda.pipeline.geometry import opk_from_rotation_many, rotation_from_opk_many, similarity_motions

from .collinearity import EO_NAMES
from .rig import rig_parameter_names

MOTION_NAMES = ("translation X", "translation Y", "translation Z",
                "rotation about X", "rotation about Y", "rotation about Z", "scale")


def parameter_names(prob) -> list[str]:
    """Readable name of every global unknown, in index order."""
    names = [""] * prob.n_g
    cams, photos, points = prob.block.cameras, prob.block.photos, prob.block.points
    for j in range(prob.K):
        pn = ("c", "xp", "yp") + tuple(prob.models[j].params)
        for t in range(len(pn)):
            i = prob.g_cam[j, t]
            if i >= 0:
                names[i] = f"parameter {pn[t]} of camera {str(cams.ids[j])!r}"
    for i_ph in range(prob.m):
        for t in range(6):
            i = prob.g_eo[i_ph, t]
            if i >= 0:
                names[i] = f"{EO_NAMES[t]} of photo {str(photos.ids[i_ph])!r}"
    for p in range(prob.n):
        for t in range(3):
            i = prob.g_pt[p, t]
            if i >= 0:
                names[i] = f"{'XYZ'[t]} of point {str(points.ids[p])!r}"
    for i, name in rig_parameter_names(prob).items():      # frames and sensors of rigs (docs/rigs.md)
        names[i] = name
    return names


def _centre_and_radius(prob, st) -> tuple[np.ndarray, float]:
    """Centroid and RMS distance from it of the used projection centres (the motions' origin and
    the length that makes rotations, translations and scale comparable)."""
    pos = st.X0[prob.photo_used]
    ctr = pos.mean(axis=0) if len(pos) else np.zeros(3)
    scale = np.sqrt(np.mean(np.sum((pos - ctr) ** 2, axis=1))) if len(pos) else 1.0
    return ctr, float(scale or 1.0)


def _pos_motion(X, ctr, scale):
    """(len, 3, 7) change of positions X under the 7 motions (rotations ΔX = ε × (X − ctr), scale
    (X − ctr) / scale)."""
    out = similarity_motions(X - ctr)
    out[:, :, 6] /= scale
    return out


def point_motions(prob, st, XYZ) -> np.ndarray:
    """(len, 3, 7) change of object points ``XYZ`` under the motions of :func:`datum_motions`."""
    ctr, scale = _centre_and_radius(prob, st)
    return _pos_motion(np.asarray(XYZ, float).reshape(-1, 3), ctr, scale)


def datum_motions(prob, st) -> np.ndarray:
    """(n_g, 7) change of every global unknown under the 7 infinitesimal similarity motions."""
    G = np.zeros((prob.n_g, 7))
    ctr, scale = _centre_and_radius(prob, st)

    def pos_motion(X):
        return _pos_motion(X, ctr, scale)

    def pose_motion(X0, opk):
        mX = pos_motion(X0)
        R = rotation_from_opk_many(opk)
        h = 1e-6
        dang = np.zeros((len(R), 3, 7))
        for a in range(3):
            w = np.zeros(3)
            w[a] = h
            Wx = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
            # world rotated by ε: R' = R (I − [ε]×)
            Rp = R @ (np.eye(3) - Wx)
            Rm = R @ (np.eye(3) + Wx)
            diff = opk_from_rotation_many(Rp) - opk_from_rotation_many(Rm)
            diff = (diff + np.pi) % (2 * np.pi) - np.pi      # wrap the difference, not the derivative
            dang[:, :, 3 + a] = diff / (2 * h)
        return np.concatenate([mX, dang], axis=1)        # (·, 6, 7)

    eo_motion = pose_motion(st.X0, st.opk)
    msk = prob.g_eo >= 0
    G[prob.g_eo[msk]] = eo_motion[msk]
    if getattr(prob, "rig", None) is not None:
        # rigs: a frame's pose moves as a photo's; a sensor's pose in its rig only scales its centre
        fm = pose_motion(st.frame[:, :3], st.frame[:, 3:])
        msk = prob.g_frame >= 0
        G[prob.g_frame[msk]] = fm[msk]
        sm = np.zeros((len(st.sensor), 6, 7))
        sm[:, :3, 6] = st.sensor[:, :3] / scale
        msk = prob.g_sensor >= 0
        G[prob.g_sensor[msk]] = sm[msk]
    mp = pos_motion(st.XYZ)
    msk = prob.g_pt >= 0
    G[prob.g_pt[msk]] = mp[msk]
    return G


def raise_rank_defect(prob, red, st):
    """Analyse the singular reduced system and raise :class:`AdjustmentError` saying what is missing."""
    K = red.K
    n_g, n_c = prob.n_g, prob.n_c
    names = parameter_names(prob)
    dg = np.abs(np.diag(K)[:n_g])
    zero = np.flatnonzero(dg <= 1e-300)
    if zero.size:
        msgs = [f"{names[i]} cannot be determined: no observation depends on it — fix it or give it an "
                "a-priori sigma" for i in zero[:5]]
        raise AdjustmentError("; ".join(msgs), state=st)
    s = np.ones(n_g + n_c)
    s[:n_g] = 1.0 / np.sqrt(dg)
    if n_c:
        s[n_g:] = 1.0 / np.maximum(np.linalg.norm(K[:n_g, n_g:] * s[:n_g, None], axis=0), 1e-300)
    Ks = K * s[:, None] * s[None, :]
    w, Vec = np.linalg.eigh(Ks)
    thr = 1e-9 * np.max(np.abs(w))
    null = Vec[:, np.abs(w) < thr]
    if null.shape[1] == 0:
        # not exactly singular but numerically hopeless: take the weakest direction
        null = Vec[:, [int(np.argmin(np.abs(w)))]]
    N = null[:n_g]
    N = N / np.maximum(np.linalg.norm(N, axis=0), 1e-300)
    msgs = []
    # --- datum part ---------------------------------------------------------------------------
    G = datum_motions(prob, st) / s[:n_g, None]
    gnorm = np.linalg.norm(G, axis=0)
    usable = gnorm > 0
    datum_dim = 0
    undetermined = []
    if usable.any() and n_c == 0:
        Gu = G[:, usable] / gnorm[usable]
        Qg, _ = np.linalg.qr(Gu)
        U, cosines, _ = np.linalg.svd(Qg.T @ N, full_matrices=False)
        datum_dim = int(np.sum(cosines > 0.99))
        # motions free on their own: (almost) entirely inside the null space.  N has orthonormal
        # columns, so ‖Nᵀ g‖ is the cosine of the angle between g and the null space (relative:
        # independent of units and of the size of the block)
        inside = np.linalg.norm(N.T @ Gu, axis=0) > 0.99
        undetermined = [MOTION_NAMES[a] for a in np.flatnonzero(usable)[inside]]
        if datum_dim:
            if datum_dim == 7 or len(undetermined) == 7:
                msgs.append("no datum: 7 degrees of freedom undetermined (3 translations, 3 rotations, scale) — "
                            "add control points or set datum = 'free'")
            else:
                D = Qg @ U[:, :datum_dim]                # the datum part of the null space
                coef = np.zeros((7, datum_dim))          # … as combinations of the 7 motions
                coef[usable] = np.linalg.lstsq(G[:, usable], D, rcond=None)[0]
                _, radius = _centre_and_radius(prob, st)
                what = _name_motions(coef, radius)
                msgs.append(f"incomplete datum: {datum_dim} degree(s) of freedom undetermined ({', '.join(what)}) — "
                            "add or spread control points, or set datum = 'free'")
        # remove the datum part from the null space
        if datum_dim:
            N = N - Qg @ (Qg.T @ N)
            keep = np.linalg.norm(N, axis=0) > 0.3
            N = N[:, keep]
            if N.shape[1]:
                N, _ = np.linalg.qr(N)
                N = N[:, :max(0, null.shape[1] - datum_dim)]
    # --- parameters -------------------------------------------------------------------------------
    if N.shape[1]:
        Ku = Ks[:n_g, :n_g]
        Q = np.linalg.inv(Ku + 1e-9 * np.eye(n_g))
        dq = np.sqrt(np.diag(Q))
        seen = set()
        for j in range(N.shape[1]):
            vec = N[:, j]
            order = np.argsort(-np.abs(vec))
            i = int(order[0])
            if i in seen:
                continue
            seen.add(i)
            corr = Q[i] / (dq[i] * dq)
            corr[i] = 0
            k = int(np.argmax(np.abs(corr)))
            other = names[k]
            msgs.append(f"{names[i]} cannot be determined (correlation {abs(corr[k]):.3f} with {_short(other, names[i])}) "
                        "— fix it or give it an a-priori sigma")
    if not msgs:
        msgs.append("the normal equations are singular (rank defect of unknown origin)")
    raise AdjustmentError("; ".join(msgs), state=st)


def _name_motions(coef: np.ndarray, radius: float) -> list[str]:
    """Name the undetermined similarity motions spanned by the columns of ``coef`` (7, k): the
    coefficients of translations (object units), rotations about the centre of the projection
    centres (rad) and scale.  A rotation about an axis off the centre is a rotation about the
    parallel axis through it plus a translation, so the space splits into pure translations and
    the rotation/scale part; each is named by coordinate axes where it contains them, else by its
    direction ("rotation about the axis (0.79, −0.58, −0.19)")."""
    C = coef * np.r_[1.0, 1.0, 1.0, radius, radius, radius, 1.0][:, None]   # as displacements
    Ua, sa, Vat = np.linalg.svd(C[3:], full_matrices=True)
    r = int(np.sum(sa > 1e-3 * max(np.abs(C).max(), 1e-300)))
    trans = C[:3] @ Vat[r:].T                                   # combinations without rotation/scale
    out = _name_subspace(trans, ("translation X", "translation Y", "translation Z"))
    out += _name_subspace(Ua[:, :r], ("rotation about X", "rotation about Y", "rotation about Z", "scale"))
    return out


def _name_subspace(B: np.ndarray, labels: tuple[str, ...]) -> list[str]:
    """Names of an (up to 4-dimensional) subspace of the motions ``labels``: the coordinate axes it
    contains (cosine > 0.99), then a direction for each remaining dimension."""
    if B.size == 0:
        return []
    U, sv, _ = np.linalg.svd(B, full_matrices=False)
    B = U[:, sv > 1e-6 * max(sv.max(), 1e-300)]
    if B.shape[1] == 0:
        return []
    named = np.flatnonzero(np.linalg.norm(B, axis=1) > 0.99)       # ‖Bᵀ e_i‖ for the axes e_i
    out = [labels[i] for i in named]
    rest = B.copy()
    if named.size:
        rest[named] = 0.0                                          # project out the named axes
    U, sv, _ = np.linalg.svd(rest, full_matrices=False)
    for vec in U[:, :B.shape[1] - named.size].T:
        vec = vec if vec[np.argmax(np.abs(vec))] > 0 else -vec
        if labels[0].startswith("translation"):
            out.append(f"translation along ({vec[0]:.2f}, {vec[1]:.2f}, {vec[2]:.2f})")
            continue
        rot, sc = vec[:3], vec[3]
        if np.linalg.norm(rot) < 0.1:
            out.append("scale")
            continue
        ax = rot / np.linalg.norm(rot)
        out.append(f"rotation about the axis ({ax[0]:.2f}, {ax[1]:.2f}, {ax[2]:.2f})"
                   + (" with scale" if abs(sc) > 0.1 else ""))
    return out


def _short(other: str, this: str) -> str:
    """'parameter K2 of camera 'P31'' → 'K2' when both belong to the same camera."""
    if other.startswith("parameter ") and this.startswith("parameter "):
        o_par, o_cam = other[len("parameter "):].split(" of ", 1)
        t_cam = this.split(" of ", 1)[1]
        if o_cam == t_cam:
            return o_par
    return other
