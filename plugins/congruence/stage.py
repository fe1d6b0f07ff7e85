"""Stages ``epoch`` and ``congruence``: deformation analysis of two or more epochs.

A monitoring project adjusts each epoch with its own source and ``bundle`` stage and ends each
with an ``epoch`` stage, which keeps the epoch's adjusted coordinates, their joint cofactor matrix,
σ0, σ̂0 and the degrees of freedom (artefact ``epochs``, a tuple that grows epoch by epoch; also
written as ``<id>_epoch.npz`` so a later run can compare with it: ``congruence.reference``).  The
``congruence`` stage then compares every later epoch with the first (the reference): variance
factors (F-test), the global congruence test, localisation of moved points, each point's
displacement with σ, test value and minimal detectable displacement (MDD), all in the datum of the
points held stable.  Numerics: :mod:`baarda.pipeline.stats.congruence` (``docs/statistics.md``,
"Deformation analysis"); project layout: ``docs/monitoring.md``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

import numpy as np

from baarda.pipeline.api import InputError, Stage, StageResult, TableData, option, parameter_covariance
from baarda.pipeline.report import markdown_table
from baarda.pipeline.stats.congruence import congruence, variance_ratio_test
from baarda.pipeline.stats.ellipses import error_ellipsoids
from baarda.pipeline.units import fmt_num, fmt_q

EPOCH_FILE_VERSION = 1


@dataclass(frozen=True, eq=False)
class Epoch:
    """One adjusted epoch: point ``ids`` (n,), coordinates ``XYZ`` (n, 3) in ``object_unit``, their joint
    cofactor matrix ``Q`` (3n, 3n; covariance = σ0² Q a priori, σ̂0² Q a posteriori), the a-priori
    ``sigma0``, the estimate ``sigma0_hat`` and the degrees of freedom ``dof`` of its adjustment."""

    name: str
    ids: tuple
    XYZ: np.ndarray
    Q: np.ndarray
    sigma0: float
    sigma0_hat: float
    dof: int
    object_unit: str

    def save(self, path) -> None:
        np.savez(path, version=EPOCH_FILE_VERSION, name=self.name, ids=np.array(self.ids, dtype=str),
                 XYZ=self.XYZ, Q=self.Q, sigma0=self.sigma0, sigma0_hat=self.sigma0_hat, dof=self.dof,
                 object_unit=self.object_unit)

    @classmethod
    def load(cls, path) -> "Epoch":
        try:
            with np.load(path, allow_pickle=False) as z:
                n = len(z["ids"])
                ep = cls(name=str(z["name"]), ids=tuple(str(i) for i in z["ids"]), XYZ=np.array(z["XYZ"], float),
                         Q=np.array(z["Q"], float), sigma0=float(z["sigma0"]), sigma0_hat=float(z["sigma0_hat"]),
                         dof=int(z["dof"]), object_unit=str(z["object_unit"]))
        except (OSError, KeyError, ValueError) as e:
            raise InputError(f"not an epoch file written by the 'epoch' stage ({e})", path=path,
                             field="reference") from None
        if ep.XYZ.shape != (n, 3) or ep.Q.shape != (3 * n, 3 * n):
            raise InputError(f"epoch file holds {n} ids but XYZ {ep.XYZ.shape} and Q {ep.Q.shape}", path=path,
                             field="reference")
        return ep


def check_point_ids(ctx, wanted, block, field: str = "points") -> None:
    """An option naming points (``wanted``) must name points of ``block``: else one option error
    naming the first unknown ids and the block's size (the epoch, datum-transform stages)."""
    known = {str(i) for i in block.points.ids}
    unknown = [str(p) for p in wanted if str(p) not in known]
    if unknown:
        raise ctx.option_error(f"unknown point id(s) {', '.join(unknown[:5])} (the block has {len(known)} points)",
                               field)


