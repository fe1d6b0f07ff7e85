"""Every analytic derivative of the independent-model numerics against central differences."""

import numpy as np
import pytest

from baarda.pipeline.geometry import rotation_from_opk
from baarda.pipeline.synthetic.normalcase import ideal_projection as project
from baarda.pipeline.imodels.block import model_observation_jacobian
from baarda.pipeline.imodels.intersection import project_with_jacobian
from baarda.pipeline.imodels.relor import _collinearity_rows, coplanarity_condition, pair_poses
from baarda.pipeline.imodels.similarity import rotation_and_derivatives, similarity_jacobian


def numdiff(f, x, h):
    x = np.asarray(x, float)
    cols = []
    for j in range(x.size):
        e = np.zeros_like(x)
        e.flat[j] = h
        cols.append((f(x + e) - f(x - e)) / (2 * h))
    return np.stack(cols, axis=-1)


def _pair_data(rng, n=7):
    X = np.column_stack([rng.uniform(-0.5, 0.9, n), rng.uniform(-0.5, 0.5, n), rng.uniform(-1.6, -1.2, n)])
    xl = project(X, np.zeros(3), rotation_from_opk(0.01, -0.02, 0.03), 100.0, 0.1, -0.2)
    xr = project(X, np.array([0.5, 0.02, -0.01]), rotation_from_opk(-0.02, 0.01, 0.02), 100.0, 0.1, -0.2)
    return X, np.hstack([xl, xr])


def test_rotation_derivatives():
    o = np.array([0.3, -0.2, 1.1])
    R, dR = rotation_and_derivatives(o)
    assert np.allclose(R, rotation_from_opk(*o), atol=1e-15)
    num = numdiff(lambda a: rotation_from_opk(*a), o, 1e-6)
    for k in range(3):
        assert np.abs(num[..., k] - dR[k]).max() < 1e-9


@pytest.mark.parametrize("parameters", ["dependent", "independent"])
def test_coplanarity_jacobians(parameters):
    rng = np.random.default_rng(1)
    _, l = _pair_data(rng)
    p = np.array([0.02, -0.01, 0.03, -0.02, 0.01]) if parameters == "dependent" else \
        np.array([0.01, -0.02, 0.03, 0.02, -0.01])
    il, ir = (100.0, 0.1, -0.2), (101.0, -0.1, 0.05)
    F, A, B = coplanarity_condition(l, p, parameters, 40.0, il, ir)
    numA = numdiff(lambda q: coplanarity_condition(l, q, parameters, 40.0, il, ir)[0], p, 1e-7)
    assert np.abs(numA - A).max() < 1e-6 * np.abs(A).max()
    numB = numdiff(lambda ll: coplanarity_condition(ll.reshape(-1, 4), p, parameters, 40.0, il, ir)[0],
                   l.reshape(-1), 1e-5)
    # ∂F_i/∂l_j is zero for j outside point i
    numB_diag = np.array([numB[i, 4 * i:4 * i + 4] for i in range(l.shape[0])])
    assert np.abs(numB_diag - B).max() < 1e-7 * np.abs(B).max()


@pytest.mark.parametrize("parameters", ["dependent", "independent"])
def test_collinearity_jacobians(parameters):
    rng = np.random.default_rng(2)
    X, _ = _pair_data(rng)
    p = np.array([0.02, -0.01, 0.03, -0.02, 0.01])
    il, ir = (100.0, 0.1, -0.2), (101.0, -0.1, 0.05)
    f, Jp, JX = _collinearity_rows(X, p, parameters, 0.5, il, ir)
    num = numdiff(lambda q: _collinearity_rows(X, q, parameters, 0.5, il, ir)[0], p, 1e-7)
    assert np.abs(num - Jp).max() < 1e-6 * np.abs(Jp).max()
    for i in range(X.shape[0]):
        numX = numdiff(lambda x: _collinearity_rows(x[None], p, parameters, 0.5, il, ir)[0][0], X[i], 1e-7)
        assert np.abs(numX - JX[i]).max() < 1e-6 * np.abs(JX[i]).max()


def test_pair_pose_derivatives():
    p = np.array([0.02, -0.01, 0.03, -0.02, 0.01])
    for parameters in ("dependent", "independent"):
        R1, dR1, R2, dR2, X02, dX02 = pair_poses(p, parameters, 0.7)
        for k, (val, der) in enumerate(((R1, dR1), (R2, dR2), (X02, dX02))):
            num = numdiff(lambda q: pair_poses(q, parameters, 0.7)[2 * k], p, 1e-7)
            assert np.abs(np.moveaxis(num, -1, 0) - der).max() < 1e-8


def test_projection_jacobian():
    rng = np.random.default_rng(3)
    X = rng.uniform(-1, 1, (5, 3)) - [0, 0, 3]
    R = rotation_from_opk(0.1, -0.05, 0.2)
    X0 = np.array([0.1, 0.2, 0.3])
    xy, d, uvw = project_with_jacobian(X, X0, R, 50.0, 0.01, -0.02)
    assert np.allclose(xy, project(X, X0, R, 50.0, 0.01, -0.02), atol=1e-13)
    for i in range(5):
        num = numdiff(lambda x: project_with_jacobian(x[None], X0, R, 50.0, 0.01, -0.02)[0][0], X[i], 1e-7)
        assert np.abs(num - d[i] @ R).max() < 1e-6


def test_similarity_and_model_jacobians():
    rng = np.random.default_rng(4)
    x = rng.uniform(-1, 1, (6, 3))
    p = np.array([1.3, 0.1, -0.2, 0.7, 10.0, -5.0, 2.0])
    X, J = similarity_jacobian(p, x)
    num = numdiff(lambda q: similarity_jacobian(q, x)[0], p, 1e-7)
    assert np.abs(num - J).max() < 1e-7
    f, Jp, JX = model_observation_jacobian(p, X)
    assert np.allclose(f, x, atol=1e-12)  # the model observation inverts the similarity
    num = numdiff(lambda q: model_observation_jacobian(q, X)[0], p, 1e-7)
    assert np.abs(num - Jp).max() < 1e-7
    for i in range(6):
        numX = numdiff(lambda y: model_observation_jacobian(p, y[None])[0][0], X[i], 1e-6)
        assert np.abs(numX - JX[i]).max() < 1e-8
