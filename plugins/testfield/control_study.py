"""``control-study``: the paper's Tables 2–4 on the simulated test field, and whether the paper's
conclusions hold there.

For each of ``repetitions`` realisations of the noise (the *same* noise for every control case,
with and without additional parameters — common random numbers, so the comparisons are paired),
the six control configurations are adjusted by the bundle (``baarda.pipeline.adjustment.adjust``) twice:

* without additional parameters (c, xp, yp fixed at the calibrated values) — Table 2;
* with Ebner's 12 parameters (and dc, dxp, dyp free when ``calibrate_iop``), selected by the
  paper's rule — remove the parameter with the largest correlation |ρ| > ``rho_max``, one after
  another, then the insignificant ones (t-test at ``ap_alpha``) — Table 3.  The selection is the
  bundle's (:func:`baarda.pipeline.adjustment.apselect.select_aps`: correlations among the camera's
  parameters); when the block is singular with every AP free (case 1) the study's own
  :func:`select_additional_parameters` takes over (weak priors while selecting, correlations
  with the exterior orientations too, c, xp, yp as candidates);

and (with ``single_model``) the single model at 4.0 m is adjusted with the control of
``single_model_case`` and APs —
Table 4.  Check-point errors are adjusted minus surveyed over the points whose role is
``check`` (``Sxy = √((Sx² + Sy²)/2)``, cm).  The tables report the RMS over all realisations;
:func:`conclusions` tests each of the paper's statements on the paired realisations.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from baarda.pipeline.accuracy import check_point_rmse
from baarda.pipeline.adjustment import BundleSettings, adjust, select_aps
from baarda.pipeline import montecarlo
from baarda.pipeline.api import AdjustmentError, Context, Stage, StageResult, TableData
from baarda.pipeline.report import markdown_table

from baarda.pipeline.synthetic.testfield import simulate_testfield

from .paper_tables import PAPER_TABLE2, PAPER_TABLE3, PAPER_TABLE4
from .study_config import ControlStudyConfig

SELECTION_LABEL = {"correlation": "bundle", "weak-priors": "study"}
"""How the tables name the two methods of :func:`baarda.pipeline.adjustment.select_aps`."""


# --------------------------------------------------------------------------------------------
# the study


def _check_rmse(res, block) -> np.ndarray:
    """(Sx, Sy, Sz) in m over the role-'check' points: adjusted minus surveyed."""
    m = block.points.role == "check"
    c = check_point_rmse(res.state.XYZ[m], block.points.XYZ[m])
    return np.array([c["Sx"], c["Sy"], c["Sz"]])


def _run(block, with_aps: bool, cfg: ControlStudyConfig):
    settings = BundleSettings(covariance=with_aps, tol_obs=1e-4, max_iter=50)
    if not with_aps:
        return adjust(block, settings), [], ""
    sel = select_aps(block, settings, rho_max=cfg.rho_max, alpha=cfg.ap_alpha, on_singular="weak-priors",
                     method="correlation" if cfg.ap_selection == "bundle" else "weak-priors")
    return sel.result, [k.parameter for k in sel.kept], SELECTION_LABEL[sel.method]


def control_study(cfg: ControlStudyConfig, seed: int, progress: Callable | None = None,
                  mapper: Callable | None = None) -> dict:
    """Run the study; returns ``{"rows": [...], "tables": {...}, "conclusions": [...]}``.

    Each row: repetition, block ("block"/"single-model"), case, aps (bool), dof, sigma0_um,
    Sx, Sy, Sz (m), kept (AP names).  Realisation ``rep`` draws from ``default_rng([seed, rep])``
    whoever computes it.  ``mapper(fn, repetitions)`` runs the realisations (any callable with the
    signature of the built-in ``map``, e.g. :func:`baarda.pipeline.montecarlo.mapper`'s; it reports
    its own progress); without one they run here and ``progress(i, total)`` is called after each.
    """
    one = functools.partial(realisation_rows, cfg, seed)
    if mapper is None:
        per_rep = []
        for rep in range(cfg.repetitions):
            per_rep.append(one(rep))
            if progress:
                progress(rep + 1, cfg.repetitions)
    else:
        per_rep = list(mapper(one, range(cfg.repetitions)))
    rows = [r for rep_rows in per_rep for r in rep_rows]
    tables = summarise(rows)
    return {"rows": rows, "tables": tables, "conclusions": conclusions(rows, cfg)}


def realisation_rows(cfg: ControlStudyConfig, seed: int, rep: int) -> list[dict]:
    """Every adjustment of realisation ``rep`` (``rng = default_rng([seed, rep])``, the same draws
    for every case, with and without APs): one row each (see :func:`control_study`)."""
    rows = []
    jobs = [("block", c) for c in cfg.cases]
    if cfg.single_model:
        jobs.append(("single-model", cfg.single_model_case))
    for kind, case in jobs:
        for with_aps in ((False, True) if kind == "block" else (True,)):
            tf = cfg.field(case, kind, ap_model=cfg.ap_model if with_aps else "none",
                           calibrate_iop=with_aps and cfg.calibrate_iop)
            block, _ = simulate_testfield(tf, np.random.default_rng([seed, rep]))
            row = {"repetition": rep, "block": kind, "case": case, "aps": with_aps}
            try:
                res, kept, method = _run(block, with_aps, cfg)
            except AdjustmentError as e:
                rows.append({**row, "dof": -1, "sigma0_um": np.nan, "Sx": np.nan, "Sy": np.nan, "Sz": np.nan,
                             "kept": [], "selection": "", "error": str(e)})
                continue
            S = _check_rmse(res, block)
            rows.append({**row, "dof": res.dof, "sigma0_um": res.sigma0_hat * cfg.sigma_image_um,
                         "Sx": S[0], "Sy": S[1], "Sz": S[2], "kept": kept, "selection": method,
                         "error": ""})
    return rows


def _pooled(rows, key) -> float:
    return float(np.sqrt(np.mean([r[key] ** 2 for r in rows])))


def summarise(rows) -> dict:
    """Tables 2, 3 (block, without / with APs) and 4 (single model vs block) in cm: RMS over the
    realisations of each realisation's check-point RMSE."""
    out = {}
    for name, kind, aps in (("table2", "block", False), ("table3", "block", True), ("single", "single-model", True)):
        cases = sorted({r["case"] for r in rows if r["block"] == kind and r["aps"] == aps})
        tab = []
        for c in cases:
            sel = [r for r in rows if r["block"] == kind and r["aps"] == aps and r["case"] == c and not r["error"]]
            if not sel:
                continue
            Sx, Sy, Sz = (_pooled(sel, k) * 100 for k in ("Sx", "Sy", "Sz"))
            kept = {}
            methods = {}
            for r in sel:
                if r.get("selection"):
                    methods[r["selection"]] = methods.get(r["selection"], 0) + 1
                for a in r["kept"]:
                    kept[a] = kept.get(a, 0) + 1
            tab.append({"case": c, "dof": int(np.median([r["dof"] for r in sel])),
                        "sigma0_um": float(np.mean([r["sigma0_um"] for r in sel])),
                        "Sx": Sx, "Sy": Sy, "Sxy": float(np.sqrt((Sx ** 2 + Sy ** 2) / 2)), "Sz": Sz,
                        "kept": " ".join(f"{a}({n})" for a, n in sorted(kept.items(), key=lambda kv: -kv[1])),
                        "selection": " ".join(f"{m}({n})" for m, n in sorted(methods.items())),
                        "failed": sum(1 for r in rows if r["block"] == kind and r["aps"] == aps and r["case"] == c
                                      and r["error"])})
        out[name] = tab
    return out


