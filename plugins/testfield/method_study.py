"""The method study of paper 001 on the simulated test field — pure numerics (no rerun, no files).

For each of ``repetitions`` seeded realisations of the simulated field (``baarda.plugins.testfield``), with
one control configuration (the paper's case 5 by default) and *the same* simulated image and control
measurements for every method (common random numbers, so the comparisons are paired):

* ``bundle, no APs`` — the bundle (``baarda.pipeline.adjustment.adjust``), c, xp, yp fixed, no additional
  parameters (the paper's Table 2 setting);
* ``bundle, APs`` — the bundle with Ebner's 12 parameters selected by the bundle's own rule
  (``baarda.pipeline.adjustment.apselect.select_aps``: remove |ρ| > ``rho_max`` one after another, then the
  insignificant ones by t-tests) — the paper's Table 3 setting and the "bundle" of its Tables 4, 5;
* ``independent models`` — the independent-model block (``baarda.pipeline.imodels``: relative orientation
  of each of the 8 stereo pairs from the same image coordinates, model coordinates, Ackermann's
  7-parameter block adjustment with the same control) — Table 5;
* ``single model 4.0 m`` — the stereo pair A, B at 4.0 m with the same control, bundle with selected
  APs (Table 4), and ``single model 4.0 m, no APs``.

Check-point errors are adjusted minus surveyed over the points whose role is ``check``;
``Sxy = √((Sx² + Sy²)/2)`` (paper 001, eqs. 2.19–2.22).  Tables report the RMS over the
realisations of each realisation's RMSE (the "pooled" RMSE), the spread over the realisations, and
the precision each adjustment *predicts* for its check points from its own covariance matrix
(a-priori σ0, plus the survey noise of the check points) — the number the B/H argument is about.

Comparisons between methods are paired by realisation: the change of the pooled RMSE in percent,
``100 (S_a − S_b)/S_b`` (the paper's "10.72 %" is the block against the single model:
``(0.0533 − 0.0597)/0.0597 = −10.72 %``), and the geometric mean of the per-realisation ratio
``S_a/S_b`` with an interval of ± 2 standard errors of its logarithm, which decides whether a
difference is more than the noise of ``repetitions`` draws.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from functools import partial
from typing import Callable, Literal

import numpy as np

from baarda.pipeline.accuracy import check_point_rmse

from baarda.pipeline.api import AdjustmentError, option
from baarda.pipeline.synthetic.testfield import (CASES, FOCAL_MM, SINGLE_MODEL_PHOTOS, STRIPS, SimulatedErrors,
                                                 TestFieldConfig, simulate_testfield)
from .paper_tables import PAPER_TABLE2, PAPER_TABLE3, PAPER_TABLE4
from baarda.plugins.testfield.study_config import StudyConfig

__all__ = ["MethodStudyConfig", "resolve", "method_study", "run_realisation", "summarise", "compare",
           "field_geometry", "conclusions", "VARIANTS", "PAPER_TABLE4", "PAPER_TABLE5", "PAPER_PERCENT"]

BUNDLE = "bundle, no APs"
BUNDLE_AP = "bundle, APs"
IM = "independent models"
SINGLE_AP = "single model 4.0 m"
SINGLE = "single model 4.0 m, no APs"
VARIANTS = (BUNDLE, BUNDLE_AP, IM, SINGLE_AP, SINGLE)
"""Every method the study runs, in report order."""

KEYS = ("Sx", "Sy", "Sxy", "Sz")

PAPER_TABLE5 = {"independent models": (0.0432, 0.0405, 0.0416, 0.3832),
                "bundle": (0.0701, 0.0279, 0.0533, 0.2155)}
"""Paper 001, Table 5 (cm; case 5, the bundle with APs).  Its last column (printed 10 and 6 under
a header the OCR copied from Table 4) is not used."""

PAPER_DISTANCE_CM = {"single model": 400, "block": 140}


def _pct(a: float, b: float) -> float:
    return 100.0 * (a - b) / b


PAPER_PERCENT = {
    # Table 4: block against the single model — the paper's "10.72 %" and "10.13 %"
    "block vs single model": {k: _pct(PAPER_TABLE4["block"][i], PAPER_TABLE4["single model"][i])
                              for i, k in enumerate(KEYS)},
    # Table 5: independent models against the bundle (the paper gives no percentages)
    "independent models vs bundle": {k: _pct(PAPER_TABLE5["independent models"][i], PAPER_TABLE5["bundle"][i])
                                     for i, k in enumerate(KEYS)},
    # Tables 2 and 3, case 5: self-calibration
    "APs vs no APs": {k: _pct(PAPER_TABLE3[5][i], PAPER_TABLE2[5][2 + i]) for i, k in enumerate(KEYS)},
}
"""The paper's differences in percent, ``100 (S_a − S_b)/S_b``."""


