"""A camera rig moved around a close-range point cloud (the rig tests, ``docs/rigs.md``).

``n_frames`` poses of a rig of cameras (sensors): the reference camera looks at the cloud from a
cap around it, every other sensor sits at its given pose in the rig (``sensors``: projection centre
in the rig frame, object unit, and ω, φ, κ of ``R_sensor_from_rig``).  Each sensor is its own
camera; the geometry is drawn from ``seed``, the image noise from ``rng``; the projection is the
bundle's collinearity.  Returns the block with its :class:`~baarda.pipeline.model.Rigs` and the
truth.
"""

from __future__ import annotations

__all__ = ["make_rig_block", "STEREO"]

import numpy as np

from baarda.pipeline.geometry import opk_from_rotation, rotation_from_opk_many
from baarda.pipeline.model import FREE, Block, Cameras, FrameMembers, Observations, Photos, Points, RigSensors, Rigs

from .closerange import look_at

STEREO = ((0.0, 0.0, 0.0, 0.0, 0.0, 0.0), (0.30, 0.01, -0.02, 0.02, -0.08, 0.01))
"""A stereo bar: the right camera 0.3 m beside the left one, turned 4.6° inwards."""


def make_rig_block(rng=None, *, n_frames=8, n_points=60, sensors=STEREO, c=25.0, noise_mm=0.0, sigma_mm=0.001,
                   n_control=6, seed=2, free_iop=False):
    """``(block, truth)``: truth = dict(frame (F, 6), sensor (S, 6), X0, opk (m, 3), XYZ)."""
    from baarda.pipeline.adjustment import project_observations

    g = np.random.default_rng(seed)
    rng = rng if rng is not None else np.random.default_rng(seed + 100)
    XYZ = np.column_stack([g.uniform(-1, 1, n_points), g.uniform(-0.8, 0.8, n_points),
                           g.uniform(-0.4, 0.4, n_points)])
    sensors = np.asarray(sensors, float)
    S = len(sensors)
    frames = []
    for i in range(n_frames):
        az = 2 * np.pi * i / n_frames
        C = np.array([2.0 * np.sin(az), 1.0 * np.cos(az) + 0.3 * (i % 2), 3.2 + 0.2 * (i % 3)])
        R = look_at(C, np.array([0.1 * np.cos(3 * az), 0.1 * np.sin(2 * az), 0.0]), roll=0.3 * (i % 3) + 0.05 * i)
        frames.append(np.r_[C - 0.15 * R.T @ np.array([1.0, 0, 0]), opk_from_rotation(R)])
    frames = np.array(frames)
    Rf = rotation_from_opk_many(frames[:, 3:])
    Rs = rotation_from_opk_many(sensors[:, 3:])
    X0, opk, cam_of, ids = [], [], [], []
    for f in range(n_frames):
        for s in range(S):
            X0.append(frames[f, :3] + Rf[f].T @ sensors[s, :3])
            opk.append(opk_from_rotation(Rs[s] @ Rf[f]))
            cam_of.append(s)
            ids.append(f"S{s + 1}_{f + 1:02d}")
    X0, opk, cam_of = np.array(X0), np.array(opk), np.array(cam_of)
    m = len(X0)
    ph = np.repeat(np.arange(m), n_points)
    pt = np.tile(np.arange(n_points), m)
    cam_params = np.tile([c, 0.0, 0.0], (S, 1))
    pr = project_observations(ph, pt, XYZ, X0, opk, cam_of, cam_params, ["none"] * S, None, jacobians=False)
    inside = (pr.W < 0) & (np.abs(pr.xy[:, 0]) < 18) & (np.abs(pr.xy[:, 1]) < 12)
    xy = pr.xy + noise_mm * rng.standard_normal(pr.xy.shape)
    ph, pt, xy = ph[inside], pt[inside], xy[inside]
    cams = Cameras.make([f"S{s + 1}" for s in range(S)], c, 0.0, 0.0,
                        sigma_iop=np.full(3, FREE if free_iop else 0.0), format_mm=(36.0, 24.0))
    photos = Photos.make(ids, cam_of, X0, opk)
    role = np.array(["tie"] * n_points, dtype=object)
    role[:n_control] = "full"
    points = Points.make([str(100 + i) for i in range(n_points)], XYZ, role)
    obs = Observations.make(ph, pt, xy, sigma=sigma_mm)
    rig = RigSensors.make(["rig"] * S, np.arange(S), np.arange(S) == 0)
    members = FrameMembers(frame=np.array([f"F{f + 1:02d}" for f in range(n_frames) for _ in range(S)]),
                           photo=np.arange(m))
    block = Block(cams, photos, points, obs, rigs=Rigs(rig, members))
    return block, {"frame": frames, "sensor": sensors, "X0": X0, "opk": opk, "XYZ": XYZ}
