"""Rigs from COLMAP (rigs.txt / frames.txt, pycolmap 4.2): read, write back, the truth of a
pycolmap-synthesised rig, and the pycolmap cross-check with rig constraints (equivalent problems
reach the same minimum)."""

import numpy as np
import pytest

pycolmap = pytest.importorskip("pycolmap")

from baarda.pipeline.adjustment import BundleSettings, adjust, rig_result
from baarda.pipeline.colmap import block_from_reconstruction, read_colmap, write_colmap
from baarda.pipeline.geometry import opk_from_rotation


def _synthetic(seed=1, rigs=2, noise_px=0.5):
    pycolmap.logging.minloglevel = 2
    pycolmap.set_random_seed(seed)
    o = pycolmap.SyntheticDatasetOptions()
    o.num_rigs, o.num_cameras_per_rig, o.num_frames_per_rig, o.num_points3D = rigs, 2, 8, 100
    o.camera_model_id = pycolmap.CameraModelId.SIMPLE_RADIAL
    rec = pycolmap.synthesize_dataset(o)
    truth = {}
    F = np.diag([1.0, -1.0, -1.0])
    for rid, rig in rec.rigs.items():
        for sid, pose in rig.non_ref_sensors.items():
            truth[sid.id] = opk_from_rotation(F @ np.asarray(pose.rotation.matrix()) @ F)
    if noise_px:
        no = pycolmap.SyntheticNoiseOptions()
        no.point2D_stddev = noise_px
        pycolmap.synthesize_noise(no, rec)
    return rec, truth


def test_colmap_rigs_read_and_write_back(tmp_path):
    rec, _ = _synthetic(noise_px=0.0)
    block, info = block_from_reconstruction(rec, intrinsics="fixed")
    assert info["rigs"] == {"sensors": 4, "frames": 16}
    # the rig composition reproduces COLMAP's image poses
    res = adjust(block, BundleSettings(datum="free", max_iter=3))
    np.testing.assert_allclose(res.state.X0, block.photos.X0, atol=1e-9)
    for fmt in ("text", "binary"):
        write_colmap(block, tmp_path / fmt, fmt=fmt)
        b2, i2 = read_colmap(tmp_path / fmt, intrinsics="fixed")
        assert i2["rigs"] == info["rigs"]
        np.testing.assert_allclose(b2.rigs.sensors.centre, block.rigs.sensors.centre, atol=1e-12)
        np.testing.assert_allclose(b2.rigs.sensors.opk, block.rigs.sensors.opk, atol=1e-12)
        assert (b2.rigs.frames.frame == block.rigs.frames.frame).all()
        np.testing.assert_allclose(b2.photos.X0, block.photos.X0, atol=1e-12)
    assert (tmp_path / "text" / "rigs.txt").read_text().count("CAMERA") >= 4


def test_synthetic_rig_truth_and_pycolmap_crosscheck():
    from baarda.plugins.crosscheck.compare import crosscheck
    from baarda.plugins.crosscheck.pycolmap_ba import SolverSettings

    rec, truth = _synthetic(seed=3)
    block, _ = block_from_reconstruction(rec, sigma_px=0.5)
    res = adjust(block, BundleSettings(datum="free"))
    assert abs(res.sigma0_hat - 1) < 0.15
    rr = rig_result(res)
    for s in rr.sensors:
        if s.reference_sensor:
            continue
        d = (s.value[3:] - truth[int(s.camera)]) / s.sigma[3:]
        assert np.all(np.abs(d) < 4), (s.camera, d)           # the relative rotation: datum-invariant
    cc = crosscheck(res, solver=SolverSettings(covariance=False))
    assert cc.plan.sensor_constant is not None and not cc.plan.sensor_constant[~block.rigs.sensors.reference].any()
    baarda_cost = 0.5 * res.vtpv / res.settings.sigma0 ** 2
    assert abs(cc.solution.final_cost - baarda_cost) <= 1e-6 * baarda_cost
    np.testing.assert_allclose(cc.solution.X0[res.photo_used], res.state.X0[res.photo_used], atol=1e-6)
    rs = cc.quantities["rig_sensors"]
    assert rs["n"] == 2 and rs["max"] < 1e-3                    # pycolmap's sensor_from_rig: baarda's, in σ