PAPER_CASE = 5
"""The control case of the paper's Tables 4 and 5."""


@dataclass(frozen=True)
class MethodStudyConfig(StudyConfig):
    """The method study's configuration: one control case and the methods compared (Tables 4, 5).

    Also the ``testfield-method-study`` stage's option table (one definition).  ``case`` and the
    simulated errors (:class:`~baarda.pipeline.synthetic.testfield.SimulatedErrors`) may be
    ``None``: "take it from the testfield block the stage reads, else the default" — resolved by
    :func:`resolve`, the one place that says so (:func:`method_study` resolves without a block)."""

    seed: int | None = option(None, "seed of the realisations; default: the project's seed for this stage")
    case: int | None = option(None, f"control configuration 1–6 (docs/testfield.md); default: that of the "
                                    f"testfield block this stage reads, else the paper's case {PAPER_CASE}")
    with_ap_errors: bool | None = option(None, "simulate the known systematic image errors; default: as the "
                                               "testfield block, else as the simulator (true)")
    sigma_image_um: float | None = option(None, "image noise per coordinate (µm); default: the testfield "
                                                "block's, else the simulator's (40, the paper's σ̂0 level)")
    sigma_control_mm: float | None = option(None, "control survey noise per coordinate (mm); default: the "
                                                  "testfield block's, else the simulator's (0.05)")
    systematic_scale: float | None = option(None, "factor on the systematic image errors; default: the "
                                                  "testfield block's, else the simulator's (1)")
    im_model_weights: Literal["propagated", "intersection", "equal"] = option(
        "propagated", "weights of the independent models' model coordinates (docs/independent-models.md)")
    single_model: bool = option(True, "also adjust the single stereo model at 4.0 m (Table 4)")
    methods: tuple[str, ...] = option(VARIANTS, "the methods to run (any of: " + ", ".join(VARIANTS) + ")")
    in_comparison: bool = option(True, "the stage: put every method's check-point RMSE in "
                                       "summary['check_points'] so the comparison stage lists and plots them")

    def __post_init__(self):
        super().__post_init__()     # every range: declared with option() or implied by the name
        if self.case is not None and self.case not in CASES:
            raise ValueError(f"case must be one of {list(CASES)}, got {self.case}")
        bad = [m for m in self.methods if m not in VARIANTS]
        if bad or not self.methods:
            raise ValueError(f"methods: expected a non-empty list drawn from {list(VARIANTS)}, "
                             f"got {list(self.methods)}")
        object.__setattr__(self, "methods", tuple(self.methods))

    def runs(self, method: str) -> bool:
        return method in self.methods and (self.single_model or method not in (SINGLE_AP, SINGLE))

    def testfield(self, block: str = "block", ap_model: str = "none") -> TestFieldConfig:
        cfg = resolve(self)[0]
        return cfg.field(cfg.case, block, ap_model)


FROM_BLOCK = ("case", "sigma_image_um", "sigma_control_mm", "with_ap_errors", "systematic_scale")
"""The fields that ``None`` means "from the testfield block, else the default"."""