def _paired(rows, a: dict, b: dict, key: str):
    """Per-realisation values of ``key`` for selections a and b (dicts of row filters)."""
    pick = lambda f: {r["repetition"]: r for r in rows if not r["error"] and all(r[k] == v for k, v in f.items())}
    ra, rb = pick(a), pick(b)
    reps = sorted(set(ra) & set(rb))
    va = np.array([_xy(ra[i], key) for i in reps])
    vb = np.array([_xy(rb[i], key) for i in reps])
    return va, vb


def _xy(r, key):
    return float(np.sqrt((r["Sx"] ** 2 + r["Sy"] ** 2) / 2)) if key == "Sxy" else float(r[key])


def _claim(rows, text, a, b, keys=("Sxy", "Sz")) -> dict:
    """Does selection a beat selection b (smaller RMSE) in each key?  Pooled RMSE, the change in
    %, the share of realisations where a < b (ties count half) and a standard error of the %
    change."""
    out = {"claim": text, "keys": {}}
    holds = True
    for key in keys:
        va, vb = _paired(rows, a, b, key)
        if va.size == 0:
            continue
        pa, pb = np.sqrt(np.mean(va ** 2)), np.sqrt(np.mean(vb ** 2))
        change = 100.0 * (pa / pb - 1.0)
        # standard error of the % change by the delta method on the paired squared errors
        d = va ** 2 / pb ** 2 - vb ** 2 * pa ** 2 / pb ** 4
        se = 100.0 * 0.5 * (pb / pa) * np.std(d, ddof=1) / np.sqrt(va.size) if va.size > 1 else float("nan")
        tie = np.isclose(va, vb, rtol=1e-6, atol=0.0)   # e.g. no AP kept: the same adjustment
        share = float(np.mean((va < vb) & ~tie) + 0.5 * np.mean(tie))
        ok = bool(pa < pb)
        holds &= ok
        out["keys"][key] = {"a_cm": pa * 100, "b_cm": pb * 100, "change_pct": change, "se_pct": se,
                            "share": share, "holds": ok, "significant": bool(abs(change) > 2 * se)}
    out["holds"] = holds
    out["verdict"] = _verdict(out["keys"].values())
    return out


