"""Stage ``blunder-rejection``: data snooping, IDS, Pope τ or RRR on any adjustment.

Reads the ``adjustment`` artefact (:class:`.artefact.AdjustmentArtefact`) and the block; writes
``blunders`` (:class:`BlunderReport`) and the block, with the rejected observations marked
inactive when ``action = "remove"``.  Statistics: :mod:`baarda.pipeline.stats`; the options
(:class:`~.decide.BlunderOptions`) and the method wiring: :mod:`.decide`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from baarda.pipeline.api import AdjustmentArtefact, Context, InputError, StageResult, TableData, ValidationContext
from baarda.pipeline.report import cap_text

from .decide import METHODS, ROBUST_METHODS, BlunderOptions, MethodResult, row_statistics, run_methods


@dataclasses.dataclass(frozen=True, eq=False)
class BlunderReport:
    """The ``blunders`` artefact: each method's result and what was done to the block."""

    adjustment: str
    methods: dict[str, MethodResult]
    decide_by: str
    action: str
    acted_rows: np.ndarray          # scalar rows of the deciding method
    acted_observations: np.ndarray  # block observation indices marked inactive (or flagged)


def redundancy_bound(block, adjuster=None) -> tuple[int, int]:
    """``(n_max, u_min)``: at most n observation rows and at least u unknowns an adjustment of ``block``
    can have, for ``baarda validate`` (n − u ≥ the adjustment's redundancy is not guaranteed the
    other way: validate refuses only what no run can accept).

    n counts every row the block can give: two per active image observation, three per GNSS
    antenna, one per weighted (0 < σ < ∞) point coordinate, orientation element and camera
    parameter, and the ``distances`` of the adjusting stage's options.  u is only bounded for a
    ``bundle``: three per tie point with two or more active observations and no a-priori σ (a tie
    point seen once adds 2 rows and 3 unknowns, or nothing when the run does not see it: left out,
    the bound holds for any block whose rows are a subset of ``block``'s); otherwise 0."""
    def weighted(s):
        s = np.asarray(s, float)
        return int(((s > 0) & np.isfinite(s)).sum()) if s.size else 0

    obs = block.observations
    active = np.asarray(obs.active, bool)
    n = 2 * int(active.sum())
    gnss = getattr(block, "gnss", None)
    n += 3 * (len(gnss) if gnss is not None else 0)
    n += weighted(block.points.sigma) + weighted(block.photos.sigma_eo)
    n += weighted(block.cameras.sigma_iop) + weighted(block.cameras.sigma_ap)
    u = 0
    if adjuster is not None:
        n += len(getattr(adjuster.options, "distances", None) or ())
        if adjuster.use == "bundle":
            rays = np.bincount(np.asarray(obs.point)[active], minlength=len(block.points))
            free = np.isinf(np.asarray(block.points.sigma, float).reshape(len(block.points), -1)).all(axis=1)
            u = 3 * int(((rays >= 2) & (np.asarray(block.points.role) == "tie") & free).sum())
    return n, u