def resolve(cfg: MethodStudyConfig, block=None) -> tuple[MethodStudyConfig, dict]:
    """``cfg`` with every ``None`` of :data:`FROM_BLOCK` filled: from the testfield block's
    configuration (``block.meta["testfield"]["config"]``) if given, else the default (the paper's
    case, :class:`SimulatedErrors`'s declaration).  Returns (config, where each came from:
    ``"option"``, ``"testfield block"`` or ``"default"``)."""
    tf = {}
    if block is not None and isinstance(getattr(block, "meta", None), dict):
        tf = block.meta.get("testfield", {}).get("config", {}) or {}
    defaults = {"case": PAPER_CASE, **{f.name: f.default for f in fields(SimulatedErrors)}}
    values, source = {}, {}
    for k in FROM_BLOCK:
        if getattr(cfg, k) is not None:
            source[k] = "option"
        elif k in tf:
            values[k], source[k] = tf[k], "testfield block"
        else:
            values[k], source[k] = defaults[k], "default"
    return (replace(cfg, **values) if values else cfg), source


# --------------------------------------------------------------------------------------------
# one realisation


def _bundle_settings():
    from baarda.pipeline.adjustment import BundleSettings

    return BundleSettings(covariance=True, tol_obs=1e-4, max_iter=50)


def _bundle_row(res, block, sigma_control_m: float) -> dict:
    """Check-point errors and the precision the bundle predicts for them (a-priori σ0)."""
    chk = res.check
    ids = list(chk.ids)
    err = np.asarray(chk.errors, float).reshape(-1, 3)
    idx = block.points.index_of(ids) if ids else np.zeros(0, int)
    Q = res.cov_points[idx] / res.variance_factor if len(idx) else np.zeros((0, 3, 3))
    return {"ids": ids, "errors": err, "pred": _predicted(Q, sigma_control_m), "dof": int(res.dof),
            "sigma0_hat": float(res.sigma0_hat)}


def _predicted(Q: np.ndarray, sigma_control_m: float) -> np.ndarray:
    """(3,) predicted RMS of adjusted − surveyed per axis: √(mean σ²_adjusted + σ²_survey)."""
    if not len(Q):
        return np.full(3, np.nan)
    return np.sqrt(np.mean(np.einsum("nii->ni", Q), axis=0) + sigma_control_m ** 2)


def _im_row(res, sigma_control_m: float) -> dict:
    blk = res.block
    chk = blk.check
    ids = [str(i) for i in chk.ids]
    pos = {p: k for k, p in enumerate(blk.point_ids.tolist())}
    Q = blk.cov_XYZ[[pos[i] for i in ids]] if ids else np.zeros((0, 3, 3))
    return {"ids": ids, "errors": np.asarray(chk.errors, float).reshape(-1, 3),
            "pred": _predicted(Q, sigma_control_m), "dof": int(blk.dof), "sigma0_hat": float(blk.sigma0_hat)}


def _with_aps(block, cfg: MethodStudyConfig, settings):
    """The bundle's AP selection; its weak-priors method where the block is singular with every AP
    free (only the minimal control of case 1)."""
    from baarda.pipeline.adjustment import select_aps

    sel = select_aps(block, settings, rho_max=cfg.rho_max, alpha=cfg.ap_alpha, on_singular="weak-priors")
    label = {"correlation": "bundle", "weak-priors": "testfield study"}[sel.method]
    return sel.result, [k.parameter for k in sel.kept], label


