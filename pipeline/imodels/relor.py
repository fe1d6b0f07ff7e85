"""Relative orientation of a stereo pair from image coordinates.

Two conditions, two parameterisations, any combination:

* **coplanarity** (Gauss–Helmert): for every point the base and the two image rays lie in one
  plane, ``F = b · (a1 × a2) = 0`` with ``a_k = R_kᵀ u_k``, ``u_k = (x − xp, y − yp, −c)``.  All
  four image coordinates of a point are observations; one condition per point.
* **collinearity** (Gauss–Markov): the model points are unknowns too; both photos' collinearity
  equations for every point.  With all four coordinates weighted alike this reaches the same
  optimum as the rigorous coplanarity adjustment (both minimise the weighted image residuals under
  the condition that the rays meet), which the tests use as a cross-check.

Parameterisations (the model frame has the left projection centre at its origin):

* **dependent** — left photo fixed (``R_left = I``), right photo ``X0 = (bx, by, bz)`` with ``bx``
  fixed (it sets the model scale), unknowns ``by, bz, ω2, φ2, κ2``;
* **independent** — the base along the model x-axis, ``X0_right = (bx, 0, 0)``, unknowns
  ``φ1, κ1, φ2, ω2, κ2`` (``ω1 = 0``: a common rotation about the base is the datum).

Residuals are observed − computed.  The statistics rows of a coplanarity adjustment are the
points' **y-parallaxes**: the linearised condition of point i, divided by
``g_i = (∂F/∂y_right − ∂F/∂y_left)/2``, is (in the normal case exactly) the residual y-parallax
``(y_right − y_left)`` observed − computed, in mm; its variance is ``B Q Bᵀ / g²``.  A
Gauss–Helmert adjustment with one condition per point is the Gauss–Markov adjustment of these
pseudo-observations, so w-tests, redundancy numbers and MDBs are per point.  A collinearity
adjustment reports its four image coordinates per point instead (x and y of one image share a
group).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import scipy.sparse as sp

from baarda.pipeline.errors import AdjustmentError
from baarda.pipeline.geometry import opk_from_rotation, rotation_from_opk
from baarda.pipeline.stats.linear import LinearModel, factor_normal_equations, solve_normal
from baarda.pipeline.stats.snapshot import Snapshot

from .intersection import project_with_jacobian, space_intersection
from .similarity import rotation_and_derivatives

__all__ = [
    "PARAMETER_NAMES", "RelativeOrientation", "relative_orientation", "coplanarity_condition",
    "pair_poses", "initial_candidates", "parameters_from_poses",
]

PARAMETER_NAMES = {
    "dependent": ("by", "bz", "omega2", "phi2", "kappa2"),
    "independent": ("phi1", "kappa1", "phi2", "omega2", "kappa2"),
}
WEAK_RCOND = 1e-6
"""Below this reciprocal condition (scaled normal matrix) a relative orientation is called weak."""
CRITICAL_HINT = ("the points lie on or near a critical surface (for example all in one plane that "
                 "contains the base, on one line, or on a circular cylinder through both projection "
                 "centres with its axis parallel to the base)")
UNDETERMINED = 1e-12
"""A parameter whose (dimensionless) normal-equation diagonal is at most this fraction of the
largest, or of its own before the point unknowns are eliminated, is undetermined (rounding)."""


def pair_poses(p, parameters: str, bx: float):
    """Poses of both photos in the model frame and their derivatives by the 5 parameters.

    Returns ``R_left, dR_left (5, 3, 3), R_right, dR_right (5, 3, 3), X0_right (3,),
    dX0_right (5, 3)``; ``X0_left`` is the origin.  ``R_*`` are ``R_cam_from_model``.
    """
    p = np.asarray(p, dtype=float)
    dR1 = np.zeros((5, 3, 3))
    dR2 = np.zeros((5, 3, 3))
    dX02 = np.zeros((5, 3))
    if parameters == "dependent":
        R1 = np.eye(3)
        R2, d = rotation_and_derivatives(p[2:5])
        dR2[2:5] = d
        X02 = np.array([bx, p[0], p[1]])
        dX02[0, 1] = dX02[1, 2] = 1.0
    elif parameters == "independent":
        R1, d1 = rotation_and_derivatives(np.array([0.0, p[0], p[1]]))
        dR1[0], dR1[1] = d1[1], d1[2]
        R2, d2 = rotation_and_derivatives(np.array([p[3], p[2], p[4]]))
        dR2[2], dR2[3], dR2[4] = d2[1], d2[0], d2[2]
        X02 = np.array([bx, 0.0, 0.0])
    else:
        raise ValueError(f"parameters must be 'dependent' or 'independent', got {parameters!r}")
    return R1, dR1, R2, dR2, X02, dX02


def _rays(l: np.ndarray, interior_left, interior_right):
    c1, xp1, yp1 = interior_left
    c2, xp2, yp2 = interior_right
    n = l.shape[0]
    u1 = np.column_stack([l[:, 0] - xp1, l[:, 1] - yp1, np.full(n, -c1)])
    u2 = np.column_stack([l[:, 2] - xp2, l[:, 3] - yp2, np.full(n, -c2)])
    return u1, u2


def coplanarity_condition(l, p, parameters: str, bx: float, interior_left, interior_right=None):
    """Coplanarity condition of every point and its derivatives.

    Parameters
    ----------
    l : (n, 4) image coordinates ``x_left, y_left, x_right, y_right`` (mm).
    p : (5,) orientation parameters (see :data:`PARAMETER_NAMES`).
    interior_left, interior_right : ``(c, xp, yp)`` in mm (right defaults to left).

    Returns
    -------
    F : (n,) ``b · (a1 × a2)``; A : (n, 5) ``∂F/∂p``; B : (n, 4) ``∂F/∂l``.
    """
    interior_right = interior_left if interior_right is None else interior_right
    l = np.asarray(l, dtype=float).reshape(-1, 4)
    R1, dR1, R2, dR2, b, db = pair_poses(p, parameters, bx)
    u1, u2 = _rays(l, interior_left, interior_right)
    a1, a2 = u1 @ R1, u2 @ R2  # rows of R_kᵀ u_k
    cr = np.cross(a1, a2)
    F = cr @ b
    g1 = np.cross(a2, b)  # ∂F/∂a1
    g2 = np.cross(b, a1)  # ∂F/∂a2
    A = np.empty((l.shape[0], 5))
    for j in range(5):
        A[:, j] = cr @ db[j] + np.einsum("ni,ni->n", u1 @ dR1[j], g1) + np.einsum("ni,ni->n", u2 @ dR2[j], g2)
    B = np.column_stack([(g1 @ R1.T)[:, :2], (g2 @ R2.T)[:, :2]])
    return F, A, B


def parameters_from_poses(R_right_from_left: np.ndarray, base_in_left: np.ndarray, parameters: str,
                          bx: float) -> np.ndarray:
    """The 5 parameters of a given relative geometry.

    ``R_right_from_left`` rotates left-camera vectors into the right camera; ``base_in_left`` is the
    right projection centre in the left camera frame (any positive scale).  For ``dependent`` the
    base is scaled so that its x-component is ``bx`` (a base with no x-component cannot be
    expressed: ``ValueError``).
    """
    b = np.asarray(base_in_left, dtype=float)
    if parameters == "dependent":
        if abs(b[0]) < 1e-9 * np.linalg.norm(b) or np.sign(b[0]) != np.sign(bx):
            raise ValueError("the base has no x-component of the sign of bx")
        b = b * (bx / b[0])
        return np.r_[b[1], b[2], opk_from_rotation(R_right_from_left)]
    nb = b / np.linalg.norm(b)
    phi1 = np.arcsin(np.clip(nb[2], -1, 1))
    kappa1 = np.arctan2(-nb[1], nb[0])
    R1 = rotation_from_opk(0.0, phi1, kappa1)  # R_left_from_model
    o2 = opk_from_rotation(R_right_from_left @ R1)
    return np.array([phi1, kappa1, o2[1], o2[0], o2[2]])


def _essential_candidates(u1: np.ndarray, u2: np.ndarray):
    """Relative geometries from the linear 8-point essential matrix (baarda's camera frames).

    Returns a list of ``(R_right_from_left, base_in_left)`` (usually one: the decomposition whose
    triangulated points lie in front of both cameras), or ``[]`` when fewer than 8 points are
    given or the points are degenerate for the 8-point method (e.g. coplanar object points).
    """
    n = u1.shape[0]
    if n < 8:
        return []
    v1 = u1 / -u1[:, 2:3]
    v2 = u2 / -u2[:, 2:3]
    # u2ᵀ E u1 = 0 with E = R [t]×  (t = right centre in the left frame)
    D = np.einsum("ni,nj->nij", v2, v1).reshape(n, 9)
    s, Vt = np.linalg.svd(D, full_matrices=True)[1:]
    if s.size < 8 or s[7] < 1e-8 * s[0]:
        return []
    E = Vt[-1].reshape(3, 3)
    U, _, Wt = np.linalg.svd(E)
    if np.linalg.det(U) < 0:
        U = -U
    if np.linalg.det(Wt) < 0:
        Wt = -Wt
    W = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    best, best_count = None, -1
    for R in (U @ W @ Wt, U @ W.T @ Wt):
        for t in (U[:, 2], -U[:, 2]):
            base = -R.T @ t  # t = −R · base
            d2 = v2 @ R  # rows Rᵀ v2
            # λ1 v1 − λ2 d2 = base, least squares per point
            M = np.stack([v1, -d2], axis=2)  # (n, 3, 2)
            MtM = np.einsum("nia,nib->nab", M, M)
            Mtb = np.einsum("nia,i->na", M, base)
            ok = np.abs(np.linalg.det(MtM)) > 1e-15
            lam = np.zeros((n, 2))
            lam[ok] = np.linalg.solve(MtM[ok], Mtb[ok][..., None])[..., 0]
            count = int(np.sum((lam[:, 0] > 0) & (lam[:, 1] > 0)))
            if count > best_count:
                best, best_count = (R, base), count
    return [best] if best is not None else []


def initial_candidates(l, parameters: str, bx: float, interior_left, interior_right=None,
                       initial: str = "auto", fixed_bx: bool = True) -> list[tuple[str, np.ndarray, float]]:
    """Initial values ``(label, p0, bx)``: ``zero`` (normal case: all angles and by, bz zero) and/or
    ``essential`` (8-point essential matrix, ≥ 8 points).  Unless ``fixed_bx``, the essential
    candidate takes the sign of ``bx`` from its own base (the x-parallax only guesses it)."""
    interior_right = interior_left if interior_right is None else interior_right
    out = []
    if initial in ("auto", "zero"):
        out.append(("zero", np.zeros(5), bx))
    if initial in ("auto", "essential"):
        u1, u2 = _rays(np.asarray(l, float).reshape(-1, 4), interior_left, interior_right)
        for R, base in _essential_candidates(u1, u2):
            b = bx
            if not fixed_bx:
                b = abs(bx) if parameters == "independent" else abs(bx) * (1.0 if base[0] >= 0 else -1.0)
            try:
                out.append(("essential", parameters_from_poses(R, base, parameters, b), b))
            except ValueError:
                pass
    return out


def _cofactor(cov_left, cov_right, n, sigma0):
    """(n, 4, 4) cofactor matrices of the four coordinates of each point (cov / σ0²)."""
    Q = np.zeros((n, 4, 4))
    Q[:, :2, :2] = np.eye(2) if cov_left is None else np.asarray(cov_left, float).reshape(n, 2, 2)
    Q[:, 2:, 2:] = np.eye(2) if cov_right is None else np.asarray(cov_right, float).reshape(n, 2, 2)
    return Q / sigma0 ** 2


def _conditioning(N: np.ndarray, names, what: str, min_rcond: float, check: bool = True, *,
                  scale: np.ndarray, gross: np.ndarray | None = None) -> float:
    """Reciprocal condition number (≥ 0) of the unit-diagonal scaled N; raise when below ``min_rcond``.

    A parameter is undetermined when its information ``N_jj`` (made dimensionless by the step
    ``scale``: base components relative to bx) is at most :data:`UNDETERMINED` of the largest,
    or, for a Schur complement, of its own information before the point unknowns were eliminated
    (``gross``): what is left is rounding.  Dividing by such a diagonal would make the scaled
    matrix meaningless, so it is named instead.  With ``check`` False (a run that did not
    converge) nothing is raised and a singular system reports 0.
    """
    N = np.asarray(N, float)
    if not np.all(np.isfinite(N)):
        if not check:
            return 0.0
        raise AdjustmentError(f"{what}: the normal equations are not finite: {CRITICAL_HINT}")
    s2 = np.asarray(scale, float) ** 2
    info = np.diag(N) * s2
    ref = np.full(info.shape, np.max(info, initial=0.0))
    if gross is not None:
        ref = np.maximum(ref, np.diag(gross) * s2)
    lost = info <= UNDETERMINED * ref
    if lost.any():
        if not check:
            return 0.0
        which = ", ".join(names[j] for j in np.flatnonzero(lost))
        raise AdjustmentError(
            f"{what}: the normal equations are singular: the image coordinates do not determine "
            f"{which}: {CRITICAL_HINT}")
    d = np.sqrt(np.diag(N))
    with np.errstate(over="ignore"):
        Ns = N / d[:, None] / d[None, :]
    try:
        if not np.all(np.isfinite(Ns)):
            raise np.linalg.LinAlgError("scaled normal matrix not finite")
        w, V = np.linalg.eigh(Ns)
    except np.linalg.LinAlgError as e:
        if not check:
            return 0.0
        raise AdjustmentError(f"{what}: the normal equations are singular ({e}): {CRITICAL_HINT}") from None
    rcond = float(max(w[0], 0.0) / w[-1]) if w[-1] > 0 else 0.0
    if check and not rcond >= min_rcond:
        combo = V[:, 0] / d
        combo = combo / np.max(np.abs(combo))
        terms = " ".join(f"{c:+.2g}·{names[j]}" for j, c in enumerate(combo) if abs(c) > 1e-3)
        raise AdjustmentError(
            f"{what}: the normal equations are singular or nearly so (reciprocal condition "
            f"{rcond:.1e} < {min_rcond:.0e}): {CRITICAL_HINT}; the combination {terms} is not "
            "determined by the image coordinates")
    return rcond


@dataclass(frozen=True, eq=False)
class RelativeOrientation:
    """Result of :func:`relative_orientation` (model frame: left projection centre at the origin).

    Attributes
    ----------
    name : label of the pair (used in messages and snapshot labels).
    method : ``"coplanarity"`` or ``"collinearity"``; parameters : ``"dependent"``/``"independent"``.
    param_names : the 5 names; p : (5,) estimates (angles in radians); Qpp : (5, 5) cofactor matrix
        (covariance = σ0² Qpp a priori, σ̂0² Qpp a posteriori).
    bx : the fixed base component (model scale).
    R_left, R_right : (3, 3) ``R_cam_from_model``; X0_left (origin), X0_right : (3,).
    point_ids : (n,); xy : (n, 4) observed ``x_left, y_left, x_right, y_right``.
    v : (n, 4) image residuals observed − computed (nan for points not used).
    py : (n,) residual y-parallax ``F(l_observed, p̂) / g`` in mm, every point (used or not).
    XYZ : (n, 3) model coordinates by space intersection; cov_XYZ : (n, 3, 3) a priori.
    in_front : (n,) bool, the point lies in front of both cameras.
    sigma0_hat, dof, iterations, converged, rcond : adjustment figures.
    initial : which initial value won (``"zero"``, ``"essential"``, ``"given"``).
    snapshot : :class:`baarda.pipeline.stats.snapshot.Snapshot` (rows: points for coplanarity, image
        coordinates for collinearity).
    active : (n,) points used.
    """

    name: str
    method: str
    parameters: str
    param_names: tuple
    p: np.ndarray
    Qpp: np.ndarray
    bx: float
    R_left: np.ndarray
    R_right: np.ndarray
    X0_left: np.ndarray
    X0_right: np.ndarray
    point_ids: np.ndarray
    xy: np.ndarray
    v: np.ndarray
    py: np.ndarray
    XYZ: np.ndarray
    cov_XYZ: np.ndarray
    in_front: np.ndarray
    sigma0_hat: float
    dof: int
    iterations: int
    converged: bool
    rcond: float
    initial: str
    snapshot: Snapshot
    active: np.ndarray
    history: list = field(default_factory=list)
    _inputs: dict = field(default_factory=dict, repr=False)

    @property
    def R_right_from_left(self) -> np.ndarray:
        return self.R_right @ self.R_left.T

    @property
    def base_in_left(self) -> np.ndarray:
        """Right projection centre in the left camera frame."""
        return self.R_left @ (self.X0_right - self.X0_left)

    def std(self, a_posteriori: bool = True) -> np.ndarray:
        """(5,) standard deviations of the parameters (σ̂0 or σ0 scaled)."""
        s0 = self.sigma0_hat if a_posteriori and np.isfinite(self.sigma0_hat) else self.snapshot.sigma0
        return s0 * np.sqrt(np.diag(self.Qpp))

    def report(self) -> dict:
        """Small JSON-friendly summary."""
        d = {"name": self.name, "method": self.method, "parameters": self.parameters,
             "points": int(self.active.sum()), "dof": self.dof, "sigma0_hat": self.sigma0_hat,
             "iterations": self.iterations, "converged": self.converged, "rcond": self.rcond,
             "initial": self.initial, "bx": self.bx}
        for k, nm in enumerate(self.param_names):
            d[nm] = float(self.p[k])
        return d

    def refit(self, active) -> Snapshot:
        """Adjust again with the rows of the snapshot where ``active`` is True (Refittable)."""
        return self.rerun(active).snapshot

    def rerun(self, active) -> "RelativeOrientation":
        """The whole result for another set of active snapshot rows (starts from this solution)."""
        act = np.asarray(active, bool).reshape(-1)
        if act.shape[0] != self.snapshot.n:
            raise ValueError(f"active has {act.shape[0]} entries, the snapshot has {self.snapshot.n} rows")
        kw = dict(self._inputs)
        if self.method == "coplanarity":
            kw["active"] = act
        else:
            kw["active_rows"] = act.reshape(-1, 4)
        kw["initial"] = self.p
        return relative_orientation(**kw)


def relative_orientation(xy_left, xy_right, interior_left, interior_right=None, *,
                         cov_left=None, cov_right=None,
                         method: Literal["coplanarity", "collinearity"] = "coplanarity",
                         parameters: Literal["dependent", "independent"] = "dependent",
                         bx: float | None = None, initial: Any = "auto", point_ids=None,
                         sigma0: float = 1.0, active=None, active_rows=None, max_iter: int = 50,
                         tol: float = 1e-11, min_rcond: float = 1e-10,
                         name: str = "pair") -> RelativeOrientation:
    """Relative orientation of a stereo pair.

    Parameters
    ----------
    xy_left, xy_right : (n, 2) image coordinates of the same n points, mm (corrected for the
        principal point only through ``interior``; other corrections must already be applied).
    interior_left, interior_right : ``(c, xp, yp)`` mm; right defaults to left.
    cov_left, cov_right : (n, 2, 2) a-priori covariances, mm² (default identity, σ = 1 mm).
    method : ``"coplanarity"`` (Gauss–Helmert) or ``"collinearity"`` (model points unknown).
    parameters : ``"dependent"`` or ``"independent"`` (see the module docstring).
    bx : model scale: the fixed base component (default: the mean x-parallax ``x_left − x_right``
        of the used points, so that the model is roughly at photo scale, as in Wolf & DeWitt).
    initial : ``"auto"`` (zero angles and, with ≥ 8 points, the essential matrix; the converged
        solution with the most points in front of both cameras and the smallest vᵀPv wins),
        ``"zero"``, ``"essential"``, or a (5,) parameter vector.
    point_ids : (n,) labels (default ``"1" … "n"``).
    sigma0 : a-priori σ0.
    active : (n,) bool points to use (coplanarity and collinearity).
    active_rows : (n, 4) bool image coordinates to use (collinearity only).
    min_rcond : smallest accepted reciprocal condition of the scaled normal matrix; below it the
        configuration is reported as (nearly) critical.
    name : label used in messages, e.g. ``"model 11-12"``.

    Raises
    ------
    AdjustmentError : fewer than 5 points, critical configuration, no convergence.
    """
    xy_left = np.array(xy_left, dtype=float).reshape(-1, 2)
    xy_right = np.array(xy_right, dtype=float).reshape(-1, 2)
    n = xy_left.shape[0]
    if xy_right.shape[0] != n:
        raise ValueError(f"{name}: {n} left but {xy_right.shape[0]} right image points")
    interior_left = tuple(float(a) for a in interior_left)
    interior_right = interior_left if interior_right is None else tuple(float(a) for a in interior_right)
    l = np.hstack([xy_left, xy_right])
    ids = np.array([str(i + 1) for i in range(n)] if point_ids is None else [str(s) for s in point_ids])
    act = np.ones(n, bool) if active is None else np.array(active, bool).reshape(n)
    rows = np.ones((n, 4), bool) if active_rows is None else np.array(active_rows, bool).reshape(n, 4)
    if method == "collinearity":
        # a point needs three coordinates to be determined
        act = act & (rows.sum(axis=1) >= 3)
        rows = rows & act[:, None]
    act = act & np.all(np.isfinite(l), axis=1)
    if act.sum() < 5:
        raise AdjustmentError(
            f"{name}: relative orientation needs at least 5 points common to both photos, "
            f"got {int(act.sum())}" + (f" ({', '.join(ids[act])})" if act.any() else ""))
    fixed_bx = bx is not None
    if bx is None:
        bx = float(np.mean(l[act, 0] - l[act, 2]))
        if not abs(bx) > 1e-9 * interior_left[0]:
            raise AdjustmentError(f"{name}: the mean x-parallax is zero; give the model scale bx explicitly")
    bx = float(bx)
    inputs = dict(xy_left=xy_left, xy_right=xy_right, interior_left=interior_left,
                  interior_right=interior_right, cov_left=cov_left, cov_right=cov_right,
                  method=method, parameters=parameters, bx=bx, point_ids=ids, sigma0=sigma0,
                  active=act if method == "coplanarity" else None,
                  active_rows=rows if method == "collinearity" else None,
                  max_iter=max_iter, tol=tol, min_rcond=min_rcond, name=name)
    names = PARAMETER_NAMES[parameters]
    Q = _cofactor(cov_left, cov_right, n, sigma0)

    if isinstance(initial, str):
        cands = initial_candidates(l[act], parameters, bx, interior_left, interior_right, initial,
                                   fixed_bx=fixed_bx)
        if not cands:
            raise AdjustmentError(f"{name}: no initial value from {initial!r} "
                                  "(the essential matrix needs 8 points in general position)")
    else:
        cands = [("given", np.asarray(initial, float).reshape(5), bx)]

    solve = _solve_coplanarity if method == "coplanarity" else _solve_collinearity
    best, first_error = None, None
    for label, p0, bx_c in cands:
        try:
            sol = solve(l, Q, p0, parameters, bx_c, interior_left, interior_right, act, rows,
                        names, max_iter, tol, min_rcond, name)
        except AdjustmentError as e:
            first_error = first_error or e
            continue
        except np.linalg.LinAlgError as e:  # a singular 3×3 point block or normal matrix
            first_error = first_error or AdjustmentError(
                f"{name}: the normal equations are singular from the {label} initial values "
                f"({e}): {CRITICAL_HINT}")
            continue
        if not sol["converged"]:
            hint = (f"; the normal equations are poorly conditioned (reciprocal condition "
                    f"{sol['rcond']:.1e}): {CRITICAL_HINT}" if sol["rcond"] < WEAK_RCOND else "")
            first_error = first_error or AdjustmentError(
                f"{name}: relative orientation did not converge in {max_iter} iterations from "
                f"the {label} initial values{hint}")
            continue
        sol["initial"] = label
        sol["bx"] = bx_c
        key = (-sol["n_front"], sol["vtpv"])
        if best is None or key < best[0]:
            best = (key, sol)
    if best is None:
        raise first_error
    sol = best[1]
    if sol["n_front"] < 0.5 * act.sum():
        raise AdjustmentError(
            f"{name}: the relative orientation puts {int(act.sum()) - sol['n_front']} of "
            f"{int(act.sum())} points behind the cameras (from the {sol['initial']} initial values): "
            "are left and right swapped, or is the pair strongly convergent with fewer than 8 points? "
            "Give initial values")
    bx = inputs["bx"] = sol["bx"]
    return _finish(sol, l, Q, parameters, bx, interior_left, interior_right, act, rows, names,
                   ids, method, sigma0, name, inputs)


def _step_scale(bx: float, parameters: str) -> np.ndarray:
    return np.array([abs(bx), abs(bx), 1, 1, 1.0]) if parameters == "dependent" else np.ones(5)


def _small_step(dp, scale, fac, tol) -> bool:
    """Converged: the step is below ``tol`` (angles in rad, base components relative to bx), or
    below 1e-8 of the parameters' a-priori standard deviations (a poorly conditioned but regular
    system cannot reach the absolute tolerance in floating point)."""
    if np.max(np.abs(dp) / scale) < tol:
        return True
    sd = np.sqrt(np.maximum(np.diag(solve_normal(fac, np.eye(dp.size))), 0.0))
    return bool(np.all(np.abs(dp) <= 1e-8 * sd))


def _solve_coplanarity(l, Q, p0, parameters, bx, il, ir, act, rows, names, max_iter, tol,
                       min_rcond, name):
    """Rigorous Gauss–Helmert iteration (linearised at the adjusted observations)."""
    la = l[act]
    Qa = Q[act]
    lhat = la.copy()
    p = p0.copy()
    scale = _step_scale(bx, parameters)
    converged = False
    history = []
    rcond = np.nan
    for it in range(1, max_iter + 1):
        F, A, B = coplanarity_condition(lhat, p, parameters, bx, il, ir)
        w = F + np.einsum("ni,ni->n", B, la - lhat)
        M = np.einsum("ni,nij,nj->n", B, Qa, B)
        if not np.all(M > 0):
            raise AdjustmentError(f"{name}: degenerate coplanarity condition (rays along the base)")
        Wt = 1.0 / M
        N = A.T @ (A * Wt[:, None])
        if it == 1:
            _conditioning(N, names, name, min_rcond, scale=scale)
        fac = factor_normal_equations(N, names)
        dp = solve_normal(fac, -A.T @ (Wt * w))
        k = Wt * (A @ dp + w)
        e = -np.einsum("nij,nj->ni", Qa, B) * k[:, None]
        lhat = la + e
        p = p + dp
        history.append(float(e.ravel() @ np.linalg.solve(Qa, e[..., None])[..., 0].ravel()))
        if not np.all(np.isfinite(p)) or _small_step(dp, scale, fac, tol):
            converged = bool(np.all(np.isfinite(p)))
            break
    F, A, B = coplanarity_condition(lhat, p, parameters, bx, il, ir)
    M = np.einsum("ni,nij,nj->n", B, Qa, B)
    N = A.T @ (A / M[:, None])
    rcond = _conditioning(N, names, name, min_rcond, check=converged, scale=scale)
    e = lhat - la
    vtpv = float(np.einsum("ni,ni->", e, np.linalg.solve(Qa, e[..., None])[..., 0]))
    R1, _, R2, _, X02, _ = pair_poses(p, parameters, bx)
    n_front = _count_in_front(la, R1, R2, X02, il, ir)
    return {"p": p, "lhat": lhat, "iterations": it, "converged": converged, "vtpv": vtpv,
            "rcond": rcond, "n_front": n_front, "history": history}


def _count_in_front(la, R1, R2, X02, il, ir) -> int:
    u1, u2 = _rays(la, il, ir)
    d1, d2 = u1 @ R1, u2 @ R2
    Mx = np.stack([d1, -d2], axis=2)
    MtM = np.einsum("nia,nib->nab", Mx, Mx)
    Mtb = np.einsum("nia,i->na", Mx, X02)
    ok = np.abs(np.linalg.det(MtM)) > 1e-300
    lam = np.zeros((la.shape[0], 2))
    lam[ok] = np.linalg.solve(MtM[ok], Mtb[ok][..., None])[..., 0]
    return int(np.sum((lam[:, 0] > 0) & (lam[:, 1] > 0)))


def _image_weights(Q, rows):
    """(n, 4, 4) weights of the active image coordinates (marginal inverse per image point)."""
    n = Q.shape[0]
    P = np.zeros((n, 4, 4))
    for s in (slice(0, 2), slice(2, 4)):
        Qs = Q[:, s, s]
        rs = rows[:, s]
        both = rs.all(axis=1)
        Ps = np.zeros((n, 2, 2))
        if both.any():
            Ps[both] = np.linalg.inv(Qs[both])
        for j in range(2):
            one = rs[:, j] & ~rs[:, 1 - j]
            Ps[one, j, j] = 1.0 / Qs[one, j, j]
        P[:, s, s] = Ps
    return P


def _collinearity_rows(X, p, parameters, bx, il, ir):
    """Computed image coordinates (n, 4) and Jacobians by p (n, 4, 5) and by X (n, 4, 3)."""
    R1, dR1, R2, dR2, X02, dX02 = pair_poses(p, parameters, bx)
    n = X.shape[0]
    f = np.empty((n, 4))
    Jp = np.zeros((n, 4, 5))
    JX = np.zeros((n, 4, 3))
    for s, R, dR, X0, dX0, (c, xp, yp) in ((slice(0, 2), R1, dR1, np.zeros(3), np.zeros((5, 3)), il),
                                          (slice(2, 4), R2, dR2, X02, dX02, ir)):
        xy, d, _ = project_with_jacobian(X, X0, R, c, xp, yp)
        f[:, s] = xy
        JX[:, s] = d @ R
        dX = X - X0
        for j in range(5):
            duvw = dX @ dR[j].T - (R @ dX0[j])[None, :]
            Jp[:, s, j] = np.einsum("nab,nb->na", d, duvw)
    return f, Jp, JX


def _solve_collinearity(l, Q, p0, parameters, bx, il, ir, act, rows, names, max_iter, tol,
                        min_rcond, name):
    """Gauss–Newton with the model points as unknowns (points eliminated per 3×3 block)."""
    p = p0.copy()
    R1, _, R2, _, X02, _ = pair_poses(p, parameters, bx)
    X = space_intersection(np.stack([l[:, :2], l[:, 2:]], axis=1), np.stack([R1, R2]),
                           np.stack([np.zeros(3), X02]), [il[0], ir[0]], [il[1], ir[1]],
                           [il[2], ir[2]]).XYZ
    ia = np.flatnonzero(act)
    P = _image_weights(Q[ia], rows[ia])
    la = l[ia]
    X = X[ia]
    if not np.all(np.isfinite(X)):
        raise AdjustmentError(f"{name}: rays do not intersect at the initial orientation")
    scale = _step_scale(bx, parameters)
    converged = False
    history = []
    for it in range(1, max_iter + 1):
        f, Jp, JX = _collinearity_rows(X, p, parameters, bx, il, ir)
        r = la - f
        history.append(float(np.einsum("ni,nij,nj->", r, P, r)))
        JpP = np.einsum("nai,nab->nib", Jp, P)
        JXP = np.einsum("nai,nab->nib", JX, P)
        Npp = np.einsum("nib,nbj->ij", JpP, Jp)
        NpX = np.einsum("nib,nbj->nij", JpP, JX)
        NXX = np.einsum("nib,nbj->nij", JXP, JX)
        gp = np.einsum("nib,nb->i", JpP, r)
        gX = np.einsum("nib,nb->ni", JXP, r)
        NXXi = np.linalg.inv(NXX)
        S = Npp - np.einsum("nij,njk,nlk->il", NpX, NXXi, NpX)
        rhs = gp - np.einsum("nij,njk,nk->i", NpX, NXXi, gX)
        if it == 1:
            _conditioning(S, names, name, min_rcond, scale=scale, gross=Npp)
        fac = factor_normal_equations(0.5 * (S + S.T), names)
        dp = solve_normal(fac, rhs)
        dX = np.einsum("nij,nj->ni", NXXi, gX - np.einsum("nji,j->ni", NpX, dp))
        p = p + dp
        X = X + dX
        if not np.all(np.isfinite(p)) or _small_step(dp, scale, fac, tol):
            converged = bool(np.all(np.isfinite(p)))
            break
    f, Jp, JX = _collinearity_rows(X, p, parameters, bx, il, ir)
    r = la - f
    JpP = np.einsum("nai,nab->nib", Jp, P)
    NpX = np.einsum("nib,nbj->nij", JpP, JX)
    NXX = np.einsum("nai,nab,nbj->nij", JX, P, JX)
    Npp = np.einsum("nib,nbj->ij", JpP, Jp)
    S = Npp - np.einsum("nij,njk,nlk->il", NpX, np.linalg.inv(NXX), NpX)
    rcond = _conditioning(S, names, name, min_rcond, check=converged, scale=scale, gross=Npp)
    R1, _, R2, _, X02, _ = pair_poses(p, parameters, bx)
    n_front = _count_in_front(la, R1, R2, X02, il, ir)
    return {"p": p, "X": X, "iterations": it, "converged": converged,
            "vtpv": float(np.einsum("ni,nij,nj->", r, P, r)), "rcond": rcond,
            "n_front": n_front, "history": history}


def _finish(sol, l, Q, parameters, bx, il, ir, act, rows, names, ids, method, sigma0, name, inputs):
    n = l.shape[0]
    p = sol["p"]
    R1, _, R2, _, X02, _ = pair_poses(p, parameters, bx)
    inter = space_intersection(np.stack([l[:, :2], l[:, 2:]], axis=1), np.stack([R1, R2]),
                               np.stack([np.zeros(3), X02]), [il[0], ir[0]], [il[1], ir[1]],
                               [il[2], ir[2]], cov=_image_cov(Q * sigma0 ** 2))
    # residual y-parallax of the observed coordinates at the adjusted orientation (every point)
    F, A, B = coplanarity_condition(l, p, parameters, bx, il, ir)
    g = 0.5 * (B[:, 3] - B[:, 1])
    py = F / g
    ia = np.flatnonzero(act)
    v = np.full((n, 4), np.nan)
    if method == "coplanarity":
        v[ia] = l[ia] - sol["lhat"]
        # statistics rows: one per point, the y-parallax pseudo-observation
        Fa, Aa, Ba = coplanarity_condition(sol["lhat"], p, parameters, bx, il, ir)
        A[ia], B[ia] = Aa, Ba
        g = 0.5 * (B[:, 3] - B[:, 1])
        lrow = F / g  # inactive points: predicted y-parallax
        lrow[ia] = np.einsum("ni,ni->n", Ba, v[ia]) / g[ia]
        M = np.einsum("ni,nij,nj->n", B, Q, B)
        lm = LinearModel(A / g[:, None], lrow, P=g ** 2 / M, sigma0=sigma0,
                         labels=[f"{name} point {i} py" for i in ids], names=list(names))
        adj = lm.adjust(act)
        Qpp = adj.Qxx
        meta = {"kind": "relative-orientation", "method": method, "rows": "y-parallax per point",
                "unit": "mm"}
        snap = _with_meta(adj.snapshot, meta)
    else:
        X = np.full((n, 3), np.nan)
        X[ia] = sol["X"]
        Xall = np.where(act[:, None], X, inter.XYZ)
        f, Jp, JX = _collinearity_rows(np.nan_to_num(Xall), p, parameters, bx, il, ir)
        res = l - f
        v[ia] = np.where(rows[ia], res[ia], np.nan)
        # rows of point i: 4i..4i+3; unknowns: p then X of each used point
        col_of = -np.ones(n, int)
        col_of[ia] = np.arange(ia.size)
        u = 5 + 3 * ia.size
        rr, cc, vals = [], [], []
        for i in range(n):
            for a in range(4):
                rr += [4 * i + a] * 5
                cc += list(range(5))
                vals += list(Jp[i, a])
                if col_of[i] >= 0:
                    rr += [4 * i + a] * 3
                    cc += list(range(5 + 3 * col_of[i], 8 + 3 * col_of[i]))
                    vals += list(JX[i, a])
        Am = sp.csr_matrix((vals, (rr, cc)), shape=(4 * n, u))
        Pfull = _image_weights(Q, np.ones((n, 4), bool))
        Pm = sp.block_diag(list(Pfull)).toarray() if np.any(Pfull[:, 0, 1] != 0) or np.any(
            Pfull[:, 2, 3] != 0) else np.einsum("nii->ni", Pfull).reshape(-1)
        labels = [f"{name} point {i} {c}" for i in ids for c in ("x_left", "y_left", "x_right", "y_right")]
        group = np.repeat(np.arange(2 * n), 2)
        pnames = list(names) + [f"{name} point {ids[i]} {c}" for i in ia for c in "XYZ"]
        lm = LinearModel(Am, np.nan_to_num(res).reshape(-1), P=Pm, sigma0=sigma0, labels=labels,
                         group=group, names=pnames)
        adj = lm.adjust(rows.reshape(-1))
        Qpp = adj.Qxx[:5, :5]
        snap = _with_meta(adj.snapshot, {"kind": "relative-orientation", "method": method,
                                          "rows": "image coordinates", "unit": "mm"})
    s0h = snap.sigma0_hat
    XYZ = inter.XYZ.copy()
    if method == "collinearity":  # the adjusted points (a removed coordinate does not enter)
        XYZ[ia] = sol["X"]
    return RelativeOrientation(
        name=name, method=method, parameters=parameters, param_names=tuple(names), p=p,
        Qpp=0.5 * (Qpp + Qpp.T), bx=bx, R_left=R1, R_right=R2, X0_left=np.zeros(3), X0_right=X02,
        point_ids=ids, xy=l, v=v, py=py, XYZ=XYZ, cov_XYZ=inter.cov,
        in_front=inter.in_front.all(axis=1), sigma0_hat=s0h, dof=snap.dof,
        iterations=sol["iterations"], converged=sol["converged"], rcond=sol["rcond"],
        initial=sol["initial"], snapshot=snap, active=act.copy(), history=sol["history"],
        _inputs=inputs)


def _image_cov(Q):
    """(n, 2, 2, 2): per point, per photo covariance from the (n, 4, 4) matrices."""
    return np.stack([Q[:, :2, :2], Q[:, 2:, 2:]], axis=1)


def _with_meta(snap: Snapshot, extra: dict) -> Snapshot:
    import dataclasses

    return dataclasses.replace(snap, meta={**snap.meta, **extra})


def model_covariance(ro: RelativeOrientation, points=None) -> tuple[np.ndarray, np.ndarray]:
    """Covariance of the model coordinates including the uncertainty of the orientation.

    The collinearity equations of the pair are linearised at the solution (the same optimum for
    every method), the joint cofactor matrix of the 5 parameters and the model points is propagated
    to the coordinates of the points *and both projection centres*, and then S-transformed to the
    minimum-trace datum of a 3-D similarity (inner constraints over all these points).  That removes
    what depends on the orientation's arbitrary datum (left photo fixed, bx fixed), which the block
    adjustment's 7 parameters per model absorb anyway.

    Parameters
    ----------
    ro : a relative orientation; points : (k,) indices of the points to use (default: the used,
        intersected points).

    Returns
    -------
    idx : (k,) the point indices; cov : (k + 2, 3, 3) a-priori covariance (σ0² Q) of those points,
        then the left and the right projection centre.  Correlations between points are dropped.
    """
    inp = ro._inputs
    il, ir = inp["interior_left"], inp["interior_right"]
    if points is None:
        points = np.flatnonzero(ro.active & np.all(np.isfinite(ro.XYZ), axis=1))
    idx = np.asarray(points, int)
    n = idx.size
    Q = _cofactor(inp["cov_left"], inp["cov_right"], len(ro.point_ids), inp["sigma0"])[idx]
    rows = inp.get("active_rows")
    P = _image_weights(Q, np.ones((n, 4), bool) if rows is None else rows[idx])
    X = ro.XYZ[idx]
    _, Jp, JX = _collinearity_rows(X, ro.p, ro.parameters, ro.bx, il, ir)
    # joint cofactors by the Schur complement over the 3 × 3 point blocks:
    # Q_XiXj = δij NXXi⁻¹ + Ai Qpp Ajᵀ,  Q_Xip = −Ai Qpp,  Ai = NXXi⁻¹ NXpi
    Npp = np.einsum("nai,nab,nbj->ij", Jp, P, Jp)
    NXp = np.einsum("nai,nab,nbj->nij", JX, P, Jp)
    NXXi = np.linalg.inv(np.einsum("nai,nab,nbj->nij", JX, P, JX))
    Ai = NXXi @ NXp
    S = Npp - np.einsum("nji,njk->ik", NXp, Ai)
    Qpp = solve_normal(factor_normal_equations(0.5 * (S + S.T), list(ro.param_names)), np.eye(5))
    # coordinates c = [X_1 … X_n, X0_left, X0_right(p)]:  C = D + B Qpp Bᵀ (D block diagonal)
    m = n + 2
    D = np.zeros((m, 3, 3))
    D[:n] = NXXi
    B = np.zeros((m, 3, 5))
    B[:n] = Ai
    B[n + 1] = -pair_poses(ro.p, ro.parameters, ro.bx)[5].T
    # S-transform to the minimum-trace similarity datum: S = I − G (GᵀG)⁻¹ Gᵀ
    coords = np.vstack([X, ro.X0_left, ro.X0_right])
    d = coords - coords.mean(axis=0)
    d = d / np.sqrt(np.mean(np.sum(d ** 2, axis=1)))
    G = np.zeros((m, 3, 7))
    G[:, :, :3] = np.eye(3)
    G[:, 0, 4], G[:, 0, 5], G[:, 0, 6] = d[:, 2], -d[:, 1], d[:, 0]
    G[:, 1, 3], G[:, 1, 5], G[:, 1, 6] = -d[:, 2], d[:, 0], d[:, 1]
    G[:, 2, 3], G[:, 2, 4], G[:, 2, 6] = d[:, 1], -d[:, 0], d[:, 2]
    H = np.linalg.inv(np.einsum("mai,maj->ij", G, G))
    GtB = np.einsum("mai,maj->ij", G, B)  # (7, 5)
    GtC = np.einsum("mai,mab->mib", G, D) + np.einsum("ij,jk,mak->mia", GtB, Qpp, B)  # blocks (m, 7, 3)
    GtCG = np.einsum("mib,mbj->ij", GtC, G)
    Cii = D + np.einsum("mai,ij,mbj->mab", B, Qpp, B)
    GH = G @ H  # (m, 3, 7)
    T = np.einsum("mai,mib->mab", GH, GtC)
    cov = (Cii - T - np.swapaxes(T, 1, 2) + np.einsum("mai,ij,mbj->mab", GH, GtCG, GH)) * inp["sigma0"] ** 2
    return idx, 0.5 * (cov + np.swapaxes(cov, 1, 2))