def _verdict(keys) -> str:
    """holds / holds, not significant / mixed / does not hold / contradicted (2 standard errors)."""
    keys = list(keys)
    better = [k["holds"] for k in keys]
    sig = [k["significant"] for k in keys]
    if all(better):
        return "holds" if all(sig) else "holds, not significant"
    if not any(better):
        return "contradicted" if any(sig) else "does not hold, not significant"
    return "mixed" + (" (significant)" if any(s for s, b in zip(sig, better)) else "")


def conclusions(rows, cfg: ControlStudyConfig) -> list[dict]:
    """The paper's statements (SPEC §2), each tested on the paired realisations."""
    blk = lambda c, aps=False: {"block": "block", "case": c, "aps": aps}
    out = []
    cases = set(cfg.cases)
    if {1, 2, 3}.issubset(cases):
        for c in (2, 3):
            out.append(_claim(rows, f"more control improves accuracy: case {c} beats case 1", blk(c), blk(1)))
    if {2, 3, 4, 5, 6}.issubset(cases):
        for hi in (4, 5, 6):
            for lo in (2, 3):
                out.append(_claim(rows, f"more control improves accuracy: case {hi} beats case {lo}", blk(hi), blk(lo)))
    if {2, 3}.issubset(cases):
        out.append(_claim(rows, "the same control stiffening the interior beats the outline: case 2 beats case 3",
                          blk(2), blk(3)))
    if {4, 5}.issubset(cases):
        out.append(_claim(rows, "paper detail: case 4 has the better planimetry than case 5", blk(4), blk(5), ("Sxy",)))
        out.append(_claim(rows, "paper detail: case 5 has the better height than case 4", blk(5), blk(4), ("Sz",)))
    for c in cfg.cases:
        out.append(_claim(rows, f"self-calibration improves case {c}", blk(c, True), blk(c, False)))
    sm = cfg.single_model_case
    if cfg.single_model and sm in cases:
        out.append(_claim(rows, f"the block at 1.4 m beats the single model at 4.0 m (case {sm}, with APs; "
                                "paper: by about 10 %)", blk(sm, True),
                          {"block": "single-model", "case": sm, "aps": True}))
    return out


# --------------------------------------------------------------------------------------------
# the stage


