"""Make ``fixtures/colmap/rig/``: a synthetic COLMAP text model of a three-camera rig (COLMAP ≥ 3.12
``rigs.txt`` / ``frames.txt``) and a prior calibration of the rig as a baarda rig table.

    .venv/bin/python tools/make_rig_fixture.py        # rewrites fixtures/colmap/rig/model/, calibration.csv, truth.json
    .venv/bin/python tools/make_rig_fixture.py DIR    # writes them into DIR instead

Geometry from baarda's simulated rig (``baarda.pipeline.synthetic.rig.make_rig_block``, seed 4):
a rig of three cameras (``front`` the reference, ``left`` and ``right`` 0.25 m and 0.30 m beside it,
turned outwards) moved through 8 frames around 80 points.  The image points are projected by
**pycolmap** (``Image.project_point`` of the frame's ``rig_from_world`` composed with the sensor's
``sensor_from_rig``) and checked against baarda's collinearity (to 1e-6 px), so the rig convention
of ``rigs.txt`` is COLMAP's own; Gaussian noise of 0.5 px (seed 11) is added.  The model's frame
poses, sensor poses and points are the true ones disturbed (2 mm / 0.02°, 1 mm / 0.02°, 2 mm): the
state a COLMAP reconstruction with a rig hands over.  The model is metric (metres).

``calibration.csv`` is a *prior* calibration of the rig (a lab calibration, say): ``left`` agrees
with the truth within its σ (1 mm, 0.02°), ``right`` is deliberately 5 mm off in Y (across the baseline) and 0.1° off in φ
(the rig was knocked since) — the bundle's stability test is expected to flag ``right`` only.
``truth.json`` holds the true sensor poses.  The same seed gives the same files, bit for bit.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pycolmap

from baarda.pipeline.geometry import opk_from_rotation, rotation_from_opk_many
from baarda.pipeline.geometry.pose import cv_from_pose
from baarda.pipeline.synthetic.rig import make_rig_block

OUT = Path(__file__).resolve().parent.parent / "fixtures" / "colmap" / "rig"
SENSORS = {"front": (0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
           # centre in the rig frame (m; x right, y up, z back), ω φ κ of R_sensor_from_rig (degrees)
           "left": (-0.25, 0.005, -0.03, 0.5, 6.0, -0.8),
           "right": (0.30, -0.01, -0.02, -0.4, -8.0, 1.2)}
C_MM, PIXEL_MM, W, H = 25.0, 0.006, 6000, 4000
NOISE_PX = 0.5
PRIOR_SIGMA = (0.001, 0.001, 0.001, 0.02, 0.02, 0.02)       # m, m, m, °, °, °
PRIOR_OFF = {"right": (0.0, 0.005, 0.0, 0.0, 0.1, 0.0)}      # the prior's deliberate error (m, °)
F = np.diag([1.0, -1.0, -1.0])


def main(out_dir: Path = OUT):
    """Write the model, the calibration and the truth into ``out_dir``."""
    sens = np.array([s[:3] + tuple(np.radians(s[3:])) for s in SENSORS.values()])
    block, truth = make_rig_block(n_frames=8, n_points=80, sensors=sens, c=C_MM, noise_mm=0.0, seed=4)
    obs = block.observations
    names = list(SENSORS)
    S, nF = len(names), len(truth["frame"])
    rng = np.random.default_rng(11)

    def poses(frames, sensors):
        """pycolmap rig_from_world of each frame and sensor_from_rig of each sensor (y-down frames)."""
        Rf, tf = cv_from_pose(frames[:, :3], frames[:, 3:])
        Rs = rotation_from_opk_many(sensors[:, 3:])
        rig_from_world = [pycolmap.Rigid3d(pycolmap.Rotation3d(Rf[f]), tf[f]) for f in range(len(frames))]
        sensor_from_rig = [pycolmap.Rigid3d(pycolmap.Rotation3d(F @ Rs[s] @ F), -F @ Rs[s] @ sensors[s, :3])
                           for s in range(len(sensors))]
        return rig_from_world, sensor_from_rig

    def reconstruction(frames, sensors, XYZ, keypoints):
        rig_from_world, sensor_from_rig = poses(frames, sensors)
        rec = pycolmap.Reconstruction()
        cam_t = pycolmap.SensorType.CAMERA
        for s in range(S):
            cam = pycolmap.Camera.create_from_model_name(s + 1, "PINHOLE", C_MM / PIXEL_MM, W, H)
            rec.add_camera(cam)
        rig = pycolmap.Rig(rig_id=1)
        rig.add_ref_sensor(pycolmap.sensor_t(type=cam_t, id=1))
        for s in range(1, S):
            rig.add_sensor(pycolmap.sensor_t(type=cam_t, id=s + 1), sensor_from_rig[s])
        rec.add_rig(rig)
        for f in range(nF):
            frame = pycolmap.Frame(frame_id=f + 1, rig_id=1)
            for s in range(S):
                frame.add_data_id(pycolmap.data_t(sensor_id=pycolmap.sensor_t(type=cam_t, id=s + 1),
                                                  id=f * S + s + 1))
            frame.rig_from_world = rig_from_world[f]
            rec.add_frame(frame)
        for f in range(nF):
            for s in range(S):
                k = f * S + s
                image = pycolmap.Image(name=f"{names[s]}/{f + 1:04d}.jpg", keypoints=keypoints[k], camera_id=s + 1,
                                       image_id=k + 1)
                image.frame_id = f + 1
                rec.add_image(image)
        for j in np.unique(obs.point):
            track = pycolmap.Track()
            for r in np.flatnonzero(obs.point == j):
                track.add_element(int(obs.photo[r]) + 1, int(kp_index[r]))
            rec.add_point3D(XYZ[j], track, np.array([200, 200, 200], np.uint8))
        return rec

    # the photo index of make_rig_block is frame-major (f * S + s), as the image ids here
    kp_index = np.zeros(len(obs), int)
    for k in range(nF * S):
        rows = np.flatnonzero(obs.photo == k)
        kp_index[rows] = np.arange(rows.size)
    # baarda's image points (mm, y up, origin at the format centre) as pixels
    uv_b = np.column_stack([obs.xy[:, 0] / PIXEL_MM + W / 2, -obs.xy[:, 1] / PIXEL_MM + H / 2])
    # the same points projected by pycolmap through the rig: the convention check
    true_rec = reconstruction(truth["frame"], truth["sensor"], truth["XYZ"],
                              [uv_b[obs.photo == k] for k in range(nF * S)])
    uv_c = np.array([true_rec.images[int(obs.photo[r]) + 1].project_point(truth["XYZ"][obs.point[r]])
                     for r in range(len(obs))])
    assert np.abs(uv_c - uv_b).max() < 1e-6, f"pycolmap's rig projection differs: {np.abs(uv_c - uv_b).max()} px"
    uv = uv_c + NOISE_PX * rng.standard_normal(uv_c.shape)

    frames = truth["frame"] + np.r_[[0.002] * 3, [np.radians(0.02)] * 3] * rng.standard_normal(truth["frame"].shape)
    sensors = truth["sensor"] + np.r_[[0.001] * 3, [np.radians(0.02)] * 3] * rng.standard_normal(sens.shape)
    sensors[0] = 0.0
    XYZ = truth["XYZ"] + 0.002 * rng.standard_normal(truth["XYZ"].shape)
    rec = reconstruction(frames, sensors, XYZ, [uv[obs.photo == k] for k in range(nF * S)])
    out = Path(out_dir) / "model"
    out.mkdir(parents=True, exist_ok=True)
    rec.write_text(str(out))

    # the prior calibration: the truth, within its σ (seed 11 continues), and 'right' knocked
    sig = np.array(PRIOR_SIGMA)
    lines = ["# A prior calibration of the rig (made by tools/make_rig_fixture.py): 'right' was knocked since",
             "# (5 mm in Y, 0.1° in φ) — the bundle's stability test should say so.  Cameras are the",
             "# COLMAP camera ids of model/cameras.txt (1 front, 2 left, 3 right).",
             "# A COLMAP model without control points is in model units (_mu): here metres, the scale of the",
             "# rig's metric sensor_from_rig poses.",
             "rig,camera,reference,status,X_mu,Y_mu,Z_mu,omega_deg,phi_deg,kappa_deg,"
             "sX_mu,sY_mu,sZ_mu,somega_deg,sphi_deg,skappa_deg",
             "rig,1,yes,fixed,0,0,0,0,0,0,,,,,,"]
    for s in range(1, S):
        v = np.r_[truth["sensor"][s, :3], np.degrees(truth["sensor"][s, 3:])] + sig * rng.standard_normal(6)
        v += np.array(PRIOR_OFF.get(names[s], np.zeros(6)))
        lines.append(f"rig,{s + 1},no,weighted," + ",".join(f"{x:.6f}" for x in v) + ","
                     + ",".join(f"{x:g}" for x in sig))
    (Path(out_dir) / "calibration.csv").write_text("\n".join(lines) + "\n")
    (Path(out_dir) / "truth.json").write_text(json.dumps(
        {"sensors": {n: {"camera_id": s + 1,
                         "centre_m": [round(float(x), 9) for x in truth["sensor"][s, :3]],
                         "omega_phi_kappa_deg": [round(float(x), 9) for x in np.degrees(truth["sensor"][s, 3:])],
                         "baseline_m": round(float(np.linalg.norm(truth["sensor"][s, :3])), 9)}
                     for s, n in enumerate(names)},
         "prior_error": {n: {"centre_m": list(v[:3]), "omega_phi_kappa_deg": list(v[3:])}
                         for n, v in PRIOR_OFF.items()},
         "camera": {"model": "PINHOLE", "f_px": C_MM / PIXEL_MM, "size_px": [W, H], "pixel_mm": PIXEL_MM},
         "noise_px": NOISE_PX, "frames": nF, "images": nF * S, "points": int(np.unique(obs.point).size),
         "observations": int(len(obs))}, indent=1) + "\n")
    print(f"{nF} frames × {S} cameras, {np.unique(obs.point).size} points, {len(obs)} observations → {out_dir}")


if __name__ == "__main__":
    import sys

    main(Path(sys.argv[1]) if len(sys.argv) > 1 else OUT)
