"""Stage ``helmert-screening``: its summary, tables and Markdown report (the stage is
:mod:`.stage`; numerics in :mod:`.helmert` and :mod:`.screen`)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from baarda.pipeline.api import AdjustmentArtefact, TableData
from baarda.pipeline.protocol import global_test_protocol, global_test_text
from baarda.pipeline.units import fmt_q

if TYPE_CHECKING:
    from .stage import PairResult, ScreeningArtefact


def _f(x, nd=3):
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else round(float(x), nd)


def _robust_rows(rob, adj: AdjustmentArtefact, block) -> list[tuple]:
    ids = block.observation_ids()
    return [(str(rob.labels[i]), "/".join(map(str, ids[adj.obs_rows[i, 0]])) + " " + "xy"[adj.obs_rows[i, 1]],
             float(rob.weights[i]), float(rob.u[i])) for i in rob.downweighted]


def robust_summary(rob) -> dict:
    return {} if rob is None else {"robust": rob.summary()}


def robust_report(rob, adj: AdjustmentArtefact, block) -> str:
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


def robust_tables(rob, adj: AdjustmentArtefact, block) -> dict:
    if rob is None:
        return {}
    ids = block.observation_ids()
    n = adj.snapshot.n
    return {"robust": TableData({
        "row": [str(x) for x in rob.labels],
        "observation": ["/".join(map(str, ids[adj.obs_rows[i, 0]])) + " " + "xy"[adj.obs_rows[i, 1]] for i in range(n)],
        "weight": np.asarray(rob.weights, dtype=float),
        "u": np.asarray(rob.u, dtype=float),
        "downweighted": [bool(x) for x in np.isin(np.arange(n), rob.downweighted)]},
        f"robust estimation ({rob.method}, c = {rob.c:g}): every right-image coordinate's final IRLS weight and "
        "standardised residual u", detail=True)}


def summary(art: ScreeningArtefact, flagged_obs, block, options) -> dict:
    pairs = []
    for p in art.pairs:
        s = p.screening
        i = s.most_suspicious
        flags = s.method_flags()
        pairs.append({
            "pair": [p.left, p.right], "points": len(s.point_ids), "dof": s.adjustment.dof,
            "sigma0": s.settings.sigma0, "sigma0_hat": _f(s.adjustment.sigma0_hat, 4),
            "global_test": {"T": _f(s.global_.T, 4), "critical": _f(s.global_.critical, 4),
                            "critical_lower": _f(s.global_.critical_lower, 4), "p_value": s.global_.p_value,
                            "method": s.global_.method, "verdict": s.global_.verdict,
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


def report(art: ScreeningArtefact, block, options, flagged_obs) -> str:
    out = []
    for p in art.pairs:
        s = p.screening
        a, b, tx, ty = s.adjustment.x
        g = s.global_
        out += [f"**Pair {p.left} → {p.right}**: {len(s.point_ids)} common points, dof {s.adjustment.dof}; "
                f"scale {math.hypot(a, b):.6f}, rotation {math.degrees(math.atan2(b, a)):.4f}°, "
                f"shift ({tx:.3f}, {ty:.3f}) mm.", "",
                f"- σ̂0 = {fmt_q(s.adjustment.sigma0_hat, 'mm')} against σ0 = {fmt_q(s.settings.sigma0, 'mm')}: "
                f"global test {global_test_text(global_test_protocol(g), 'mm')}.",
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


def tables(art: ScreeningArtefact, action: str = "flag") -> dict:
    """The observations table; its ``decision`` is ``rejected`` for flagged rows that ``action = "remove"``
    took out of the block, ``flagged`` for those kept, else ``ok`` (``flagged`` keeps the boolean)."""
    cols = {k: [] for k in ("pair", "point", "coord", "label", "left_mm", "right_observed_mm", "v_mm", "r",
                            "w", "tau", "nabla_hat_mm", "mdb_mm", "data_snooping", "pope", "threshold", "format",
                            "swap_with", "flagged", "decision")}
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
            cols["left_mm"].append(float(s.xy_left[q, c]))
            cols["right_observed_mm"].append(float(s.xy_right[q, c]))
            for name, value in (("v_mm", s.adjustment.v), ("r", s.snooping.r), ("w", s.snooping.w),
                                ("tau", s.pope.tau), ("nabla_hat_mm", s.snooping.nabla_hat),
                                ("mdb_mm", s.snooping.mdb)):
                cols[name].append(float(value[k]))
            for m, col in (("data-snooping", "data_snooping"), ("pope", "pope"), ("threshold", "threshold"),
                           ("format", "format")):
                cols[col].append("reject" if flags[m][k] else "accept")
            cols["swap_with"].append(partner[q])
            cols["flagged"].append(bool(s.flagged[k]))
            cols["decision"].append(("rejected" if action == "remove" else "flagged") if s.flagged[k] else "ok")
    return {"observations": TableData(cols, "Helmert screening: every right-image coordinate with residual "
                                            "(observed − computed, mm), redundancy number, w, τ, ∇̂, MDB and "
                                            "the decision of each check", detail=True)}
