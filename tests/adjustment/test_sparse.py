"""The sparse route of the reduced camera system against dense linear algebra and the dense route.

* the supernodal Cholesky factorisation, its solves and its selected inversion against numpy's
  dense inverse of the same matrix (random block-sparse SPD matrices with a dense border);
* whole adjustments solved both ways (``BundleSettings.solver``): the same solution, redundancy
  numbers, ``P Qvv P`` blocks, point/orientation/camera covariances, predicted variances of
  left-out observations and cofactor columns — control datum, free networks (inner constraints on
  points and on projection centres: minimal constraints + S-transformation), self-calibration,
  scale bars;
* a singular sparse system names what is missing.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from baarda.pipeline.adjustment import BundleSettings, adjust
from baarda.pipeline.adjustment.settings import Distance
from baarda.pipeline.adjustment.sparse import NotPositiveDefinite, Symbolic, SupernodalCholesky
from baarda.pipeline.errors import AdjustmentError
from baarda.pipeline.synthetic.aerial import perturb_start, simulate_aerial, simulate_convergent


# ---- the factorisation ---------------------------------------------------------------------------
def _block_spd(rng, g=9, b=6, border=4, diag_shift=1.0):
    """A grid of g×g nodes of b columns (neighbours within ±1 row, ±2 columns) and one border node
    coupled to every node: the structure of an aerial block's reduced system."""
    N = g * g
    node = np.r_[np.repeat(np.arange(N), b), np.full(border, N)]
    n = len(node)
    cols_of = [np.flatnonzero(node == v) for v in range(N + 1)]
    R, C, V = [], [], []
    for i in range(g):
        for j in range(g):
            a = i * g + j
            nbrs = [(i + di) * g + (j + dj) for di in (0, 1) for dj in (-2, -1, 0, 1, 2)
                    if 0 <= i + di < g and 0 <= j + dj < g and (di, dj) > (0, 0)] + [N]
            for c in nbrs:
                M = rng.normal(size=(len(cols_of[a]), len(cols_of[c])))
                for x, y, m in ((cols_of[a], cols_of[c], M), (cols_of[c], cols_of[a], M.T)):
                    R.append(np.repeat(x, len(y)))
                    C.append(np.tile(y, len(x)))
                    V.append(m.ravel())
    K = sp.csr_matrix((np.concatenate(V), (np.concatenate(R), np.concatenate(C))), shape=(n, n))
    K = K + sp.diags(np.abs(K).sum(axis=1).A1 + diag_shift)        # diagonally dominant: SPD
    return K.tocsr(), node, N


def test_factor_solve_and_selected_inverse_equal_dense():
    rng = np.random.default_rng(7)
    K, node, border = _block_spd(rng)
    sym = Symbolic.analyse(K, node, last_nodes=[border])
    assert sym.n_super < len(np.unique(node))                      # chains were merged into supernodes
    F = SupernodalCholesky(sym, K)
    Kd = K.toarray()
    Z = np.linalg.inv(Kd)
    b = rng.normal(size=(K.shape[0], 3))
    assert np.allclose(F.solve(b), np.linalg.solve(Kd, b), rtol=0, atol=1e-12)
    assert F.logdet() == pytest.approx(np.linalg.slogdet(Kd)[1], rel=1e-12)
    seen = np.zeros(Kd.shape, bool)
    worst = [0.0]

    def visit(s, front, Zf):
        worst[0] = max(worst[0], float(np.abs(Zf - Z[np.ix_(front, front)]).max()))
        seen[np.ix_(front, front)] = True

    F.selected_inverse(visit)
    assert worst[0] < 1e-13 * np.abs(Z).max()
    assert seen[Kd != 0].all()                 # every entry of K's pattern is in some front
    # the border node is ordered last: its columns are the last positions
    assert set(sym.perm[-4:]) == set(np.flatnonzero(node == border))


def test_singular_matrix_names_the_column():
    rng = np.random.default_rng(8)
    K, node, border = _block_spd(rng, g=5)
    K = K.tolil()
    col, twin = 17, 16                          # same node: column 17 becomes a copy of column 16
    K[col, :] = K[twin, :]
    K[:, col] = K[:, twin]
    K[col, col] = K[twin, twin]
    K = K.tocsr()
    with pytest.raises(NotPositiveDefinite) as e:
        SupernodalCholesky(Symbolic.analyse(K, node, last_nodes=[border]), K)
    assert e.value.column in (col, twin)


# ---- whole adjustments, both routes ---------------------------------------------------------------
def _free(block):
    p = block.points
    return block.replace(points=p.replace(sigma=np.full_like(p.sigma, np.inf), role=np.full(len(p), "tie")))


def _aerial():
    noisy, _ = simulate_aerial(np.random.default_rng(3), n_strips=5, photos_per_strip=7)
    return perturb_start(noisy, np.random.default_rng(1), position=0.5, angle=0.002, point=0.5)


def _convergent():
    noisy, _ = simulate_convergent(np.random.default_rng(4), n_photos=12, model="brown",
                                   free_intrinsics=("c", "xp", "yp", "K1", "K2", "P1", "P2"))
    return noisy


def _rel(a, b):
    a, b = np.nan_to_num(np.asarray(a)), np.nan_to_num(np.asarray(b))
    return float(np.abs(a - b).max() / max(np.abs(a).max(), 1e-300))


