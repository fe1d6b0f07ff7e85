"""Stage ``datum-transform``: an adjusted block's points and precision in the datum of chosen points.

Baarda's S-transformation (``docs/statistics.md``, "Deformation analysis"): the coordinates and
their joint covariance are re-expressed as if the adjustment had held its datum by inner
constraints on the chosen points (relative to the block's approximate coordinates), without
adjusting again. A free network's precision then describes the object relative to the points a
user considers stable (e.g. the reference points of a monitoring job), not relative to the
centroid of all points. The joint covariance of all points is needed: ``3 n`` solves of the
bundle's system (refused beyond ``max_points``).

External reliability is re-expressed too (``reliability = true``): the effect of every image
row's MDB on its own point, ``S ∇x`` in the new datum (one solve per row, up to ``max_rows``), with
its size in σ of the new datum.  The MDBs themselves and Baarda's δ̄0 do not depend on the datum.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from baarda.pipeline.adjustment import own_point_effects_in_datum
from baarda.pipeline.api import Stage, StageResult, TableData, option, parameter_covariance
from baarda.pipeline.stats.critical import delta0 as delta0_of
from baarda.pipeline.stats.ellipses import ellipse_columns
from baarda.pipeline.report import markdown_table
from baarda.pipeline.stats.congruence import s_transform
from baarda.pipeline.units import ImageUnits, fmt_num, fmt_q

from .stage import check_point_ids


@dataclass(frozen=True)
class DatumTransformOptions:
    points: list[str] = option([], "ids of the points that define the new datum (inner constraints on them)")
    kind: Literal["similarity", "rigid", "translation"] = option(
        "similarity", "datum parameters: 'similarity' (7: a free network without scale), 'rigid' (6: with scale "
                      "bars), 'translation' (3)")
    max_points: int = option(3000, "refuse blocks with more estimated points than this (the joint covariance of all "
                                   "points is 9 n² numbers)", ge=3, le=100000)
    reliability: bool = option(True, "re-express external reliability: the effect of every image row's MDB on its "
                                     "own point in the new datum (one solve per row)")
    max_rows: int = option(50000, "skip the reliability part (with a note) for more active image rows than this",
                           ge=1, le=10_000_000)
    alpha0: float = option(0.001, "level of the w-test the MDBs refer to (as the bundle's tests.alpha0)",
                           gt=0.0, lt=0.5)
    beta0: float = option(0.80, "power of the w-test the MDBs refer to (as the bundle's tests.beta0)",
                          gt=0.0, lt=1.0)


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
        check_point_ids(ctx, o.points, blk)
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
            x2, C2, S = s_transform((X - X_approx).reshape(-1), C, X_approx, datum, kind=o.kind)
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
        for name, v in ellipse_columns(cov2, suffix=f"_{su}").items():
            cols[name] = v
            units[name] = "deg" if name.endswith("_deg") else ("" if "axis1" in name else u)
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
        tables = {"points": table}
        if o.reliability:
            rel = _reliability(res, keep, S, C2 / res.variance_factor, o, ctx)
            if rel is not None:
                tables["reliability"] = rel.pop("table")
                summary["reliability"] = rel
                report += "\n\n" + rel["text"]
        return StageResult(artefacts={"datum": {"ids": cols["point"], "XYZ": X2, "cov": cov2}}, summary=summary,
                           report=report, tables=tables)


def _reliability(res, keep, S, Q2, o: DatumTransformOptions, ctx) -> dict | None:
    """External reliability in the new datum: per active image row the largest effect of its MDB
    on its own point (coordinate, object units, in a-priori σ of the new datum), beside the same
    figure in the adjustment's datum."""
    blk = res.block_in
    obs = blk.observations
    n_rows = int(np.asarray(res.row_active).sum())
    if res.snapshot is None:
        return {"skipped": "the bundle ran without covariance", "text": "External reliability: not re-expressed "
                "(the bundle ran without covariance)."}
    if n_rows > o.max_rows:
        return {"skipped": f"{n_rows} image rows > max_rows = {o.max_rows}",
                "text": f"External reliability: not re-expressed ({n_rows} image rows exceed max_rows = {o.max_rows})."}
    d0 = delta0_of(o.alpha0, o.beta0)
    ctx.progress.message(f"external reliability in the new datum ({n_rows} image rows, one solve each)")
    eff, bias = own_point_effects_in_datum(
        res, keep, S, d0, progress=lambda done, total: ctx.progress.message(
            f"external reliability in the new datum: {done}/{total} rows"))
    sig2 = res.sigma0 * np.sqrt(np.clip(np.einsum("ii->i", Q2), 0, None)).reshape(-1, 3)   # a-priori σ, new datum
    where = np.full(len(blk.points), -1)
    where[np.asarray(keep)] = np.arange(len(keep))
    own = where[np.asarray(obs.point)]
    s_own = np.where((own >= 0)[:, None], sig2[np.clip(own, 0, None)], np.nan)                   # (k, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        in_sig = np.where(s_own[:, None, :] > 0, np.abs(eff) / s_own[:, None, :], np.nan)         # (k, 2, 3)
    valid = np.isfinite(in_sig).any(axis=2)
    j = np.argmax(np.nan_to_num(in_sig, nan=-1.0), axis=2)                                       # (k, 2)
    val = np.take_along_axis(eff, j[..., None], axis=2)[..., 0]
    sv = np.take_along_axis(in_sig, j[..., None], axis=2)[..., 0]
    iu = ImageUnits.of(blk)
    u = ctx.object_unit
    su = "um" if u == "µm" else u
    cols = {"photo": [str(blk.photos.ids[i]) for i in obs.photo], "point": [str(blk.points.ids[i]) for i in obs.point]}
    units = {"photo": "", "point": ""}
    for c, cn in enumerate("xy"):
        mdb = iu.diff(np.abs(bias[:, c]))
        cols[f"mdb_{cn}{iu.suffix}"] = np.where(valid[:, c], mdb, np.nan)
        units[f"mdb_{cn}{iu.suffix}"] = iu.unit
        cols[f"ext_point_coord_{cn}"] = ["XYZ"[jj] if ok else "" for jj, ok in zip(j[:, c], valid[:, c])]
        units[f"ext_point_coord_{cn}"] = ""
        cols[f"ext_point_{cn}_{su}"] = np.where(valid[:, c], val[:, c], np.nan)
        units[f"ext_point_{cn}_{su}"] = u
        cols[f"ext_point_in_sigma_{cn}"] = np.where(valid[:, c], sv[:, c], np.nan)
        units[f"ext_point_in_sigma_{cn}"] = "σ"
    table = TableData(cols, f"external reliability in the new datum: the largest effect of each image coordinate's "
                            f"MDB (δ0 = {d0:.2f}) on its own point ({u}, and in a-priori σ of the new datum)",
                      units=units, detail=True)
    if not valid.any():
        return {"table": table, "rows": 0, "text": "External reliability in the new datum: no image row observes "
                                                   "a transformed point."}
    flat = np.where(valid, sv, -1.0)
    k, c = np.unravel_index(int(np.argmax(flat)), flat.shape)
    where_txt = f"photo {cols['photo'][k]} point {cols['point'][k]} {'xy'[c]}"
    largest = {"observation": where_txt, "coordinate": "XYZ"[j[k, c]], "effect": float(val[k, c]),
               "in_sigma": float(sv[k, c]), "unit": u}
    med = float(np.nanmedian(np.where(valid, sv, np.nan)))
    text = (f"External reliability in the new datum (δ0 = {d0:.2f}, {int(valid.sum())} image coordinates): the "
            f"largest effect of an MDB on its own point is {fmt_q(abs(largest['effect']), u)} in "
            f"{largest['coordinate']} = {fmt_num(largest['in_sigma'])} σ ({where_txt}); median "
            f"{fmt_num(med)} σ. Table `reliability`; the same figures in the adjustment's datum are the bundle's "
            f"`ext_point_*` columns.")
    return {"table": table, "rows": int(valid.sum()), "delta0": d0, "largest": largest, "median_in_sigma": med,
            "text": text}
