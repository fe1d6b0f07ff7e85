"""Stage ``datum-transform``: an adjusted block's points and precision in the datum of chosen points.

Baarda's S-transformation (``docs/statistics.md``, "Deformation analysis"): the coordinates and
their joint covariance are re-expressed as if the adjustment had held its datum by inner
constraints on the chosen points (relative to the block's approximate coordinates), without
adjusting again. A free network's precision then describes the object relative to the points a
user considers stable (e.g. the reference points of a monitoring job), not relative to the
centroid of all points. The joint covariance of all points is needed: ``3 n`` solves of the
bundle's system (refused beyond ``max_points``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from baarda.pipeline.api import Stage, StageResult, TableData, option, parameter_covariance
from baarda.pipeline.stats.ellipses import ellipse_columns
from baarda.pipeline.report import markdown_table
from baarda.pipeline.stats.congruence import s_transform
from baarda.pipeline.units import fmt_q


@dataclass(frozen=True)
class DatumTransformOptions:
    points: list[str] = option([], "ids of the points that define the new datum (inner constraints on them)")
    kind: Literal["similarity", "rigid", "translation"] = option(
        "similarity", "datum parameters: 'similarity' (7: a free network without scale), 'rigid' (6: with scale "
                      "bars), 'translation' (3)")
    max_points: int = option(3000, "refuse blocks with more estimated points than this (the joint covariance of all "
                                   "points is 9 n² numbers)", ge=3, le=100000)


class DatumTransform(Stage):
    summary = "S-transformation: points and their precision in the datum of chosen points, without re-adjusting"
    reads = ("bundle",)
    writes = ("datum",)
    Options = DatumTransformOptions

    def run(self, inputs, o: DatumTransformOptions, ctx) -> StageResult:
        res = inputs["bundle"]
        blk = res.block
        ids = [str(i) for i in blk.points.ids]
        est = np.isfinite(res.cov_points).all(axis=(1, 2))
        keep = [k for k in range(len(ids)) if est[k]]
        if not o.points:
            raise ctx.option_error("name the points of the new datum ('points')", "points")
        unknown = [p for p in o.points if str(p) not in set(ids)]
        if unknown:
            raise ctx.option_error(f"unknown point id(s) {', '.join(map(str, unknown[:5]))}", "points")
        not_est = [p for p in o.points if not est[ids.index(str(p))]]
        if not_est:
            raise ctx.option_error(f"point(s) {', '.join(map(str, not_est[:5]))} were not estimated (fixed control or "
                                   "not in the adjustment)", "points")
        if len(keep) > o.max_points:
            raise ctx.option_error(f"{len(keep)} estimated points exceed max_points = {o.max_points} (the joint "
                                   "covariance of all points is needed)", "max_points")
        ctx.progress.message(f"joint covariance of {len(keep)} points ({3 * len(keep)} solves)")
        _, C = parameter_covariance(res, [f"point {ids[k]}" for k in keep])
        X = np.asarray(blk.points.XYZ, float)[keep]
        X_approx = np.asarray(res.block_in.points.XYZ, float)[keep]
        X_approx = np.where(np.isfinite(X_approx), X_approx, X)
        datum = [keep.index(ids.index(str(p))) for p in o.points]
        try:
            x2, C2, _ = s_transform((X - X_approx).reshape(-1), C, X_approx, datum, kind=o.kind)
        except ValueError as e:
            raise ctx.option_error(str(e), "points") from None
        X2 = X_approx + x2.reshape(-1, 3)
        cov2 = np.array([C2[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i in range(len(keep))])
        cov1 = np.array([C[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i in range(len(keep))])
        s1 = np.sqrt(np.clip(np.einsum("nii->ni", cov1), 0, None))
        s2 = np.sqrt(np.clip(np.einsum("nii->ni", cov2), 0, None))
        u = ctx.object_unit
        su = "um" if u == "µm" else u
        cols = {"point": [ids[k] for k in keep], "role": [str(blk.points.role[k]) for k in keep],
                "datum": [ids[k] in set(map(str, o.points)) for k in keep]}
        units = {"point": "", "role": "", "datum": ""}
        for j, a in enumerate("XYZ"):
            cols[f"{a}_{su}"] = X2[:, j]
            units[f"{a}_{su}"] = u
        for j, a in enumerate("XYZ"):
            cols[f"sigma_{a}_{su}"] = s2[:, j]
            units[f"sigma_{a}_{su}"] = u
        for name, v in ellipse_columns(cov2).items():
            unit = "deg" if name.endswith("_deg") else ("" if "axis1" in name else u)
            key = name if unit in ("", "deg") else f"{name}_{su}"
            cols[key] = v
            units[key] = unit
        shift = np.linalg.norm(X2 - X, axis=1)
        p1 = np.sqrt((s1 ** 2).sum(axis=1))
        p2 = np.sqrt((s2 ** 2).sum(axis=1))
        table = TableData(cols, f"points and their 1-σ precision in the datum of {len(o.points)} point(s) "
                                f"({o.kind}; S-transformation of the adjustment, {u})", units=units, detail=True)
        summary = {"datum_points": list(map(str, o.points)), "kind": o.kind, "points": len(keep),
                   "median_sigma_before": float(np.median(p1)), "median_sigma_after": float(np.median(p2)),
                   "largest_shift": float(shift.max()), "unit": u,
                   "headline": (f"datum of {len(o.points)} point(s) ({o.kind}): median point σ "
                                f"{fmt_q(float(np.median(p1)), u)} → {fmt_q(float(np.median(p2)), u)}")}
        order = np.argsort(-p2)[:10]
        rows = [[ids[keep[k]], "yes" if cols["datum"][k] else "", fmt_q(p1[k], u), fmt_q(p2[k], u),
                 fmt_q(shift[k], u)] for k in order]
        report = "\n".join([
            f"The adjusted points in the datum of {', '.join(map(str, o.points[:8]))}"
            f"{' …' if len(o.points) > 8 else ''} ({o.kind}, inner constraints on these points relative to the "
            f"approximate coordinates), by S-transformation of the joint covariance of {len(keep)} points.",
            "",
            f"- Median 3-D point σ: {fmt_q(float(np.median(p1)), u)} in the adjustment's datum, "
            f"{fmt_q(float(np.median(p2)), u)} in the new one; the datum points' own σ "
            f"{fmt_q(float(np.median(p2[datum])), u)} (median).",
            f"- Largest change of a coordinate triple: {fmt_q(float(shift.max()), u)}.",
            "", f"Least precise points in the new datum (10 of {len(keep)}; all in the table `points`):", "",
            markdown_table(["point", "datum", "σ before", "σ after", "shift"], rows),
        ])
        return StageResult(artefacts={"datum": {"ids": cols["point"], "XYZ": X2, "cov": cov2}}, summary=summary,
                           report=report, tables={"points": table})
