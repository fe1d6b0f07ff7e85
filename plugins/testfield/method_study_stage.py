"""Stage ``method-study``: paper 001's Tables 4 and 5 on the simulated test field.

Numerics in :mod:`.method_study` (pure; its :class:`~.method_study.MethodStudyConfig` is this stage's
option table); this module resolves what the options leave to the testfield block, writes the CSV tables, the
summary the ``comparison`` stage collects (``summary["check_points"]``: one entry per method) and
the recording; the report in the shape of the paper's tables is :mod:`.method_study_report`'s.
See docs/method-study.md.
"""

from __future__ import annotations

import re

import numpy as np

from baarda.pipeline import montecarlo
from baarda.pipeline.api import Context, Stage, StageResult, TableData

from .method_study import KEYS, PAPER_PERCENT, VARIANTS, MethodStudyConfig, method_study, resolve
from .method_study_report import study_report, table_columns


class MethodStudy(Stage):
    formerly = ("method-study",)
    summary = ("Paper 001's Tables 4 and 5 on the simulated field: bundle with/without APs, independent "
               "models, single model at 4.0 m vs block at 1.4 m, over seeded realisations")
    reads = ("block?",)
    writes = ("method-study",)
    Options = MethodStudyConfig

    def run(self, inputs, options: MethodStudyConfig, ctx: Context) -> StageResult:
        cfg, source = resolve(options, inputs.get("block"))
        seed = cfg.seed if cfg.seed is not None else int(ctx.rng.integers(2 ** 31))
        bar = iter(ctx.progress.track(range(cfg.repetitions), total=cfg.repetitions, what="realisation"))
        step = lambda i, n: next(bar, None)  # noqa: E731
        study = method_study(cfg, seed, progress=step, mapper=montecarlo.mapper(progress=step))
        for _ in bar:
            pass
        study["source"] = source
        failed = {v: d["failed"] for v, d in study["variants"].items() if d.get("failed")}
        for v, n in failed.items():
            msg = next(r["error"] for r in study["rows"] if r["variant"] == v and r["error"])
            ctx.warn(f"{v}: {n} of {cfg.repetitions} realisation(s) failed (first: {msg})")
        summary = _summary(study, cfg.in_comparison)
        return StageResult(artefacts={"method-study": study}, summary=summary, report=study_report(study),
                           tables=_tables(study), data=study)

    def plots(self, result: StageResult, ctx: Context) -> dict:
        """Figures for report.html: the study's curves beside the paper's tables (plugins/testfield/figures.py)."""
        from .figures import method_study_figures

        return method_study_figures(result.data)

    def log(self, result: StageResult, rec, ctx: Context) -> None:
        import rerun as rr

        study = result.data
        root = ctx.stage_id
        names = [v for v in VARIANTS if study["variants"].get(v, {}).get("realisations")]
        for r in study["rows"]:
            if r["error"] or r["variant"] not in names:
                continue
            rec.set_time("realisation", sequence=int(r["repetition"]))
            sxy = float(np.sqrt((r["Sx"] ** 2 + r["Sy"] ** 2) / 2))
            rec.log(f"{root}/Sxy_cm/{_slug(r['variant'])}", rr.Scalars([100 * sxy]))
            rec.log(f"{root}/Sz_cm/{_slug(r['variant'])}", rr.Scalars([100 * r["Sz"]]))
        rec.reset_time()
        for k in ("Sxy", "Sz"):
            rec.log(f"{root}/pooled/{k}_cm", rr.BarChart(np.array([study["variants"][v][k] for v in names])),
                    static=True)
        rec.log(f"{root}/pooled/methods", rr.TextDocument("\n".join(f"{i}: {v}" for i, v in enumerate(names))),
                static=True)


