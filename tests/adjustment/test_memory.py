"""Peak memory of the adjustment (docs/benchmarks.md, "Whole runs"): systems are freed when the last
reference goes (no reference cycle waiting for the garbage collector), external reliability works
on a lean system, released caches are rebuilt the same, freed pages are handed back."""

from __future__ import annotations

import gc
import weakref

import numpy as np
import pytest

from baarda.pipeline.adjustment import BundleSettings, adjust
from baarda.pipeline.adjustment.lm import final_system
from baarda.pipeline.adjustment.memory import release_freed
from baarda.pipeline.adjustment.reliability import own_effects
from baarda.pipeline.model import FREE
from baarda.pipeline.synthetic.closerange import make_block


def _free_block():
    blk, _ = make_block(model="none", n_photos=6, n_points=24, noise_mm=0.002, rng=np.random.default_rng(5))
    pts = blk.points
    return blk.replace(points=pts.replace(role=np.array(["tie"] * len(pts)), sigma=np.full((len(pts), 3), FREE)))


@pytest.mark.parametrize("solver", ["dense", "sparse"])
def test_a_reduced_system_is_freed_without_the_garbage_collector(solver):
    res = adjust(_free_block(), BundleSettings(datum="free", solver=solver), covariance=False)
    lin, red = final_system(res.problem, res.route, res.state)
    red.solution
    B, blocks = weakref.ref(red.B), weakref.ref(red)
    was = gc.isenabled()
    gc.disable()
    try:
        del lin, red
        assert B() is None and blocks() is None       # by reference counting alone
    finally:
        if was:
            gc.enable()


@pytest.mark.parametrize("solver", ["dense", "sparse"])
def test_lean_system_keeps_solution_factor_and_datum(solver):
    res = adjust(_free_block(), BundleSettings(datum="free", solver=solver), covariance=False)
    lin, red = final_system(res.problem, res.route, res.state)
    dx, fac = red.solution
    basis = red.datum_basis
    lean = red.lean()
    assert lean.lin is None and lean.K is None
    assert lean.solution[1] is fac and lean.solution[0] is dx and lean.datum_basis is basis
    assert lean.B is red.B and lean.Li is red.Li and lean.rhs is red.rhs


def test_released_normals_are_rebuilt_the_same():
    res = adjust(_free_block(), BundleSettings(datum="free", solver="sparse"))
    a = own_effects(res)                      # takes the adjustment's system
    prob = res.problem
    old = prob.normals
    groups = [g.copy() for g, _ in old.track_groups]
    prob.release_normals()
    assert "normals" not in prob.__dict__
    assert prob.normals is not old
    assert all(np.array_equal(g, h) for g, (h, _) in zip(groups, prob.normals.track_groups))
    b = own_effects(res)                      # rebuilds the system with new normals: the same numbers
    np.testing.assert_array_equal(a.point, b.point)
    np.testing.assert_array_equal(a.eo, b.eo)
    assert not a.point_sigma.flags.writeable and a.point_sigma.shape == a.point.shape
    np.testing.assert_array_equal(a.eo_sigma[:, 0], a.eo_sigma[:, 1])


def test_release_freed_says_whether_it_could():
    import sys

    assert release_freed() in (True, False)
    if sys.platform.startswith("linux"):
        import ctypes

        try:
            ctypes.CDLL(None).malloc_trim
        except AttributeError:
            return
        assert release_freed() is True