class ControlStudy(Stage):
    formerly = ("control-study",)
    summary = "Paper 001's control-configuration study (Tables 2–4) on the simulated test field"
    reads = ()
    writes = ("study",)
    Options = ControlStudyConfig            # the study's configuration is the option table

    def run(self, inputs, options: ControlStudyConfig, ctx: Context) -> StageResult:
        cfg = options
        seed = options.seed if options.seed is not None else int(ctx.rng.integers(2**31))
        bar = iter(ctx.progress.track(range(cfg.repetitions), total=cfg.repetitions, what="realisation"))
        step = lambda i, n: next(bar, None)  # noqa: E731
        study = control_study(cfg, seed, progress=step, mapper=montecarlo.mapper(progress=step))
        for _ in bar:
            pass
        study["config"] = dataclasses.asdict(cfg)
        study["seed"] = seed
        held = [c for c in study["conclusions"] if c["holds"]]
        summary = {"repetitions": cfg.repetitions, "seed": seed, "sigma_image_um": cfg.sigma_image_um,
                   "conclusions_holding": len(held), "conclusions": len(study["conclusions"]),
                   "table2": [{k: v for k, v in r.items() if k != "kept"} for r in study["tables"]["table2"]],
                   "table3": study["tables"]["table3"], "single": study["tables"]["single"],
                   "claims": [{"claim": c["claim"], "holds": c["holds"], "verdict": c["verdict"],
                               **{f"{k}_change_pct": round(v["change_pct"], 1) for k, v in c["keys"].items()}}
                              for c in study["conclusions"]]}
        summary["headline"] = _headline(study, cfg)
        return StageResult(artefacts={"study": study}, summary=summary, report=study_report(study),
                           tables=_tables(study), data=study)

    def plots(self, result: StageResult, ctx: Context) -> dict:
        """Figures for report.html: the study's curves beside the paper's tables (plugins/testfield/figures.py)."""
        from .figures import control_study_figures

        return control_study_figures(result.data)

    def log(self, result: StageResult, rec, ctx: Context) -> None:
        import rerun as rr

        tabs = result.data["tables"]
        for name, label in (("table2", "without_aps"), ("table3", "with_aps")):
            for row in tabs[name]:
                rec.set_time("case", sequence=row["case"])
                for key in ("Sxy", "Sz", "sigma0_um"):
                    rec.log(f"study/{key}/{label}", rr.Scalars([row[key]]))
                for key, idx in (("Sxy", 4), ("Sz", 5)):
                    rec.log(f"study/{key}/paper_{label}",
                            rr.Scalars([PAPER_TABLE2[row["case"]][idx] if name == "table2"
                                        else PAPER_TABLE3[row["case"]][idx - 2]]))


def _headline(study, cfg: ControlStudyConfig) -> str:
    """One line for ``baarda review``: realisations, noise and systematic errors, the configurations
    run (control cases without and with APs, the single model) and their adjustments (failures when
    any), how many of the paper's statements hold on the simulation."""
    rows = study["rows"]
    configs = {(r["block"], r["case"], r["aps"]) for r in rows}
    failed = sum(1 for r in rows if r["error"])
    held = sum(1 for c in study["conclusions"] if c["holds"])
    single = any(b == "single-model" for b, _, _ in configs)
    syst = f"systematics ×{cfg.systematic_scale:g}" if cfg.with_ap_errors else "no systematics"
    return (f"{cfg.repetitions} realisations, σ {cfg.sigma_image_um:g} µm, {syst}: {len(configs)} configurations "
            f"({len(cfg.cases)} cases with/without APs{', single model' if single else ''}), {len(rows)} adjustments"
            + (f" ({failed} failed)" if failed else "") + f"; {held}/{len(study['conclusions'])} paper claims hold")


def _tables(study) -> dict:
    out = {}
    for name, desc in (("table2", "Table 2: check-point RMSE (cm) without additional parameters"),
                       ("table3", "Table 3: check-point RMSE (cm) with selected additional parameters"),
                       ("single", "Table 4: single model at 4.0 m (with selected APs)")):
        rows = study["tables"][name]
        if rows:
            out[name] = TableData({(k + "_cm" if k in ("Sx", "Sy", "Sxy", "Sz") else k): [r[k] for r in rows]
                                   for k in rows[0]}, desc)          # the RMSE columns in cm: Sx_cm …
    rows = study["rows"]
    out["realisations"] = TableData({
        "repetition": [r["repetition"] for r in rows], "block": [r["block"] for r in rows],
        "case": [r["case"] for r in rows], "aps": [r["aps"] for r in rows], "dof": [r["dof"] for r in rows],
        "sigma0_um": [r["sigma0_um"] for r in rows], "Sx_cm": [100 * r["Sx"] for r in rows],
        "Sy_cm": [100 * r["Sy"] for r in rows], "Sz_cm": [100 * r["Sz"] for r in rows],
        "kept": [" ".join(r["kept"]) for r in rows], "selection": [r.get("selection", "") for r in rows],
        "error": [r["error"] for r in rows]}, "every adjustment of the study")
    out["conclusions"] = TableData({
        "claim": [c["claim"] for c in study["conclusions"]], "holds": [c["holds"] for c in study["conclusions"]],
        "verdict": [c["verdict"] for c in study["conclusions"]],
        **{f"{k}_{f}": [c["keys"].get(k, {}).get(f, float("nan")) for c in study["conclusions"]]
           for k in ("Sxy", "Sz") for f in ("change_pct", "se_pct", "share")}},
        "the paper's conclusions on the simulation: % change of the pooled RMSE, its standard error, "
        "share of realisations where the claim holds")
    return out


