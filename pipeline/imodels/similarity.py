"""3-D similarity (7-parameter, conformal) transformation.

    X = s · Mᵀ · x + T,      M = R_src_from_dst = R3(κ) R2(φ) R1(ω)

``x`` are source (e.g. model) coordinates, ``X`` destination (e.g. object) coordinates.  ``M`` is
built from ω, φ, κ exactly like a camera's ``R_cam_from_world`` (``docs/conventions.md``): the
source frame plays the part of the camera frame.  This is also Wolf & DeWitt's form
(``X = s Mᵀ x + T`` in their 3DCONF program).

* :func:`similarity_closed_form` — Horn/Umeyama: the weighted least-squares solution in closed form
  (minimises ``Σ w_i |X_i − s Mᵀ x_i − T|²``); used for initial values.
* :func:`similarity_transform` — Gauss–Markov adjustment with ``X`` as the observations (any subset
  of coordinates, weighted, correlated within a point), residuals observed − computed, σ̂0,
  redundancy and a statistics :class:`~baarda.pipeline.stats.snapshot.Snapshot`.  With all coordinates
  observed and equal weights it converges to the closed-form solution, which the tests use.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from baarda.pipeline.errors import AdjustmentError
from baarda.pipeline.stats.linear import LinearModel, factor_normal_equations, solve_normal
from baarda.pipeline.stats.snapshot import Snapshot

from baarda.pipeline.geometry.transforms import (PARAMETER_NAMES, apply_similarity, rotation_and_derivatives_one,
                                                 similarity_closed_form, similarity_jacobian)

rotation_and_derivatives = rotation_and_derivatives_one

__all__ = ["PARAMETER_NAMES", "similarity_closed_form", "similarity_transform", "SimilarityTransform",
           "similarity_jacobian", "apply_similarity"]

@dataclass(frozen=True, eq=False)
class SimilarityTransform:
    """Result of :func:`similarity_transform`.

    params : (7,) ``scale, ω, φ, κ, tx, ty, tz`` (radians); Qxx : (7, 7) cofactor matrix.
    R_src_from_dst : (3, 3) ``M``.  point_ids : (n,); residuals : (n, 3) observed − computed in
    the destination frame (nan where a coordinate is not observed or not used).
    sigma0_hat, dof, iterations, converged; snapshot : rows = used destination coordinates.
    """

    params: np.ndarray
    Qxx: np.ndarray
    R_src_from_dst: np.ndarray
    point_ids: np.ndarray
    residuals: np.ndarray
    sigma0_hat: float
    dof: int
    iterations: int
    converged: bool
    snapshot: Snapshot
    rows: np.ndarray
    _inputs: dict = field(default_factory=dict, repr=False)

    @property
    def scale(self) -> float:
        return float(self.params[0])

    @property
    def opk(self) -> np.ndarray:
        return self.params[1:4].copy()

    @property
    def T(self) -> np.ndarray:
        return self.params[4:7].copy()

    def std(self, a_posteriori: bool = True) -> np.ndarray:
        s0 = self.sigma0_hat if a_posteriori and np.isfinite(self.sigma0_hat) else self.snapshot.sigma0
        return s0 * np.sqrt(np.diag(self.Qxx))

    def transform(self, x_src, a_posteriori: bool = True):
        """Transformed points (n, 3) and their standard deviations (n, 3) from the parameters'
        covariance (the source coordinates taken as error-free, as in Wolf & DeWitt)."""
        X, J = similarity_jacobian(self.params, x_src)
        s0 = self.sigma0_hat if a_posteriori and np.isfinite(self.sigma0_hat) else self.snapshot.sigma0
        var = np.einsum("nai,ij,naj->na", J, self.Qxx, J)
        return X, s0 * np.sqrt(np.maximum(var, 0.0))

    def refit(self, active) -> Snapshot:
        """Adjust again with the snapshot rows where ``active`` is True (Refittable)."""
        act = np.asarray(active, bool).reshape(-1)
        if act.shape[0] != self.rows.shape[0]:
            raise ValueError(f"active has {act.shape[0]} entries, the snapshot has {self.rows.shape[0]} rows")
        kw = dict(self._inputs, mask=(act & self.rows).reshape(-1, 3), initial=self.params)
        return similarity_transform(**kw).snapshot


def similarity_transform(x_src, X_dst, *, mask=None, cov=None, sigma=None, sigma0: float = 1.0,
                         initial=None, point_ids=None, max_iter: int = 50, tol: float = 1e-12,
                         what: str = "3-D similarity transformation") -> SimilarityTransform:
    """Least-squares 3-D similarity transformation, the destination coordinates observed.

    Parameters
    ----------
    x_src : (n, 3) source coordinates (error-free).
    X_dst : (n, 3) observed destination coordinates (nan where unknown).
    mask : (n, 3) bool, which destination coordinates are observations (default: the finite ones).
    cov : (n, 3, 3) a-priori covariance of X_dst, or ``sigma`` (n, 3) / scalar standard deviations
        (default 1: equal weights).
    initial : (7,) start; default :func:`similarity_closed_form` on the fully observed points.
    point_ids : (n,) labels.

    Raises
    ------
    AdjustmentError : fewer than 7 observed coordinates or a singular configuration.
    """
    x = np.array(x_src, float).reshape(-1, 3)
    X = np.array(X_dst, float).reshape(-1, 3)
    n = x.shape[0]
    ids = np.array([str(i + 1) for i in range(n)] if point_ids is None else [str(s) for s in point_ids])
    obs = np.isfinite(X) & np.all(np.isfinite(x), axis=1)[:, None]
    mask = obs if mask is None else (np.asarray(mask, bool).reshape(n, 3) & obs)
    if cov is None:
        sd = np.broadcast_to(np.asarray(1.0 if sigma is None else sigma, float), (n, 3))
        C = np.zeros((n, 3, 3))
        C[:, [0, 1, 2], [0, 1, 2]] = sd ** 2
    else:
        C = np.asarray(cov, float).reshape(n, 3, 3)
    inputs = dict(x_src=x, X_dst=X, cov=C, sigma0=sigma0, point_ids=ids, max_iter=max_iter,
                  tol=tol, what=what)
    if mask.sum() < 7:
        raise AdjustmentError(f"{what}: needs at least 7 observed coordinates (e.g. two full and "
                              f"one height control point), got {int(mask.sum())}")
    if initial is None:
        full = mask.all(axis=1)
        if full.sum() < 3:
            raise AdjustmentError(f"{what}: initial values need 3 points with X, Y and Z observed "
                                  f"(got {int(full.sum())}); give initial values")
        p = similarity_closed_form(x[full], X[full], what=what)
    else:
        p = np.array(initial, float).reshape(7)
    rows = mask.reshape(-1)
    idx = np.flatnonzero(rows)
    # weights of the observed coordinates: marginal inverse of each point's covariance
    Sig = np.zeros((3 * n, 3 * n))
    for i in range(n):
        Sig[3 * i:3 * i + 3, 3 * i:3 * i + 3] = C[i]
    Sa = Sig[np.ix_(idx, idx)]
    Pa = np.linalg.inv(Sa) * sigma0 ** 2
    names = list(PARAMETER_NAMES)
    Xa = X.reshape(-1)[idx]
    converged = False
    it = 0
    for it in range(1, max_iter + 1):
        f, J = similarity_jacobian(p, x)
        A = J.reshape(3 * n, 7)[idx]
        r = Xa - f.reshape(-1)[idx]
        N = A.T @ Pa @ A
        dp = solve_normal(factor_normal_equations(N, names), A.T @ Pa @ r)
        p = p + dp
        if np.max(np.abs(dp) / np.r_[max(abs(p[0]), 1e-300), 1, 1, 1, np.full(3, max(1.0, np.abs(Xa).max()))]) < tol:
            converged = True
            break
    if not converged:
        raise AdjustmentError(f"{what} did not converge in {max_iter} iterations from the given "
                              "initial values")
    f, J = similarity_jacobian(p, x)
    A = J.reshape(3 * n, 7)
    res = np.nan_to_num(X.reshape(-1) - f.reshape(-1))
    diag_only = all(np.count_nonzero(C[i] - np.diag(np.diag(C[i]))) == 0 for i in range(n))
    P = (sigma0 ** 2 / np.where(np.diag(Sig) > 0, np.diag(Sig), 1.0)) if diag_only else np.linalg.inv(Sig) * sigma0 ** 2
    labels = [f"point {i} {c}" for i in ids for c in "XYZ"]
    adj = LinearModel(A, res, P=P, sigma0=sigma0, labels=labels, names=names).adjust(rows)
    snap = dataclasses.replace(adj.snapshot, meta={**adj.snapshot.meta, "kind": "3-D similarity"})
    residuals = np.where(mask, res.reshape(n, 3), np.nan)
    return SimilarityTransform(
        params=p, Qxx=adj.Qxx, R_src_from_dst=rotation_and_derivatives(p[1:4])[0], point_ids=ids,
        residuals=residuals, sigma0_hat=snap.sigma0_hat, dof=snap.dof, iterations=it,
        converged=converged, snapshot=snap, rows=rows, _inputs=inputs)