class BlunderRejection:
    summary = "Reject gross errors in any adjustment: data snooping, IDS, Pope τ, RRR (side by side)"
    reads = ("adjustment", "block")
    writes = ("blunders", "block")
    Options = BlunderOptions

    keeps_rows = True               # its block: the observations it read, some marked inactive

    def validate_with(self, v: ValidationContext) -> None:
        """``baarda validate``: RRR's ``rho`` below an upper bound of n − u, from a block bounding the
        adjustment's rows (``v.rows``: the source's block, or a dry construction of a block that
        exists only during the run) and the adjusting stage (``v.adjuster``) — :func:`redundancy_bound`."""
        options, ctx = v.options, v.ctx
        methods = list(METHODS) if options.method == "all" else [options.method]
        if "rrr" not in methods or not options.rho or v.rows is None:
            return
        n, u = redundancy_bound(v.rows, v.adjuster)
        if options.rho >= n - u:
            raise ctx.option_error(f"rho = {options.rho} suspects leave no redundant clean observation: RRR needs "
                                   f"rho < n − u, and this block gives at most n = {n} observation rows and at "
                                   f"least u = {u} unknowns (n − u ≤ {n - u})", "rho")

    def run(self, inputs, options: BlunderOptions, ctx: Context) -> StageResult:
        art = inputs["adjustment"]
        block = inputs["block"]
        if not isinstance(art, AdjustmentArtefact):
            raise InputError(f"the 'adjustment' artefact is a {type(art).__name__}, expected an "
                             "AdjustmentArtefact (baarda.pipeline.contracts)", None, None, "adjustment")
        methods = list(METHODS) if options.method == "all" else [options.method]
        if options.method == "rrr" and not art.supports_rrr:
            raise InputError(f"method 'rrr' needs a linear model; the adjustment '{art.name}' offers only "
                             "refit() — use data-snooping, ids or pope", None, None, "method")
        dof = int(getattr(art.snapshot, "dof", 0) or 0)
        if "rrr" in methods and options.rho and art.supports_rrr and options.rho >= dof:
            raise ctx.option_error(f"rho = {options.rho} suspects leave no redundant clean observation: RRR needs "
                                   f"rho < n − u = {dof} for this adjustment", "rho")
        results = run_methods(art, methods, options, ctx.rng, progress=ctx.progress)
        if options.method in ROBUST_METHODS and results[options.method].skipped:
            raise InputError(f"method '{options.method}' cannot run: {results[options.method].skipped}",
                             None, None, "method")
        for m in set(results) & set(ROBUST_METHODS):
            if not results[m].summary["converged"]:
                ctx.warn(f"{m}: IRLS did not converge in {results[m].summary['iterations']} weighted adjustments")
        for r in results.values():
            if r.skipped:
                ctx.warn(f"{r.method} skipped: {r.skipped}")
        decide = options.method if options.method != "all" else options.decide_by
        acted_rows = np.array(sorted(results[decide].rejected), int)
        acted_obs = art.observations_of(acted_rows) if acted_rows.size else np.zeros(0, int)
        out_block = block
        if options.action == "remove" and acted_obs.size:
            active = block.observations.active.copy()
            active[acted_obs] = False
            out_block = block.replace(observations=block.observations.replace(active=active))
        report = BlunderReport(art.name, results, decide, options.action, acted_rows, acted_obs)
        stats = row_statistics(art, options)
        return StageResult(
            artefacts={"blunders": report, "block": out_block},
            summary=_summary(report, block, art) | {"rrr_note": _rho_note(report, options, art.snapshot.dof)}
            | _protocol_entry(report, art, options),
            report=_report(report, block, art, options, f"{ctx.stage_id}_observations.csv"),
            tables={"observations": _table(report, art, block, stats)},
            data={"report": report, "artefact": art, "block": block, "options": options},
        )

    def plots(self, result: StageResult, ctx: Context) -> dict:
        """Figures for report.html (drawn by the engine): w against N(0, 1), redundancy numbers."""
        from .figures import figures

        return figures(result.data["artefact"], result.data["options"])

    def log(self, result: StageResult, rec, ctx: Context) -> None:
        """Each method's statistic per step as a time series with its critical value in the same view
        when that value changes (IDS's F with the dof, Pope's τ with the dof, RRR's naive Beta quantile
        with the number of recursive residuals); a critical value that stays the same for the whole run
        (IDS's K, RRR's Monte Carlo H) is a static value under ``…/constants`` (``docs/recordings.md``)."""
        import rerun as rr

        from baarda.pipeline.recording import log_series

        report: BlunderReport = result.data["report"]
        for name, res in report.methods.items():
            base = f"blunders/{name}"
            h = res.history
            if h:
                steps = np.arange(len(h))
                col = lambda k, f=_num: [f(x[k]) for x in h]   # noqa: E731
                if name == "ids":
                    log_series(rec, f"{base}/global_test", steps, {"T": col("T")}, {"F_critical": col("F_critical")})
                    log_series(rec, f"{base}/w", steps, {"w_max": col("w_max", lambda x: abs(_num(x)))},
                               {"K": [res.summary.get("K", np.nan)] * len(h)})
                elif name == "pope":
                    log_series(rec, f"{base}/tau", steps, {"tau_max": col("tau_max")},
                               {"tau_critical": col("tau_critical")})
                    log_series(rec, f"{base}/sigma0", steps, {"sigma0_hat": col("sigma0_hat")})
                elif name == "rrr":
                    log_series(rec, f"{base}/H", steps, {"H_exp": col("H_exp")},
                               {"H": col("H"), "H_naive": col("H_naive")})
                for i, step in enumerate(h):
                    rec.set_time("iteration", sequence=i)
                    rec.log(f"{base}/step", rr.AnyValues(**{k: (str(v) if not isinstance(v, (int, float, bool)) else v)
                                                            for k, v in step.items() if not isinstance(v, list)}))
            rec.reset_time()
            rec.log(f"{base}/rejected", rr.AnyValues(labels=[d.label for d in res.decisions] or [""],
                                                     skipped=res.skipped or ""))


