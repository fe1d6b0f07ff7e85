"""The ``bundle`` stage: options, artefacts, tables, report, recording, blunder handling."""

import numpy as np
import pytest

from pipeline.testing import check_stage, log_stage, run_stage
from plugins.bundle.stage import BundleAdjustment

from .synth import make_block, perturb


def test_stage_protocol():
    check_stage(BundleAdjustment, "bundle")


def test_stage_runs_and_logs(tmp_path):
    blk, truth = make_block(model="brown", n_photos=8, n_points=40, noise_mm=0.001,
                            rng=np.random.default_rng(5))
    res = run_stage(BundleAdjustment, {"block": perturb(blk, np.random.default_rng(1))},
                    {"blunders": "data-snooping"}, tmp_path=tmp_path)
    b = res.artefacts["bundle"]
    assert res.artefacts["adjustment"].snapshot.n == 2 * len(blk.observations)
    assert abs(b.sigma0_hat - 1) < 0.15
    t = res.tables["observations"]
    assert len(t) == len(blk.observations)
    assert {"vx", "wy", "mdb_x", "decision"} <= set(t.columns)
    assert "Camera parameters" in res.report
    path = log_stage(BundleAdjustment, res, tmp_path / "bundle.rrd")
    from pipeline.recording import read_recording

    rec = read_recording(path)
    ents = {e.path: e for e in rec.entities}
    for p in ("/world/points", "/world/photos/P1", "/images/P1/residuals", "/cameras/cam/distortion",
              "/convergence/vtpv", "/bundle/report"):
        assert p in ents, p
    assert "iteration" in ents["/convergence/vtpv"].timelines
    assert ents["/convergence/vtpv"].rows == b.iterations + 1
    assert {"Transform3D", "Pinhole"} <= {c.split(":")[0] for c in ents["/world/photos/P1"].columns}


def test_ids_rejects_a_planted_blunder(tmp_path):
    blk, truth = make_block(model="none", n_photos=8, n_points=40, noise_mm=0.001, rng=np.random.default_rng(7))
    obs = blk.observations
    xy = obs.xy.copy()
    k = 37
    xy[k, 1] += 0.02                  # 20 σ in y
    bad = blk.replace(observations=obs.replace(xy=xy))
    res = run_stage(BundleAdjustment, {"block": bad}, {"blunders": "ids"}, tmp_path=tmp_path)
    dec = np.array(res.tables["observations"].columns["decision"])
    assert dec[k] == "rejected"
    assert (dec == "rejected").sum() == 1
    assert not res.artefacts["block"].observations.active[k]
    assert abs(res.artefacts["bundle"].sigma0_hat - 1) < 0.15
