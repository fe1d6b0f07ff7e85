"""The adjustment limits its own BLAS threads (threadpoolctl) whoever calls it, and restores them."""

import numpy as np
import pytest
from threadpoolctl import ThreadpoolController

from baarda.pipeline.adjustment import BundleSettings, adjust
from baarda.pipeline import threads as thr
from baarda.pipeline.synthetic.closerange import make_block


def _counts_during(monkeypatch, module, name):
    """Run the adjustment while recording the BLAS thread counts inside the wrapped function."""
    seen = []
    real = getattr(module, name)

    def spy(*a, **k):
        seen.append(thr.blas_thread_counts())
        return real(*a, **k)

    monkeypatch.setattr(module, name, spy)
    return seen


def test_adjust_runs_single_threaded_blas_and_restores(monkeypatch):
    import sys

    A = sys.modules["baarda.pipeline.adjustment.adjust"]     # the module (the package exports the function)

    ctl = ThreadpoolController()
    if not ctl.lib_controllers:
        pytest.skip("no BLAS library threadpoolctl can control")
    block, _ = make_block(n_photos=6, n_points=30, noise_mm=1e-3, rng=np.random.default_rng(1))
    seen = _counts_during(monkeypatch, A, "solve_bundle")
    with ctl.limit(limits=2):                      # a caller with threaded BLAS (the library default)
        before = thr.blas_thread_counts()
        adjust(block, BundleSettings(covariance=False))
        after = thr.blas_thread_counts()
    assert seen and all(c == 1 for c in seen[0])
    assert before == after and max(before) == 2


def test_adjust_block_limits_too(monkeypatch):
    import sys

    W = sys.modules["baarda.pipeline.adjustment.workflow"]
    from baarda.pipeline.api import BundleConfig, adjust as api_adjust

    ctl = ThreadpoolController()
    if not ctl.lib_controllers:
        pytest.skip("no BLAS library threadpoolctl can control")
    block, _ = make_block(n_photos=6, n_points=30, noise_mm=1e-3, rng=np.random.default_rng(2))
    seen = _counts_during(monkeypatch, W, "own_effects")
    with ctl.limit(limits=2):
        api_adjust(block, BundleConfig(datum="control"))
        assert max(thr.blas_thread_counts()) == 2
    assert seen and all(c == 1 for c in seen[0])


def test_no_op_when_already_single():
    ctl = ThreadpoolController()
    with ctl.limit(limits=1):
        cm = thr.blas_threads(1)
        with cm:
            assert all(c == 1 for c in thr.blas_thread_counts())
        assert all(c == 1 for c in thr.blas_thread_counts())
