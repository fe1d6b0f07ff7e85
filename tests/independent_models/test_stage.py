"""The independent-models stage: protocol, outputs, recording, errors."""

import numpy as np
import pytest

from baarda.pipeline.errors import AdjustmentError
from baarda.pipeline.model import Points
from baarda.pipeline.recording import read_recording
from baarda.pipeline.testing import check_stage, log_stage, run_stage
from baarda.pipeline.contracts import AdjustmentArtefact
from baarda.plugins.independent_models.stage import IndependentModels

from baarda.pipeline.synthetic.normalcase import make_block


def _weighted(block, s=0.0003):
    pts = block.points
    sigma = np.array(pts.sigma)
    sigma[pts.role == "full"] = s
    sigma[pts.role == "z", 2] = s
    return block.replace(points=Points(ids=pts.ids, XYZ=pts.XYZ, role=pts.role, sigma=sigma))


def test_protocol():
    check_stage(IndependentModels)
    assert IndependentModels.reads == ("block", "bundle?")
    assert set(IndependentModels.writes) == {"independent-models", "adjustment"}


def test_run_and_log(tmp_path):
    block, truth = make_block(n_strips=2, n_photos=4, noise_mm=0.004, rng=np.random.default_rng(9))
    block = _weighted(block)
    obs = block.observations
    xy = obs.xy.copy()
    k = np.flatnonzero((obs.photo == 1) & (obs.point == obs.point[obs.photo == 1][5]))[0]
    xy[k, 1] += 0.08  # a y-parallax blunder in photo 12
    block = block.replace(observations=obs.replace(xy=xy))
    res = run_stage(IndependentModels, {"block": block}, {"ro_snooping": "iterated"}, tmp_path=tmp_path)
    s = res.summary
    assert s["models"] == 6 and s["check_rmse"]["n"] == 22
    assert s["block"]["dof"] > 300 and 0.6 < s["block"]["sigma0_hat"] < 1.5
    pid = block.points.ids[obs.point[k]]
    removed = [lab for v in s["ro_removed"].values() for lab in v]
    assert removed and all(f"point {pid} py" in lab for lab in removed)
    assert f"point {pid}" in res.report and "Sxy" in res.report
    for name in ("models", "ro_tests", "ro_points", "transformations", "points", "residuals", "control",
                 "check_points"):
        assert len(res.tables[name]) > 0, name
    art = res.artefacts["adjustment"]
    assert isinstance(art, AdjustmentArtefact) and art.obs_rows.shape == (art.snapshot.n, 2)
    assert art.refit(art.snapshot.active).n == art.snapshot.n
    assert res.artefacts["independent-models"].check.rmse() == s["check_rmse"]
    # the comparison convention (docs/plugins.md): headline, check_points dict and table
    cp, tab = s["check_points"], res.tables["check_points"]
    assert cp["unit"] == "m" and cp["n"] == len(tab) == 22 and "22" in s["headline"]
    d = np.column_stack([np.asarray(tab.columns[c], float) for c in ("dX_m", "dY_m", "dZ_m")])
    S = np.sqrt(np.mean(d ** 2, axis=0))   # recomputed from the table's errors
    assert [cp["Sx"], cp["Sy"], cp["Sz"]] == pytest.approx(S, rel=1e-12)
    assert cp["Sxy"] == pytest.approx(np.sqrt((S[0] ** 2 + S[1] ** 2) / 2), rel=1e-12)
    assert list(tab.columns)[:4] == ["point", "dX_m", "dY_m", "dZ_m"]

    rec = read_recording(log_stage(IndependentModels, res, tmp_path / "im.rrd"))
    paths = {e.path for e in rec.entities}
    for p in ("/im/independent-models/models/11-12/points", "/im/independent-models/models/11-12/y_parallax",
              "/im/independent-models/models/11-12/projection_centres", "/im/independent-models/block/points",
              "/im/independent-models/block/models/23-24", "/im/independent-models/block/tie_discrepancies",
              "/im/independent-models/block/control_residuals", "/im/independent-models/block/check_errors",
              "/im/independent-models/block/sigma0_hat", "/im/independent-models/legend"):
        assert p in paths, p


def test_consecutive_pairing_option(tmp_path):
    block, _ = make_block(n_strips=2, n_photos=3, with_pairs=False)
    res = run_stage(IndependentModels, {"block": block},
                    {"pairing": "consecutive", "strips": [["11", "12", "13"], ["21", "22", "23"]],
                     "parameters": "independent", "method": "collinearity"}, tmp_path=tmp_path)
    assert [m["model"] for m in res.summary["per_model"]] == ["11-12", "12-13", "21-22", "22-23"]
    assert res.summary["check_rmse"]["Sz"] < 1e-10


def test_degenerate_block_is_reported(tmp_path):
    block, _ = make_block(n_strips=1, n_photos=3)
    pts = block.points
    none = Points.make(pts.ids, pts.XYZ, np.where(pts.role == "check", "check", "tie"))
    with pytest.raises(AdjustmentError, match="datum missing"):
        run_stage(IndependentModels, {"block": block.replace(points=none)}, {}, tmp_path=tmp_path)


def test_stage_defaults_are_the_workflow_defaults(tmp_path):
    """The stage's default weights are the documented default ('propagated'), so a study calling
    independent_model_block(block) and a project running the stage get the same numbers."""
    from baarda.pipeline.imodels import independent_model_block

    block, _ = make_block(n_strips=2, n_photos=3, noise_mm=0.004, rng=np.random.default_rng(4))
    res = run_stage(IndependentModels, {"block": _weighted(block)}, {}, tmp_path=tmp_path)
    ref = independent_model_block(_weighted(block))
    assert ref.options.model_weights == "propagated"
    assert res.summary["check_points"]["Sz"] == ref.check.Sz
    assert res.summary["block"]["sigma0_hat"] == ref.sigma0_hat
