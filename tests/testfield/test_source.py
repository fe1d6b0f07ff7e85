"""The ``testfield`` source stage: options, report, recording, errors."""

from __future__ import annotations

import numpy as np
import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.recording import read_recording
from baarda.pipeline.testing import check_stage, log_stage, run_stage
from baarda.plugins.testfield.source import TestFieldSource


def test_protocol():
    check_stage(TestFieldSource)


def test_run_and_log(tmp_path):
    r = run_stage(TestFieldSource, {}, {"case": 3, "seed": 7, "ap_model": "ebner12"}, tmp_path=tmp_path)
    block = r.artefacts["block"]
    assert r.summary["dof_without_aps"] == 52 and r.summary["min_rays"] >= 2
    assert r.summary["roles"] == {"full": 2, "xy": 4, "z": 5, "check": 10, "tie": 0}
    assert "Degrees of freedom" in r.report and "forward" in r.report
    assert set(r.tables) == {"points", "photos", "observations"}
    assert block.meta["truth"]["c"] == pytest.approx(101.77)
    again = run_stage(TestFieldSource, {}, {"case": 3, "seed": 7}, tmp_path=tmp_path)
    np.testing.assert_array_equal(again.artefacts["block"].observations.xy, block.observations.xy)
    rec = read_recording(log_stage(TestFieldSource, r, tmp_path / "tf.rrd"))
    paths = {e.path for e in rec.entities}
    assert "/tf/world/targets" in paths and "/tf/world/cameras/11" in paths and "/tf/world/cameras/25/image/targets" in paths
    assert {"Points3D", "Transform3D", "Pinhole", "Points2D"} <= set(rec.archetypes)


def test_single_model_and_project_seed(tmp_path):
    a = run_stage(TestFieldSource, {}, {"block": "single-model"}, tmp_path=tmp_path, seed=1)
    b = run_stage(TestFieldSource, {}, {"block": "single-model"}, tmp_path=tmp_path, seed=2)
    assert list(a.artefacts["block"].photos.ids) == ["A", "B"]
    assert not np.array_equal(a.artefacts["block"].observations.xy, b.artefacts["block"].observations.xy)


def test_bad_options(tmp_path):
    with pytest.raises(InputError) as e:
        run_stage(TestFieldSource, {}, {"case": 9}, tmp_path=tmp_path)
    assert "case" in str(e.value)
    with pytest.raises(InputError) as e:
        run_stage(TestFieldSource, {}, {"blunders": [{"photo": "11", "point": "1", "dx": 0.1}]}, tmp_path=tmp_path)
    assert e.value.field == "blunders" and "does not observe" in e.value.message
    with pytest.raises(InputError) as e:
        run_stage(TestFieldSource, {}, {"blunders": [{"photo": "11", "dx": 0.1}]}, tmp_path=tmp_path)
    assert e.value.field == "blunders.point" and "missing" in e.value.message
    with pytest.raises(InputError):
        run_stage(TestFieldSource, {}, {"sigma_image_um": -1.0}, tmp_path=tmp_path)
