"""Accuracy at check points: adjusted minus surveyed coordinates (paper 001, eqs. 2.19–2.22).

Pure numerics, one definition for every adjustment (bundle, independent models, the studies).
"""

from __future__ import annotations

import numpy as np

__all__ = ["check_point_rmse"]


def check_point_rmse(adjusted, surveyed) -> dict:
    """``Sx = √(Σ(Xp − XG)²/n_x)``, likewise ``Sy``, ``Sz``; ``Sxy = √((Sx² + Sy²)/2)``.

    ``adjusted``, ``surveyed``: ``(n, 3)``; errors are adjusted minus surveyed.  A coordinate whose
    error is not finite (a point the adjustment could not determine, or one without a surveyed
    value) is left out of that coordinate's sum — it is counted in ``undetermined``, never averaged
    away silently.  Returns ``{"n", "undetermined", "Sx", "Sy", "Sxy", "Sz", "errors"}``: ``n`` the
    points with at least one finite error; ``nan`` for a coordinate without any; ``errors (n, 3)``.
    """
    d = np.asarray(adjusted, float).reshape(-1, 3) - np.asarray(surveyed, float).reshape(-1, 3)
    fin = np.isfinite(d)
    out: dict = {"n": int(np.sum(fin.any(axis=1))), "undetermined": int(np.sum(~fin.all(axis=1)))}
    for k, c in enumerate("xyz"):
        dk = d[fin[:, k], k]
        out[f"S{c}"] = float(np.sqrt(np.mean(dk * dk))) if dk.size else float("nan")
    out["Sxy"] = float(np.sqrt((out["Sx"] ** 2 + out["Sy"] ** 2) / 2))
    out = {k: out[k] for k in ("n", "undetermined", "Sx", "Sy", "Sxy", "Sz")}
    out["errors"] = d
    return out