def study_report(study) -> str:
    cfg = study["config"]
    t2, t3, sm = study["tables"]["table2"], study["tables"]["table3"], study["tables"]["single"]
    lines = [f"{cfg['repetitions']} realisations (seed {study['seed']}), image noise σ = {cfg['sigma_image_um']:g} µm, "
             f"control σ = {cfg['sigma_control_mm']:g} mm, systematic image errors "
             f"{'×' + format(cfg['systematic_scale'], 'g') if cfg['with_ap_errors'] else 'off'}; APs: "
             f"{cfg['ap_model']}{' + c, xp, yp' if cfg['calibrate_iop'] else ''} selected ({cfg['ap_selection']}'s "
             f"selection) with |ρ| ≤ {cfg['rho_max']}"
             f"{', then t-tests at α = ' + format(cfg['ap_alpha'], 'g') if cfg['ap_alpha'] > 0 else ''}. "
             "RMSE over the check points (cm), RMS over the realisations; paper values in brackets.", "",
             "**Table 2** (no additional parameters)", ""]
    rows = []
    for r in t2:
        p = PAPER_TABLE2.get(r["case"])
        rows.append([r["case"], f"{r['dof']} ({p[0]})", f"{r['sigma0_um']:.2f} ({p[1]:.2f})",
                     *(f"{r[k]:.4f} ({p[i]:.4f})" for i, k in zip(range(2, 6), ("Sx", "Sy", "Sxy", "Sz")))])
    lines += [markdown_table(["case", "dof", "σ0 µm", "Sx", "Sy", "Sxy", "Sz"], rows), ""]
    lines += ["**Table 3** (with selected additional parameters; parameters kept and in how many realisations)", ""]
    rows = []
    for r in t3:
        p = PAPER_TABLE3.get(r["case"])
        rows.append([r["case"], r["dof"], f"{r['sigma0_um']:.2f}",
                     *(f"{r[k]:.4f} ({p[i]:.4f})" for i, k in enumerate(("Sx", "Sy", "Sxy", "Sz"))),
                     f"{r['kept'] or '—'} ({p[4]})", r["selection"] + (f", {r['failed']} failed" if r["failed"] else "")])
    lines += [markdown_table(["case", "dof", "σ0 µm", "Sx", "Sy", "Sxy", "Sz", "APs kept (paper)", "selection"], rows),
              "", "(dof: median over the realisations; selection: whose AP selection ran, and how often.)", ""]
    if sm:
        b = next((r for r in t3 if r["case"] == sm[0]["case"]), None)
        rows = [["single model 4.0 m", *(f"{sm[0][k]:.4f}" for k in ("Sx", "Sy", "Sxy", "Sz")),
                 " ".join(f"{v:.4f}" for v in PAPER_TABLE4["single model"])]]
        if b:
            rows.append(["block 1.4 m", *(f"{b[k]:.4f}" for k in ("Sx", "Sy", "Sxy", "Sz")),
                         " ".join(f"{v:.4f}" for v in PAPER_TABLE4["block"])])
        lines += [f"**Table 4** (control case {sm[0]['case']}, with APs)", "",
                  markdown_table(["", "Sx", "Sy", "Sxy", "Sz", "paper Sx Sy Sxy Sz"], rows), ""]
    lines += ["**The paper's conclusions on the simulation** (change of the pooled RMSE of the first against "
              "the second configuration, ± its standard error over the paired realisations; share of "
              "realisations in which the first is better). A verdict is significant when the change exceeds two "
              "standard errors.", ""]
    rows = []
    for c in study["conclusions"]:
        cells = []
        for k in ("Sxy", "Sz"):
            v = c["keys"].get(k)
            cells.append("—" if v is None else f"{v['change_pct']:+.1f} % ± {v['se_pct']:.1f} ({100 * v['share']:.0f} %)")
        v = c["verdict"]
        rows.append([c["claim"], v if v.startswith("holds") else f"**{v}**", *cells])
    lines += [markdown_table(["statement", "on the simulation", "Sxy", "Sz"], rows), ""]
    lines.append("Independent-model triangulation (the paper's Table 5) is compared by the independent-models "
                 "study, not here.")
    return "\n".join(lines)
