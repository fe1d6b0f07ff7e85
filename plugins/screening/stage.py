"""Stage ``helmert-screening``: screen every stereo pair by a 2-D Helmert transformation.

See docs/screening.md.  Numerics in :mod:`.helmert` and :mod:`.screen`; statistics from
:mod:`baarda.pipeline.stats`; this module handles the block, options, tables, report and recording.
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar, Literal

import numpy as np

from baarda.pipeline.errors import InputError
from baarda.pipeline.options import option
from baarda.pipeline.report import TABLE_DECIMALS
from baarda.pipeline.stage import Context, Stage, StageResult, TableData
from baarda.pipeline.contracts import AdjustmentArtefact
from baarda.pipeline import stats

from .helmert import stack_models
from .screen import FLAG_METHODS, PairScreening, ScreeningSettings, screen_pair


@dataclasses.dataclass(frozen=True)
class ScreeningOptions:
    RENAMED: ClassVar[dict[str, str]] = {"deactivate": "action"}
    RENAMED_VALUES: ClassVar[dict[str, dict[str, str]]] = {"on_too_few": {"fail": "error"}}
    sigma0_mm: float = option(
        0.2, "a-priori σ (mm) of one right-image coordinate about the Helmert transformation, "
             "including relief displacement the 2-D transformation cannot model (used by the "
             "global test, data snooping, MDB and the swap check; Pope's τ uses σ̂0 instead)")
    alpha0: float = option(0.001, "significance level of data snooping (two-sided, per residual)")
    beta0: float = option(0.80, "power β0 for the MDB (δ0 from α0 and β0)")
    alpha_pope: float = option(0.001, "significance level of Pope's τ test (two-sided, per residual)")
    threshold_mm: float = option(2.0, "flag residuals whose magnitude exceeds this (mm)")
    format_margin_mm: float = option(0.0, "tolerance beyond the camera format before a coordinate "
                                          "counts as outside (mm)")
    detect_swaps: bool = option(True, "try exchanging the right coordinates of flagged points with "
                                      "every other point to find swapped point numbers")
    flag_by: list[str] = option(
        ["pope", "threshold", "format", "swap"],
        "checks whose findings flag an observation: any of data-snooping, pope, threshold, format, "
        "swap (data snooping only makes sense when sigma0_mm is known)")
    action: Literal["flag", "remove"] = option(
        "flag", "what happens to flagged observations: 'flag' reports them, 'remove' also marks them "
                "inactive in the output block")
    on_too_few: Literal["error", "skip"] = option(
        "error", "a pair with fewer than 3 common points: stop with an error, or skip the pair")
    arrow_scale: float = option(10.0, "scale of the residual arrows in the recording")
    robust: Literal["none", "huber", "danish", "l1"] = option(
        "none", "also estimate the Helmert transformations robustly (IRLS, docs/statistics.md) and report the "
                "down-weighted coordinates (weight < 0.5) with their weights; report only, flags are unchanged")
    robust_c: float = option(0.0, "robust estimation: tuning constant in standardised residuals; 0 = Huber 1.5, "
                                  "Danish 2.5 (L1: the floor of |u|, 0.001)", ge=0.0)

    def __post_init__(self):
        bad = [m for m in self.flag_by if m not in FLAG_METHODS]
        if bad:
            raise ValueError(f"flag_by: unknown check {bad[0]!r}; expected some of {', '.join(FLAG_METHODS)}")
        for name in ("alpha0", "beta0", "alpha_pope"):
            if not 0 < getattr(self, name) < 1:
                raise ValueError(f"{name} must lie strictly between 0 and 1, got {getattr(self, name)}")
        if not self.sigma0_mm > 0:
            raise ValueError(f"sigma0_mm must be positive, got {self.sigma0_mm}")
        if not self.threshold_mm > 0:
            raise ValueError(f"threshold_mm must be positive, got {self.threshold_mm}")

    def settings(self) -> ScreeningSettings:
        return ScreeningSettings(self.sigma0_mm, self.alpha0, self.beta0, self.alpha_pope,
                                 self.threshold_mm, self.format_margin_mm, self.detect_swaps,
                                 tuple(self.flag_by))


@dataclasses.dataclass(frozen=True, eq=False)
class PairResult:
    """One screened pair: photo ids, block-observation indices and the screening."""

    left: str
    right: str
    obs_left: np.ndarray    # (m,) indices into block.observations
    obs_right: np.ndarray   # (m,)
    screening: PairScreening
    after_swaps: PairScreening | None = None
    """The pair screened again with the detected swaps undone (None without swaps)."""
    cleared: list[str] = dataclasses.field(default_factory=list)
    """Labels flagged by the checks that are no longer flagged once the swaps are undone."""

    @property
    def swap_explains(self) -> bool:
        """A detected swap accounts for every flag: undone, nothing is flagged any more."""
        return self.after_swaps is not None and not self.after_swaps.flagged.any()


@dataclasses.dataclass(frozen=True, eq=False)
class ScreeningArtefact:
    """The ``screening`` artefact: every screened pair and the pairs skipped (with the reason)."""

    pairs: list[PairResult]
    skipped: list[tuple[str, str, str]]
    settings: ScreeningSettings

    def flagged_observations(self) -> np.ndarray:
        """Block-observation indices flagged by the screening (right photo rows; format: both)."""
        out = set()
        for p in self.pairs:
            s = p.screening
            rows = np.flatnonzero(s.flagged)
            out.update(p.obs_right[rows // 2].tolist())
            if "format" in s.settings.flag_by:
                out.update(p.obs_left[s.outside_left].tolist())
        return np.array(sorted(out), int)


class HelmertScreening:
    summary = "Screen stereo pairs by a 2-D Helmert transformation: data snooping, Pope τ, swaps, format, thresholds"
    reads = ("block",)
    writes = ("screening", "block", "adjustment")
    Options = ScreeningOptions

    def run(self, inputs, options: ScreeningOptions, ctx: Context) -> StageResult:
        block = inputs["block"]
        settings = options.settings()
        src = block.source.path
        pair_lines = block.source.pair_lines
        if len(block.pairs) == 0:
            raise InputError("the block has no stereo pairs to screen (declare them, e.g. 'pair L R')",
                             src, None, "pair")
        obs = block.observations
        multi = len(block.pairs) > 1
        results, skipped = [], []
        for k, (li, ri) in enumerate(zip(block.pairs.left, block.pairs.right)):
            lid, rid = str(block.photos.ids[li]), str(block.photos.ids[ri])
            common_l, common_r, ids = _common(block, li, ri)
            if len(ids) < 3:
                why = ("only 2 common points: the 4-parameter transformation is determined exactly, "
                       "with no redundancy to screen" if len(ids) == 2 else
                       f"only {len(ids)} common point(s): the 4-parameter transformation needs 2 to be "
                       "determined and 3 to be checked")
                msg = f"pair {lid} {rid}: {why}; at least 3 common points are needed"
                if options.on_too_few == "error":
                    path, line = pair_lines[k] if k < len(pair_lines) else (src, None)
                    raise InputError(msg, path, line, "pair")
                skipped.append((lid, rid, msg))
                ctx.warn(msg)
                continue
            fmt_l = block.cameras.format_mm[block.photos.camera[li]]
            fmt_r = block.cameras.format_mm[block.photos.camera[ri]]
            kw = {"format_left": fmt_l, "format_right": fmt_r, "prefix": f"{lid}-{rid} " if multi else ""}
            scr = screen_pair(obs.xy[common_l], obs.xy[common_r], ids, settings, **kw)
            results.append(_narrow_by_swaps(PairResult(lid, rid, common_l, common_r, scr), settings, kw))
        if not results:
            raise InputError("no pair could be screened: " + "; ".join(s[2] for s in skipped), src, None, "pair")
        artefact = ScreeningArtefact(results, skipped, settings)

        flagged_obs = artefact.flagged_observations()
        out_block = block
        if options.action == "remove" and flagged_obs.size:
            active = obs.active.copy()
            active[flagged_obs] = False
            out_block = block.replace(observations=obs.replace(active=active))

        model = stack_models([p.screening.model for p in results])
        obs_rows = np.concatenate([np.column_stack([np.repeat(p.obs_right, 2),
                                                    np.tile([0, 1], len(p.obs_right))]) for p in results])
        row_active = out_block.observations.active[obs_rows[:, 0]]
        adjustment = AdjustmentArtefact("helmert-screening", model.refit(row_active), model, obs_rows)
        robust = _robust(adjustment, options)

        return StageResult(
            artefacts={"screening": artefact, "block": out_block, "adjustment": adjustment},
            summary=_summary(artefact, flagged_obs, block, options) | _robust_summary(robust),
            report=_report(artefact, block, options, flagged_obs) + _robust_report(robust, adjustment, block),
            tables=_tables(artefact) | _robust_tables(robust, adjustment, block),
            data={"artefact": artefact, "block": block, "arrow_scale": options.arrow_scale},
        )

    def plots(self, result: StageResult, ctx: Context) -> dict:
        """Figures for report.html (drawn by the engine): residual vectors and |w| per pair."""
        from .figures import helmert_residuals

        return helmert_residuals(result.data["artefact"])

    def log(self, result: StageResult, rec, ctx: Context) -> None:
        import rerun as rr

        from baarda.pipeline.recording import entity_part, view_from_photo, view_vectors

        art: ScreeningArtefact = result.data["artefact"]
        scale = result.data["arrow_scale"]
        red, grey, blue = [230, 40, 40], [150, 150, 150], [40, 90, 230]
        for p in art.pairs:
            s = p.screening
            ids = s.point_ids
            flagged_pt = s.flagged.reshape(-1, 2).any(axis=1)
            colors = [red if f else blue for f in flagged_pt]
            left, right = entity_part(p.left), entity_part(p.right)
            rec.log(f"photos/{left}/points", rr.Points2D(view_from_photo(s.xy_left), labels=ids, colors=colors,
                                                         radii=0.6))
            rec.log(f"photos/{right}/points", rr.Points2D(view_from_photo(s.xy_right), labels=ids, colors=colors,
                                                          radii=0.6))
            v = s.adjustment.v.reshape(-1, 2)
            rec.log(f"photos/{right}/residuals",
                    rr.Arrows2D(origins=view_from_photo(s.xy_right - v), vectors=view_vectors(v * scale),
                                colors=[red if f else grey for f in flagged_pt]))   # v per point: pairs/…/tests
            if flagged_pt.any():
                rec.log(f"photos/{right}/flagged",
                        rr.Points2D(view_from_photo(s.xy_right[flagged_pt]),
                                    labels=[ids[i] for i in np.flatnonzero(flagged_pt)],
                                    colors=red, radii=2.0))
            w = s.snooping.w.reshape(-1, 2)
            tau = s.pope.tau.reshape(-1, 2)
            nab = s.snooping.nabla_hat.reshape(-1, 2)
            rec.log(f"pairs/{p.left}-{p.right}/tests", rr.AnyValues(
                point=ids, vx=v[:, 0], vy=v[:, 1], wx=w[:, 0], wy=w[:, 1], taux=tau[:, 0], tauy=tau[:, 1],
                nabla_x=nab[:, 0], nabla_y=nab[:, 1], flagged=flagged_pt.tolist()))
            rec.log(f"pairs/{p.left}-{p.right}/summary", rr.AnyValues(
                sigma0=s.settings.sigma0, sigma0_hat=s.adjustment.sigma0_hat, dof=s.adjustment.dof,
                global_T=s.global_.T, global_critical=s.global_.critical, K=s.snooping.critical,
                tau_critical=s.pope.critical, arrow_scale=scale))


def _narrow_by_swaps(pair: PairResult, settings: ScreeningSettings, kw: dict) -> PairResult:
    """Flag what is left once the detected swaps are undone, plus the swapped points.

    Swapped right coordinates smear over every residual of the transformation, so the threshold
    and τ checks flag points that are fine.  The pair is screened again with the exchanges
    undone (best first, each point once); the flags are then the swapped points and whatever is
    still flagged after the correction.  Only when ``swap`` is among ``flag_by``.
    """
    scr = pair.screening
    if not scr.swaps or "swap" not in settings.flag_by:
        return pair
    xy_right = scr.xy_right.copy()
    used: set[int] = set()
    for sw in scr.swaps:
        if used.isdisjoint((sw.i, sw.j)):
            xy_right[[sw.i, sw.j]] = xy_right[[sw.j, sw.i]]
            used.update((sw.i, sw.j))
    after = screen_pair(scr.xy_left, xy_right, scr.point_ids,
                        dataclasses.replace(settings, detect_swaps=False), **kw)
    flagged = scr.method_flags()["swap"] | after.flagged
    cleared = [str(lab) for lab in scr.labels[scr.flagged & ~flagged]]
    return dataclasses.replace(pair, screening=dataclasses.replace(scr, flagged=flagged),
                               after_swaps=after, cleared=cleared)


def _common(block, li: int, ri: int):
    """Observation indices (left, right) of the active points common to both photos, and their ids."""
    obs = block.observations
    act = obs.active
    left = {int(obs.point[i]): i for i in np.flatnonzero((obs.photo == li) & act)[::-1]}
    right = {int(obs.point[i]): i for i in np.flatnonzero((obs.photo == ri) & act)[::-1]}
    pts = [q for q in sorted(left, key=lambda q: left[q]) if q in right]
    return (np.array([left[q] for q in pts], int), np.array([right[q] for q in pts], int),
            [str(block.points.ids[q]) for q in pts])


def _f(x, nd=3):
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else round(float(x), nd)


def _robust(adj: AdjustmentArtefact, options):
    """IRLS on the stacked pair models (report only)."""
    if options.robust == "none":
        return None
    refit, _ = stats.weighted_refit(adj.model, adj.snapshot.active)
    return stats.irls(refit, adj.snapshot, options.robust, options.robust_c or None, max_iter=200)


def _robust_rows(rob, adj: AdjustmentArtefact, block) -> list[tuple]:
    ids = block.observation_ids()
    return [(str(rob.labels[i]), "/".join(map(str, ids[adj.obs_rows[i, 0]])) + " " + "xy"[adj.obs_rows[i, 1]],
             float(rob.weights[i]), float(rob.u[i])) for i in rob.downweighted]


def _robust_summary(rob) -> dict:
    return {} if rob is None else {"robust": rob.summary()}


def _robust_report(rob, adj: AdjustmentArtefact, block) -> str:
    if rob is None:
        return ""
    rows = _robust_rows(rob, adj, block)
    out = ["", "", f"### Robust estimation ({rob.method}, c = {rob.c:g})", "",
           f"IRLS on every pair's Helmert transformation, residuals standardised by σ √r of the least-squares "
           f"adjustment; {rob.iterations} weighted adjustment(s), {'converged' if rob.converged else 'NOT converged'}; "
           f"{len(rows)} coordinate(s) end with weight < {rob.threshold:g} (screening_robust.csv). Report only: the "
           "flags above are the screening's."]
    if rows:
        out += ["", "| row | observation | weight | u |", "|---|---|---|---|"]
        out += [f"| {a} | {b} | {w:.3g} | {u:+.2f} |" for a, b, w, u in rows[:40]]
    return "\n".join(out)


def _robust_tables(rob, adj: AdjustmentArtefact, block) -> dict:
    if rob is None:
        return {}
    ids = block.observation_ids()
    n = adj.snapshot.n
    return {"robust": TableData({
        "row": [str(x) for x in rob.labels],
        "observation": ["/".join(map(str, ids[adj.obs_rows[i, 0]])) + " " + "xy"[adj.obs_rows[i, 1]] for i in range(n)],
        "weight": [round(float(x), 6) for x in rob.weights],
        "u": [None if not math.isfinite(x) else round(float(x), 4) for x in rob.u],
        "downweighted": [bool(x) for x in np.isin(np.arange(n), rob.downweighted)]},
        f"robust estimation ({rob.method}, c = {rob.c:g}): every right-image coordinate's final IRLS weight and "
        "standardised residual u")}


def _summary(art: ScreeningArtefact, flagged_obs, block, options) -> dict:
    pairs = []
    for p in art.pairs:
        s = p.screening
        i = s.most_suspicious
        flags = s.method_flags()
        pairs.append({
            "pair": [p.left, p.right], "points": len(s.point_ids), "dof": s.adjustment.dof,
            "sigma0": s.settings.sigma0, "sigma0_hat": _f(s.adjustment.sigma0_hat, 4),
            "global_test": {"T": _f(s.global_.T, 4), "critical": _f(s.global_.critical, 4),
                            "alpha": s.global_.alpha, "rejected": s.global_.rejected},
            "K": _f(s.snooping.critical, 4), "tau_critical": _f(s.pope.critical, 4),
            "most_suspicious": None if i is None else {
                "row": str(s.labels[i]), "v": _f(s.adjustment.v[i]), "w": _f(s.snooping.w[i], 2),
                "tau": _f(s.pope.tau[i], 2), "nabla_hat": _f(s.snooping.nabla_hat[i])},
            "flagged": {m: [str(x) for x in s.labels[f]] for m, f in flags.items()},
            "swaps": [[s.point_ids[w.i], s.point_ids[w.j]] for w in s.swaps],
            "after_swaps": None if p.after_swaps is None else {
                "explains": p.swap_explains, "sigma0_hat": _f(p.after_swaps.adjustment.sigma0_hat, 4),
                "global_T": _f(p.after_swaps.global_.T, 4),
                "still_flagged": [str(x) for x in p.after_swaps.labels[p.after_swaps.flagged]],
                "cleared": p.cleared},
            "parameters": dict(zip(("a", "b", "tx", "ty"), map(float, s.adjustment.x))),
            "notes": s.notes,
        })
    flagged_ids = [list(block.observation_ids()[i]) for i in flagged_obs]
    worst = [f"{p['pair'][0]}→{p['pair'][1]}: {p['most_suspicious']['row']} (w {p['most_suspicious']['w']})"
             for p in pairs if p["most_suspicious"] is not None and any(p["flagged"].values())]
    swaps = [f"{a}↔{b} in {p['pair'][1]}" + (" (explains every flag)" if p["after_swaps"]
                                              and p["after_swaps"]["explains"] else "")
             for p in pairs for a, b in p["swaps"]]
    headline = (f"{len(pairs)} pair(s) screened; {len(flagged_ids)} image point(s) flagged"
                + (f"; swapped point numbers {', '.join(swaps)}" if swaps else
                   (f" — most suspicious {', '.join(worst[:3])}" if worst else "")))
    return {"headline": headline, "pairs": pairs, "skipped": [list(x) for x in art.skipped],
            "flagged_observations": flagged_ids,
            "deactivated": bool(options.action == "remove" and len(flagged_obs)), "flag_by": list(options.flag_by)}


def _report(art: ScreeningArtefact, block, options, flagged_obs) -> str:
    out = []
    for p in art.pairs:
        s = p.screening
        a, b, tx, ty = s.adjustment.x
        g = s.global_
        out += [f"**Pair {p.left} → {p.right}**: {len(s.point_ids)} common points, dof {s.adjustment.dof}; "
                f"scale {math.hypot(a, b):.6f}, rotation {math.degrees(math.atan2(b, a)):.4f}°, "
                f"shift ({tx:.3f}, {ty:.3f}) mm.", "",
                f"- σ̂0 = {s.adjustment.sigma0_hat:.4f} mm against σ0 = {s.settings.sigma0:g} mm: global test "
                f"T = {g.T:.3f} vs F = {g.critical:.3f} (α′ = {g.alpha:.3g}) → "
                f"{'rejected' if g.rejected else 'accepted'}.",
                f"- Data snooping (σ0 = {s.settings.sigma0:g} mm, K = {s.snooping.critical:.2f}): "
                f"{', '.join(s.snooping.flagged_labels) or 'nothing'}.",
                f"- Pope τ (σ̂0, τc = {s.pope.critical:.3f} at α = {s.pope.alpha:g}, dof {s.pope.dof}): "
                f"{', '.join(s.pope.flagged_labels) or 'nothing'}.",
                f"- |v| > {s.settings.threshold_mm:g} mm: {', '.join(s.labels[s.beyond]) or 'nothing'}."]
        i = s.most_suspicious
        if i is not None:
            nab = s.snooping.nabla_hat[i]
            text = (f"- Most suspicious: **{s.labels[i]}** — v = {s.adjustment.v[i]:+.3f} mm, "
                    f"w = {s.snooping.w[i]:+.2f}, τ = {s.pope.tau[i]:+.2f}, estimated error "
                    f"∇̂ = {nab:+.3f} mm in the right photo (MDB {s.snooping.mdb[i]:.3f} mm)")
            if abs(math.atan2(b, a)) < math.radians(5):
                text += (f"; the transformation cannot tell it from an error of about {-nab / math.hypot(a, b):+.3f} mm "
                         f"in the left photo's {'xy'[i % 2]} of point {s.point_ids[i // 2]}")
            out.append(text + ".")
        fl, fr = s.outside_left, s.outside_right
        if fl.any() or fr.any():
            names = [f"{p.left}/{s.point_ids[k]}" for k in np.flatnonzero(fl)] + \
                    [f"{p.right}/{s.point_ids[k]}" for k in np.flatnonzero(fr)]
            out.append(f"- Outside the camera format: {', '.join(names)}.")
        for w in s.swaps:
            out.append(f"- Swapped point numbers? Exchanging the right coordinates of {s.point_ids[w.i]} and "
                       f"{s.point_ids[w.j]} lowers vᵀPv from {w.vtpv_before:.4g} to {w.vtpv_after:.4g} mm² and "
                       f"both points then pass the w-test (|w| ≤ {max(abs(x) for x in w.w_after):.2f}).")
        if p.after_swaps is not None:
            out.append(_swap_finding(p))
        out += [f"- Note: {n}." for n in s.notes]
        out.append("")
    for lid, rid, why in art.skipped:
        out.append(f"- Skipped: {why}.")
    ids = block.observation_ids()
    act = "marked inactive" if options.action == "remove" else "flagged only (option action = \"flag\")"
    out.append(f"Flagged observations ({', '.join(options.flag_by)}): "
               f"{', '.join(f'{ph}/{pt}' for ph, pt in (ids[i] for i in flagged_obs)) or 'none'} — {act}.")
    return "\n".join(out)


def _swap_finding(p: PairResult) -> str:
    """The report's line on what remains once the detected swaps are undone."""
    s, a = p.screening, p.after_swaps
    names = " and ".join(f"{s.point_ids[w.i]}↔{s.point_ids[w.j]}" for w in s.swaps)
    state = (f"σ̂0 = {a.adjustment.sigma0_hat:.4f} mm, global test T = {a.global_.T:.3f} vs F = "
             f"{a.global_.critical:.3f} → {'rejected' if a.global_.rejected else 'accepted'}")
    checks = ", ".join(m for m in s.settings.flag_by if m != "swap") or "no other check"
    cleared = (f" The flags of {', '.join(p.cleared)} come from the swap's smear and disappear once it is "
               "corrected; they are not flagged." if p.cleared else "")
    if p.swap_explains:
        swapped = sorted({s.point_ids[k] for w in s.swaps for k in (w.i, w.j)}, key=s.point_ids.index)
        return (f"- **Finding: point numbers {names} swapped in photo {p.right}.** With the exchange undone "
                f"the pair passes ({state}; nothing flagged by {checks}), so only {p.right}/"
                + f", {p.right}/".join(swapped) + f" are flagged.{cleared}")
    flags = a.method_flags()
    still = ", ".join(f"{lab} ({', '.join(m for m in s.settings.flag_by if m != 'swap' and flags[m][k])})"
                      for k, lab in enumerate(a.labels) if a.flagged[k])
    return (f"- With {names} undone ({state}) still flagged: {still} — flagged besides the swapped "
            f"points.{cleared}")