def epoch_of(res, name: str, ids=None, object_unit: str = "m") -> Epoch:
    """The :class:`Epoch` of a bundle result ``res`` (the points ``ids``; default every point the
    adjustment estimated): coordinates and their joint cofactor matrix (``len(ids)`` solves)."""
    blk = res.block
    all_ids = [str(i) for i in blk.points.ids]
    if ids is None or len(ids) == 0:
        ok = np.isfinite(res.cov_points).all(axis=(1, 2))
        ids = [i for i, good in zip(all_ids, ok) if good]
    index = {p: k for k, p in enumerate(all_ids)}
    rows = [index[str(i)] for i in ids]
    _, C = parameter_covariance(res, [f"point {i}" for i in ids])
    factor = res.variance_factor
    return Epoch(name=name, ids=tuple(str(i) for i in ids), XYZ=np.array(blk.points.XYZ[rows], float),
                 Q=C / factor, sigma0=float(res.sigma0), sigma0_hat=float(res.sigma0_hat), dof=int(res.dof),
                 object_unit=object_unit)


class EpochStage(Stage):
    summary = "Keep an adjusted epoch (coordinates, joint cofactors, σ̂0) for the congruence stage"
    reads = ("bundle", "epochs?")
    writes = ("epochs",)

    @dataclass(frozen=True)
    class Options:
        name: str = option("", "name of the epoch (default: the stage id)")
        points: list[str] = option([], "ids of the points compared between epochs (default: every point the "
                                        "bundle estimated)")

    def run(self, inputs, options, ctx) -> StageResult:
        res = inputs["bundle"]
        check_point_ids(ctx, options.points, res.block)
        ctx.progress.message(f"joint covariance of {len(options.points) or 'all'} points")
        ep = epoch_of(res, options.name or ctx.stage_id, [str(p) for p in options.points] or None,
                      ctx.object_unit)
        before = tuple(inputs.get("epochs") or ())
        if any(e.name == ep.name for e in before):
            raise ctx.option_error(f"an epoch named {ep.name!r} is already kept by an earlier stage", "name")
        if ctx.run_dir is not None:
            ep.save(ctx.run_dir / f"{ctx.stage_id}_epoch.npz")
        u = ep.object_unit
        summary = {"epoch": ep.name, "points": len(ep.ids), "sigma0_hat": ep.sigma0_hat, "dof": ep.dof,
                   "file": f"{ctx.stage_id}_epoch.npz",
                   "headline": f"epoch {ep.name}: {len(ep.ids)} points, σ̂0 = {fmt_num(ep.sigma0_hat)}, dof {ep.dof}"}
        sig = np.sqrt(np.clip(np.diag(ep.Q), 0, None)).reshape(-1, 3) * (ep.sigma0_hat if ep.dof > 0 else ep.sigma0)
        report = (f"Epoch **{ep.name}**: {len(ep.ids)} points with their joint cofactor matrix "
                  f"({3 * len(ep.ids)} × {3 * len(ep.ids)}), σ̂0 = {fmt_num(ep.sigma0_hat)} (dof {ep.dof}); "
                  f"median σ of a coordinate {fmt_q(float(np.median(sig)), u)}. Kept in "
                  f"`{ctx.stage_id}_epoch.npz` for comparison with later epochs.")
        return StageResult(artefacts={"epochs": before + (ep,)}, summary=summary, report=report)