def _protocol_entry(report, art, options) -> dict:
    from .figures import protocol

    p = protocol(report, art, options)
    return {"protocol": p} if p else {}


def _num(x) -> float:
    return float("nan") if x is None else float(x)


def _obs_label(art: AdjustmentArtefact, block, row: int) -> str:
    o, c = art.obs_rows[row]
    if o < 0:
        return ""
    ph, pt = block.observation_ids()[o]
    return f"{ph}/{pt} {'xy'[c]}"


SUMMARY_MOST = 20
"""Rows listed per method in results.json (rejected labels, decisions, rows acted on; any list of
a method's details): the first ones, their number beside them (``n_…``); every row is in the
observations table (``blunders_observations``)."""


def _summary(report: BlunderReport, block, art) -> dict:
    ids = block.observation_ids()
    per = [f"{m}: {', '.join(r.rejected_labels[:4]) or 'none'}{' …' if len(r.rejected_labels) > 4 else ''}"
           for m, r in report.methods.items() if not r.skipped]
    return {
        "headline": f"{report.adjustment}: " + "; ".join(per) + f" (decisive: {report.decide_by}, {report.action})",
        "adjustment": report.adjustment, "decide_by": report.decide_by, "action": report.action,
        "methods": {m: ({"rejected": r.rejected_labels[:SUMMARY_MOST], "n_rejected": len(r.rejected_labels),
                         "decisions": [dataclasses.asdict(d) for d in r.decisions[:SUMMARY_MOST]]} if not r.skipped
                        else {"skipped": r.skipped}) | {"details": _capped(_plain(r.summary))}
                    for m, r in report.methods.items()},
        "acted_on": [list(ids[i]) for i in report.acted_observations[:SUMMARY_MOST]],
        "n_acted_on": len(report.acted_observations),
    }


TEXT_MOST = 10
"""Rows named per list in the report's text (rejected rows, decisive statistics, points acted on); the
count and the table beside them (every row is in the stage's observations table)."""


def _capped(x):
    """``x`` with every list longer than :data:`SUMMARY_MOST` cut to its first ones; a dict's
    ``key`` cut so gets ``n_key``, its length."""
    if isinstance(x, dict):
        out = {}
        for k, v in x.items():
            out[k] = _capped(v)
            if isinstance(v, list) and len(v) > SUMMARY_MOST and f"n_{k}" not in x:
                out[f"n_{k}"] = len(v)
        return out
    if isinstance(x, list):
        return [_capped(v) for v in x[:SUMMARY_MOST]]
    return x


def _plain(x):
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    return x


