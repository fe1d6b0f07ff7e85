"""Robust estimation on the real AICON network (fixtures/aicon/aicon.toml) against iterated data
snooping: the same adjustment (the file's sx, sy scaled by their variance component, C1, C2 free),
IDS removing one coordinate at a time while |w| > 3.29, Huber and Danish IRLS from the same start.
The down-weighted sets are compared with IDS's rejections (docs/statistics.md, "Robust estimation";
``pytest -s`` prints the numbers).  About a minute: slow."""

import time

import numpy as np
import pytest

from baarda.pipeline.adjustment import adjust_block
from baarda.pipeline.plugins import PluginManager
from baarda.pipeline.project import load_project, stage_context
from baarda.pipeline.stats import irls, weighted_refit


@pytest.mark.slow
def test_aicon_robust_against_ids(repo_root, shared_data, tmp_path):
    if (repo_root.parent / "shared" / "data").resolve() != shared_data.resolve():
        pytest.skip(f"shared data is not beside the repository ({shared_data})")
    project = load_project(repo_root / "fixtures/aicon/aicon.toml", PluginManager())
    k = next(k for k, spec in enumerate(project.stages) if spec.use == "bundle")
    store = {}
    for spec in project.stages[:k]:                  # the source: the block the bundle stage reads
        ctx = stage_context(project, spec, run_dir=tmp_path)
        inputs = {n.rstrip("?"): store[n.rstrip("?")] for n in spec.cls.reads if n.rstrip("?") in store}
        store.update(spec.cls().run(inputs, spec.options, ctx).artefacts)
    report = adjust_block(store["block"], project.stages[k].options)   # the bundle stage's workflow
    ids = report.ids
    start = report.before_ids.result                 # the adjustment IDS started from
    ids_rows = set(ids.removed)
    print(f"\nAICON: {int(start.snapshot.active.sum())} coordinates, dof {start.dof}, σ̂0 {start.sigma0_hat:.4f}; "
          f"IDS rejected {len(ids_rows)}")
    found = {}
    for method in ("huber", "danish"):
        t0 = time.perf_counter()
        refit, _ = weighted_refit(start)
        rob = irls(refit, start.snapshot, method, max_iter=100)
        dt = time.perf_counter() - t0
        down = set(rob.downweighted.tolist())
        both = down & ids_rows
        w_ids = np.asarray(rob.weights)[sorted(ids_rows)]
        print(f"  {method}: {rob.iterations} iterations ({dt:.1f} s), converged {rob.converged}; "
              f"{len(down)} down-weighted (ω < 0.5), {len(both)} of them rejected by IDS; "
              f"IDS rows not down-weighted: {len(ids_rows - down)} (their ω: median {np.median(w_ids):.3g}, "
              f"max {w_ids.max():.3g}); down-weighted not rejected by IDS: {len(down - ids_rows)}")
        found[method] = (rob, down, both)
        assert rob.converged
    # what must hold: IDS's first rejections (its largest |w|) are down-weighted by both estimators
    first = [h.row for h in ids.history if h.removed][:10]
    for method, (rob, down, both) in found.items():
        assert set(first) <= down, method
        assert len(both) >= 0.8 * len(ids_rows), method
