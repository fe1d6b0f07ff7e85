"""The bundle's recording of a rig (``plugins/bundle/rrlog.py``, ``docs/recordings.md``): each
frame's pose and each sensor's pose in the rig as transforms under ``world/rigs/<rig>/frames/<frame>``
that compose to the photo's adjusted pose, the photos of frames not drawn twice, and the sensors'
poses with σ as values and a text view."""

import numpy as np

from baarda.pipeline.geometry import rotation_from_opk
from baarda.pipeline.recording import read_recording
from baarda.pipeline.synthetic.rig import make_rig_block
from baarda.pipeline.testing import check_recording, log_stage, run_stage
from baarda.plugins.bundle.stage import BundleAdjustment


def _static_values(path):
    """entity path → {column: first value} of the recording's static chunks."""
    from rerun.chunk import RrdReader

    out = {}
    for chunk in RrdReader(str(path)).stream().to_chunks():
        if not chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        d = out.setdefault(str(chunk.entity_path), {})
        for name, col in zip(batch.schema.names, batch.columns):
            v = col.to_pylist()[0]
            while isinstance(v, list) and len(v) == 1:
                v = v[0]
            d[name] = v
    return out


def test_rig_frames_and_sensors_compose_to_the_photo_poses(tmp_path):
    block, truth = make_rig_block(np.random.default_rng(4), n_frames=4, n_points=30, noise_mm=0.001)
    res = run_stage(BundleAdjustment, {"block": block}, {}, tmp_path=tmp_path)
    path = log_stage(BundleAdjustment, res, tmp_path / "bundle.rrd")
    check_recording(path)
    rec = read_recording(path)
    paths = {e.path for e in rec.entities}
    assert not any(p.startswith("/bundle/world/photos/") for p in paths)       # drawn under the rig instead
    vals = _static_values(path)
    eo = res.tables["eo"].columns
    ids = [str(p) for p in eo["photo"]]
    for f in range(4):
        frame = vals[f"/bundle/world/rigs/rig/frames/F{f + 1:02d}"]
        t_f = np.array(frame["Transform3D:translation"])
        R_wf = np.array(frame["Transform3D:mat3x3"]).reshape(3, 3).T           # rerun: column-major
        assert "TransformAxes3D:axis_length" in frame
        for s, cam in enumerate(("S1", "S2")):
            sensor = vals[f"/bundle/world/rigs/rig/frames/F{f + 1:02d}/{cam}"]
            assert sensor["photo"] == f"{cam}_{f + 1:02d}"
            assert "Pinhole:image_from_camera" in sensor
            t_s = np.array(sensor["Transform3D:translation"])
            R_rs = np.array(sensor["Transform3D:mat3x3"]).reshape(3, 3).T
            # world_from_sensor = world_from_rig · rig_from_sensor: the photo's adjusted pose
            k = ids.index(sensor["photo"])
            X0 = np.array([eo[c][k] for c in ("X0_m", "Y0_m", "Z0_m")])
            opk = np.radians([eo["omega_deg"][k], eo["phi_deg"][k], eo["kappa_deg"][k]])
            np.testing.assert_allclose(t_f + R_wf @ t_s, X0, atol=1e-6)
            np.testing.assert_allclose(R_wf @ R_rs, rotation_from_opk(*opk).T, atol=1e-6)
        assert f"/bundle/world/rigs/rig/frames/F{f + 1:02d}/baselines" in paths
    right = vals["/bundle/rigs/rig/sensors/S2"]
    np.testing.assert_allclose([right["X_m"], right["Y_m"], right["Z_m"]], truth["sensor"][1, :3], atol=5e-3)
    assert right["sX_m"] > 0 and right["sbaseline_m"] > 0 and right["status"] == "estimated"
    assert abs(right["baseline_m"] - np.linalg.norm(truth["sensor"][1, :3])) < 5 * right["sbaseline_m"] + 1e-4
    text = vals["/bundle/rigs/rig/sensors"]["TextDocument:text"]
    assert "**S2** (estimated): baseline" in text and "± " in text
    assert any(v.kind == "TextDocument" and v.origin == "/bundle/rigs/rig/sensors" for v in rec.views)