def _report(report: BlunderReport, block, art: AdjustmentArtefact, options,
            where: str = "blunders_observations.csv") -> str:
    snap = art.snapshot
    out = [f"Adjustment **{art.name}**: {int(snap.active.sum())} active rows, dof {snap.dof}, "
           f"σ0 = {snap.sigma0:g}, σ̂0 = {snap.sigma0_hat:.4g}.", "",
           # with action = flag a method's outliers are flagged, not rejected (the block is unchanged)
           f"| method | {'rejected' if report.action == 'remove' else 'would reject (flagged here)'} (in order) "
           "| decisive statistics |", "|---|---|---|"]
    for m, r in report.methods.items():
        if r.skipped:
            out.append(f"| {m} | — | skipped: {r.skipped} |")
            continue
        stats = "; ".join(f"{d.label}: {d.statistic} = {d.value:+.4g} vs {d.critical:.4g}"
                          for d in r.decisions[:TEXT_MOST])
        if len(r.decisions) > TEXT_MOST:
            stats += f" … ({cap_text(TEXT_MOST, len(r.decisions), what='decisions', where=where)})"
        labels = ", ".join(r.rejected_labels[:TEXT_MOST]) or "nothing"
        if len(r.rejected_labels) > TEXT_MOST:
            labels += f" … ({cap_text(TEXT_MOST, len(r.rejected_labels), what='rows', where=where)})"
        out.append(f"| {m} | {labels} | {stats or '—'} |")
    out.append("")
    for m, r in report.methods.items():
        if r.skipped:
            continue
        if m == "ids":
            out.append(f"- IDS (K = {r.summary['K']:.3f}) stopped: {r.summary['stop']}.")
        elif m in ROBUST_METHODS:
            s = r.summary
            out.append(f"- {m}: IRLS ({s['how']}), c = {s['c']:g}, residuals standardised by "
                       + {"redundancy": "σ √r of the given adjustment", "apriori": "the a-priori σ",
                          "current": "σ √r of the current weighted adjustment"}[s["standardise"]]
                       + f"; {s['iterations']} weighted adjustment(s), "
                       + ("converged" if s["converged"] else "NOT converged")
                       + f"; {s['n_downweighted']} row(s) end with weight < {s['threshold']:g} (their weights are "
                         f"in column {m.replace('-', '_')}_weight).")
        elif m == "pope":
            h = r.history[-1]
            out.append(f"- Pope (α = {r.summary['alpha']:g}) stopped at dof {h['dof']}, σ̂0 = {h['sigma0_hat']:.4g}: "
                       f"{r.summary['stop']} (|τ|max = {h['tau_max']:.3f}, τc = {h['tau_critical']:.3f}).")
        elif m == "rrr":
            s = r.summary
            out.append(f"- RRR: ρ = {s['rho']}, suspects {', '.join(s['suspects'])} (largest |∇̂| of the full "
                       f"adjustment); H = {s['H']:.4f} at α = {s['alpha']:g} from {s['n_sim']} Monte Carlo runs "
                       f"of the whole procedure for this design (95 % interval {s['H_ci'][0]:.4f}–{s['H_ci'][1]:.4f}); "
                       "H_exp: " + ", ".join(f"{lab} {h:.4f}" for lab, h in zip(s['suspects'], s['H_exp'])) +
                       "; naive Beta quantiles (no selection): " +
                       ", ".join(f"{h:.4f}" for h in s['H_naive']) + ".")
            note = _rho_note(report, options, snap.dof)
            if note:
                out.append(f"- **{note}**")
    ids = block.observation_ids()
    acted = ", ".join(f"{ph}/{pt}" for ph, pt in (ids[i] for i in report.acted_observations[:TEXT_MOST])) or "none"
    if len(report.acted_observations) > TEXT_MOST:
        n_acted = len(report.acted_observations)
        acted += f" … ({cap_text(TEXT_MOST, n_acted, what='image points', where=where + ', column decision')})"
    verb = "marked inactive" if report.action == "remove" else "flagged (action = flag; the block is unchanged)"
    out += ["", f"Decisions of **{report.decide_by}** act on the block: {acted} — {verb}. "
                "A rejected x or y takes the whole image point out (the block's active flag is per point)."]
    return "\n".join(out)


