"""The compiled per-observation kernels (``pipeline/adjustment/kernels.py``) against the numpy
formulas they replace, written out here independently, on random data (with repeated points,
observations of no eliminated point and fixed columns)."""

from __future__ import annotations

import numpy as np

from baarda.pipeline.camera import kernels as camera_kernels
import pytest

from baarda.pipeline.adjustment import kernels

RNG_SEED = 20261125


@pytest.fixture
def rng():
    return np.random.default_rng(RNG_SEED)


def _rotations(rng, m):
    Q = np.linalg.qr(rng.normal(size=(m, 3, 3)))[0]
    return Q * np.sign(np.linalg.det(Q))[:, None, None]


def test_project_is_the_collinearity_formula(rng):
    k, m, n, K = 200, 5, 40, 2
    XYZ = rng.normal(size=(n, 3)) * 10
    X0 = rng.normal(size=(m, 3)) + [0, 0, 30]
    R = _rotations(rng, m)
    pt, ph, cam = rng.integers(0, n, k), rng.integers(0, m, k), rng.integers(0, K, k)
    cp = rng.normal(size=(K, 6)) + [50, 0, 0, 0, 0, 0]
    d, xbar, xy = kernels.project(XYZ, X0, R, pt, ph, cam, cp)
    d_ref = np.einsum("kij,kj->ki", R[ph], XYZ[pt] - X0[ph])
    xbar_ref = -cp[cam, 0, None] * d_ref[:, :2] / d_ref[:, 2:]
    np.testing.assert_allclose(d, d_ref, rtol=1e-14, atol=1e-12)
    np.testing.assert_allclose(xbar, xbar_ref, rtol=1e-13)
    np.testing.assert_allclose(xy, cp[cam, 1:3] + xbar_ref, rtol=1e-13)


@pytest.mark.parametrize("with_model", [False, True])
def test_eo_point_jacobians_match_finite_differences(rng, with_model):
    """J_point and the angle columns by central differences of d → x̄ (with a linear model
    Δ = A x̄, whose ∂Δ/∂x̄ = A), and (I + A) x̄ / c for the principal distance."""
    k, m = 30, 3
    R = _rotations(rng, m)
    X0 = rng.normal(size=(m, 3))
    XYZ = rng.normal(size=(k, 3)) * 5 + [0, 0, -40]
    ph = rng.integers(0, m, k)
    c = rng.uniform(20, 60, k)
    A = rng.normal(size=(k, 2, 2)) * 0.05 if with_model else None
    sv = rng.normal(size=(m, 3, 3))                   # any axial vectors: ∂d/∂angle_a = s_a × d

    def image(XYZ_, d_extra=None):
        d = np.einsum("kij,kj->ki", R[ph], XYZ_ - X0[ph])
        if d_extra is not None:
            d = d + d_extra
        xb = -c[:, None] * d[:, :2] / d[:, 2:]
        return xb + (np.einsum("kij,kj->ki", A, xb) if with_model else 0.0)

    d = np.einsum("kij,kj->ki", R[ph], XYZ - X0[ph])
    xbar = -c[:, None] * d[:, :2] / d[:, 2:]
    J_point, J_eo, J_c = kernels.eo_point_jacobians(d, xbar, c, A, R, sv, ph)
    h = 1e-6
    for j in range(3):
        dX = np.zeros(3)
        dX[j] = h
        fd = (image(XYZ + dX) - image(XYZ - dX)) / (2 * h)
        np.testing.assert_allclose(J_point[:, :, j], fd, rtol=1e-6, atol=1e-8)
        np.testing.assert_array_equal(J_eo[:, :, j], -J_point[:, :, j])
    for a in range(3):
        step = np.cross(sv[ph, a], d) * h
        fd = (image(XYZ, step) - image(XYZ, -step)) / (2 * h)
        np.testing.assert_allclose(J_eo[:, :, 3 + a], fd, rtol=1e-6, atol=1e-8)
    M = np.eye(2) + (A if with_model else 0.0)
    np.testing.assert_allclose(J_c, np.einsum("kij,kj->ki", np.broadcast_to(M, (k, 2, 2)), xbar / c[:, None]),
                               rtol=1e-14)


