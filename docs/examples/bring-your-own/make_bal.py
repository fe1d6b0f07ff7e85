"""Write your own measurements as a BAL file: here 6 cameras around 40 points, made up with numpy."""
import numpy as np
from scipy.spatial.transform import Rotation

rng = np.random.default_rng(7)
points = rng.uniform(-1, 1, (40, 3)) * [2.0, 2.0, 0.5]          # object points (m)
f, k1, k2 = 1500.0, 0.0, 0.0                                       # focal length (px), radial terms
cameras, obs = [], []
for i, a in enumerate(np.linspace(0, 2 * np.pi, 6, endpoint=False)):
    centre = np.array([6 * np.cos(a), 6 * np.sin(a), 3.0])
    # BAL cameras look down their −Z axis: −Z towards the block's centre
    z = centre / np.linalg.norm(centre)
    x = np.cross([0, 0, 1], z); x /= np.linalg.norm(x)
    R = np.vstack([x, np.cross(z, x), z])                          # world → camera rotation
    t = -R @ centre
    cameras.append(np.r_[Rotation.from_matrix(R).as_rotvec(), t, f, k1, k2])
    for j, X in enumerate(points):
        P = R @ X + t
        p = -P[:2] / P[2]                                          # BAL's projection
        uv = f * p + rng.normal(0, 0.5, 2)                         # pixels, origin centre, y up; 0.5 px noise
        obs.append((i, j, *uv))
with open("mine.txt", "w") as out:
    out.write(f"{len(cameras)} {len(points)} {len(obs)}\n")
    for i, j, u, v in obs:
        out.write(f"{i} {j} {u:.4f} {v:.4f}\n")
    for c in cameras:                                              # start values: the truth disturbed
        out.write("\n".join(f"{v:.9g}" for v in c + np.r_[rng.normal(0, 0.01, 3), rng.normal(0, 0.05, 3), 0, 0, 0]) + "\n")
    for X in points:
        out.write("\n".join(f"{v:.9g}" for v in X + rng.normal(0, 0.05, 3)) + "\n")
