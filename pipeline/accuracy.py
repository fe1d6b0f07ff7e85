"""Accuracy at check points: adjusted minus surveyed coordinates (paper 001, eqs. 2.19–2.22).

Pure numerics, one definition for every adjustment (bundle, independent models, the studies).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["check_point_rmse", "CheckPoints"]

STATISTICS = ("n", "undetermined", "Sx", "Sy", "Sxy", "Sz")
"""The statistics of :func:`check_point_rmse` and :class:`CheckPoints`, in the order a summary lists them."""


def check_point_rmse(adjusted, surveyed) -> dict:
    """``Sx = √(Σ(Xp − XG)²/n_x)``, likewise ``Sy``, ``Sz``; ``Sxy = √((Sx² + Sy²)/2)``.

    ``adjusted``, ``surveyed``: ``(n, 3)``; errors are adjusted minus surveyed.  A coordinate whose
    error is not finite (a point the adjustment could not determine, or one without a surveyed
    value) is left out of that coordinate's sum — it is counted in ``undetermined``, never averaged
    away silently.  Returns ``{"n", "undetermined", "Sx", "Sy", "Sxy", "Sz", "errors"}``: ``n`` the
    points with at least one finite error; ``nan`` for a coordinate without any; ``errors (n, 3)``.
    """
    d = np.asarray(adjusted, float).reshape(-1, 3) - np.asarray(surveyed, float).reshape(-1, 3)
    return {**_statistics(d), "errors": d}


def _statistics(d: np.ndarray) -> dict:
    fin = np.isfinite(d)
    out: dict = {"n": int(np.sum(fin.any(axis=1))), "undetermined": int(np.sum(~fin.all(axis=1)))}
    for k, c in enumerate("xyz"):
        dk = d[fin[:, k], k]
        out[f"S{c}"] = float(np.sqrt(np.mean(dk * dk))) if dk.size else float("nan")
    out["Sxy"] = float(np.sqrt((out["Sx"] ** 2 + out["Sy"] ** 2) / 2))
    return {k: out[k] for k in STATISTICS}


@dataclass(frozen=True, eq=False)
class CheckPoints:
    """The check points of an adjustment: their ``ids``, ``errors`` (n, 3) adjusted − surveyed
    (read-only) and the statistics of :func:`check_point_rmse` (``n`` points with a finite error,
    ``undetermined``, ``Sx``, ``Sy``, ``Sxy``, ``Sz``; ``nan`` without any).  Built with
    :meth:`of` or :meth:`from_errors`; ``bool(check)`` is False without a check point."""

    ids: tuple
    errors: np.ndarray
    n: int
    undetermined: int
    Sx: float
    Sy: float
    Sxy: float
    Sz: float

    @classmethod
    def from_errors(cls, ids, errors) -> CheckPoints:
        """From the point ids and their errors adjusted − surveyed ``(n, 3)`` (copied)."""
        d = np.array(errors, float).reshape(-1, 3)
        ids = tuple(np.asarray(ids).tolist())
        if len(ids) != len(d):
            raise ValueError(f"{len(ids)} check-point ids for {len(d)} errors")
        d.flags.writeable = False
        return cls(ids, d, **_statistics(d))

    @classmethod
    def of(cls, ids, adjusted, surveyed) -> CheckPoints:
        """From adjusted and surveyed coordinates ``(n, 3)`` of the points ``ids``."""
        return cls.from_errors(ids, np.asarray(adjusted, float).reshape(-1, 3)
                               - np.asarray(surveyed, float).reshape(-1, 3))

    def __bool__(self) -> bool:
        return self.n > 0

    def rmse(self) -> dict:
        """``{"n", "undetermined", "Sx", "Sy", "Sxy", "Sz"}`` (plain numbers)."""
        return {k: getattr(self, k) for k in STATISTICS}

    def summary(self) -> dict:
        """The statistics and the ids (a list), for a stage's summary (results.json)."""
        return {**self.rmse(), "ids": list(self.ids)}
