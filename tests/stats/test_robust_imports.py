"""The statistics library does not import the adjustment core (the cycle stats.robust ↔ adjustment
is gone, not hidden in a function): the bundle's weighted refit is ``BundleResult.weighted_refit``."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np

import baarda.pipeline.stats as stats_pkg
from baarda.pipeline.adjustment import BundleSettings, adjust
from baarda.pipeline.stats import weighted_refit
from baarda.pipeline.synthetic.aerial import simulate_aerial


def test_no_module_of_the_statistics_library_imports_the_adjustment():
    for path in Path(stats_pkg.__file__).parent.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):          # imports inside functions count
            if isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            assert not any("adjustment" in n for n in names), f"{path.name} imports {names}"


def test_bundle_weighted_refit_is_the_results_own():
    block, _ = simulate_aerial(np.random.default_rng(3), n_strips=3, photos_per_strip=5)
    res = adjust(block, BundleSettings(covariance=False))
    refit, how = weighted_refit(res)
    assert how == "bundle, adjusted again from its solution"
    out = refit(np.ones(2 * len(res.residuals)))
    assert out.result.vtpv == res.vtpv or abs(out.result.vtpv - res.vtpv) < 1e-9 * res.vtpv
    assert out.v.shape == (2 * len(res.residuals),)
