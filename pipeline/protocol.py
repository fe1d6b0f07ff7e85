"""The protocol summary's numbers of an adjustment — pure numerics (numpy; no files, no plots).

A *protocol* is the JSON-friendly dict a stage puts under ``summary["protocol"]``; the engine
prints it first in ``report.html`` (:mod:`baarda.pipeline.html`) and ``results.json`` holds the
same values.  :func:`snapshot_protocol` gives the part every adjustment has (σ̂0, the global
test, RMS of the residuals, the smallest redundancy number, the largest MDB, what the w-test
flagged); the bundle stage adds photos, points, cameras and scale bars
(``baarda.plugins.bundle.protocol``).  Keys (all optional except ``kind``)::

    kind, adjustment, sigma0, sigma0_hat, dof, global_test{T, critical, alpha, rejected},
    unit, rms{x, y, all, n}, rms_per_camera[…], n_cameras, rms_per_photo[…], n_photos, opencv_rms_px,
    point_precision{…}, scale_bars[…], control{…}, check{…}, reliability{…}, tests{…},
    cameras[…], n_cameras_used, warnings[…]
"""

from __future__ import annotations

import numpy as np

from . import stats

MOST_LABELS = 10
"""Labels listed per category (flagged, rejected); the counts are always complete."""


def rms(a) -> float:
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a * a))) if a.size else float("nan")


def snapshot_protocol(snap, *, name: str, alpha0: float = 0.001, beta0: float = 0.80, unit: str = "",
                      scale: float = 1.0, coordinate_rows=None) -> dict:
    """The protocol of one adjustment's :class:`~baarda.pipeline.stats.Snapshot`.

    ``scale`` multiplies residuals and MDBs into ``unit`` (e.g. 1000 for mm → µm);
    ``coordinate_rows`` (n,) int: 0 for x, 1 for y, −1 for other rows (weighted constraints), for
    the RMS per coordinate (default: every row counts in ``all`` only).
    """
    active = np.asarray(snap.active, bool)
    gt = stats.global_test(snap, alpha0=alpha0, beta0=beta0)
    ds = stats.data_snooping(snap, alpha0=alpha0, beta0=beta0)
    v = np.asarray(snap.v, float) * scale
    xy = np.full(len(v), -1) if coordinate_rows is None else np.asarray(coordinate_rows, int)
    obs = active & ((xy >= 0) if coordinate_rows is not None else True)
    out = {
        "kind": "adjustment", "adjustment": name, "sigma0": float(snap.sigma0),
        "sigma0_hat": float(snap.sigma0_hat), "dof": int(snap.dof),
        "global_test": {"T": gt.T, "critical": gt.critical, "alpha": gt.alpha, "rejected": bool(gt.rejected)},
        "unit": unit,
        "rms": {"x": rms(v[active & (xy == 0)]), "y": rms(v[active & (xy == 1)]), "all": rms(v[obs]),
                "n": int(obs.sum())},
    }
    r = np.asarray(snap.r, float)
    ctrl = active & (r > 1e-9)
    rel = {"r_min": float("nan"), "r_min_label": "", "r_mean": float("nan"), "n_uncontrolled": int((active & ~ctrl).sum()),
           "mdb_max": float("nan"), "mdb_max_label": "", "delta0": float(ds.delta0)}
    if ctrl.any():
        i = int(np.flatnonzero(ctrl)[np.argmin(r[ctrl])])
        rel.update(r_min=float(r[i]), r_min_label=str(snap.labels[i]), r_mean=float(np.mean(r[ctrl])))
        m = np.where(ctrl, ds.mdb, -np.inf)
        k = int(np.argmax(m))
        rel.update(mdb_max=float(ds.mdb[k] * scale), mdb_max_label=str(snap.labels[k]), mdb_max_row=k)
    out["reliability"] = rel
    flagged = np.flatnonzero(ds.flagged)
    flagged = flagged[np.argsort(-np.abs(ds.w[flagged]))]
    wmax = int(ds.largest) if ds.largest is not None else None
    out["tests"] = {"critical_w": float(ds.critical), "alpha0": float(alpha0), "n_tested": int(ctrl.sum()),
                    "n_flagged": int(flagged.size), "flagged": [str(snap.labels[i]) for i in flagged[:MOST_LABELS]],
                    "w_max": float(ds.w[wmax]) if wmax is not None else float("nan"),
                    "w_max_label": str(snap.labels[wmax]) if wmax is not None else "",
                    "n_rejected": 0, "rejected": []}
    return out
