"""The solver route is chosen once, at the start state, as a strategy object (route.py), and the
core's records are typed and frozen: the reduced system, the linearisation, the precision, the solve
info; the problem is not written to by the iteration (caches are cached_property)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from baarda.pipeline.adjustment import BundleProblem, BundleSettings, adjust, solve_bundle
from baarda.pipeline.adjustment.route import DenseRoute, ReducedSystem, SparseRoute, choose_route
from baarda.pipeline.synthetic.aerial import perturb_start, simulate_aerial


def _aerial():
    noisy, _ = simulate_aerial(np.random.default_rng(3), n_strips=4, photos_per_strip=6)
    return perturb_start(noisy, np.random.default_rng(1), position=0.5, angle=0.002, point=0.5)


def _free(block):
    p = block.points
    return block.replace(points=p.replace(sigma=np.full_like(p.sigma, np.inf), role=np.full(len(p), "tie")))


def _route(block, **kw):
    prob = BundleProblem(block, BundleSettings(**kw))
    return prob, choose_route(prob, prob.initial_state())


def test_route_chosen_from_settings_and_datum():
    prob, r = _route(_aerial(), solver="dense")
    assert isinstance(r, DenseRoute) and r.name == "dense" and not r.sparse_normals
    prob, r = _route(_aerial(), solver="sparse")
    assert isinstance(r, SparseRoute) and r.held is None and r.sparse_normals
    prob, r = _route(_free(_aerial()), solver="sparse", datum="free")
    assert isinstance(r, SparseRoute) and len(r.held) == prob.n_c == 7
    assert (r.sym.n == prob.n_g - prob.n_c)                      # the held parameters are not in the factor
    # inner constraints and fixed control points: no null space of the similarity motions → bordered
    prob, r = _route(_aerial(), solver="sparse", datum="free")
    assert isinstance(r, DenseRoute)


def test_records_are_frozen_and_the_problem_is_not_written():
    block = _aerial()
    prob = BundleProblem(block, BundleSettings(solver="sparse", datum="free"))
    before = set(vars(prob))
    prob2, st, info = solve_bundle(_free(block), BundleSettings(solver="sparse", datum="free"))
    assert isinstance(info.red, ReducedSystem) and info.route is info.red.route
    for rec, name in ((info, "vtpv"), (info.red, "lam"), (info.lin, "t")):
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(rec, name, 0.0)
    # only cached properties appear on the problem after a whole adjustment
    res = adjust(block, BundleSettings(solver="dense"))
    assert set(vars(res.problem)) - before <= {"normals"}
    assert isinstance(res.route, DenseRoute) and res.solver_route == "dense"


def test_reduced_system_solves_once():
    prob, st, info = solve_bundle(_aerial(), BundleSettings(solver="dense"))
    red = info.red
    assert red.solution is red.solution                         # computed once, on first use
    dx, fac = red.solution
    K = red.K
    assert np.allclose(K @ dx, red.rhs, rtol=0, atol=1e-8 * np.abs(red.rhs).max())
    assert np.allclose(fac.inverse() @ K, np.eye(len(K)), atol=1e-6)
