"""External reliability of the bundle and covariances of chosen parameters, on both solver routes.

An undetected bias ``∇_i`` in scalar image row ``i`` moves the unknowns by (Baarda 1968)::

    ∇x_i = Q Aᵀ P e_i ∇_i = Q J̃ᵀ (L e_i) ∇_i            (J̃ = L J the whitened Jacobian, LᵀL = P)

with ``∇_i`` the row's minimal detectable bias ``δ0 σ0 / √(P Qvv P)_ii``.  ``Aᵀ P e_i`` is non-zero
only on the observation's own photo (its camera, orientation, scale-bar point) and its own point, so

* :func:`own_effects` — the effect of every row on **its own point and its own photo's
  orientation** (usually the largest), vectorised over the observations: with the points
  eliminated (``V_p = L_p L_pᵀ``, ``B = W L⁻ᵀ``, ``K`` the reduced system) ``Q a`` is
  ``x = K⁻¹(a_g − B L⁻¹ a_p)``, ``y = L⁻ᵀ(L⁻¹ a_p − Bᵀ x)``; for a row of point ``p`` the
  right-hand side lives on the columns of ``p``'s track, so only ``K⁻¹`` on those columns is needed —
  the blocks the precision forms anyway (dense route: gathered from ``K⁻¹``; sparse route: from the
  selected inversion, front by front; a free network's minimal-datum effects S-transformed onto
  the inner constraints with ``Y = Q₀ C`` from ``n_c`` solves);
* :func:`effect_vectors` — the full effect on **every** parameter for chosen rows (one solve of the
  whole system per row);
* :func:`parameter_covariance` — the joint covariance of any named parameters (``"photo 3"``,
  ``"point 17"``, ``"camera cam"``, or one component ``"point 17 Z"``), from the same solves;
* :func:`linearised_model` — the bundle linearised at its solution as a dense
  :class:`~baarda.pipeline.stats.linear.LinearModel` (small and medium blocks), for RRR;
* :func:`global_rows` — residuals, redundancy numbers and a statistics-library
  :class:`~baarda.pipeline.stats.snapshot.Snapshot` (w-tests, MDBs, data snooping) of the
  observations on global unknowns: scale bars and GNSS antennas.

Baarda's scalar ``δ̄0_i = √(∇xᵀ N ∇x)/σ0 = ∇_i √(P − P Qvv P)_ii / σ0`` bounds the effect on any
function ``f`` of the unknowns: ``|∇f| ≤ δ̄0_i σ_f`` (a-priori ``σ_f``).  Effects "in σ" below use the
a-priori standard deviations ``σ0 √Q``, the same scale as the MDBs.  Everything here is pure: a
:class:`~.adjust.BundleResult` in, new arrays out.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from baarda.pipeline.stats import mdb
from baarda.pipeline.stats.linear import LinearModel
from baarda.pipeline.stats.snapshot import Snapshot

from .collinearity import EO_NAMES
from .phases import phase_step
from .lm import final_system
from .memory import release_freed
from .rig import photo_columns, rig_parameter_names

__all__ = ["OwnEffects", "own_effects", "own_point_effects_in_datum", "effect_vectors", "ParameterVectors", "parameter_covariance", "parameter_names_of",
           "row_mdb", "bar_delta0", "linearised_model", "GlobalRowStats", "global_rows"]


# --------------------------------------------------------------------------------------------------
# the linearised system at the solution
def _system(res):
    """``(prob, lin, red, Qx)`` at the solution on the result's route, the reduced system factored,
    ``Qx = K⁻¹`` on the dense route (the result's own when it has one; ``None`` sparse)."""
    prob, st = res.problem, res.state
    if res.final_system is not None:     # the adjustment's own (same state, same route): taken once,
        lin, red = res.final_system      # so it does not stay in memory through the outputs
        res.final_system = None
    else:
        lin, red = final_system(prob, res.route, st)
    red.solution
    return prob, lin, red, res.route.inverse(red, res.Qx)


def _apply_Q(prob, red, Qx, st, a_g: np.ndarray, a_p: np.ndarray):
    """``Q a`` for right-hand sides ``a_g`` (n_g, j) on the global unknowns and ``a_p`` (n_e, 3, j)
    on the eliminated points: ``(x_g (n_g, j), y (n_e, 3, j))``, inner-constraint datum for a free
    network on either route."""
    n_g, n_e, n_c = prob.n_g, prob.n_e, prob.n_c
    B, Li = red.B, red.Li
    j = a_g.shape[1]
    z = np.einsum("pab,pbj->paj", Li, a_p) if n_e else np.zeros((0, 3, j))
    n_x = n_g + n_c
    r = np.zeros((n_x, j))
    r[:n_g] = a_g
    if n_e:
        for c in range(j):
            r[:, c] -= B.matvec(z[:, :, c])
    x = red.route.apply_inverse(red, Qx, r)
    y = np.zeros((n_e, 3, j))
    if n_e:
        for c in range(j):
            y[:, :, c] = np.einsum("pba,pb->pa", Li, z[:, :, c] - B.rmatvec(x[:, c]))
    xg = x[:n_g]
    datum = red.route.datum_transform(red)     # sparse route: minimal datum → inner constraints
    if datum is not None:
        Gg, Gp, T, Yg, Yp = datum
        CtD = red.Cg.T @ xg + np.einsum("pac,paj->cj", red.Cp, y)
        xg = xg - Gg @ (T @ CtD)
        y = y - np.einsum("pac,cj->paj", Gp, T @ CtD)
    y = y * prob.elim_free[:, :, None]
    return xg, y


# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class GlobalRowStats:
    """One kind of observation on global unknowns (``"distance"``, ``"gnss"``) at the solution.

    ``index`` (G,) the observations' rows in their source (the result's ``distances``;
    ``block.gnss``); ``v`` (G, r) residuals observed − computed (object units); ``sigma`` (G, r)
    a-priori σ; ``r`` (G, r) redundancy numbers ``(Qvv P)_ii``; ``PQvvP`` (G, r, r) blocks;
    ``snapshot`` the rows as a :class:`~baarda.pipeline.stats.snapshot.Snapshot` (the bundle's vᵀPv
    and dof; rows ``r g + i``), so ``stats.w_test``, ``stats.mdb``, ``stats.data_snooping`` apply."""

    kind: str
    index: np.ndarray
    v: np.ndarray
    sigma: np.ndarray
    r: np.ndarray
    PQvvP: np.ndarray
    snapshot: object = field(repr=False)


def _cofactor_blocks(res, cols: np.ndarray) -> np.ndarray:
    """(G, w, w) cofactors of the global unknowns ``cols`` (G, w) (n_g: fixed → 0), from the
    route's cofactors (:meth:`~.precision.Cofactors.blocks`)."""
    if res.cofactors is None:
        raise ValueError("the statistics of the observations need the precision: adjust with covariance = true")
    return res.cofactors.blocks(cols)


def global_rows(res) -> dict:
    """``{kind: GlobalRowStats}`` of the observations on global unknowns (scale bars, GNSS antennas):
    ``H = J̃ Q J̃ᵀ`` per observation (r × r, ``J̃ = L J`` whitened, ``Q`` the cofactors of its
    columns), ``Qvv P = L⁻¹ (I − H) L``, ``P Qvv P = Lᵀ (I − H) L`` — as for the image points.
    Needs the precision (``covariance = true``); either solver route."""
    prob, st = res.problem, res.state
    blk = res.block_in
    out = {}
    for k in prob.grows:
        f, J = prob.global_rows_eval(k, st)
        v = k.l - f
        Jw = np.einsum("gij,gjq->giq", k.L, J)
        Q = _cofactor_blocks(res, np.where(k.cols >= 0, k.cols, prob.n_g))
        H = np.einsum("giq,gqs,gjs->gij", Jw, Q, Jw)
        R = np.eye(k.r)[None] - H
        Li = np.linalg.inv(k.L)
        r = np.einsum("gij,gjl,gli->gi", Li, R, k.L)
        PQ = np.einsum("gji,gjl,glm->gim", k.L, R, k.L)
        P = np.einsum("gji,gjl->gil", k.L, k.L)
        Pv = np.einsum("gij,gj->gi", P, v)
        sig = prob.settings.sigma0 * np.sqrt(np.einsum("gii->gi", np.linalg.inv(P)))
        if k.kind == "distance":
            labels = [f"distance {res.distances[i].a}–{res.distances[i].b}" for i in k.index]
        else:
            ids = blk.photos.ids[blk.gnss.photo[k.index]]
            labels = [f"antenna photo {p} {c}" for p in ids.tolist() for c in "XYZ"]
        G = len(k.cols)
        snap = Snapshot(v=v.reshape(-1), Pv=Pv.reshape(-1), PQvvP=np.einsum("gii->gi", PQ).reshape(-1),
                        r=r.reshape(-1), sigma_l=sig.reshape(-1), vtpv=res.vtpv, dof=res.dof, sigma0=res.sigma0,
                        active=np.ones(G * k.r, bool), labels=np.array(labels, dtype=str),
                        group=np.repeat(np.arange(G), k.r) if k.r > 1 else np.full(G, -1),
                        meta={"source": f"bundle {k.kind}", "rows": f"row {k.r} g + i: coordinate i of observation g"})
        out[k.kind] = GlobalRowStats(kind=k.kind, index=k.index, v=v, sigma=sig, r=r, PQvvP=PQ, snapshot=snap)
    return out


# --------------------------------------------------------------------------------------------------
def row_mdb(res, delta0: float) -> np.ndarray:
    """(k_all, 2) minimal detectable bias of every image row (mm): ``δ0 σ0 / √(P Qvv P)_ii``, the
    statistics library's :func:`~baarda.pipeline.stats.mdb` on the snapshot (nan inactive, inf
    uncontrolled: r ≤ 1e-10)."""
    if res.snapshot is None:
        raise ValueError("MDBs need the precision: adjust with covariance = true")
    return mdb(res.snapshot, delta0).reshape(-1, 2)


def _p_diag(res) -> np.ndarray:
    prob = res.problem
    P = np.zeros((len(res.residuals), 2))
    P[prob.oi] = np.einsum("kji,kji->ki", prob.L, prob.L)          # (LᵀL)_ii
    return P


def bar_delta0(res, mdb: np.ndarray) -> np.ndarray:
    """(k_all, 2) Baarda's ``δ̄0_i = ∇_i √(P − P Qvv P)_ii / σ0``: the bound on the effect of row i's
    MDB on any function of the unknowns in units of its (a-priori) σ."""
    q = np.clip(_p_diag(res) - np.einsum("kii->ki", res.PQvvP), 0.0, None)
    with np.errstate(invalid="ignore"):
        return np.abs(mdb) * np.sqrt(q) / res.sigma0


# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class OwnEffects:
    """Effect of every image row's bias on its own point and its own photo's orientation.

    ``point`` (k_all, 2, 3): shift of the observed point's X, Y, Z (object units) for the bias
    ``bias`` (k_all, 2) (mm) in the row; ``eo`` (k_all, 2, 6): shift of the photo's
    X0, Y0, Z0 (object units), ω, φ, κ (rad).  ``point_sigma`` (k_all, 2, 3), ``eo_sigma``
    (k_all, 2, 6): a-priori σ of those parameters (σ0 √Q; 0 fixed; read-only views, the same for a
    row's x and y).  Inactive rows: nan.
    ``point_in_sigma`` / ``eo_in_sigma``: |effect| / σ (nan for fixed parameters)."""

    bias: np.ndarray
    point: np.ndarray
    eo: np.ndarray
    point_sigma: np.ndarray
    eo_sigma: np.ndarray
    bar_delta0: np.ndarray = field(repr=False)

    def _in_sigma(self, eff, sig):
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(sig > 0, np.abs(eff) / np.where(sig > 0, sig, 1.0), np.nan)

    @property
    def point_in_sigma(self) -> np.ndarray:
        return self._in_sigma(self.point, self.point_sigma)

    @property
    def eo_in_sigma(self) -> np.ndarray:
        return self._in_sigma(self.eo, self.eo_sigma)

    def largest(self):
        """Per row: ``(point coordinate 0..2, its effect, in σ; orientation component 0..5, its
        effect, in σ)`` of the largest effect measured in σ (arrays (k_all, 2); −1 / nan when none:
        inactive rows, fixed points such as control)."""
        out = []
        n = self.point.shape[0]
        step = 1 << 16                  # rows at a time: the (k, 2, 6) temporaries of a whole block are 30 MB each
        for eff, sig in ((self.point, self.point_sigma), (self.eo, self.eo_sigma)):
            j = np.empty(eff.shape[:2], np.intp)
            val, sv = np.empty(eff.shape[:2]), np.empty(eff.shape[:2])
            for a in range(0, n, step):
                e = eff[a:a + step]
                s = self._in_sigma(e, sig[a:a + step])
                jj = np.argmax(np.nan_to_num(s, nan=-1.0), axis=2)
                val[a:a + step] = np.take_along_axis(e, jj[..., None], axis=2)[..., 0]
                sv[a:a + step] = np.take_along_axis(s, jj[..., None], axis=2)[..., 0]
                j[a:a + step] = jj
            j = np.where(np.isfinite(sv), j, -1)
            out += [j, val, sv]
        return tuple(out)


def own_effects(res, delta0: float = 4.13, bias=None, chunk_bytes: float = 3.2e7) -> OwnEffects:
    """Effect of the MDB (``δ0`` with the a-priori σ0; or ``bias`` (k_all, 2) mm) of every active
    image row on its own point's coordinates and its own photo's orientation, either solver route."""
    if res.snapshot is None:
        raise ValueError("external reliability needs the precision: adjust with covariance = true")
    phase_step("external reliability", 0, len(res.problem.oi), "observations")     # the system at the solution first
    prob, lin, red, Qx = _system(res)
    st = res.state
    k_all = len(res.residuals)
    bias = row_mdb(res, delta0) if bias is None else np.asarray(bias, float).reshape(k_all, 2)
    n_e, n_c, q = prob.n_e, prob.n_c, prob.layout.q
    Jc, Jp, L = lin.Jc, lin.Jp, prob.L
    Li, B = red.Li, red.B
    k = len(prob.oi)
    pt_eff = np.zeros((k, 2, 3))          # per unit bias, active order
    eo_eff = np.zeros((k, 2, 6))
    eo_pos, pt_pos = _layout(prob)
    rigT = rig_cols = None
    if getattr(prob, "rig", None) is not None:        # a rig photo's orientation: its frame's and sensor's 12
        eo_pos = _layout(prob, 12)[0]
        rig_cols, rigT = photo_columns(prob, st, np.arange(prob.m))
    G_all = np.einsum("kiq,kic->kqc", Jc, L)                 # a_g of row c: J̃cᵀ L e_c   (k, q, 2)
    Ap_all = np.einsum("kia,kic->kac", Jp, L)                # a_p                       (k, 3, 2)
    # nothing below needs the linearisation (Jacobians, residuals, projection) or K (its factor is
    # kept): freed, and their pages handed back, before the walk over the factor
    red = red.lean()
    del lin, Jc, Jp
    release_freed()
    cons = red.route.constraint_cofactors(red, Qx)
    datum = red.route.datum_transform(red)

    done = [0]

    def tracks(obs_mat, Qsub):
        """Rows of the points whose observations are ``obs_mat`` (N, t); ``Qsub`` (N, tq, tq)."""
        phase_step("external reliability", done[0], k, "observations")
        done[0] += obs_mat.size
        N, t = obs_mat.shape
        C = prob.layout.cidx[obs_mat].reshape(N, t * q)
        pts = prob.layout.pidx[obs_mat[:, 0]]
        Bk = B.Bk[obs_mat]                                                     # (N, t, q, 3)
        z = np.einsum("nab,ntbc->ntac", Li[pts], Ap_all[obs_mat])              # L⁻¹ a_p  (N, t, 3, 2)
        R = -np.einsum("nlqa,nsac->nlqsc", Bk, z)                              # (N, t, q, t, 2)
        s = np.arange(t)
        R[:, s, :, s, :] += np.transpose(G_all[obs_mat], (1, 0, 2, 3))
        R = R.reshape(N, t * q, 2 * t)
        X = np.matmul(Qsub, R)                                                 # (N, tq, 2t)
        if cons is not None:
            Qgc, Qcc = cons
            Bc = B.Bc[pts]                                                     # (N, n_c, 3)
            rc = -np.einsum("nca,nsad->ncsd", Bc, z).reshape(N, n_c, 2 * t)
            X += np.matmul(Qgc[C], rc)
            lam = np.matmul(np.transpose(Qgc[C], (0, 2, 1)), R) + np.matmul(Qcc[None], rc)
        X5 = X.reshape(N, t, q, t, 2)
        own = X5[:, s, :, s, :]                                                # (t, N, q, 2)
        BtX = np.einsum("nlqa,nlqsc->nasc", Bk, X5)                            # (N, 3, t, 2)
        if cons is not None:
            BtX += np.einsum("nca,ncsd->nasd", Bc, lam.reshape(N, n_c, t, 2))
        y = np.einsum("nba,ntbc->ntac", Li[pts], z - np.transpose(BtX, (0, 2, 1, 3)))   # (N, t, 3, 2)
        rows = obs_mat.ravel()
        own = np.transpose(own, (1, 0, 2, 3)).reshape(N * t, q, 2)
        _store(rows, own, y.reshape(N * t, 3, 2))

    def singles(ob, Qk):
        """Rows of observations of no eliminated point (scale-bar points): ``Qk`` (r, q, q)."""
        X = np.matmul(Qk, G_all[ob])
        _store(ob, X, None)

    def _store(rows, own, y):
        if rigT is None:
            eo_eff[rows] = np.transpose(_pick(own, eo_pos), (0, 2, 1))
        else:
            eo_eff[rows] = np.transpose(np.matmul(rigT[prob.obs_photo[rows]], _pick(own, eo_pos)), (0, 2, 1))
        if y is not None:
            pt_eff[rows] = np.transpose(y, (0, 2, 1)) * prob.layout.pt_mask[rows][:, None, :]
        else:
            pt_eff[rows] = np.transpose(_pick(own, pt_pos), (0, 2, 1))

    groups = [obs_mat for obs_mat, _ in prob.normals.track_groups] if n_e else []
    single = np.flatnonzero(prob.layout.pidx == n_e)
    red.route.hand_blocks(red, Qx, groups, single, tracks, singles, chunk_bytes)
    if datum is not None:
        _s_transform_effects(prob, datum, G_all, Ap_all, eo_eff, pt_eff, chunk_bytes, rigT, rig_cols)
    # to block order, scaled by the biases
    # (scaled in place and freed one by one: no second copy of the effects at the peak)
    b = bias[prob.oi]
    bf = np.where(np.isfinite(b), b, np.nan)
    point = np.full((k_all, 2, 3), np.nan)
    np.multiply(pt_eff, bf[:, :, None], out=pt_eff)
    point[prob.oi] = pt_eff
    del pt_eff
    eo = np.full((k_all, 2, 6), np.nan)
    np.multiply(eo_eff, bf[:, :, None], out=eo_eff)
    eo[prob.oi] = eo_eff
    del eo_eff
    point[~res.row_active] = np.nan
    eo[~res.row_active] = np.nan
    var0 = res.sigma0 ** 2 / res.variance_factor
    obs = res.block_in.observations
    psig = np.sqrt(np.clip(np.einsum("nii->ni", np.nan_to_num(res.cov_points)), 0, None) * var0)[obs.point]
    esig = np.sqrt(np.clip(np.einsum("mii->mi", res.cov_eo), 0, None) * var0)[obs.photo]
    # the σ of a row's parameters is the same for its x and y: one (k_all, 3/6) array seen twice
    # (a read-only broadcast view) instead of a repeated copy
    return OwnEffects(bias=bias, point=point, eo=eo, point_sigma=np.broadcast_to(psig[:, None], (k_all, 2, 3)),
                      eo_sigma=np.broadcast_to(esig[:, None], (k_all, 2, 6)), bar_delta0=bar_delta0(res, bias))


def _s_transform_effects(prob, datum, G_all, Ap_all, eo_eff, pt_eff, chunk_bytes, rigT=None, rig_cols=None):
    """A free network's S-transformation of the per-unit effects (in place): ``eo_eff`` (k, 2, 6)
    and ``pt_eff`` (k, 2, 3) minus the datum part ``G T Cᵀ D`` of each row, ``C`` the row's
    constraint columns (``Y``), ``G`` the motions of its photo and point (with rigs, ``rigT``
    (m, 6, 12) maps the frame's and sensor's motions, columns ``rig_cols`` (m, 12), to the photo's).
    Over chunks of rows, so that the (rows, columns, n_c) gathers stay within ``chunk_bytes`` (at
    10 000 photos one gather of every row was 0.5 GB); each row's products are the same einsums as
    over all rows at once."""
    Gg, Gp, T, Yg, Yp = datum
    n_g, n_e, n_c = prob.n_g, prob.n_e, prob.n_c
    k = len(G_all)
    Yx = np.vstack([Yg, np.zeros((1, n_c))])
    Gx = np.vstack([Gg, np.zeros((1, n_c))])
    cidx, pidx, mask = prob.layout.cidx, prob.layout.pidx, prob.layout.pt_mask
    geo = np.where(prob.g_eo[prob.obs_photo] >= 0, prob.g_eo[prob.obs_photo], n_g)
    gpt = np.where(prob.g_pt[prob.obs_point] >= 0, prob.g_pt[prob.obs_point], n_g)
    step = max(1, int(chunk_bytes / (8.0 * max(1, cidx.shape[1] + 9) * n_c)))
    for a in range(0, k, step):
        phase_step("external reliability: datum", a, k, "rows")
        sl = slice(a, min(k, a + step))
        pid = pidx[sl]
        ep = np.flatnonzero(pid < n_e)                      # rows of eliminated points, in the chunk
        gp = np.flatnonzero(pid >= n_e)                     # rows of global points (scale bars)
        CtD = np.einsum("kqc,kqd->kcd", Yx[cidx[sl]], G_all[sl])                       # (c, n_c, 2)
        if ep.size:
            CtD[ep] += np.einsum("kac,kad->kcd", Yp[pid[ep]], Ap_all[sl][ep])
        TC = np.einsum("cd,kdr->kcr", T, CtD)                                           # (c, n_c, 2)
        if rigT is None:
            eo_eff[sl] -= np.einsum("kac,kcr->kra", Gx[geo[sl]], TC)
        else:
            ph = prob.obs_photo[sl]
            c12 = rig_cols[ph]
            G12 = np.matmul(rigT[ph], Gx[np.where(c12 >= 0, c12, n_g)])
            eo_eff[sl] -= np.einsum("kac,kcr->kra", G12, TC)
        if ep.size:
            rows = a + ep
            pt_eff[rows] -= np.einsum("kac,kcr->kra", Gp[pid[ep]], TC[ep]) * mask[rows][:, None, :]
        if gp.size:
            rows = a + gp
            pt_eff[rows] -= np.einsum("kac,kcr->kra", Gx[gpt[rows]], TC[gp])


def _layout(prob, n_eo: int = 6):
    """Positions of the orientation's 6 (with rigs: ``n_eo`` = 12, the frame's and the sensor's)
    and a global point's 3 columns in ``cidx`` (−1: dropped)."""
    P = 3 + prob.pmax
    off = {}
    o = 0
    for name, w in prob.layout.groups:
        off[name] = o
        o += w
    where = {int(c): j for j, c in enumerate(prob.layout.keep)}
    eo = np.array([where.get(off["eo"] + a, -1) for a in range(n_eo)]) if "eo" in off else np.full(n_eo, -1)
    pt = np.array([where.get(off["pt"] + a, -1) for a in range(3)]) if "pt" in off else np.full(3, -1)
    del P
    return eo, pt


def _pick(X, pos):
    """X (r, q, 2) → (r, len(pos), 2) with zeros where ``pos`` is −1."""
    Xp = np.concatenate([X, np.zeros((X.shape[0], 1, X.shape[2]))], axis=1)
    return Xp[:, np.where(pos >= 0, pos, X.shape[1]), :]


# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class ParameterVectors:
    """``r`` vectors over every parameter of the bundle, split by kind: ``cameras`` (a tuple per
    camera of (r, 3 + p) over ``[c, xp, yp, ap…]``), ``eo`` (r, m, 6), ``points`` (r, n, 3) —
    object units / rad; zero for fixed parameters, nan for points and photos not adjusted."""

    cameras: tuple
    eo: np.ndarray
    points: np.ndarray


def effect_vectors(res, rows, delta0: float = 4.13, bias=None) -> ParameterVectors:
    """Full effect of the MDB (or ``bias``) of chosen scalar rows on **every** parameter (one solve
    per row).  ``rows``: scalar row indices ``2 i + c`` (observation i, c = 0 x / 1 y).

    Returns a :class:`ParameterVectors`, one vector per row."""
    prob, lin, red, Qx = _system(res)
    rows = np.asarray(rows, int).reshape(-1)
    k_all = len(res.residuals)
    bias = row_mdb(res, delta0) if bias is None else np.asarray(bias, float).reshape(k_all, 2)
    pos = np.full(k_all, -1)
    pos[prob.oi] = np.arange(len(prob.oi))
    obs_i, coord = rows // 2, rows % 2
    kl = pos[obs_i]
    if (kl < 0).any() or not res.row_active[obs_i, coord].all():
        bad = int(rows[(kl < 0) | ~res.row_active[obs_i, coord]][0])
        raise ValueError(f"row {bad} is not an active image row of the adjustment")
    Jc, Jp, L = lin.Jc, lin.Jp, prob.L
    r = len(rows)
    a_g = np.zeros((prob.n_g + 1, r))
    a_p = np.zeros((prob.n_e + 1, 3, r))
    for j, (kk, c) in enumerate(zip(kl, coord)):
        u = L[kk][:, c]
        np.add.at(a_g[:, j], prob.layout.cidx[kk], Jc[kk].T @ u)
        a_p[prob.layout.pidx[kk], :, j] += Jp[kk].T @ u
    xg, y = _apply_Q(prob, red, Qx, res.state, a_g[:-1], a_p[:-1])
    b = bias[obs_i, coord]
    xg = xg * b[None, :]
    y = y * b[None, None, :]
    return _scatter(res, xg, y)


def own_point_effects_in_datum(res, points, S, delta0: float = 4.13, chunk: int = 256, progress=None):
    """Effect of every active image row's MDB on its own point's coordinates **after** the
    S-transformation ``S`` (3 n × 3 n over the points ``points``, indices into the block's points,
    e.g. :func:`baarda.pipeline.stats.congruence.s_transform`'s third result).

    The effect of row i's bias on all parameters, ``∇x = Q Aᵀ P c_i ∇_i``, is a vector in the
    adjustment's datum; in another datum it is ``S ∇x`` over the points (the same linear map the
    coordinates and their cofactors undergo).  Each row's full effect vector is needed (the shift of
    the new datum's points moves every point): one solve per row, ``chunk`` rows at a time.

    Returns ``(effect (k_all, 2, 3), bias (k_all, 2))``: the shift of the row's own point's X, Y, Z
    (object units) in the new datum, nan for inactive rows and rows whose point is not in
    ``points``; ``bias`` the rows' MDBs (mm).  ``progress(done, total)`` is called per chunk."""
    points = np.asarray(points, int)
    n = len(points)
    S = np.asarray(S, float)
    if S.shape != (3 * n, 3 * n):
        raise ValueError(f"S must be {3 * n}×{3 * n} for {n} points, got {S.shape}")
    k_all = len(res.residuals)
    bias = row_mdb(res, delta0)
    obs = res.block_in.observations
    where = np.full(len(res.block_in.points), -1)
    where[points] = np.arange(n)
    own = where[np.asarray(obs.point)]
    act = np.asarray(res.row_active, bool) & (own >= 0)[:, None] & np.isfinite(bias)
    rows = np.flatnonzero(act.reshape(-1))
    out = np.full((k_all, 2, 3), np.nan)
    flat = out.reshape(-1, 3)
    for a in range(0, len(rows), chunk):
        r = rows[a:a + chunk]
        vec = effect_vectors(res, r, bias=bias).points[:, points, :]          # (r, n, 3), this datum
        vec = np.nan_to_num(vec).reshape(len(r), 3 * n) @ S.T                 # the new datum
        o = own[r // 2]
        flat[r] = vec.reshape(len(r), n, 3)[np.arange(len(r)), o]
        if progress is not None:
            progress(min(a + chunk, len(rows)), len(rows))
    return out, bias


def _scatter(res, xg, y) -> ParameterVectors:
    """Global vector (n_g, r) and eliminated points (n_e, 3, r) → per-parameter arrays."""
    prob = res.problem
    r = xg.shape[1]
    xpad = np.vstack([xg, np.zeros((1, r))])
    n_g = prob.n_g

    def gather(idx):
        return np.moveaxis(xpad[np.where(idx >= 0, idx, n_g)], -1, 0)

    cams = [gather(prob.g_cam[j, :3 + m.n_params]) for j, m in enumerate(prob.models)]
    if getattr(prob, "rig", None) is None:
        eo = gather(prob.g_eo)
    else:                           # rigs: each photo's orientation through its frame's and sensor's 12
        cols, T = photo_columns(prob, res.state, np.arange(prob.m))
        eo = np.einsum("mij,rmj->rmi", T, gather(cols))
    eo[:, ~prob.photo_used] = np.nan
    pts = gather(prob.g_pt)
    if prob.n_e:
        pts[:, prob.elim_points] = np.moveaxis(y, -1, 0)
    pts[:, ~prob.point_used] = np.nan
    return ParameterVectors(tuple(cams), eo, pts)


# --------------------------------------------------------------------------------------------------
def parameter_names_of(res, spec: str) -> list[tuple[str, int, int, str]]:
    """Parse one request: ``"photo <id>"`` (X0 … kappa), ``"point <id>"`` (X, Y, Z), ``"camera <id>"``
    (c, xp, yp, APs), optionally followed by one component name (``"point 17 Z"``, ``"photo 3 kappa"``).
    Returns ``[(kind, index, component, name)]``; ``KeyError`` naming what is unknown."""
    blk = res.block_in
    parts = str(spec).split()
    if len(parts) < 2 or parts[0] not in ("photo", "point", "camera"):
        raise KeyError(f"{spec!r}: expected 'photo <id>', 'point <id>' or 'camera <id>' (optionally + a component)")
    kind = parts[0]
    table = {"photo": blk.photos, "point": blk.points, "camera": blk.cameras}[kind]
    ids = [str(i) for i in table.ids]
    ident, comp = " ".join(parts[1:]), None
    if ident not in ids and len(parts) > 2:
        ident, comp = " ".join(parts[1:-1]), parts[-1]
    if ident not in ids:
        raise KeyError(f"{spec!r}: no {kind} with id {ident!r}")
    i = ids.index(ident)
    if kind == "photo":
        comps = list(EO_NAMES)
    elif kind == "point":
        comps = ["X", "Y", "Z"]
    else:
        comps = list(res.cam_param_names[i])
    if comp is not None:
        if comp not in comps:
            raise KeyError(f"{spec!r}: {kind} components are {', '.join(comps)}")
        sel = [comps.index(comp)]
    else:
        sel = range(len(comps))
    return [(kind, i, t, f"{kind} {ident} {comps[t]}") for t in sel]


def parameter_covariance(res, specs) -> tuple[list[str], np.ndarray]:
    """Joint a-posteriori covariance (``σ̂0² Q``; ``σ0² Q`` without redundancy) of the parameters
    named by ``specs`` (see :func:`parameter_names_of`): ``(names, C)``.  Fixed parameters have zero
    rows and columns.  Needs ``len`` solves of the whole system (both routes)."""
    prob = res.problem
    params = [p for s in specs for p in parameter_names_of(res, s)]
    names = [p[3] for p in params]
    r = len(params)
    a_g = np.zeros((prob.n_g + 1, r))
    a_p = np.zeros((prob.n_e + 1, 3, r))
    gidx = np.full(r, -1)
    rig_cols = rig_T = None
    if getattr(prob, "rig", None) is not None:
        rig_cols, rig_T = photo_columns(prob, res.state, np.arange(prob.m))
    for j, (kind, i, t, _) in enumerate(params):
        if kind == "camera":
            g = prob.g_cam[i, t] if t < prob.g_cam.shape[1] else -1
        elif kind == "photo" and rig_cols is not None:     # a linear function of the frame's and sensor's 12
            on = rig_cols[i] >= 0
            np.add.at(a_g[:, j], rig_cols[i][on], rig_T[i][t][on])
            g = -1
        elif kind == "photo":
            g = prob.g_eo[i, t]
        else:
            g = prob.g_pt[i, t]
            if g < 0 and prob.elim_of[i] >= 0 and prob.pt_free[i, t]:
                a_p[prob.elim_of[i], t, j] = 1.0
        if g >= 0:
            a_g[g, j] = 1.0
            gidx[j] = g
    _, lin, red, Qx = _system(res)
    xg, y = _apply_Q(prob, red, Qx, res.state, a_g[:-1], a_p[:-1])
    out = _scatter(res, xg, y)
    C = np.zeros((r, r))
    for j, (kind, i, t, _) in enumerate(params):
        if kind == "camera":
            C[:, j] = out.cameras[i][:, t]
        elif kind == "photo":
            C[:, j] = out.eo[:, i, t]
        else:
            C[:, j] = out.points[:, i, t]
    C = np.nan_to_num(0.5 * (C + C.T)) * res.variance_factor
    return names, C


# --------------------------------------------------------------------------------------------------
DENSE_LIMIT = 2.0e7          # entries of the dense design matrix of :func:`linearised_model` (160 MB)


def linearised_model(res, max_entries: float = DENSE_LIMIT):
    """The bundle linearised at its solution as a dense
    :class:`~baarda.pipeline.stats.linear.LinearModel` ``l = A Δx + e`` (for RRR and other
    methods that need the design): rows ``2 i + c`` are image coordinate ``c`` of block observation
    ``i`` (the snapshot's rows: ``l`` = the residual at the solution, inactive rows zero with unit
    weight), followed by the weighted constraints (camera/orientation priors, control coordinates,
    scale bars, GNSS antennas; ``l`` = their residuals).  Unknowns: the free global parameters and the free
    coordinates of the eliminated points; a free network's datum is held by the minimal datum of
    the sparse route (``n_c`` photo parameters), which changes no residual, redundancy or test.
    Its least-squares solution is ``Δx = 0`` with the bundle's ``v``, ``vᵀPv``, dof and redundancy
    numbers.  Returns ``(model, n_image_rows)``; ``ValueError`` above ``max_entries``."""
    prob, st = res.problem, res.state
    k_all = len(res.residuals)
    n_img = 2 * k_all
    n_pri = len(prob.prior_g_idx) + len(prob.prior_p_idx) + prob.n_grow_rows
    n_rows = n_img + n_pri
    held = np.zeros(0, int)
    if prob.n_c:
        held = res.route.held_datum(prob, st)
        if held is None:
            raise ValueError("the free network's datum cannot be held by photo parameters; no linearised model")
    free_pt = prob.elim_free.reshape(-1)
    u_full = prob.n_g + int(free_pt.sum())
    u = u_full - len(held)
    if float(n_rows) * u > max_entries:
        raise ValueError(f"the linearised bundle would be a dense {n_rows} × {u} design matrix, more than "
                         f"{max_entries:.3g} entries; RRR and other design-based methods are for small and medium "
                         "blocks (use data-snooping, ids or pope, which work on any size)")
    lin, _ = final_system(prob, res.route, st)
    # column of every global unknown / eliminated point coordinate (−1: fixed or held)
    gcol = np.full(prob.n_g + 1, -1)
    keep_g = np.ones(prob.n_g, bool)
    keep_g[held] = False
    gcol[:prob.n_g][keep_g] = np.arange(int(keep_g.sum()))
    ncg = int(keep_g.sum())
    pcol = np.full(3 * prob.n_e, -1)
    pcol[free_pt] = ncg + np.arange(int(free_pt.sum()))
    pcol = pcol.reshape(-1, 3)
    A = np.zeros((n_rows, u))
    l = np.zeros(n_rows)
    # image rows: unwhiten J̃ = L J (inactive rows of a half-active point: unit L)
    L = prob.L.copy()
    ra = prob.row_active[prob.oi]
    for c in (0, 1):
        L[~ra[:, c], c, c] = 1.0
    Linv = np.linalg.inv(L)
    Jc = np.einsum("kij,kjq->kiq", Linv, lin.Jc)
    Jp = np.einsum("kij,kja->kia", Linv, lin.Jp)
    rows = 2 * prob.oi[:, None] + np.arange(2)[None, :]                       # (k, 2)
    cc = gcol[prob.layout.cidx]                                                      # (k, q)
    for c in (0, 1):
        r = np.broadcast_to(rows[:, c, None], cc.shape)
        ok = cc >= 0
        np.add.at(A, (r[ok], cc[ok]), Jc[:, c, :][ok])
        ep = prob.layout.pidx < prob.n_e
        pc = pcol[prob.layout.pidx[ep]]                                              # (k', 3)
        rp = np.broadcast_to(rows[ep, c, None], pc.shape)
        okp = pc >= 0
        np.add.at(A, (rp[okp], pc[okp]), Jp[ep, c, :][okp])
    l[:n_img] = np.where(res.row_active, np.nan_to_num(res.residuals), 0.0).reshape(-1)
    # weights
    Pblk = np.einsum("kji,kjl->kil", L, L)                                    # LᵀL (unit on inactive rows)
    w_pri = []
    v, e, dg, dpv, dd, _ = lin.parts
    r0 = n_img
    for g, w, d in zip(prob.prior_g_idx, prob.prior_g_w, dg):
        if gcol[g] >= 0:
            A[r0, gcol[g]] = 1.0
        l[r0], r0 = d, r0 + 1
        w_pri.append(w)
    for p, c, w, d in zip(prob.prior_p_idx, prob.prior_p_coord, prob.prior_p_w, dpv):
        A[r0, pcol[p, c]] = 1.0
        l[r0], r0 = d, r0 + 1
        w_pri.append(w)
    grow_P = []                       # rows on global unknowns (scale bars, GNSS antennas): P blocks
    for k in prob.grows:
        f, J = prob.global_rows_eval(k, st)
        cc = gcol[np.where(k.cols >= 0, k.cols, prob.n_g)]                      # (G, w)
        for g in range(len(k.cols)):
            ok = cc[g] >= 0
            A[r0:r0 + k.r, cc[g][ok]] = J[g][:, ok]
            l[r0:r0 + k.r] = k.l[g] - f[g]
            grow_P.append((r0, k.L[g].T @ k.L[g]))
            w_pri.extend(np.diag(grow_P[-1][1]))
            r0 += k.r
    labels = list(np.asarray(res.snapshot.labels)) if res.snapshot is not None else [str(i) for i in range(n_img)]
    labels += _prior_labels(res)
    group = np.r_[np.repeat(np.arange(k_all), 2), np.full(n_pri, -1)]
    grow_diag = all(np.count_nonzero(Pg - np.diag(np.diag(Pg))) == 0 for _, Pg in grow_P)
    if prob.L_diag and grow_diag:
        P = np.ones(n_rows)
        Pd = np.ones((k_all, 2))
        Pd[prob.oi] = np.einsum("kii->ki", Pblk)
        P[:n_img] = Pd.reshape(-1)
        P[n_img:] = w_pri
    else:
        P = np.eye(n_rows)
        for kk, o in enumerate(prob.oi):
            P[2 * o:2 * o + 2, 2 * o:2 * o + 2] = Pblk[kk]
        P[np.arange(n_img, n_rows), np.arange(n_img, n_rows)] = w_pri
        for r0, Pg in grow_P:
            P[r0:r0 + len(Pg), r0:r0 + len(Pg)] = Pg
    return LinearModel(A, l, P, sigma0=prob.settings.sigma0, labels=labels, group=group), n_img


def _prior_labels(res) -> list[str]:
    """Labels of the weighted-constraint rows of :func:`linearised_model`."""
    prob, blk = res.problem, res.block_in
    names = {}
    for j, m in enumerate(prob.models):
        for t in range(3 + m.n_params):
            if prob.g_cam[j, t] >= 0:
                names[int(prob.g_cam[j, t])] = f"camera {blk.cameras.ids[j]} {res.cam_param_names[j][t]}"
    gi = np.argwhere(prob.g_eo >= 0)
    for i, t in gi:
        names[int(prob.g_eo[i, t])] = f"photo {blk.photos.ids[i]} {EO_NAMES[t]}"
    gi = np.argwhere(prob.g_pt >= 0)
    for i, t in gi:
        names[int(prob.g_pt[i, t])] = f"point {blk.points.ids[i]} {'XYZ'[t]}"
    names.update(rig_parameter_names(prob))                 # frames and sensors of rigs (docs/rigs.md)
    out = [f"prior {names.get(int(g), g)}" for g in prob.prior_g_idx]
    out += [f"control point {blk.points.ids[prob.elim_points[p]]} {'XYZ'[c]}"
            for p, c in zip(prob.prior_p_idx, prob.prior_p_coord)]
    for k in prob.grows:
        if k.kind == "distance":
            out += [f"distance {prob.distances[i].a}–{prob.distances[i].b}" for i in k.index]
        else:
            out += [f"antenna photo {p} {c}" for p in blk.photos.ids[blk.gnss.photo[k.index]].tolist() for c in "XYZ"]
    return out