@dataclass(frozen=True)
class CongruenceOptions:
    reference: str = option("", "an epoch file (<id>_epoch.npz) of an earlier run to compare with, as the first "
                                "epoch (empty: the first epoch of this run)")
    datum_points: list[str] = option([], "ids of the points declared stable (the datum); empty: every common point "
                                         "is a candidate and localisation finds the moved ones")
    datum: Literal["similarity", "rigid", "translation"] = option(
        "rigid", "datum transformation between the epochs: 'rigid' (3 shifts + 3 rotations), 'similarity' (+ scale) "
                 "or 'translation'")
    alpha: float = option(0.05, "level of the global congruence test", gt=0.0, lt=1.0)
    alpha_point: float = option(0.001, "level of each point's 3-D displacement test and of its MDD (0.1 %, as data "
                                       "snooping's α0: every point is tested)", gt=0.0, lt=1.0)
    beta0: float = option(0.80, "power of the MDD (minimal detectable displacement)", gt=0.0, lt=1.0)
    variance: Literal["a-posteriori", "a-priori"] = option(
        "a-posteriori", "σ0 of the tests: the epochs' pooled σ̂0 (F tests) or the a-priori σ0 (χ² tests)")
    alpha_variance: float = option(0.05, "level of the F-test comparing the epochs' variance factors", gt=0.0, lt=1.0)
    max_moved: int = option(0, "stop localisation after this many moved points (0: until the rest is congruent)",
                            ge=0, le=100000)


class CongruenceStage(Stage):
    summary = "Congruence test of epochs: stable datum, moved points, displacements with σ and MDD"
    reads = ("epochs",)
    writes = ("congruence",)
    Options = CongruenceOptions

    def run(self, inputs, options: CongruenceOptions, ctx) -> StageResult:
        epochs = list(inputs["epochs"])
        if options.reference:
            path = ctx.resolve(options.reference)
            if not path.is_file():
                raise ctx.option_error(f"epoch file not found: {path}", "reference")
            epochs.insert(0, Epoch.load(path))
        if len(epochs) < 2:
            raise ctx.option_error(f"congruence needs two epochs, got {len(epochs)} (an 'epoch' stage after each "
                                   "epoch's bundle, or 'reference' naming an earlier epoch file)", "reference")
        ref = epochs[0]
        comparisons = []
        for ep in epochs[1:]:
            comparisons.append(_compare(ref, ep, options, ctx))
        summary = {"conclusion": True, "reference": ref.name, "comparisons": [c["summary"] for c in comparisons],
                   "headline": "; ".join(c["summary"]["headline"] for c in comparisons)}
        report = "\n\n".join(c["report"] for c in comparisons)
        tables = {f"{c['summary']['epoch']}_points" if len(comparisons) > 1 else "points": c["table"]
                  for c in comparisons}
        return StageResult(artefacts={"congruence": comparisons}, summary=summary, report=report, tables=tables,
                           data={"comparisons": comparisons, "epochs": epochs})

    def plots(self, result, ctx) -> dict:
        from .figures import displacement_figure

        out = {}
        for c in result.data["comparisons"]:
            key = f"displacements_{c['summary']['epoch']}"
            out[key] = (displacement_figure(c), f"displacements {c['ref'].name} → {c['epoch'].name}")
        return out

    def log(self, result, rec, ctx) -> None:
        from .rrlog import log_congruence

        log_congruence(rec, result.data["comparisons"])