def _slug(name: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")


# --------------------------------------------------------------------------------------------
# summary and tables


def _summary(study: dict, in_comparison: bool) -> dict:
    cfg = study["config"]
    var = study["variants"]
    out = {"repetitions": cfg.repetitions, "seed": study["seed"], "case": cfg.case,
           "sigma_image_um": cfg.sigma_image_um, "systematic_scale": cfg.systematic_scale if cfg.with_ap_errors else 0.0,
           "headline": _headline(study),
           "variants": {v: {k: (float(x) if isinstance(x, (float, np.floating)) else x) for k, x in d.items()}
                        for v, d in var.items()},
           "conclusions": [{"claim": c["claim"], "verdict": c["verdict"], "key": c["key"],
                            "change_pct": round(c["comparison"]["change_pct"], 2),
                            "paper_pct": round(c["paper_pct"], 2)} for c in study["conclusions"]],
           "geometry": study["geometry"]}
    if in_comparison:
        out["check_points"] = {v: {"n": d["n"], "realisations": d["realisations"], "unit": "m",
                                   **{k: float(d[k]) / 100 for k in KEYS}}
                               for v, d in var.items() if d.get("realisations")}
    return out


def _headline(study: dict) -> str:
    cfg = study["config"]
    c = study["comparisons"]
    parts = [f"{cfg.repetitions} realisations, case {cfg.case}, σ {cfg.sigma_image_um:g} µm"]
    if "block vs single model" in c and "Sz" in c["block vs single model"]:
        b = c["block vs single model"]
        parts.append(f"block vs single model Sxy {b['Sxy']['change_pct']:+.0f} %, Sz {b['Sz']['change_pct']:+.0f} % "
                     f"(paper {PAPER_PERCENT['block vs single model']['Sxy']:+.1f}, "
                     f"{PAPER_PERCENT['block vs single model']['Sz']:+.1f} %)")
    if "Sz" in c["independent models vs bundle"]:
        m = c["independent models vs bundle"]
        parts.append(f"IM vs bundle Sxy {m['Sxy']['change_pct']:+.0f} %, Sz {m['Sz']['change_pct']:+.0f} % "
                     f"(paper {PAPER_PERCENT['independent models vs bundle']['Sxy']:+.0f}, "
                     f"{PAPER_PERCENT['independent models vs bundle']['Sz']:+.0f} %)")
    if "Sz" in c["APs vs no APs"]:
        a = c["APs vs no APs"]
        parts.append(f"APs Sxy {a['Sxy']['change_pct']:+.0f} %, Sz {a['Sz']['change_pct']:+.0f} %")
    return "; ".join(parts)


def _tables(study: dict) -> dict:
    out = {}
    t4, t5 = table_columns(study, 4), table_columns(study, 5)
    pct = {c: "" for c in (*t4, *t5) if c.endswith("_pct")}          # a percentage: a ratio, no unit
    if t4:
        out["table4"] = TableData(t4, "Table 4: single model vs block, check-point RMSE (cm): baarda (RMS over the "
                                      "realisations), the paper, their difference (%), the object distance (cm); "
                                      "block vs single model (%) is in the comparisons table", units=pct)
    out["table5"] = TableData(t5, "Table 5: independent models vs bundle (APs), check-point RMSE (cm): baarda, the "
                                  "paper, their difference (%); independent models vs bundle (%) is in the "
                                  "comparisons table", units=pct)
    var = study["variants"]
    names = [v for v in VARIANTS if var.get(v, {}).get("realisations")]
    fields = ["realisations", "failed", "n", "Sx", "Sy", "Sxy", "Sz", "Sxy_sd", "Sz_sd", "Sxy_q10", "Sxy_q90",
              "Sz_q10", "Sz_q90", "pred_Sx", "pred_Sy", "pred_Sxy", "pred_Sz", "sigma0_hat", "dof", "kept"]
    in_cm = set(fields) - {"realisations", "failed", "n", "sigma0_hat", "dof", "kept"}     # RMSE columns, cm
    out["variants"] = TableData({"method": names, **{f + ("_cm" if f in in_cm else ""): [var[v][f] for v in names]
                                                     for f in fields}},
                                "every method: pooled check-point RMSE (cm), spread over the realisations "
                                "(standard deviation, 10 / 90 % quantiles), RMSE predicted by the adjustment's "
                                "covariance (cm), mean σ̂0, median dof, APs kept (in how many realisations)")
    rows = []
    for name, c in study["comparisons"].items():
        for k in KEYS:
            if k in c:
                d = c[k]
                rows.append([name, c["a"], c["b"], k, d["a_cm"], d["b_cm"], d["change_pct"], d["ratio"],
                             d["ratio_lo"], d["ratio_hi"], d["share"], d["significant"],
                             PAPER_PERCENT.get(name, {}).get(k, float("nan"))])
    head = ["comparison", "a", "b", "key", "a_cm", "b_cm", "change_pct", "ratio", "ratio_lo", "ratio_hi", "share_a_better",
            "significant", "paper_pct"]
    out["comparisons"] = TableData({h: [r[i] for r in rows] for i, h in enumerate(head)},
                                   "paired comparisons: change of the pooled RMSE 100 (a − b)/b, geometric mean "
                                   "of a/b over the realisations with ± 2 standard errors, share with a < b")
    out["conclusions"] = TableData({
        "claim": [c["claim"] for c in study["conclusions"]], "verdict": [c["verdict"] for c in study["conclusions"]],
        "change_pct": [c["comparison"]["change_pct"] for c in study["conclusions"]],
        "paper_pct": [c["paper_pct"] for c in study["conclusions"]],
        "ratio_lo": [c["comparison"]["ratio_lo"] for c in study["conclusions"]],
        "ratio_hi": [c["comparison"]["ratio_hi"] for c in study["conclusions"]]},
        "the paper's conclusions on the simulation")
    R = study["rows"]
    out["realisations"] = TableData({
        "repetition": [r["repetition"] for r in R], "method": [r["variant"] for r in R],
        "Sx_cm": [100 * r["Sx"] for r in R], "Sy_cm": [100 * r["Sy"] for r in R], "Sz_cm": [100 * r["Sz"] for r in R],
        "pred_Sz_cm": [100 * r["pred"][2] for r in R], "sigma0_hat": [r["sigma0_hat"] for r in R],
        "dof": [r["dof"] for r in R], "kept": [" ".join(r["kept"]) for r in R],
        "selection": [r["selection"] for r in R], "error": [r["error"] for r in R]}, "every adjustment of the study")
    pts = [(r["variant"], r["repetition"], p, e) for r in R if not r["error"] for p, e in zip(r["ids"], r["errors"])]
    out["check_points"] = TableData({
        "point": [p[2] for p in pts], "dX_m": [float(p[3][0]) for p in pts], "dY_m": [float(p[3][1]) for p in pts],
        "dZ_m": [float(p[3][2]) for p in pts], "method": [p[0] for p in pts], "repetition": [p[1] for p in pts]},
        "check points of every method and realisation: adjusted − surveyed (m)")
    return out