def run_realisation(cfg: MethodStudyConfig, seed: int, repetition: int) -> list[dict]:
    """Every method on realisation ``repetition`` of the field (``rng = default_rng([seed,
    repetition])``; the same draws for every method).  One row per variant: ``variant,
    repetition, Sx, Sy, Sz`` (m), ``pred`` (3,) predicted RMS (m), ``dof``, ``sigma0_hat``,
    ``kept`` (AP names), ``selection``, ``ids``, ``errors`` (k, 3), ``error`` (message or "")."""
    from baarda.pipeline.adjustment import adjust
    from baarda.pipeline.imodels import independent_model_block

    cfg = resolve(cfg)[0]
    settings = _bundle_settings()
    sc = cfg.sigma_control_mm * 1e-3
    rng = lambda: np.random.default_rng([seed, repetition])  # noqa: E731 — same draws for every method
    sim = {}

    def simulated(kind, ap_model):   # each block simulated once, from the same draws
        if (kind, ap_model) not in sim:
            sim[kind, ap_model] = simulate_testfield(cfg.testfield(kind, ap_model), rng())[0]
        return sim[kind, ap_model]

    jobs = {BUNDLE: lambda: (_bundle_row(adjust(simulated("block", "none"), settings), simulated("block", "none"),
                                         sc), [], ""),
            BUNDLE_AP: lambda: _ap_job(simulated("block", "ebner12"), cfg, settings, sc),
            IM: lambda: (_im_row(independent_model_block(simulated("block", "none"),
                                                         model_weights=cfg.im_model_weights), sc), [], ""),
            SINGLE_AP: lambda: _ap_job(simulated("single-model", "ebner12"), cfg, settings, sc),
            SINGLE: lambda: (_bundle_row(adjust(simulated("single-model", "none"), settings),
                                         simulated("single-model", "none"), sc), [], "")}
    rows = []
    for name in VARIANTS:
        if not cfg.runs(name):
            continue
        job = jobs[name]
        row = {"variant": name, "repetition": repetition}
        try:
            r, kept, how = job()
        except AdjustmentError as e:
            rows.append({**row, "Sx": np.nan, "Sy": np.nan, "Sz": np.nan, "pred": np.full(3, np.nan), "dof": -1,
                         "sigma0_hat": np.nan, "kept": [], "selection": "", "ids": [], "errors": np.zeros((0, 3)),
                         "error": str(e)})
            continue
        c = check_point_rmse(r["errors"], np.zeros_like(r["errors"]))
        S = np.array([c["Sx"], c["Sy"], c["Sz"]])
        rows.append({**row, "Sx": float(S[0]), "Sy": float(S[1]), "Sz": float(S[2]), "pred": r["pred"],
                     "dof": r["dof"], "sigma0_hat": r["sigma0_hat"], "kept": kept, "selection": how,
                     "ids": r["ids"], "errors": r["errors"], "error": ""})
    return rows


def _ap_job(block, cfg, settings, sc):
    res, kept, how = _with_aps(block, cfg, settings)
    return _bundle_row(res, block, sc), kept, how


# --------------------------------------------------------------------------------------------
# geometry behind the numbers


def field_geometry(cfg: MethodStudyConfig) -> dict:
    """Object distance H, base B, B/H, image scale H/c, the systematic image errors, rays per check
    point — for the block and the single model — and the first-order precision of a normal-case
    stereo pair, ``σ_XY ≈ (H/c) σ``, ``σ_Z ≈ (H/B)(H/c) σ`` (σ per image coordinate; a parallax
    from two independent measurements has √2 σ)."""
    cfg = resolve(cfg)[0]
    out = {}
    kinds = [("block", STRIPS)] + ([("single model", (SINGLE_MODEL_PHOTOS,))]
                                   if cfg.runs(SINGLE) or cfg.runs(SINGLE_AP) else [])
    for kind, strips in kinds:
        block, truth = simulate_testfield(cfg.testfield("block" if kind == "block" else "single-model"),
                                          np.random.default_rng(0))
        ids = [str(p) for p in truth.photo_ids]
        bases = [float(np.linalg.norm(truth.X0[ids.index(b)] - truth.X0[ids.index(a)]))
                 for s in strips for a, b in zip(s[:-1], s[1:])]
        H = float(block.meta["testfield"]["geometry"]["distance_m"])
        B = float(np.mean(bases))
        scale = H / (FOCAL_MM * 1e-3)
        sig = cfg.sigma_image_mm * 1e-3   # m in the image
        chk = np.flatnonzero(block.points.role == "check")
        rays = [int((block.observations.point == k).sum()) for k in chk]
        out[kind] = {"H_m": H, "B_m": B, "B_over_H": B / H, "scale": scale, "photos": len(ids),
                     "sigma_xy_first_order_m": scale * sig, "sigma_z_first_order_m": scale * sig / (B / H),
                     "rays_per_check_point": float(np.mean(rays)) if rays else float("nan"),
                     "systematic_rms_um": float(np.sqrt(np.mean(truth.systematic ** 2)) * 1e3),
                     "systematic_max_um": float(np.max(np.linalg.norm(truth.systematic, axis=1)) * 1e3)
                     if len(truth.systematic) else 0.0,
                     "check_points": int(chk.size)}
    return out


# --------------------------------------------------------------------------------------------
# summaries and paired comparisons


def _sxy(sx, sy):
    return np.sqrt((np.asarray(sx) ** 2 + np.asarray(sy) ** 2) / 2)