def _compare(ref: Epoch, ep: Epoch, o: CongruenceOptions, ctx) -> dict:
    if ref.object_unit != ep.object_unit:
        raise ctx.option_error(f"epochs {ref.name!r} ({ref.object_unit}) and {ep.name!r} ({ep.object_unit}) are in "
                               "different object units", "reference")
    common = [i for i in ref.ids if i in set(ep.ids)]
    if len(common) < 3:
        raise ctx.option_error(f"epochs {ref.name!r} and {ep.name!r} share {len(common)} point(s); at least 3 are "
                               "needed", "datum_points")
    missing = [p for p in o.datum_points if str(p) not in set(common)]
    if missing:
        raise ctx.option_error(f"datum point(s) {', '.join(map(str, missing[:5]))} not in both epochs "
                               f"({ref.name!r}, {ep.name!r})", "datum_points")
    ia = [ref.ids.index(i) for i in common]
    ib = [ep.ids.index(i) for i in common]
    rows = lambda idx: (np.asarray(idx)[:, None] * 3 + np.arange(3)).reshape(-1)  # noqa: E731
    Q1 = ref.Q[np.ix_(rows(ia), rows(ia))]
    Q2 = ep.Q[np.ix_(rows(ib), rows(ib))]
    vr = None
    if ref.dof > 0 and ep.dof > 0:
        vr = variance_ratio_test(ref.sigma0_hat / ref.sigma0, ref.dof, ep.sigma0_hat / ep.sigma0, ep.dof,
                                 o.alpha_variance)
        if vr["differ"]:
            ctx.warn(f"the variance factors of epochs {ref.name!r} and {ep.name!r} differ significantly "
                     f"(F = {fmt_num(vr['F'])}, p = {fmt_num(vr['p'], 3)}): the pooled σ̂0 of the congruence test "
                     "mixes unequal precisions")
    post = o.variance == "a-posteriori" and ref.dof > 0 and ep.dof > 0
    datum = [common.index(str(p)) for p in o.datum_points] or None
    ctx.progress.message(f"congruence {ref.name} → {ep.name}: {len(common)} points")
    try:
        r = congruence(ref.XYZ[ia], Q1, ep.XYZ[ib], Q2, sigma0=ref.sigma0, kind=o.datum, datum_points=datum,
                       alpha=o.alpha, alpha_point=o.alpha_point, beta0=o.beta0,
                       sigma0_hat=((ref.sigma0_hat, ref.dof), (ep.sigma0_hat, ep.dof)) if post else None,
                       n_max_moved=o.max_moved or None)
    except ValueError as e:
        raise ctx.option_error(f"congruence {ref.name!r} → {ep.name!r}: {e}", "datum_points") from None
    s0 = r.sigma0
    u = ref.object_unit
    d = np.array([p.d for p in r.points])
    sig = np.array([np.sqrt(np.clip(np.diag(p.Q), 0, None)) * s0 for p in r.points])
    length = np.linalg.norm(d, axis=1)
    semi, _axes = error_ellipsoids(np.array([p.Q * s0 * s0 for p in r.points]), 0.95)
    datum_set = set(datum) if datum is not None else None
    status = []
    for k, p in enumerate(r.points):
        if p.moved:
            status.append("moved")
        elif datum_set is not None and k not in datum_set:
            status.append("moved" if p.p < o.alpha_point else "object point")
        else:
            status.append("stable")
    table = TableData({
        "point": common, "status": status,
        f"dX_{_suffix(u)}": d[:, 0], f"dY_{_suffix(u)}": d[:, 1], f"dZ_{_suffix(u)}": d[:, 2],
        f"length_{_suffix(u)}": length,
        f"sigma_dX_{_suffix(u)}": sig[:, 0], f"sigma_dY_{_suffix(u)}": sig[:, 1], f"sigma_dZ_{_suffix(u)}": sig[:, 2],
        "T": [p.T for p in r.points], "p": [p.p for p in r.points],
        f"mdd_{_suffix(u)}": [p.mdd for p in r.points],
        **{f"ellipsoid95_a{j + 1}_{_suffix(u)}": semi[:, j] for j in range(3)},
        f"X_{_suffix(u)}": ep.XYZ[ib, 0], f"Y_{_suffix(u)}": ep.XYZ[ib, 1], f"Z_{_suffix(u)}": ep.XYZ[ib, 2],
    }, f"displacements {ref.name} → {ep.name} in the datum of the stable points ({u}); T the 3-D test value "
       f"({'F(3, f)' if r.test == 'F' else 'χ²(3)/3'}), p its p-value, mdd the minimal detectable displacement "
       f"(α = {o.alpha_point:g}, β0 = {o.beta0:g}, worst direction), ellipsoid95 the semi-axes of the displacement's "
       f"95 % confidence ellipsoid",
        units={"point": "", "status": "", **{f"{c}_{_suffix(u)}": u for c in (
            "dX", "dY", "dZ", "length", "sigma_dX", "sigma_dY", "sigma_dZ", "mdd", "X", "Y", "Z",
            "ellipsoid95_a1", "ellipsoid95_a2", "ellipsoid95_a3")}, "T": "", "p": ""},
        detail=False)
    moved_ids = [common[i] for i in r.moved] + [common[k] for k, s in enumerate(status)
                                                   if s == "moved" and k not in r.moved]
    verdict = "congruent (no point moved)" if r.accepted0 else f"not congruent: {len(moved_ids)} point(s) moved"
    dist = f"F({r.dof0}, {r.dof_sigma:g})" if r.test == "F" else f"χ²({r.dof0})/{r.dof0}"
    summary = {
        "epoch": ep.name, "reference": ref.name, "points": len(common), "datum": o.datum,
        "datum_points": list(map(str, o.datum_points)),
        "global_test": {"T": r.T0, "critical": r.critical, "dof": r.dof0, "p": r.p0, "alpha": o.alpha,
                        "accepted": r.accepted0, "distribution": r.test},
        "after_localisation": {"T": r.T, "dof": r.dof, "p": r.p},
        "moved": moved_ids, "sigma0": s0,
        "variance_ratio": vr,
        "largest_displacement": {"point": common[int(np.argmax(length))], "length": float(length.max()), "unit": u},
        "headline": f"{ref.name} → {ep.name}: {verdict}"
                    + (f" ({', '.join(moved_ids[:6])})" if moved_ids else ""),
    }
    lines = [
        f"**{ref.name} → {ep.name}**: {len(common)} common points, datum "
        f"{'of the points ' + ', '.join(map(str, o.datum_points)) if o.datum_points else 'of the points found stable'} "
        f"({o.datum}); σ0 of the tests {fmt_num(s0)} ({'pooled σ̂0 of both epochs' if r.test == 'F' else 'a priori'}).",
        "",
        f"- Global congruence test: T = {fmt_num(r.T0)} against {fmt_num(r.critical)} ({dist}, "
        f"α = {o.alpha:g}), p = {fmt_num(r.p0, 3)}: **{'accepted' if r.accepted0 else 'rejected'}**.",
    ]
    if vr is not None:
        lines.append(f"- Variance factors: σ̂0 {fmt_num(ref.sigma0_hat)} (dof {ref.dof}) and {fmt_num(ep.sigma0_hat)} "
                     f"(dof {ep.dof}); F = {fmt_num(vr['F'])}, interval [{fmt_num(vr['lower'])}, {fmt_num(vr['upper'])}] "
                     f"at α = {o.alpha_variance:g}: {'**differ**' if vr['differ'] else 'agree'}.")
    if r.history:
        lines.append("- Localisation (largest point test first, repeated until the rest is congruent): "
                     + "; ".join(f"{common[h['moved']]} (T = {fmt_num(h['T_point'])}, rest T = {fmt_num(h['T_rest'])}, "
                                 f"p = {fmt_num(h['p_rest'], 3)})" for h in r.history) + ".")
    order = np.argsort(-np.array([p.T for p in r.points]))[:10]
    rows = [[common[k], status[k], fmt_q(length[k], u), fmt_q(float(np.linalg.norm(sig[k])), u),
             fmt_num(r.points[k].T), fmt_num(r.points[k].p, 3), fmt_q(r.points[k].mdd, u)] for k in order]
    lines += ["", f"Largest test values ({len(order)} of {len(common)}; all in the table `points`):", "",
              markdown_table(["point", "status", "‖d‖", "σ‖d‖", "T", "p", "MDD"], rows)]
    return {"summary": summary, "report": "\n".join(lines), "table": table, "result": r, "ref": ref, "epoch": ep,
            "common": common, "d": d, "status": status, "ia": ia, "ib": ib}


def _suffix(unit: str) -> str:
    return {"µm": "um"}.get(unit, unit)
