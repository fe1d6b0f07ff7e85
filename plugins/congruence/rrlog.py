"""The congruence stage in the recording: both epochs' points and the displacements as arrows."""

from __future__ import annotations

import numpy as np


def log_congruence(rec, comparisons) -> None:
    import rerun as rr

    colours = {"moved": (192, 57, 43), "stable": (31, 78, 156), "object point": (127, 140, 141)}
    for c in comparisons:
        ref, ep = c["ref"], c["epoch"]
        base = f"congruence/{ep.name}"
        Xa, Xb = ref.XYZ[c["ia"]], ep.XYZ[c["ib"]]
        cols = np.array([colours[s] for s in c["status"]], np.uint8)
        rec.log(f"{base}/{ref.name}", rr.Points3D(Xa, labels=list(c["common"]), colors=(150, 150, 150)), static=True)
        rec.log(f"{base}/{ep.name}", rr.Points3D(Xb, colors=cols), static=True)
        length = np.linalg.norm(c["d"], axis=1)
        span = float(np.ptp(Xb, axis=0).max()) or 1.0
        scale = 0.1 * span / max(float(length.max()), 1e-300)
        rec.log(f"{base}/displacements", rr.Arrows3D(origins=Xa, vectors=c["d"] * scale, colors=cols,
                                                      labels=[f"{p} {s}" for p, s in zip(c["common"], c["status"])]),
                static=True)
        rec.log(f"{base}/scale", rr.TextDocument(f"displacement arrows drawn × {scale:.4g}"), static=True)
