"""Stage ``helmert-screening``: screen every stereo pair by a 2-D Helmert transformation.

See docs/screening.md.  Numerics in :mod:`.helmert` and :mod:`.screen`; statistics from
:mod:`baarda.pipeline.stats`; this module handles the block, options and recording, :mod:`.report`
the summary, tables and report text.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar, Literal

import numpy as np

from baarda.pipeline.api import AdjustmentArtefact, Context, InputError, Stage, StageResult, option, stats
from baarda.pipeline.options import check_bounds

from . import report as screening_report
from .helmert import stack_models
from .screen import FLAG_METHODS, PairScreening, ScreeningSettings, screen_pair


@dataclasses.dataclass(frozen=True)
class ScreeningOptions(stats.SnoopingLevels):
    """The stage's options; ``alpha0`` and ``beta0`` (data snooping, the MDB) are the statistics
    library's :class:`~baarda.pipeline.stats.SnoopingLevels`, the ``robust`` table its
    :class:`~baarda.pipeline.stats.RobustConfig` (declared once for every stage)."""

    RENAMED: ClassVar[dict[str, str]] = {"deactivate": "action"}
    RENAMED_VALUES: ClassVar[dict[str, dict[str, str]]] = {"on_too_few": {"fail": "error"}}
    MOVED: ClassVar[dict[str, str]] = {"robust": "robust.method", "robust_c": "robust.c"}
    sigma0_mm: float = option(
        0.2, "a-priori σ (mm) of one right-image coordinate about the Helmert transformation, "
             "including relief displacement the 2-D transformation cannot model (used by the "
             "global test, data snooping, MDB and the swap check; Pope's τ uses σ̂0 instead)")
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
    robust: stats.RobustConfig = option(
        stats.RobustConfig(), "also estimate the Helmert transformations robustly (IRLS, docs/statistics.md) and "
                              "report the down-weighted right-image coordinates (weight < 0.5) with their weights; "
                              "report only, flags are unchanged")

    def __post_init__(self):
        check_bounds(self)
        bad = [m for m in self.flag_by if m not in FLAG_METHODS]
        if bad:
            raise ValueError(f"flag_by: unknown check {bad[0]!r}; expected some of {', '.join(FLAG_METHODS)}")

    def settings(self) -> ScreeningSettings:
        return ScreeningSettings(self.sigma0_mm, self.alpha0, self.beta0, self.alpha_pope,
                                 self.threshold_mm, self.format_margin_mm, self.detect_swaps,
                                 tuple(self.flag_by), self.alpha_global)


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
    keeps_rows = True               # its block: the observations it read, some flagged or inactive
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
            summary=screening_report.summary(artefact, flagged_obs, block, options) | screening_report.robust_summary(robust),
            report=screening_report.report(artefact, block, options, flagged_obs) + screening_report.robust_report(robust, adjustment, block),
            tables=screening_report.tables(artefact, options.action) | screening_report.robust_tables(robust, adjustment, block),
            data={"artefact": artefact, "block": block, "arrow_scale": options.arrow_scale},
        )

    def plots(self, result: StageResult, ctx: Context) -> dict:
        """Figures for report.html (drawn by the engine): residual vectors and |w| per pair."""
        from .figures import helmert_residuals

        return helmert_residuals(result.data["artefact"])

    def log(self, result: StageResult, rec, ctx: Context) -> None:
        import rerun as rr

        from baarda.pipeline.api import entity_part, view_from_photo, view_vectors

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


def _robust(adj: AdjustmentArtefact, options):
    """IRLS on the stacked pair models (report only)."""
    r = options.robust
    if r.method == "none":
        return None
    refit, _ = stats.weighted_refit(adj.model, adj.snapshot.active)
    return stats.irls(refit, adj.snapshot, r.method, r.c or None, standardise=r.standardise, max_iter=200)