CASES = {
    "aerial-control": (_aerial, {}),
    "aerial-free-points": (lambda: _free(_aerial()), {"datum": "free"}),
    "aerial-free-centres": (lambda: _free(_aerial()), {"datum": "free", "datum_centres": True}),
    "selfcal-control": (_convergent, {}),
    "selfcal-free": (lambda: _free(_convergent()), {"datum": "free"}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_sparse_route_equals_dense_route(case):
    make, kw = CASES[case]
    block = make()
    res = {s: adjust(block, BundleSettings(solver=s, **kw)) for s in ("dense", "sparse")}
    d, s = res["dense"], res["sparse"]
    assert d.solver_route == "dense" and s.solver_route == "sparse"
    assert s.vtpv == pytest.approx(d.vtpv, rel=1e-10)
    assert np.abs(s.state.XYZ - d.state.XYZ).max() < 1e-8
    assert np.abs(s.state.X0 - d.state.X0).max() < 1e-8
    assert _rel(d.redundancy, s.redundancy) < 1e-9
    assert _rel(d.PQvvP, s.PQvvP) < 1e-9
    assert _rel(d.cov_points, s.cov_points) < 1e-8
    assert _rel(d.cov_eo, s.cov_eo) < 1e-8
    for a, b in zip(d.cov_cameras, s.cov_cameras):
        if a.size:
            assert _rel(a, b) < 1e-8
    # redundancy numbers add up to the degrees of freedom (no priors here)
    assert s.redundancy.sum() == pytest.approx(s.dof, rel=1e-9)
    # cofactors on demand: the diagonal and a few columns
    assert _rel(d.cofactor_diagonal(), s.cofactor_diagonal()) < 1e-8
    cols = [0, 7, d.problem.n_g - 1]
    assert _rel(d.cofactor_columns(cols), s.cofactor_columns(cols)) < 1e-8


def test_scale_bars_in_a_free_network():
    """Scale-bar points are global unknowns (nodes of their own); the datum has 6 defects."""
    block = _free(_convergent())
    ids = block.points.ids
    dist = tuple(Distance(str(ids[a]), str(ids[b]), float(np.linalg.norm(block.points.XYZ[a] - block.points.XYZ[b])),
                          0.001) for a, b in ((0, 5), (10, 40)))
    res = {s: adjust(block, BundleSettings(solver=s, datum="free", distances=dist)) for s in ("dense", "sparse")}
    d, s = res["dense"], res["sparse"]
    assert d.problem.n_c == 6 and s.solver_route == "sparse"
    assert s.vtpv == pytest.approx(d.vtpv, rel=1e-10)
    assert np.abs(s.state.XYZ - d.state.XYZ).max() < 1e-8
    assert _rel(d.redundancy, s.redundancy) < 1e-9
    assert _rel(d.cov_points, s.cov_points) < 1e-8


def test_predicted_variance_of_left_out_observations():
    block = _aerial()
    obs = block.observations
    k = len(obs)
    rays = np.bincount(obs.point)
    ok = np.flatnonzero(rays[obs.point] >= 4)           # points that keep ≥ 3 rays without one of them
    rng = np.random.default_rng(0)
    pick = rng.choice(ok, 6, replace=False)
    pick = pick[np.unique(obs.point[pick], return_index=True)[1]][:6]
    rows = np.ones((k, 2), bool)
    rows[pick[:4], 0] = False                           # x left out
    rows[pick[4:], :] = False                           # both left out
    res = {s: adjust(block, BundleSettings(solver=s), row_active=rows) for s in ("dense", "sparse")}
    a, b = res["dense"].snapshot.sigma_v_pred, res["sparse"].snapshot.sigma_v_pred
    assert np.isfinite(a).sum() == 4 + 2 * (len(pick) - 4)
    assert np.array_equal(np.isfinite(a), np.isfinite(b))
    assert _rel(a[np.isfinite(a)], b[np.isfinite(b)]) < 1e-9


def test_singular_sparse_system_names_the_missing_datum():
    block = _free(_aerial())                            # no control at all, but datum = control
    with pytest.raises(AdjustmentError, match="datum"):
        adjust(block, BundleSettings(solver="sparse"))


def test_mixed_free_network_and_control_uses_the_bordered_system():
    """Inner constraints *and* fixed control points: the similarity motions are no null space, the
    constraints restrict the solution; the sparse request falls back to the bordered dense system."""
    block = _aerial()
    res = adjust(block, BundleSettings(solver="sparse", datum="free"))
    ref = adjust(block, BundleSettings(solver="dense", datum="free"))
    assert res.solver_route == "dense"
    assert res.vtpv == pytest.approx(ref.vtpv, rel=1e-12)


def test_auto_route_by_size():
    small = adjust(_aerial(), BundleSettings())
    assert small.solver_route == "dense"
    noisy, _ = simulate_aerial(np.random.default_rng(5), n_strips=12, photos_per_strip=30)
    blk = perturb_start(noisy, np.random.default_rng(2), position=0.3, angle=0.001, point=0.3)
    big = adjust(blk, BundleSettings(covariance=False))
    assert big.problem.n_g >= 2000 and big.solver_route == "sparse"


def test_threads_do_not_change_the_results():
    """The photo-pair products of the Schur complement on two threads, BLAS single-threaded
    throughout: the same adjustment to the last bit, including the selected inversion's redundancy
    numbers."""
    noisy, _ = simulate_aerial(np.random.default_rng(5), n_strips=8, photos_per_strip=12)
    block = perturb_start(noisy, np.random.default_rng(2), position=0.3, angle=0.001, point=0.3)
    one = adjust(block, BundleSettings(solver="sparse", threads=1))
    two = adjust(block, BundleSettings(solver="sparse", threads=2))
    assert two.vtpv == one.vtpv
    assert np.array_equal(two.state.XYZ, one.state.XYZ)
    assert np.array_equal(one.redundancy, two.redundancy)
    assert np.array_equal(one.cov_points, two.cov_points)
