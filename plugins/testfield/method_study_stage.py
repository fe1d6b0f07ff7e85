"""Stage ``method-study``: paper 001's Tables 4 and 5 on the simulated test field.

Numerics in :mod:`.method_study` (pure); this module maps options, writes the CSV tables, the
summary the ``comparison`` stage collects (``summary["check_points"]``: one entry per method) and
the recording; the report in the shape of the paper's tables is :mod:`.method_study_report`'s.
See docs/method-study.md.
"""

from __future__ import annotations

import dataclasses
import re
from typing import Literal

import numpy as np

from baarda.pipeline import montecarlo
from baarda.pipeline.options import option
from baarda.pipeline.stage import Context, Stage, StageResult, TableData
from baarda.pipeline.synthetic.testfield import CASES

from .method_study import KEYS, PAPER_PERCENT, VARIANTS, MethodStudyConfig, method_study, with_options
from .method_study_report import table4_rows, table5_rows, study_report
from .study_config import StudyRuns


@dataclasses.dataclass(frozen=True)
class MethodStudyOptions(StudyRuns):
    """repetitions, rho_max and ap_alpha: :class:`~.study_config.StudyRuns`, declared once."""

    seed: int | None = option(None, "seed of the realisations; default: the project's seed for this stage")
    case: int | None = option(None, "control configuration 1–6 (docs/testfield.md); default: that of the "
                                    "testfield block this stage reads, else the paper's case 5")
    sigma_image_um: float | None = option(None, "image noise per coordinate (µm); default: the testfield "
                                                "block's, else the simulator's (40, the paper's σ̂0 level)")
    sigma_control_mm: float | None = option(None, "control survey noise per coordinate (mm); default: the "
                                                  "testfield block's, else 0.05")
    with_ap_errors: bool | None = option(None, "simulate the known systematic image errors; default: as the "
                                               "testfield block, else true")
    systematic_scale: float | None = option(None, "factor on the systematic image errors; default: the "
                                                  "testfield block's, else 1")
    im_model_weights: Literal["propagated", "intersection", "equal"] = option(
        "propagated", "weights of the independent models' model coordinates (docs/independent-models.md)")
    single_model: bool = option(True, "also adjust the single stereo model at 4.0 m (Table 4)")
    methods: list[str] = option(list(VARIANTS), "the methods to run (any of: " + ", ".join(VARIANTS) + ")")
    in_comparison: bool = option(True, "put every method's check-point RMSE in summary['check_points'] so "
                                       "the comparison stage lists and plots them")

    def __post_init__(self):
        super().__post_init__()     # every range: declared with option() or implied by the name
        if self.case is not None and self.case not in CASES:
            raise ValueError(f"case must be one of {list(CASES)}, got {self.case}")
        bad = [m for m in self.methods if m not in VARIANTS]
        if bad or not self.methods:
            raise ValueError(f"methods: expected a non-empty list drawn from {list(VARIANTS)}, got {self.methods}")


FROM_BLOCK = ("case", "sigma_image_um", "sigma_control_mm", "with_ap_errors", "systematic_scale")


def study_config(options: MethodStudyOptions, block=None) -> tuple[MethodStudyConfig, dict]:
    """The study's configuration: options first, then the testfield block's configuration
    (``block.meta["testfield"]["config"]``), then the defaults.  Returns (config, where each
    simulation setting came from)."""
    tf = {}
    if block is not None and isinstance(getattr(block, "meta", None), dict):
        tf = block.meta.get("testfield", {}).get("config", {}) or {}
    values, source = {}, {}
    for k in FROM_BLOCK:
        if getattr(options, k) is not None:
            values[k], source[k] = getattr(options, k), "option"
        elif k in tf:
            values[k], source[k] = tf[k], "testfield block"
        else:
            source[k] = "default"
    cfg = with_options(MethodStudyConfig(), repetitions=options.repetitions, rho_max=options.rho_max,
                       ap_alpha=options.ap_alpha, im_model_weights=options.im_model_weights,
                       single_model=options.single_model, methods=tuple(options.methods), **values)
    return cfg, source


class MethodStudy(Stage):
    formerly = ("method-study",)
    summary = ("Paper 001's Tables 4 and 5 on the simulated field: bundle with/without APs, independent "
               "models, single model at 4.0 m vs block at 1.4 m, over seeded realisations")
    reads = ("block?",)
    writes = ("method-study",)
    Options = MethodStudyOptions

    def run(self, inputs, options: MethodStudyOptions, ctx: Context) -> StageResult:
        cfg, source = study_config(options, inputs.get("block"))
        seed = options.seed if options.seed is not None else int(ctx.rng.integers(2 ** 31))
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
        summary = _summary(study, options.in_comparison)
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
    t4, t5 = table4_rows(study), table5_rows(study)
    cols = ["method", "source", *KEYS, "distance_cm"]
    if t4:
        out["table4"] = TableData({c: [r[i] for r in t4] for i, c in enumerate(cols)},
                                  "Table 4: single model vs block, check-point RMSE (cm): baarda (RMS over the "
                                  "realisations), the paper, their difference (%), and block vs single model (%)")
    out["table5"] = TableData({c: [r[i] for r in t5] for i, c in enumerate(cols[:-1])},
                              "Table 5: independent models vs bundle (APs), check-point RMSE (cm): baarda, the "
                              "paper, their difference (%), and independent models vs bundle (%)")
    var = study["variants"]
    names = [v for v in VARIANTS if var.get(v, {}).get("realisations")]
    fields = ["realisations", "failed", "n", "Sx", "Sy", "Sxy", "Sz", "Sxy_sd", "Sz_sd", "Sxy_q10", "Sxy_q90",
              "Sz_q10", "Sz_q90", "pred_Sx", "pred_Sy", "pred_Sxy", "pred_Sz", "sigma0_hat", "dof", "kept"]
    out["variants"] = TableData({"method": names, **{f: [var[v][f] for v in names] for f in fields}},
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
        "point": [p[2] for p in pts], "dX": [float(p[3][0]) for p in pts], "dY": [float(p[3][1]) for p in pts],
        "dZ": [float(p[3][2]) for p in pts], "method": [p[0] for p in pts], "repetition": [p[1] for p in pts]},
        "check points of every method and realisation: adjusted − surveyed (m)")
    return out
