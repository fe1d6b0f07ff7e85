"""The protocol summary's numbers of an adjustment — pure numerics (numpy; no files, no plots).

A *protocol* is the JSON-friendly dict a stage puts under ``summary["protocol"]``; the engine
prints it first in ``report.html`` (:mod:`baarda.pipeline.html`) and ``results.json`` holds the
same values.  :func:`snapshot_protocol` gives the part every adjustment has (σ̂0, the global
test, RMS of the residuals, the smallest redundancy number, the largest MDB, what the w-test
flagged); the bundle stage adds photos, points, cameras and scale bars
(``baarda.plugins.bundle.protocol``).  Keys (all optional except ``kind``)::

    kind, adjustment, sigma0, sigma0_hat, dof,
    global_test{T, critical, critical_lower, alpha, method, p_value, rejected, verdict, interval},
    unit, rms{x, y, all, n}, rms_per_camera[…], n_cameras, rms_per_photo[…], n_photos, opencv_rms_px,
    point_precision{…}, scale_bars[…], control{…}, check{…}, reliability{…}, tests{…},
    cameras[…], n_cameras_used, warnings[…]
"""

from __future__ import annotations

import numpy as np

from . import stats
from .units import fmt_num, fmt_q

MOST_LABELS = 10
"""Labels listed per category (flagged, rejected); the counts are always complete."""


def rms(a) -> float:
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a * a))) if a.size else float("nan")


def global_test_protocol(gt) -> dict:
    """The protocol's ``global_test`` entry of a :class:`~baarda.pipeline.stats.GlobalTestResult`."""
    return {"T": float(gt.T), "critical": float(gt.critical), "critical_lower": float(gt.critical_lower),
            "alpha": float(gt.alpha), "method": gt.method, "p_value": float(gt.p_value),
            "rejected": bool(gt.rejected), "verdict": gt.verdict, "dof": int(gt.dof),
            "interval": [float(gt.interval[0]), float(gt.interval[1])]}


def global_test_text(g: dict, unit: str = "") -> str:
    """The global test as metrology packages print it, from a protocol's ``global_test`` entry:
    ``T = σ̂0²/σ0² = 1.032, p = 0.41 (two-sided χ², α = 5 %; 95 % interval of σ̂0: 0.9610–1.039):
    accepted``.  ``unit``: that of σ0 (the interval's bounds are σ̂0 values), "" for a variance factor."""
    def q(x):
        return fmt_q(x, unit) if unit else fmt_num(x)
    if g.get("method") == "B-method":
        level = f"B-method, one-sided, α′ = {fmt_num(g['alpha'], 3)}"
        bounds = f"F-critical {fmt_num(g['critical'])}"
    else:
        level = f"two-sided χ², α = {100 * g['alpha']:g} %"
        bounds = f"{100 * (1 - g['alpha']):g} % interval of σ̂0: {q(g['interval'][0])} – {q(g['interval'][1])}"
    verdict = g.get("verdict") or ("rejected" if g["rejected"] else "accepted")
    if g["rejected"]:
        verdict = "REJECTED" + verdict[len("rejected"):]
    p = g["p_value"]
    ptext = "p < 1e-300" if p == 0 else f"p = {fmt_num(p, 3)}"      # below the smallest double scipy returns
    return f"T = σ̂0²/σ0² = {fmt_num(g['T'])}, {ptext} ({level}; {bounds}): {verdict}"


def snapshot_protocol(snap, *, name: str, alpha0: float = 0.001, beta0: float = 0.80, unit: str = "",
                      scale: float = 1.0, coordinate_rows=None,
                      alpha_global: float | str = stats.ALPHA_GLOBAL) -> dict:
    """The protocol of one adjustment's :class:`~baarda.pipeline.stats.Snapshot`.

    ``scale`` multiplies residuals and MDBs into ``unit`` (e.g. 1000 for mm → µm);
    ``coordinate_rows`` (n,) int: 0 for x, 1 for y, −1 for other rows (weighted constraints), for
    the RMS per coordinate (default: every row counts in ``all`` only).
    """
    active = np.asarray(snap.active, bool)
    gt = stats.global_test(snap, alpha=alpha_global, alpha0=alpha0, beta0=beta0)
    ds = stats.data_snooping(snap, alpha0=alpha0, beta0=beta0)
    v = np.asarray(snap.v, float) * scale
    xy = np.full(len(v), -1) if coordinate_rows is None else np.asarray(coordinate_rows, int)
    obs = active & ((xy >= 0) if coordinate_rows is not None else True)
    out = {
        "kind": "adjustment", "adjustment": name, "sigma0": float(snap.sigma0),
        "sigma0_hat": float(snap.sigma0_hat), "dof": int(snap.dof),
        "global_test": global_test_protocol(gt),
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