def test_point_normals_sum_per_point(rng):
    k, n_e = 300, 50
    Jp, e = rng.normal(size=(k, 2, 3)), rng.normal(size=(k, 2))
    pidx = rng.integers(0, n_e + 1, k)                # n_e: an observation of no eliminated point
    V, bp = kernels.point_normals(Jp, e, pidx, n_e)
    V_ref, bp_ref = np.zeros((n_e + 1, 3, 3)), np.zeros((n_e + 1, 3))
    np.add.at(V_ref, pidx, np.einsum("kra,krb->kab", Jp, Jp))
    np.add.at(bp_ref, pidx, np.einsum("kra,kr->ka", Jp, e))
    np.testing.assert_allclose(V, V_ref[:-1], rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(bp, bp_ref[:-1], rtol=1e-13, atol=1e-13)


def test_chol3_inv_and_its_failure(rng):
    A = rng.normal(size=(100, 3, 3))
    V = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(3)
    Li, ok = kernels.chol3_inv(V)
    assert ok
    np.testing.assert_allclose(Li, np.linalg.inv(np.linalg.cholesky(V)), rtol=1e-10, atol=1e-12)
    V[7] = np.diag([1.0, -1.0, 1.0])                  # not positive definite
    assert kernels.chol3_inv(V)[1] is False


def _dense_B(BkT, pidx, cols, n_g, n_e):
    """B (n_g, 3 n_e) from the per-observation blocks (column n_g and point n_e dropped)."""
    B = np.zeros((n_g + 1, 3 * (n_e + 1)))
    for i in range(len(BkT)):
        for a in range(3):
            np.add.at(B[:, 3 * pidx[i] + a], cols[i], BkT[i, a, :cols.shape[1]])
    return B[:n_g, :3 * n_e]


def _segments(rng, k, n_seg, q, n_g):
    cuts = np.sort(rng.choice(np.arange(1, k), n_seg - 1, replace=False))
    start = np.r_[0, cuts]
    end = np.r_[cuts, k]
    seg_cols = rng.integers(0, n_g + 1, (n_seg, q))   # shared and fixed (n_g) columns
    obs_cols = np.repeat(seg_cols, end - start, axis=0)
    return start, end, seg_cols, obs_cols


def test_schur_blocks_and_products_with_B(rng):
    k, n_e, q, n_g, n_seg = 400, 60, 9, 50, 7
    Jc, Jp = rng.normal(size=(k, 2, q)), rng.normal(size=(k, 2, 3))
    A = rng.normal(size=(n_e, 3, 3))
    Li = np.linalg.inv(np.linalg.cholesky(A @ np.swapaxes(A, 1, 2) + np.eye(3)))
    pidx = rng.integers(0, n_e + 1, k)
    BkT = kernels.schur_blocks(Jc, Jp, Li, pidx)
    Li1 = np.concatenate([Li, np.eye(3)[None]])
    ref = np.einsum("krb,kab,krj->kaj", Jp, Li1[pidx], Jc)          # (Jp L⁻ᵀ)ᵀ Jc
    np.testing.assert_allclose(BkT, ref, rtol=1e-12, atol=1e-12)
    start, end, seg_cols, obs_cols = _segments(rng, k, n_seg, q, n_g)
    B = _dense_B(BkT, pidx, obs_cols, n_g, n_e)
    z = rng.normal(size=(n_e, 3))
    np.testing.assert_allclose(kernels.b_matvec(BkT, z, pidx, start, end, seg_cols, n_g), B @ z.ravel(),
                               rtol=1e-12, atol=1e-12)
    x = rng.normal(size=n_g)
    np.testing.assert_allclose(kernels.b_rmatvec(BkT, x, pidx, start, end, seg_cols, n_e).ravel(), B.T @ x,
                               rtol=1e-12, atol=1e-12)


def test_pair_products(rng):
    k, q = 120, 7
    X = rng.normal(size=(k, 3, q))
    oa, ob = rng.integers(0, k, 90), rng.integers(0, k, 90)
    gs = np.array([0, 10, 10, 55])                    # one empty group
    ge = np.array([10, 10, 55, 90])
    S = np.full((4, q, q), np.nan)
    kernels.pair_products(X, oa, ob, gs, ge, 1, 4, S)
    assert np.isnan(S[0]).all()                       # outside g0 … g1 − 1: untouched
    for g in range(1, 4):
        ref = X[oa[gs[g]:ge[g]]].reshape(-1, q).T @ X[ob[gs[g]:ge[g]]].reshape(-1, q)
        np.testing.assert_allclose(S[g], ref, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("points", [True, False])
def test_linear_change(rng, points):
    k, q, n_g, n_e = 200, 9, 40, 30
    Jc, Jp = rng.normal(size=(k, 2, q)), rng.normal(size=(k, 2, 3))
    cidx = rng.integers(0, n_g + 1, (k, q))
    pidx = rng.integers(0, n_e + 1, k) if points else np.full(k, 0)
    dx, dp = rng.normal(size=n_g), rng.normal(size=(n_e, 3))
    got = kernels.linear_change(Jc, cidx, dx, Jp, pidx, dp if points else None)
    ref = np.einsum("krj,kj->kr", Jc, np.append(dx, 0.0)[cidx])
    if points:
        ref += np.einsum("kra,ka->kr", Jp, np.vstack([dp, np.zeros((1, 3))])[pidx])
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12)


def test_kernels_run_without_a_writable_cache(monkeypatch):
    """No cache locator (a read-only install without a user cache): compiled without caching."""
    from numba.core import caching

    monkeypatch.setattr(caching.FunctionCache._impl_class, "_locator_classes", [])

    def twice(a):
        return 2.0 * a

    f = kernels._jit(twice)
    assert f(np.arange(3.0)).tolist() == [0.0, 2.0, 4.0]
    assert f.compiled._cache.__class__.__name__ == "NullCache"


def test_add_blocks(rng):
    ng1, m = 13, 40
    flat = rng.integers(0, ng1 * ng1, m)              # repeated positions and the dropped row/column 12
    vals = rng.normal(size=m)
    out = np.zeros((ng1 + 2, ng1 + 2))                # larger than ng1 − 1: the border rows stay 0
    kernels.add_blocks(out, flat, vals, ng1, True)
    A = np.bincount(flat, vals, minlength=ng1 * ng1).reshape(ng1, ng1)
    ref = np.zeros_like(out)
    ref[:ng1 - 1, :ng1 - 1] = (A + A.T)[:-1, :-1]
    np.testing.assert_allclose(out, ref, rtol=1e-14, atol=1e-14)
    out2 = np.zeros((ng1 - 1, ng1 - 1))
    kernels.add_blocks(out2, flat.astype(np.int32), vals, ng1, False)
    np.testing.assert_allclose(out2, A[:-1, :-1], rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("diagonal", [True, False])
def test_whitened_columns(rng, diagonal):
    k = 150
    L = np.triu(rng.normal(size=(k, 2, 2))) if not diagonal else rng.normal(size=(k, 2, 2)) * np.eye(2)
    J_cam, J_eo, J_point = rng.normal(size=(k, 2, 2)), rng.normal(size=(k, 2, 6)), rng.normal(size=(k, 2, 3))
    se, spt = np.array([0, 1, 2, 4, 5]), np.array([2, 0])
    Jc, Jp = kernels.whitened(L, J_cam, J_eo, se, J_point, spt)
    J = np.concatenate([J_cam, J_eo[:, :, se], J_point[:, :, spt]], axis=2)
    np.testing.assert_allclose(Jc, L @ J, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(Jp, L @ J_point, rtol=1e-14, atol=1e-14)


def test_no_cache_when_the_source_changed_since_import(monkeypatch):
    """A kernels.py edited after this process imported it is not cached under the new stamp."""
    monkeypatch.setattr(kernels._jit, "imported_stamp", (0.0, 0))

    def thrice(a):
        return 3.0 * a

    f = kernels._jit(thrice)
    assert f(np.arange(2.0)).tolist() == [0.0, 3.0]
    assert f.compiled._cache.__class__.__name__ == "NullCache"


def _csc_front_case(rng, n=40, c0=12, c1=17):
    """A symmetric sparse matrix (sorted CSC) and the rows below columns c0 … c1 − 1."""
    import scipy.sparse as sp

    A = sp.random(n, n, density=0.15, random_state=np.random.RandomState(7), format="csc")
    K = (A + A.T + sp.eye(n)).tocsc()
    K.sort_indices()
    sub = K[:, c0:c1].tocoo()
    R = np.unique(sub.row[sub.row >= c1]).astype(np.intp)
    R = np.union1d(R, [n - 1, n - 3])                 # rows without an entry in these columns too
    return K, R


def test_front_assembles_the_csc_columns(rng):
    c0, c1 = 12, 17
    K, R = _csc_front_case(rng, c0=c0, c1=c1)
    F = kernels.front(K.indptr, K.indices, K.data, c0, c1, R)
    ns = c1 - c0
    ref = np.zeros((ns + len(R), ns + len(R)))        # the numpy assembly it replaces
    a, b = K.indptr[c0], K.indptr[c1]
    r = K.indices[a:b]
    cj = np.repeat(np.arange(ns), np.diff(K.indptr[c0:c1 + 1]))
    keep = r >= c0
    r, cj, v = r[keep], cj[keep], K.data[a:b][keep]
    ref[np.where(r < c1, r - c0, ns + np.searchsorted(R, r)), cj] = v
    assert np.array_equal(F, ref)
    F64 = kernels.front(K.indptr.astype(np.int64), K.indices.astype(np.int64), K.data, c0, c1, R)
    assert np.array_equal(F64, ref)


def test_extend_add_and_gather_block(rng):
    n, m = 30, 12
    F = rng.normal(size=(n, n))
    rel = np.sort(rng.choice(n, m, replace=False)).astype(np.intp)
    P = rng.normal(size=(m + 4, m + 4))
    U = P[4:, 4:]                                     # a strided view, as a child's update matrix is
    ref = F.copy()
    ref[np.ix_(rel, rel)] += U
    kernels.extend_add(F, rel, U)
    assert np.array_equal(F, ref)
    G = kernels.gather_block(F, rel)
    assert G.flags.c_contiguous
    assert np.array_equal(G, F[np.ix_(rel, rel)])


def _brown_invert_numpy(xb, yb, P, tol=1e-13, max_iter=30):
    """The numpy form of the ``brown-backward`` inversion (every point stepped until all converged)."""
    from baarda.pipeline.camera.models import BrownBackward

    corr = BrownBackward._correction
    gx, gy, _, _ = corr(xb, yb, P, False)
    mx, my = 2 * xb - gx, 2 * yb - gy
    scale = np.maximum(1.0, np.abs(xb) + np.abs(yb))
    for _ in range(max_iter):
        gx, gy, G, _ = corr(mx, my, P, True)
        rx, ry = gx - xb, gy - yb
        done = np.abs(rx) + np.abs(ry) <= tol * scale
        if done.all():
            break
        det = G[:, 0, 0] * G[:, 1, 1] - G[:, 0, 1] * G[:, 1, 0]
        mx, my = mx - (G[:, 1, 1] * rx - G[:, 0, 1] * ry) / det, my - (-G[:, 1, 0] * rx + G[:, 0, 0] * ry) / det
    return mx, my, done


def test_brown_invert_is_the_newton_iteration(rng):
    """Inside the format the compiled inversion is the numpy iteration's to the last bit and g(m) = x̄;
    beyond the fold of g (no inverse) it keeps the first-order value and says so."""
    from baarda.pipeline.camera.models import BrownBackward

    n = 500
    xb, yb = rng.uniform(-18, 18, n), rng.uniform(-12, 12, n)
    P = np.tile([-2.0e-4, 3.0e-7, -1.0e-10, 2.0e-5, -1.5e-5, 1.0e-4, -2.0e-4], (n, 1))
    mx, my, ok = camera_kernels.brown_invert(xb, yb, P, 1e-13, 30)
    rx, ry, done = _brown_invert_numpy(xb, yb, P)
    assert ok.all() and done.all()
    np.testing.assert_array_equal(mx, rx)
    np.testing.assert_array_equal(my, ry)
    gx, gy, _, _ = BrownBackward._correction(mx, my, P, False)
    assert np.abs(gx - xb).max() < 1e-12 and np.abs(gy - yb).max() < 1e-12
    # far outside the format a strong negative K1 folds g back: no inverse, the first-order value
    far = np.array([400.0]), np.array([300.0])
    Pf = np.array([[-1.0e-3, 0, 0, 0, 0, 0, 0]])
    mx, my, ok = camera_kernels.brown_invert(*far, Pf, 1e-13, 30)
    gx, gy, _, _ = BrownBackward._correction(*far, Pf, False)
    assert not ok[0] and mx[0] == 2 * far[0][0] - gx[0] and my[0] == 2 * far[1][0] - gy[0]