def _rho_note(report: BlunderReport, options, dof: int) -> str | None:
    """When RRR with the default ρ rejected nothing: say that a larger ρ may be needed."""
    r = report.methods.get("rrr")
    if r is None or r.skipped or r.rejected or options.rho:
        return None
    rho = r.summary["rho"]
    others = [f"{m} {len(o.rejected)}" for m, o in report.methods.items()
              if m != "rrr" and not o.skipped and o.rejected]
    return (f"RRR rejected nothing with the default ρ = {rho} suspects (⌈0.20 (n − u)⌉, n − u = {dof})"
            + (f" while other methods rejected rows ({', '.join(others)})" if others else "")
            + ". A gross error left among the non-suspects masks the others, so a larger ρ may be needed: "
            + f"try rho = {rho + 1}" + ("" if others else " if gross errors are expected") + ".")


def _table(report: BlunderReport, art: AdjustmentArtefact, block, stats) -> TableData:
    snap = art.snapshot
    n = snap.n
    cols = {"row": list(range(n)), "label": [str(s) for s in snap.labels],
            "observation": [_obs_label(art, block, i) for i in range(n)],
            "active": [bool(a) for a in snap.active]}
    for k in ("v", "r", "w", "tau", "nabla_hat", "mdb"):          # full precision; NaN: an empty cell
        cols[k] = np.asarray(stats[k], dtype=float)
        if k == "mdb":      # v, ∇̂ and MDB are in the row's own unit: say it per row
            cols["unit"] = _row_units(art, block)
    # one verdict per row, the decisive method's (the summary's): rejected = taken out of the block
    # (action = remove), flagged = its test exceeded the critical value and the row is kept (action = flag);
    # every method's own decision is in its column
    decided = set(int(i) for i in report.acted_rows)
    acted = set(int(i) for i in report.acted_rows) if report.action == "remove" else set()
    if acted:   # a rejected x or y takes the whole image point out of the block
        obs = np.asarray(art.obs_rows, int)[:, 0]
        acted |= set(np.flatnonzero(np.isin(obs, report.acted_observations) & (obs >= 0)).tolist())
    cols["decision"] = ["rejected" if i in acted else ("flagged" if i in decided else "ok") for i in range(n)]
    for m, r in report.methods.items():
        key = m.replace("-", "_")
        by_row = {d.row: d for d in r.decisions}
        cols[key] = ["skipped" if r.skipped else ("reject" if i in by_row else "accept") for i in range(n)]
        cols[f"{key}_statistic"] = [f"{by_row[i].statistic}={by_row[i].value:.4g}"
                                    f"{'<' if by_row[i].statistic == 'weight' else '>'}{by_row[i].critical:.4g}"
                                    f"@{by_row[i].step}" if i in by_row else "" for i in range(n)]
        if m in ROBUST_METHODS and not r.skipped:
            cols[f"{key}_weight"] = np.asarray(r.raw.weights, dtype=float)
    return TableData(cols, "every scalar observation of the adjustment with v, r, w, τ, ∇̂, MDB and the "
                           "decision of each method (statistic > critical @ step); v, nabla_hat and mdb are "
                           "in the unit of the row's observation, given per row in column unit (image "
                           "coordinates in mm, control in the object unit, model coordinates in model units)",
                     detail=True)


def _row_units(art: AdjustmentArtefact, block) -> list[str]:
    """Each scalar row's unit: image coordinates are mm (the adjustment's internal image unit, also for a
    pixel source at its pitch); an independent-model block's control rows are in the object unit and its
    model-coordinate rows in model units; other constraint rows have no known unit ("")."""
    obs = np.asarray(art.obs_rows, int)[:, 0]
    out = []
    for o, lab in zip(obs, art.snapshot.labels):
        lab = str(lab)
        if o >= 0:
            out.append("mm")
        elif lab.startswith("control "):
            out.append(str(getattr(block, "object_unit", "") or ""))
        elif lab.startswith("model "):
            out.append("model units")
        else:
            out.append("")
    return out
