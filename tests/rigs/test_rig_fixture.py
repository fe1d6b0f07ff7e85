"""The bundled COLMAP rig (``fixtures/colmap/rig/``, made by ``tools/make_rig_fixture.py``): the
generator reproduces it bit for bit, a rig table takes the model's own frames, the stability test
flags the knocked sensor only; and a weighted baseline gives a free network its scale."""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

pycolmap = pytest.importorskip("pycolmap")

from baarda.pipeline.adjustment import BundleSettings, adjust, rig_result
from baarda.pipeline.colmap import read_colmap
from baarda.pipeline.rigs import attach_rigs
from baarda.pipeline.synthetic.rig import make_rig_block

ROOT = Path(__file__).resolve().parents[2]
FIXTURE = ROOT / "fixtures" / "colmap" / "rig"


def test_generator_reproduces_the_fixture(tmp_path):
    spec = importlib.util.spec_from_file_location("make_rig_fixture", ROOT / "tools" / "make_rig_fixture.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.main(tmp_path)
    made = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    assert made == sorted(p.relative_to(FIXTURE) for p in FIXTURE.rglob("*") if p.is_file())
    for rel in made:
        assert (tmp_path / rel).read_bytes() == (FIXTURE / rel).read_bytes(), rel


def test_rig_table_on_the_model_frames_flags_the_knocked_sensor():
    block, info = read_colmap(FIXTURE / "model", sigma_px=0.5, pixel_mm=0.006)
    assert info["rigs"] == {"sensors": 3, "frames": 8}
    out = attach_rigs(block, FIXTURE / "calibration.csv")        # no frame table: the model's frames.txt
    assert (out.rigs.frames.frame == block.rigs.frames.frame).all()
    assert (out.rigs.frames.photo == block.rigs.frames.photo).all()
    assert out.rigs.frames_path == block.rigs.path
    assert (out.rigs.sensors.sigma[1:] > 0).all() and np.isfinite(out.rigs.sensors.sigma).all()
    res = adjust(out, BundleSettings(datum="free"))
    assert res.problem.n_c == 6                                   # the weighted baselines give the scale
    rr = rig_result(res)
    left, right = rr.sensors[1], rr.sensors[2]
    assert left.stability["stable"] and not right.stability["stable"]
    assert not rr.stability["stable"]
    # the baselines agree with the truth within 2 σ
    truth = json.loads((FIXTURE / "truth.json").read_text())["sensors"]
    for s, name in ((left, "left"), (right, "right")):
        d = s.baseline - truth[name]["baseline_m"]
        assert abs(d) < 2 * s.sigma_baseline, (name, s.baseline, s.sigma_baseline)


def test_weighted_baseline_gives_a_free_network_its_scale():
    """Start values 2 % too large: the inner constraints' scale would keep them (7 constraints); a
    weighted sensor centre observes the scale, so the constraints leave it (6) and the baseline
    comes out at the prior's, not the start values' 1.02 × it."""
    block, truth = make_rig_block(np.random.default_rng(3), noise_mm=0.001)
    pts, ph = block.points, block.photos
    block = block.replace(points=pts.replace(XYZ=1.02 * pts.XYZ, role=np.full(len(pts), "tie", dtype=object),
                                             sigma=np.full(pts.XYZ.shape, np.inf)),
                          photos=ph.replace(X0=1.02 * ph.X0))
    rs = block.rigs.sensors
    good = truth["sensor"][1]
    sig = np.r_[np.full(3, 0.001), np.full(3, np.radians(0.01))]
    weighted = block.replace(rigs=block.rigs.replace(sensors=rs.replace(
        centre=np.array([[0, 0, 0], good[:3]]), opk=np.array([[0, 0, 0], good[3:]]),
        sigma=np.array([np.zeros(6), sig]))))
    res = adjust(weighted, BundleSettings(datum="free"))
    assert res.problem.n_c == 6
    s = rig_result(res).sensors[1]
    assert abs(s.baseline - np.linalg.norm(good[:3])) < 3 * s.sigma_baseline
    # estimated (no known baseline): the scale stays a datum defect, 7 inner constraints
    free = block.replace(rigs=block.rigs.replace(sensors=rs.replace(sigma=np.array([np.zeros(6), np.full(6, np.inf)]))))
    assert adjust(free, BundleSettings(datum="free")).problem.n_c == 7