def _values(rows, variant, key) -> dict:
    """{repetition: value} of ``key`` (Sx, Sy, Sxy, Sz) for the realisations where ``variant`` ran."""
    out = {}
    for r in rows:
        if r["variant"] == variant and not r["error"]:
            out[r["repetition"]] = float(_sxy(r["Sx"], r["Sy"])) if key == "Sxy" else float(r[key])
    return out


def summarise(rows) -> dict:
    """Per variant: pooled RMSE (cm; RMS over realisations), spread (standard deviation and 10 / 90 %
    quantiles over realisations of Sxy and Sz), predicted RMSE (cm), mean σ̂0, median dof, kept APs
    and how often, failures."""
    out = {}
    for v in VARIANTS:
        sel = [r for r in rows if r["variant"] == v and not r["error"]]
        failed = sum(1 for r in rows if r["variant"] == v and r["error"])
        if not sel:
            if failed:
                out[v] = {"realisations": 0, "failed": failed}
            continue
        S = np.array([[r["Sx"], r["Sy"], r["Sz"]] for r in sel]) * 100
        pooled = np.sqrt(np.mean(S ** 2, axis=0))
        P = np.array([r["pred"] for r in sel]) * 100
        pred = np.sqrt(np.nanmean(P ** 2, axis=0))
        sxy = _sxy(S[:, 0], S[:, 1])
        kept = {}
        for r in sel:
            for a in r["kept"]:
                kept[a] = kept.get(a, 0) + 1
        d = {"realisations": len(sel), "failed": failed, "n": len(sel[0]["ids"]),
             "Sx": pooled[0], "Sy": pooled[1], "Sxy": float(_sxy(pooled[0], pooled[1])), "Sz": pooled[2],
             "Sxy_sd": float(np.std(sxy, ddof=1)) if len(sel) > 1 else float("nan"),
             "Sz_sd": float(np.std(S[:, 2], ddof=1)) if len(sel) > 1 else float("nan"),
             "Sxy_q10": float(np.quantile(sxy, 0.1)), "Sxy_q90": float(np.quantile(sxy, 0.9)),
             "Sz_q10": float(np.quantile(S[:, 2], 0.1)), "Sz_q90": float(np.quantile(S[:, 2], 0.9)),
             "pred_Sx": pred[0], "pred_Sy": pred[1], "pred_Sxy": float(_sxy(pred[0], pred[1])), "pred_Sz": pred[2],
             "sigma0_hat": float(np.mean([r["sigma0_hat"] for r in sel])),
             "dof": int(np.median([r["dof"] for r in sel])),
             "kept": " ".join(f"{a}({n})" for a, n in sorted(kept.items(), key=lambda kv: (-kv[1], kv[0])))}
        out[v] = d
    return out


def compare(rows, a: str, b: str, keys=KEYS) -> dict:
    """Variant ``a`` against ``b`` on the realisations where both ran, per key:
    ``change_pct`` = 100 (pooled a − pooled b)/pooled b; ``ratio`` = geometric mean of a/b over the
    realisations with ``ratio_lo``, ``ratio_hi`` = exp(mean log ± 2 standard errors); ``share`` =
    fraction of realisations with a < b; ``significant`` when the interval excludes 1."""
    out = {}
    for k in keys:
        va, vb = _values(rows, a, k), _values(rows, b, k)
        reps = sorted(set(va) & set(vb))
        x = np.array([va[i] for i in reps])
        y = np.array([vb[i] for i in reps])
        ok = (x > 0) & (y > 0)
        x, y = x[ok], y[ok]
        if x.size == 0:
            continue
        lr = np.log(x / y)
        m = float(lr.mean())
        se = float(lr.std(ddof=1) / np.sqrt(lr.size)) if lr.size > 1 else float("nan")
        pa, pb = np.sqrt(np.mean(x ** 2)), np.sqrt(np.mean(y ** 2))
        out[k] = {"a_cm": 100 * pa, "b_cm": 100 * pb, "change_pct": _pct(pa, pb), "ratio": float(np.exp(m)),
                  "ratio_lo": float(np.exp(m - 2 * se)), "ratio_hi": float(np.exp(m + 2 * se)),
                  "share": float(np.mean(x < y)), "n": int(x.size),
                  "significant": bool(np.isfinite(se) and abs(m) > 2 * se)}
    return out


