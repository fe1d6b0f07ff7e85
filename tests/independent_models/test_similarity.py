"""3-D similarity: closed form, least squares, partial control, degenerate input; intersection."""

import numpy as np
import pytest

from baarda.pipeline.errors import AdjustmentError
from baarda.pipeline.geometry import rotation_from_opk
from baarda.pipeline.synthetic.normalcase import ideal_projection as project
from baarda.pipeline.imodels.intersection import space_intersection
from baarda.pipeline.imodels.similarity import (apply_similarity, similarity_closed_form,
                                         similarity_transform)

TRUE = np.array([2.5, 0.3, -0.4, 2.0, 100.0, -50.0, 20.0])


def _points(n=8, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-10, 10, (n, 3))
    return x, apply_similarity(TRUE, x)


def test_closed_form_recovers_truth():
    x, X = _points()
    p = similarity_closed_form(x, X)
    assert np.allclose(p, TRUE, rtol=0, atol=1e-11)
    # X = s Mᵀ x + T with M = R3(κ) R2(φ) R1(ω) (conventions): check one point by hand
    M = rotation_from_opk(*TRUE[1:4])
    assert np.allclose(X[0], TRUE[0] * M.T @ x[0] + TRUE[4:], atol=1e-12)


def test_least_squares_equals_closed_form_from_a_poor_start():
    x = np.random.default_rng(0).uniform(-10, 10, (10, 3))
    X = apply_similarity([2.5, 0.1, -0.15, 0.3, 100.0, -50.0, 20.0], x)
    X = X + np.random.default_rng(1).normal(0, 0.05, X.shape)
    ls = similarity_transform(x, X, initial=[1.0, 0, 0, 0, 0, 0, 0])
    assert ls.converged and ls.iterations > 3
    assert np.abs(ls.params - similarity_closed_form(x, X)).max() < 1e-9
    assert ls.dof == 23 and abs(ls.snapshot.r.sum() - 23) < 1e-9
    # residuals observed − computed
    assert np.allclose(ls.residuals, X - apply_similarity(ls.params, x), atol=1e-12)
    # σ̂0 from the residuals
    assert abs(ls.sigma0_hat - np.sqrt(np.sum(ls.residuals ** 2) / 23)) < 1e-12


def test_partial_control_and_weights():
    x, X = _points(6)
    mask = np.ones((6, 3), bool)
    mask[0:2, 2] = False  # two planimetric points
    mask[2, :2] = False  # one height point (three full ones give the initial values)
    ls = similarity_transform(x, X, mask=mask, sigma=[0.01, 0.01, 0.02])
    assert ls.dof == int(mask.sum()) - 7
    assert np.allclose(ls.params, TRUE, atol=1e-10)
    assert np.isnan(ls.residuals[0, 2]) and np.isnan(ls.residuals[2, 0])


def test_refit_drops_a_blunder():
    x, X = _points(8)
    X = X + np.random.default_rng(2).normal(0, 0.01, X.shape)
    X[3, 1] += 0.5
    ls = similarity_transform(x, X, sigma=0.01)
    act = np.ones(24, bool)
    act[3 * 3 + 1] = False
    snap = ls.refit(act)
    assert snap.sigma0_hat < 2 and ls.sigma0_hat > 5
    assert snap.v_pred[10] > 0.4  # the removed coordinate's predicted residual shows the error


def test_degenerate_similarity():
    x, X = _points(3)
    line = np.outer(np.arange(4.0), [1.0, 2.0, 3.0])
    with pytest.raises(AdjustmentError, match="collinear"):
        similarity_closed_form(line, line * 2)
    with pytest.raises(AdjustmentError, match="at least 3 points"):
        similarity_closed_form(x[:2], X[:2])
    mask = np.zeros((3, 3), bool)
    mask[:2] = True
    with pytest.raises(AdjustmentError, match="at least 7 observed"):
        similarity_transform(x, X, mask=mask)
    x, X = _points(6)
    with pytest.raises(AdjustmentError, match="did not converge"):  # 115° of κ from zero angles
        similarity_transform(x, X, initial=[1.0, 0, 0, 0, 0, 0, 0], max_iter=10)


def test_space_intersection_exact_and_covariance():
    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(0, 0.6, 20), rng.uniform(-0.4, 0.4, 20), rng.uniform(-1.6, -1.2, 20)])
    R = np.stack([rotation_from_opk(0.01, 0.02, 0.0), rotation_from_opk(-0.01, 0.0, 0.03)])
    X0 = np.array([[0, 0, 0], [0.6, 0.01, 0.02]])
    xy = np.stack([project(X, X0[k], R[k], 100.0) for k in range(2)], axis=1)
    res = space_intersection(xy, R, X0, 100.0)
    assert np.abs(res.XYZ - X).max() < 1e-12 and res.in_front.all()
    # covariance against Monte Carlo (σ = 5 µm)
    cov = np.broadcast_to(np.eye(2) * 0.005 ** 2, (20, 2, 2, 2))
    sims = np.array([space_intersection(xy + 0.005 * rng.standard_normal(xy.shape), R, X0, 100.0,
                                        cov=cov).XYZ[0] for _ in range(400)])
    C = space_intersection(xy, R, X0, 100.0, cov=cov).cov[0]
    emp = np.cov(sims.T)
    assert np.allclose(np.sqrt(np.diag(emp)), np.sqrt(np.diag(C)), rtol=0.15)
    # a point with one ray is not determined
    valid = np.ones((20, 2), bool)
    valid[4, 1] = False
    one = space_intersection(xy, R, X0, 100.0, valid=valid)
    assert not one.ok[4] and np.isnan(one.XYZ[4]).all() and one.ok.sum() == 19
