"""Stage ``epoch-simulate``: a later epoch of a real network with known target displacements.

From an adjusted epoch (``bundle``): the chosen targets are displaced by known vectors, every image
coordinate is recomputed from the adjusted orientations and cameras (the bundle's own collinearity),
and the real residuals of the adjustment are added back — the same residual at each observation
(``residuals = "same"``: the displacements then come out exactly, noise-free), or the residuals of
each target shuffled among the photos that see it (``"resampled"``, the default: each target keeps
its own residual behaviour — target quality, eccentricity — but the noise of a coordinate in epoch 2
is not that of epoch 1, so that the congruence test sees two measurements of the object). The new block starts from
the input block's approximations (so the next bundle adjusts it from scratch) with the displaced
targets' approximations moved as well. ``docs/monitoring.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from baarda.pipeline.api import Stage, StageResult, TableData, option, project_block
from baarda.pipeline.units import fmt_q


@dataclass(frozen=True)
class Move:
    point: str = option("", "point id")
    dX: float = option(0.0, "displacement in X (object unit)")
    dY: float = option(0.0, "displacement in Y (object unit)")
    dZ: float = option(0.0, "displacement in Z (object unit)")


@dataclass(frozen=True)
class EpochSimulateOptions:
    displacements: list[Move] = option([], "targets to displace: a list of tables {point, dX, dY, dZ} (object unit)")
    residuals: Literal["resampled", "same", "none"] = option(
        "resampled", "noise of the new image coordinates: the adjustment's residuals shuffled within each photo, "
                     "the same residual at each observation, or none")
    seed: int | None = option(None, "seed of the shuffling; default: the project's seed for this stage")


class EpochSimulate(Stage):
    summary = "A later epoch of an adjusted network: known target displacements, real residuals added back"
    reads = ("bundle",)
    writes = ("block",)
    Options = EpochSimulateOptions

    def run(self, inputs, o: EpochSimulateOptions, ctx) -> StageResult:
        res = inputs["bundle"]
        adjusted = res.block
        ids = [str(i) for i in adjusted.points.ids]
        index = {p: k for k, p in enumerate(ids)}
        move = np.zeros((len(ids), 3))
        for m in o.displacements:
            if str(m.point) not in index:
                raise ctx.option_error(f"displacements: no point {m.point!r} in the block", "displacements")
            move[index[str(m.point)]] += (m.dX, m.dY, m.dZ)
        obs = res.block_in.observations
        moved_pts = adjusted.points.replace(XYZ=np.asarray(adjusted.points.XYZ, float) + move)
        computed = project_block(adjusted.replace(points=moved_pts), obs.photo, obs.point)
        v = np.nan_to_num(np.asarray(res.residuals, float))
        rng = np.random.default_rng(o.seed) if o.seed is not None else ctx.rng
        if o.residuals == "resampled":
            v2 = v.copy()
            active = np.asarray(res.obs_active, bool)      # inactive rows keep their own residual
            for j in np.unique(obs.point[active]):
                rows = np.flatnonzero((obs.point == j) & active)
                v2[rows] = v[rng.permutation(rows)]
            v = v2
        elif o.residuals == "none":
            v = np.zeros_like(v)
        xy = computed + v
        start = res.block_in.points
        approx = np.asarray(start.XYZ, float) + np.where(np.isfinite(start.XYZ), move, 0.0)
        block = res.block_in.replace(observations=obs.replace(xy=xy), points=start.replace(XYZ=approx))
        moved = [(ids[k], move[k]) for k in np.flatnonzero(np.any(move != 0, axis=1))]
        u = ctx.object_unit
        summary = {"displaced": {p: d.tolist() for p, d in moved}, "residuals": o.residuals,
                   "observations": int(len(obs)),
                   "headline": f"epoch simulated: {len(moved)} target(s) displaced, residuals {o.residuals}"}
        report = (f"A later epoch of the adjusted network: {len(moved)} target(s) displaced "
                  + ", ".join(f"{p} by {fmt_q(float(np.linalg.norm(d)), u)}" for p, d in moved)
                  + f"; {len(obs)} image points recomputed from the adjusted orientations and cameras, with the "
                  f"adjustment's residuals {'of each target shuffled among its photos' if o.residuals == 'resampled' else o.residuals}"
                  " added back.")
        table = TableData({"point": [p for p, _ in moved], **{f"d{a}_{u}": [float(d[k]) for _, d in moved]
                                                              for k, a in enumerate("XYZ")}},
                          f"the known displacements of this epoch ({u})",
                          units={"point": "", **{f"d{a}_{u}": u for a in "XYZ"}})
        return StageResult(artefacts={"block": block}, summary=summary, report=report, tables={"displacements": table})
