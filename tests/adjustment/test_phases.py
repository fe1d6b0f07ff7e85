"""The long phases report their progress to PHASE_CALLBACK (an observer: the numbers do not change)."""

import numpy as np

from baarda.pipeline.adjustment import PHASE_CALLBACK, BundleSettings, adjust
from baarda.pipeline.api import BundleConfig
from baarda.pipeline.api import adjust as adjust_block
from baarda.pipeline.synthetic.closerange import make_block


def _events(fn):
    seen = []
    token = PHASE_CALLBACK.set(seen.append)
    try:
        out = fn()
    finally:
        PHASE_CALLBACK.reset(token)
    return seen, out


def _block():
    block, _ = make_block(n_photos=8, n_points=40, noise_mm=1e-3, rng=np.random.default_rng(3))
    XYZ = block.points.XYZ.copy()
    XYZ[block.points.role == "tie"] = np.nan              # the tie points are intersected
    return block.replace(points=block.points.replace(XYZ=XYZ))


def test_phases_are_reported_and_change_nothing():
    block = _block()
    for solver in ("dense", "sparse"):
        settings = BundleSettings(datum="control", solver=solver)
        seen, res = _events(lambda: adjust(block, settings))
        quiet = adjust(block, settings)
        phases = {e.phase for e in seen}
        assert {"initial values: intersection", "precision"} <= phases, phases
        for e in seen:
            assert 0 <= e.done < e.total
        assert np.array_equal(res.block.points.XYZ, quiet.block.points.XYZ)
        assert np.array_equal(res.redundancy, quiet.redundancy)


def test_external_reliability_is_reported():
    seen, rep = _events(lambda: adjust_block(_block(), BundleConfig(datum="control")))
    assert rep.external is not None
    assert "external reliability" in {e.phase for e in seen}
