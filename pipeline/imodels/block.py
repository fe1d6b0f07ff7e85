"""Independent-model block adjustment (Ackermann): all models transformed at once.

Each model ``m`` has a 7-parameter similarity to the object system, ``X = s_m M_mᵀ x + T_m``
(``M_m = R3(κ) R2(φ) R1(ω)``, the parameters ordered ``scale, ω, φ, κ, tx, ty, tz`` as in
:mod:`baarda.pipeline.imodels.similarity`).  The **model coordinates are the observations**:

    x_mj + v_mj = M_m (X_j − T_m) / s_m          (residuals observed − computed, model units)

with the a-priori covariance of each model point (3 × 3, correlated).  The object coordinates of
every point measured in two or more models (tie points, projection centres shared by neighbouring
models) or carrying control are unknowns.  Control coordinates are weighted observations
``X_obs + v = X`` (sigma > 0) or fixed (sigma 0), per component, so full, planimetric and height
control mix freely (``baarda.pipeline.model.Points``: roles ``full``, ``xy``, ``z``).  Check points are
adjusted like tie points and compared afterwards (adjusted − surveyed).  A point seen in one model
only and without control carries no redundancy; it is left out of the adjustment and transformed
with its model's parameters afterwards (the result is the same).

The datum comes from the control.  Initial values: models are joined one by one through their
shared points by the closed-form similarity (:func:`~baarda.pipeline.imodels.similarity.similarity_closed_form`),
and each connected group of models is brought into the object system by the control points with
approximate X, Y and Z.  Then Gauss–Newton to convergence; the final linearisation gives the
statistics :class:`~baarda.pipeline.stats.snapshot.Snapshot` (rows: model coordinates x, y, z of every
model point — one group per model point — then the weighted control coordinates).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from baarda.pipeline.errors import AdjustmentError
from baarda.pipeline.geometry import opk_from_rotation
from baarda.pipeline.accuracy import CheckPoints
from baarda.pipeline.model import Points
from baarda.pipeline.stats.linear import LinearModel, factor_normal_equations, solve_normal
from baarda.pipeline.stats.snapshot import Snapshot

from .similarity import (PARAMETER_NAMES, rotation_and_derivatives, similarity_closed_form,
                         similarity_jacobian)

__all__ = ["ModelCoordinates", "ModelBlockAdjustment", "adjust_model_block",
           "model_observation_jacobian"]


@dataclass(frozen=True, eq=False)
class ModelCoordinates:
    """One independent model as the block adjustment sees it.

    id : str, e.g. ``"11-12"``.
    point_ids : (k,) str, keys shared across models (projection centres get keys of their own,
        e.g. ``"pc:11"``).
    xyz : (k, 3) model coordinates.
    cov : (k, 3, 3) a-priori covariance of the model coordinates (model units²).
    is_pc : (k,) bool, the point is a projection centre (for reports only).
    photos : ids of the photos that formed the model (for reports only).
    """

    id: str
    point_ids: np.ndarray
    xyz: np.ndarray
    cov: np.ndarray
    is_pc: np.ndarray | None = None
    photos: tuple = ()

    def __post_init__(self):
        k = len(self.point_ids)
        object.__setattr__(self, "point_ids", np.array([str(s) for s in self.point_ids]))
        object.__setattr__(self, "xyz", np.array(self.xyz, float).reshape(k, 3))
        object.__setattr__(self, "cov", np.array(self.cov, float).reshape(k, 3, 3))
        pc = np.zeros(k, bool) if self.is_pc is None else np.array(self.is_pc, bool).reshape(k)
        object.__setattr__(self, "is_pc", pc)
        if len(set(self.point_ids.tolist())) != k:
            raise ValueError(f"model {self.id}: duplicate point ids")


def model_observation_jacobian(params, X):
    """Computed model coordinates ``M (X − T) / s`` (n, 3) and derivatives by the model's 7
    parameters (n, 3, 7) and by X (n, 3, 3)."""
    X = np.asarray(X, float).reshape(-1, 3)
    s = float(params[0])
    M, dM = rotation_and_derivatives(np.asarray(params[1:4], float))
    d = X - np.asarray(params[4:7], float)
    f = d @ M.T / s
    Jp = np.zeros((X.shape[0], 3, 7))
    Jp[:, :, 0] = -f / s
    for k in range(3):
        Jp[:, :, 1 + k] = d @ dM[k].T / s
    Jp[:, :, 4:] = -M / s
    JX = np.broadcast_to(M / s, (X.shape[0], 3, 3)).copy()
    return f, Jp, JX


@dataclass(frozen=True, eq=False)
class ModelBlockAdjustment:
    """Result of :func:`adjust_model_block`.

    model_ids : (m,); params : (m, 7) ``scale, ω, φ, κ, tx, ty, tz``; Qparams : (m, 7, 7).
    point_ids : (p,) every point of any model; XYZ : (p, 3) adjusted object coordinates;
    cov_XYZ : (p, 3, 3) a-priori covariance (σ0² Q); role : (p,) role from the points table
    (``"tie"`` for points not in it, ``"pc"`` for projection centres); n_models : (p,);
    in_adjustment : (p,) bool (False: transformed afterwards from its only model).
    obs_model, obs_point : (g,) model and point index of each model-point observation group;
    v_model : (g, 3) residuals in model units, observed − computed (nan on inactive rows);
    v_object : (g, 3) the same rotated and scaled into the object system.
    control_point : (c,) point index and control_axis : (c,) 0/1/2 of each weighted control row;
    v_control : (c,) control residuals ``X_surveyed − X_adjusted`` (observed − computed).
    check : the check points (:class:`~baarda.pipeline.accuracy.CheckPoints`: ``ids``, ``errors``
    adjusted − surveyed, ``Sx`` … ``Sz``).
    sigma0_hat, dof, iterations, converged, history (vᵀPv per iteration).
    snapshot : rows = 3 per observation group (x, y, z) then the control rows; active : rows used.
    """

    model_ids: np.ndarray
    params: np.ndarray
    Qparams: np.ndarray
    point_ids: np.ndarray
    XYZ: np.ndarray
    cov_XYZ: np.ndarray
    role: np.ndarray
    n_models: np.ndarray
    in_adjustment: np.ndarray
    obs_model: np.ndarray
    obs_point: np.ndarray
    v_model: np.ndarray
    v_object: np.ndarray
    control_point: np.ndarray
    control_axis: np.ndarray
    v_control: np.ndarray
    check: CheckPoints
    sigma0_hat: float
    dof: int
    iterations: int
    converged: bool
    history: list
    snapshot: Snapshot
    active: np.ndarray
    _inputs: dict = field(default_factory=dict, repr=False)
    _lin: dict = field(default_factory=dict, repr=False)

    def transform(self, model_index: int, xyz) -> np.ndarray:
        """Model coordinates of model ``model_index`` into the object system."""
        p = self.params[model_index]
        M = rotation_and_derivatives(p[1:4])[0]
        return p[0] * np.asarray(xyz, float) @ M + p[4:7]

    def report(self) -> dict:
        return {"models": int(len(self.model_ids)), "points": int(self.in_adjustment.sum()),
                "sigma0_hat": self.sigma0_hat, "dof": self.dof, "iterations": self.iterations,
                "converged": self.converged, "check_rmse": self.check.rmse()}

    def refit(self, active) -> Snapshot:
        """Adjust again with the snapshot rows where ``active`` is True (Refittable)."""
        return self.rerun(active).snapshot

    def linear_model(self) -> LinearModel:
        """The adjustment linearised at its solution as a :class:`baarda.pipeline.stats.LinearModel`
        (sparse design, dense weights): ``l`` are the residuals at the solution, so that
        ``adjust(active)`` reproduces this snapshot (and allows RRR)."""
        return _linear_model(self._lin)

    def rerun(self, active) -> "ModelBlockAdjustment":
        act = np.asarray(active, bool).reshape(-1)
        if act.shape[0] != self.snapshot.n:
            raise ValueError(f"active has {act.shape[0]} entries, the snapshot has {self.snapshot.n} rows")
        start = {"params": self.params, "XYZ": dict(zip(self.point_ids.tolist(), self.XYZ))}
        return adjust_model_block(**dict(self._inputs, active=act, initial=start))


# ---------------------------------------------------------------------------------------------

def _control_table(points: Points | None):
    """id → (XYZ, sigma (3,), role)."""
    if points is None:
        return {}
    return {pid: (points.XYZ[i], points.sigma[i], points.role[i]) for i, pid in enumerate(points.ids.tolist())}


def _connectivity_check(models, keys_of):
    if len(models) < 2:
        return
    count = {}
    for m in models:
        for k in keys_of[m.id]:
            count[k] = count.get(k, 0) + 1
    for m in models:
        if not any(count[k] > 1 for k in keys_of[m.id]):
            raise AdjustmentError(
                f"model {m.id} has no tie to the block: it shares no point and no projection "
                "centre with any other model")


def _initial_values(models, ctrl, pc_prefix):
    """Initial similarity of every model and approximate object coordinates of every key."""
    n_m = len(models)
    keys_of = [dict(zip(m.point_ids.tolist(), range(len(m.point_ids)))) for m in models]
    # share counts, to start from the best connected model
    count = {}
    for kd in keys_of:
        for k in kd:
            count[k] = count.get(k, 0) + 1
    local = [None] * n_m  # params into the component frame
    comp = [-1] * n_m
    ncomp = 0
    for start in sorted(range(n_m), key=lambda i: -sum(count[k] > 1 for k in keys_of[i])):
        if local[start] is not None:
            continue
        local[start] = np.r_[1.0, 0, 0, 0, 0, 0, 0]
        comp[start] = ncomp
        acc = {k: [models[start].xyz[j]] for k, j in keys_of[start].items()}
        progress = True
        while progress:
            progress = False
            for i in range(n_m):
                if local[i] is not None:
                    continue
                shared = [k for k in keys_of[i] if k in acc]
                if len(shared) < 3:
                    continue
                x = np.array([models[i].xyz[keys_of[i][k]] for k in shared])
                X = np.array([np.mean(acc[k], axis=0) for k in shared])
                try:
                    p = similarity_closed_form(x, X, what=f"model {models[i].id}")
                except AdjustmentError:
                    continue
                local[i] = p
                comp[i] = ncomp
                Xi = _apply(p, models[i].xyz)
                for k, j in keys_of[i].items():
                    acc.setdefault(k, []).append(Xi[j])
                progress = True
        # is anything else tied to this component but not placeable?
        ncomp += 1
    # a model that joined no component with others although it shares points
    for i in range(n_m):
        if comp[i] >= 0 and sum(c == comp[i] for c in comp) == 1 and n_m > 1:
            shared = sorted(k for k in keys_of[i] if count[k] > 1)
            if shared:
                raise AdjustmentError(
                    f"model {models[i].id} is tied to the block by only {len(shared)} point(s) "
                    f"({', '.join(shared)}); at least 3 not on one line are needed")
    params = np.zeros((n_m, 7))
    approx = {}
    for cid in range(ncomp):
        members = [i for i in range(n_m) if comp[i] == cid]
        loc = {}
        for i in members:
            Xi = _apply(local[i], models[i].xyz)
            for k, j in keys_of[i].items():
                loc.setdefault(k, []).append(Xi[j])
        cks = [k for k in loc if k in ctrl and ctrl[k][2] in ("full", "xy", "z")
               and np.all(np.isfinite(ctrl[k][0]))]
        names = ", ".join(models[i].id for i in members)
        if len(cks) < 3:
            raise AdjustmentError(
                f"datum missing for model(s) {names}: {len(cks)} control point(s) with approximate "
                "X, Y and Z in them; the block needs control — at least two planimetric and three "
                "height control points, not on one line (xy/z control must carry approximate values "
                "of the other coordinates for the initial values)")
        x = np.array([np.mean(loc[k], axis=0) for k in cks])
        X = np.array([ctrl[k][0] for k in cks])
        g = similarity_closed_form(x, X, what=f"initial datum of model(s) {names}")
        for i in members:
            params[i] = _compose(g, local[i])
        for k, lst in loc.items():
            approx[k] = _apply(g, np.mean(lst, axis=0)[None])[0]
    return params, approx


def _apply(p, x):
    M = rotation_and_derivatives(np.asarray(p[1:4], float))[0]
    return p[0] * np.asarray(x, float) @ M + p[4:7]


def _compose(outer, inner):
    """Parameters of ``outer ∘ inner`` (both ``X = s Mᵀ x + T``)."""
    M1 = rotation_and_derivatives(inner[1:4])[0]
    M2 = rotation_and_derivatives(outer[1:4])[0]
    M = M1 @ M2
    T = outer[0] * M2.T @ inner[4:7] + outer[4:7]
    return np.r_[outer[0] * inner[0], opk_from_rotation(M), T]


def adjust_model_block(models: Sequence[ModelCoordinates], points: Points | None = None, *,
                       sigma0: float = 1.0, active=None, initial=None, max_iter: int = 50,
                       tol: float = 1e-10, pc_prefix: str = "pc:") -> ModelBlockAdjustment:
    """Independent-model block adjustment.

    Parameters
    ----------
    models : the models (:class:`ModelCoordinates`), at least one.
    points : object points with roles and a-priori sigmas (control ``full``/``xy``/``z``, ``check``,
        ``tie``); keys of the models not in it are tie points.
    sigma0 : a-priori σ0.
    active : (n,) bool rows of the snapshot to use (default all).
    initial : optional ``{"params": (m, 7), "XYZ": {id: (3,)}}`` start (e.g. a previous solution).
    pc_prefix : keys starting with it are projection centres (role ``"pc"`` in the result).

    Raises
    ------
    AdjustmentError : a model with no tie to the block, too weak ties, missing datum, singular
        normal equations (naming the undetermined unknowns) or no convergence.
    """
    models = list(models)
    if not models:
        raise AdjustmentError("independent-model block: no models")
    ids = [m.id for m in models]
    if len(set(ids)) != len(ids):
        raise AdjustmentError("independent-model block: duplicate model ids")
    ctrl = _control_table(points)
    inputs = dict(models=models, points=points, sigma0=sigma0, max_iter=max_iter, tol=tol,
                  pc_prefix=pc_prefix)
    _connectivity_check(models, {m.id: m.point_ids.tolist() for m in models})

    # ---- point bookkeeping
    all_keys = []
    n_models = {}
    for m in models:
        for k in m.point_ids.tolist():
            if k not in n_models:
                all_keys.append(k)
                n_models[k] = 0
            n_models[k] += 1
    key_index = {k: i for i, k in enumerate(all_keys)}
    n_p = len(all_keys)
    sig = np.full((n_p, 3), np.inf)
    XYZ_ctrl = np.full((n_p, 3), np.nan)
    role = np.array(["pc" if k.startswith(pc_prefix) else "tie" for k in all_keys], dtype=object)
    for k, (X, s, r) in ctrl.items():
        if k in key_index:
            i = key_index[k]
            role[i] = r
            XYZ_ctrl[i] = X
            if r in ("full", "xy", "z"):
                sig[i] = s
    role = role.astype(str)
    has_ctrl = np.isfinite(sig) & (sig >= 0)  # fixed (0) or weighted
    nm = np.array([n_models[k] for k in all_keys])
    in_adj = (nm >= 2) | has_ctrl.any(axis=1)

    # ---- observation groups (model points of adjusted keys) and control rows
    g_model, g_local, g_point = [], [], []
    for mi, m in enumerate(models):
        for j, k in enumerate(m.point_ids.tolist()):
            pi = key_index[k]
            if in_adj[pi]:
                g_model.append(mi)
                g_local.append(j)
                g_point.append(pi)
    g_model, g_local, g_point = map(lambda a: np.array(a, int), (g_model, g_local, g_point))
    G = g_model.size
    weighted = np.isfinite(sig) & (sig > 0) & in_adj[:, None]
    c_point, c_axis = np.nonzero(weighted)
    n_rows = 3 * G + c_point.size
    act = np.ones(n_rows, bool) if active is None else np.asarray(active, bool).reshape(-1)
    if act.shape[0] != n_rows:
        raise ValueError(f"active has {act.shape[0]} entries, the block has {n_rows} rows")
    act_g = act[:3 * G].reshape(G, 3)
    act_c = act[3 * G:]

    # ---- unknowns: 7 per model, then the free/weighted components of the adjusted points
    n_m = len(models)
    col = -np.ones((n_p, 3), int)
    free = in_adj[:, None] & ~(np.isfinite(sig) & (sig == 0))
    col[free] = 7 * n_m + np.arange(int(free.sum()))
    u = 7 * n_m + int(free.sum())
    names = [f"model {m.id} {p}" for m in models for p in PARAMETER_NAMES]
    names += [f"point {all_keys[i]} {'XYZ'[a]}" for i, a in zip(*np.nonzero(free))]

    # ---- initial values
    if initial is None:
        params, approx = _initial_values(models, ctrl, pc_prefix)
    else:
        params = np.array(initial["params"], float).copy()
        approx = dict(initial["XYZ"])
    X = np.array([approx.get(k, np.full(3, np.nan)) for k in all_keys], float)
    fixed = np.isfinite(sig) & (sig == 0)
    X[fixed] = XYZ_ctrl[fixed]
    if not np.all(np.isfinite(X[in_adj])):
        bad = [all_keys[i] for i in np.flatnonzero(in_adj & ~np.all(np.isfinite(X), axis=1))]
        raise AdjustmentError(f"no initial coordinates for point(s) {', '.join(bad[:5])}")

    # group data
    xyz_obs = np.array([models[mi].xyz[j] for mi, j in zip(g_model, g_local)]).reshape(G, 3)
    cov_g = np.array([models[mi].cov[j] for mi, j in zip(g_model, g_local)]).reshape(G, 3, 3)
    P_g = _group_weights(cov_g, act_g) * sigma0 ** 2
    idx_g = np.zeros((G, 10), int)
    idx_g[:, :7] = 7 * g_model[:, None] + np.arange(7)
    idx_g[:, 7:] = np.where(col[g_point] >= 0, col[g_point], u)  # u = dummy column
    P_c = np.where(act_c, sigma0 ** 2 / np.where(weighted[c_point, c_axis], sig[c_point, c_axis], 1.0) ** 2, 0.0)
    idx_c = col[c_point, c_axis]

    extent = max(float(np.nanmax(np.abs(X[in_adj] - np.nanmean(X[in_adj], axis=0)))) if in_adj.any() else 1.0, 1e-12)
    converged = False
    history = []
    it = 0
    for it in range(1, max_iter + 1):
        J, r = _linearise(models, params, X, g_model, g_point, xyz_obs, col)
        r_c = XYZ_ctrl[c_point, c_axis] - X[c_point, c_axis]
        history.append(float(np.einsum("ga,gab,gb->", r, P_g, r) + np.sum(P_c * r_c ** 2)))
        N = np.zeros((u + 1, u + 1))
        b = np.zeros(u + 1)
        JtP = np.einsum("gai,gab->gib", J, P_g)
        np.add.at(N, (idx_g[:, :, None], idx_g[:, None, :]), np.einsum("gib,gbj->gij", JtP, J))
        np.add.at(b, idx_g, np.einsum("gib,gb->gi", JtP, r))
        np.add.at(N, (idx_c, idx_c), P_c)
        np.add.at(b, idx_c, P_c * r_c)
        fac = factor_normal_equations(N[:u, :u], names)
        dx = solve_normal(fac, b[:u])
        params = params + dx[:7 * n_m].reshape(n_m, 7)
        Xc = X.copy()
        Xc[col >= 0] += dx[col[col >= 0]]
        X = Xc
        step = np.abs(dx[:7 * n_m].reshape(n_m, 7)) / np.r_[np.abs(params[:, 0:1]).mean(), 1, 1, 1, extent, extent, extent]
        step_pts = np.abs(dx[7 * n_m:]) / extent if u > 7 * n_m else np.zeros(1)
        if not np.all(np.isfinite(dx)):
            break
        if max(step.max(), step_pts.max()) < tol:
            converged = True
            break
    if not converged:
        raise AdjustmentError(f"independent-model block adjustment did not converge in {max_iter} "
                              "iterations", state={"params": params, "XYZ": X})

    # ---- final linearisation → statistics
    J, r = _linearise(models, params, X, g_model, g_point, xyz_obs, col)
    r_c = XYZ_ctrl[c_point, c_axis] - X[c_point, c_axis]
    labels = [f"model {models[mi].id} point {all_keys[pi]} {c}" for mi, pi in zip(g_model, g_point) for c in "xyz"]
    labels += [f"control {all_keys[pi]} {'XYZ'[a]}" for pi, a in zip(c_point, c_axis)]
    group = np.r_[np.repeat(np.arange(G), 3), -np.ones(c_point.size, int)]
    lin = dict(J=J, r=r, idx_g=idx_g, cov_g=cov_g, r_c=r_c, idx_c=idx_c,
               sig_c=sig[c_point, c_axis], u=u, sigma0=sigma0, labels=labels, group=group, names=names)
    snap, Qxx = _grouped_snapshot(lin, act_g, act_c)
    # ---- results per point (single-model points transformed afterwards)
    XYZ = X.copy()
    covX = np.zeros((n_p, 3, 3))
    sel = np.flatnonzero(in_adj)
    for i in sel:
        c3 = col[i]
        ok = c3 >= 0
        if ok.any():
            covX[i][np.ix_(ok, ok)] = sigma0 ** 2 * Qxx[np.ix_(c3[ok], c3[ok])]
    for mi, m in enumerate(models):
        for j, k in enumerate(m.point_ids.tolist()):
            i = key_index[k]
            if in_adj[i]:
                continue
            p = params[mi]
            M = rotation_and_derivatives(p[1:4])[0]
            XYZ[i] = p[0] * m.xyz[j] @ M + p[4:7]
            _, Jp = similarity_jacobian(p, m.xyz[j][None])
            Qp = Qxx[7 * mi:7 * mi + 7, 7 * mi:7 * mi + 7]
            covX[i] = sigma0 ** 2 * Jp[0] @ Qp @ Jp[0].T + p[0] ** 2 * M.T @ m.cov[j] @ M
    v_model = np.where(act_g, r, np.nan)
    v_object = np.einsum("gb,gba->ga", np.nan_to_num(v_model),
                         np.array([rotation_and_derivatives(params[mi, 1:4])[0] for mi in g_model]).reshape(G, 3, 3)) \
        * params[g_model, 0:1]
    v_object[~act_g] = np.nan
    v_control = np.where(act_c, r_c, np.nan)
    chk = np.flatnonzero(role == "check")
    check = CheckPoints.of([all_keys[i] for i in chk], XYZ[chk],
                           np.array([ctrl[all_keys[i]][0] for i in chk]).reshape(-1, 3))
    Qp = np.array([Qxx[7 * i:7 * i + 7, 7 * i:7 * i + 7] for i in range(n_m)])
    return ModelBlockAdjustment(
        model_ids=np.array(ids), params=params, Qparams=Qp, point_ids=np.array(all_keys),
        XYZ=XYZ, cov_XYZ=covX, role=role, n_models=nm, in_adjustment=in_adj, obs_model=g_model,
        obs_point=g_point, v_model=v_model, v_object=v_object, control_point=c_point,
        control_axis=c_axis, v_control=v_control, check=check, sigma0_hat=snap.sigma0_hat,
        dof=snap.dof, iterations=it, converged=converged, history=history, snapshot=snap,
        active=act.copy(), _inputs=inputs, _lin=lin)


def _linear_model(lin) -> LinearModel:
    J, idx_g, u = lin["J"], lin["idx_g"], lin["u"]
    G = J.shape[0]
    C = lin["idx_c"].size
    rr, cc, vals = [], [], []
    for a in range(3):
        rows_a = 3 * np.arange(G) + a
        for q in range(10):
            ok = idx_g[:, q] < u
            rr.append(rows_a[ok])
            cc.append(idx_g[ok, q])
            vals.append(J[ok, a, q])
    rr.append(3 * G + np.arange(C))
    cc.append(lin["idx_c"])
    vals.append(np.ones(C))
    A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rr), np.concatenate(cc))), shape=(3 * G + C, u))
    s0 = lin["sigma0"]
    blocks = [np.linalg.inv(c / s0 ** 2) for c in lin["cov_g"]]
    if C:
        blocks.append(sp.diags((s0 / lin["sig_c"]) ** 2))
    P = sp.block_diag(blocks).toarray()
    return LinearModel(A, np.r_[lin["r"].reshape(-1), lin["r_c"]], P=P, sigma0=s0, labels=lin["labels"],
                       group=lin["group"], names=lin["names"])


def _grouped_snapshot(lin, act_g, act_c) -> tuple[Snapshot, np.ndarray]:
    """Snapshot and Qxx exploiting the block-diagonal weights (3 × 3 per model point, scalar control).

    The same quantities as :meth:`baarda.pipeline.stats.LinearModel.adjust` on :func:`_linear_model`
    (checked by the tests), in O(rows) small products instead of dense n × n algebra:
    ``Q̂ = J Qxx Jᵀ`` per group, ``Qvv = Σ/σ0² − Q̂`` on the active rows, ``r = diag(Qvv P)``,
    ``(P Qvv P)_ii``; a removed row gets ``v_pred = l − a x̂`` with
    ``var = σ0² (Σ_oo/σ0² + Q̂_oo − 2 (Q P Q̂)_oo)`` (its correlation with the rest of its point).
    """
    J, r, idx_g, u, s0 = lin["J"], lin["r"], lin["idx_g"], lin["u"], lin["sigma0"]
    G = J.shape[0]
    Qg = lin["cov_g"] / s0 ** 2
    Pg = _group_weights(Qg, act_g)
    idx_c, q_c = lin["idx_c"], (lin["sig_c"] / s0) ** 2
    p_c = np.where(act_c, 1.0 / q_c, 0.0)
    N = np.zeros((u + 1, u + 1))
    JtP = np.einsum("gai,gab->gib", J, Pg)
    np.add.at(N, (idx_g[:, :, None], idx_g[:, None, :]), np.einsum("gib,gbj->gij", JtP, J))
    np.add.at(N, (idx_c, idx_c), p_c)
    Qxx = solve_normal(factor_normal_equations(N[:u, :u], lin["names"]), np.eye(u))
    Qxx = 0.5 * (Qxx + Qxx.T)
    Qe = np.zeros((u + 1, u + 1))
    Qe[:u, :u] = Qxx
    Qhat = np.einsum("gai,gij,gbj->gab", J, Qe[idx_g[:, :, None], idx_g[:, None, :]], J)
    Qvv = (Qg - Qhat) * act_g[:, :, None] * act_g[:, None, :]
    r_g = np.einsum("gab,gba->ga", Qvv, Pg)
    PQvvP_g = np.einsum("gab,gbc,gca->ga", Pg, Qvv, Pg)
    v_g = np.where(act_g, r, 0.0)
    Pv_g = np.einsum("gab,gb->ga", Pg, v_g)
    var_out = np.einsum("gaa->ga", Qg) + np.einsum("gaa->ga", Qhat) - 2 * np.einsum("gab,gbc,gca->ga", Qg, Pg, Qhat)
    qhat_c = Qxx[idx_c, idx_c]
    v_c = np.where(act_c, lin["r_c"], 0.0)
    n_act = int(act_g.sum() + act_c.sum())
    snap = Snapshot(
        v=np.r_[v_g.reshape(-1), v_c], Pv=np.r_[Pv_g.reshape(-1), p_c * v_c],
        PQvvP=np.maximum(np.r_[PQvvP_g.reshape(-1), np.where(act_c, p_c ** 2 * (q_c - qhat_c), 0.0)], 0.0),
        r=np.r_[r_g.reshape(-1), np.where(act_c, 1.0 - p_c * qhat_c, 0.0)],
        sigma_l=s0 * np.sqrt(np.r_[np.einsum("gaa->ga", Qg).reshape(-1), q_c]),
        vtpv=float(np.sum(v_g * Pv_g) + np.sum(p_c * v_c ** 2)), dof=n_act - u, sigma0=s0,
        active=np.r_[act_g.reshape(-1), act_c], labels=lin["labels"], group=lin["group"],
        meta={"kind": "independent-model block", "group_size": 3, "u": u},
        v_pred=np.r_[r.reshape(-1), lin["r_c"]],
        sigma_v_pred=np.where(np.r_[act_g.reshape(-1), act_c], np.nan,
                              s0 * np.sqrt(np.maximum(np.r_[var_out.reshape(-1), q_c + qhat_c], 0.0))))
    return snap, Qxx


def _group_weights(cov, act):
    """(G, 3, 3) weights of the active components of every group (marginal inverse)."""
    G = cov.shape[0]
    P = np.zeros((G, 3, 3))
    full = act.all(axis=1)
    if full.any():
        P[full] = np.linalg.inv(cov[full])
    for g in np.flatnonzero(~full & act.any(axis=1)):
        a = np.flatnonzero(act[g])
        P[g][np.ix_(a, a)] = np.linalg.inv(cov[g][np.ix_(a, a)])
    return P


def _linearise(models, params, X, g_model, g_point, xyz_obs, col):
    """Jacobian (G, 3, 10) — 7 model parameters then X, Y, Z of the point — and residuals."""
    G = g_model.size
    J = np.zeros((G, 3, 10))
    r = np.zeros((G, 3))
    for mi in np.unique(g_model):
        sel = np.flatnonzero(g_model == mi)
        f, Jp, JX = model_observation_jacobian(params[mi], X[g_point[sel]])
        J[sel, :, :7] = Jp
        J[sel, :, 7:] = JX * (col[g_point[sel]] >= 0)[:, None, :]
        r[sel] = xyz_obs[sel] - f
    return J, r