def _verdict(c: dict, better: bool) -> str:
    """``better``: the claim is that a is smaller than b."""
    smaller = c["ratio"] < 1
    if smaller == better:
        return "holds" if c["significant"] else "holds, not significant"
    return "contradicted" if c["significant"] else "does not hold, not significant"


def conclusions(rows, cfg: MethodStudyConfig) -> list[dict]:
    """The paper's statements that this study can test, each on the paired realisations:
    ``{"claim", "a", "b", "key", "better", "paper_pct", "comparison": compare(...)[key], "verdict"}``."""
    claims = [("self-calibration (APs) improves the bundle's planimetry", BUNDLE_AP, BUNDLE, "Sxy", True,
               PAPER_PERCENT["APs vs no APs"]["Sxy"]),
              ("self-calibration (APs) improves the bundle's height", BUNDLE_AP, BUNDLE, "Sz", True,
               PAPER_PERCENT["APs vs no APs"]["Sz"]),
              ("independent models give better planimetry than the bundle", IM, BUNDLE_AP, "Sxy", True,
               PAPER_PERCENT["independent models vs bundle"]["Sxy"]),
              ("independent models give worse height than the bundle", IM, BUNDLE_AP, "Sz", False,
               PAPER_PERCENT["independent models vs bundle"]["Sz"])]
    if cfg.single_model:
        claims += [("the block at 1.4 m beats the single model at 4.0 m in planimetry (paper: by 10.72 %)",
                    BUNDLE_AP, SINGLE_AP, "Sxy", True, PAPER_PERCENT["block vs single model"]["Sxy"]),
                   ("the block at 1.4 m beats the single model at 4.0 m in height (paper: by 10.13 %)",
                    BUNDLE_AP, SINGLE_AP, "Sz", True, PAPER_PERCENT["block vs single model"]["Sz"])]
    out = []
    for text, a, b, key, better, paper in claims:
        c = compare(rows, a, b, (key,)).get(key)
        if c is None:
            continue
        out.append({"claim": text, "a": a, "b": b, "key": key, "better": better, "paper_pct": paper,
                    "comparison": c, "verdict": _verdict(c, better)})
    return out


def method_study(cfg: MethodStudyConfig, seed: int, progress: Callable | None = None,
                 mapper: Callable | None = None) -> dict:
    """Run the study.  Returns ``{"config", "seed", "rows", "variants": summarise(rows),
    "conclusions", "comparisons": {name: compare(...)}, "geometry": field_geometry(cfg)}``.
    ``mapper(fn, repetitions)`` runs the realisations (any callable with the signature of the
    built-in ``map``, e.g. :func:`baarda.pipeline.montecarlo.mapper`'s, which reports its own
    progress); without one they run here and ``progress(i, total)`` is called after each.  Each
    realisation has its own seed (:func:`run_realisation`), so the result is the same either way.
    ``None`` fields of ``cfg`` take their defaults (:func:`resolve` without a block)."""
    cfg = resolve(cfg)[0]
    one = partial(run_realisation, cfg, seed)
    if mapper is None:
        rows = []
        for rep in range(cfg.repetitions):
            rows += one(rep)
            if progress:
                progress(rep + 1, cfg.repetitions)
    else:
        rows = [r for rep_rows in mapper(one, range(cfg.repetitions)) for r in rep_rows]
    pairs = {"APs vs no APs": (BUNDLE_AP, BUNDLE),
             "independent models vs bundle": (IM, BUNDLE_AP),
             "independent models vs bundle without APs": (IM, BUNDLE)}
    if cfg.single_model:
        pairs.update({"block vs single model": (BUNDLE_AP, SINGLE_AP),
                      "block vs single model, no APs": (BUNDLE, SINGLE)})
    return {"config": cfg, "seed": seed, "rows": rows, "variants": summarise(rows),
            "comparisons": {name: {"a": a, "b": b, **compare(rows, a, b)} for name, (a, b) in pairs.items()},
            "conclusions": conclusions(rows, cfg), "geometry": field_geometry(cfg)}
