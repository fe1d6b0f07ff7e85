"""Designs and helpers shared by the statistics tests (imported by conftest and tests)."""

import numpy as np

from baarda.pipeline.stats import LinearModel, Snapshot

XL = np.array([97.673, 128.692, 158.014, 93.523, 124.946, 156.755, 93.115, 124.410, 151.576])
YL = np.array([180.515, 180.423, 180.618, 160.744, 160.523, 159.548, 142.816, 141.949, 141.152])


def helmert_design(xl=XL, yl=YL):
    """Rows x1, y1, x2, y2, …; unknowns a, b, tx, ty (x' = a x − b y + tx, y' = b x + a y + ty)."""
    n = xl.size
    A = np.zeros((2 * n, 4))
    A[0::2] = np.c_[xl, -yl, np.ones(n), np.zeros(n)]
    A[1::2] = np.c_[yl, xl, np.zeros(n), np.ones(n)]
    labels = [f"{c}{i + 1}" for i in range(n) for c in "xy"]
    return A, labels, np.repeat(np.arange(n), 2)


def helmert_cov(n=9, seed=3):
    """Block-diagonal covariance: per point σx, σy in [0.5, 2] (relative), correlation in ±0.8."""
    g = np.random.default_rng(seed)
    C = np.zeros((2 * n, 2 * n))
    for i in range(n):
        sx, sy = g.uniform(0.5, 2.0, 2)
        rho = g.uniform(-0.8, 0.8)
        C[2 * i:2 * i + 2, 2 * i:2 * i + 2] = [[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]]
    return C


def helmert_model():
    A, labels, group = helmert_design()
    C = helmert_cov()
    P = np.linalg.inv(C)
    l = A @ np.array([1.0, 0.01, -22.0, -100.0])
    return LinearModel(A, l, P, sigma0=0.01, labels=labels, group=group)


def poly_model():
    x = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 2.2, 2.4, 3.0, 3.1, 3.3, 5.0, 9.0])
    A = np.vander(x, 4, increasing=True)
    n = x.size
    C = 0.6 ** np.abs(np.subtract.outer(np.arange(n), np.arange(n))) * np.outer(
        np.linspace(1, 2, n), np.linspace(1, 2, n))
    return LinearModel(A, A @ np.array([1.0, -2.0, 0.5, 0.1]), np.linalg.inv(C), sigma0=0.3)


def cov_of(model):
    """Σ_ll = σ0² P⁻¹ of a model."""
    P = model.P if model.kind == "full" else np.diag(model.P)
    return model.sigma0 ** 2 * np.linalg.inv(P)


def stacked(snap: Snapshot, Pv: np.ndarray, v: np.ndarray | None = None) -> Snapshot:
    """One snapshot holding many simulated data sets (rows of ``Pv``) with the design of ``snap``.

    The per-row quantities that do not depend on the data are tiled; group ids are made unique
    per data set; vᵀPv is meaningless (set to the total) — only row-wise tests may use it.
    """
    m, n = Pv.shape
    ng = int(snap.group.max()) + 1
    group = (np.where(snap.group >= 0, snap.group, -1)[None, :] + ng * np.arange(m)[:, None])
    group[:, snap.group < 0] = -1
    blocks = None
    if snap.PQvvP_blocks:
        blocks = {int(g + ng * k): b for k in range(m) for g, b in snap.PQvvP_blocks.items()}
    v = np.zeros_like(Pv) if v is None else v
    return Snapshot(v=v.ravel(), Pv=Pv.ravel(), PQvvP=np.tile(snap.PQvvP, m),
                    r=np.tile(snap.r, m), sigma_l=np.tile(snap.sigma_l, m), vtpv=float(np.sum(v * Pv)),
                    dof=snap.dof, sigma0=snap.sigma0, active=np.tile(snap.active, m),
                    group=group.ravel(), PQvvP_blocks=blocks)


def operators(model):
    """(R, G): v = R l and Pv = G l, built column by column with the library (linear in l)."""
    n = model.n
    R = np.zeros((n, n))
    G = np.zeros((n, n))
    P = model.P if model.kind != "identity" else None
    for j in range(n):
        e = np.zeros(n)
        e[j] = 1.0
        s = LinearModel(model.A, e, P, sigma0=model.sigma0).adjust().snapshot
        R[:, j], G[:, j] = s.v, s.Pv
    return R, G