def _tables(art: ScreeningArtefact) -> dict:
    cols = {k: [] for k in ("pair", "point", "coord", "label", "left", "right_observed", "v", "r", "w",
                            "tau", "nabla_hat", "mdb", "data_snooping", "pope", "threshold", "format",
                            "swap_with", "flagged")}
    for p in art.pairs:
        s = p.screening
        flags = s.method_flags()
        partner = s.swap_partner
        for k, lab in enumerate(s.labels):
            q, c = k // 2, k % 2
            cols["pair"].append(f"{p.left}-{p.right}")
            cols["point"].append(s.point_ids[q])
            cols["coord"].append("xy"[c])
            cols["label"].append(str(lab))
            cols["left"].append(round(float(s.xy_left[q, c]), 6))
            cols["right_observed"].append(round(float(s.xy_right[q, c]), 6))
            for name, value in (("v", s.adjustment.v), ("r", s.snooping.r), ("w", s.snooping.w),
                                ("tau", s.pope.tau), ("nabla_hat", s.snooping.nabla_hat), ("mdb", s.snooping.mdb)):
                cols[name].append(round(float(value[k]), TABLE_DECIMALS[name]))
            for m, col in (("data-snooping", "data_snooping"), ("pope", "pope"), ("threshold", "threshold"),
                           ("format", "format")):
                cols[col].append("reject" if flags[m][k] else "accept")
            cols["swap_with"].append(partner[q])
            cols["flagged"].append(bool(s.flagged[k]))
    return {"observations": TableData(cols, "Helmert screening: every right-image coordinate with residual "
                                            "(observed − computed, mm), redundancy number, w, τ, ∇̂, MDB and "
                                            "the decision of each check")}
