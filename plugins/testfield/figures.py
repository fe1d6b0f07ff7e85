"""Figures of the test-field studies for report.html (matplotlib; the engine draws them with Agg).

``testfield-control-study``: check-point RMSE Sxy, Sz and σ̂0 against the control case, without and
with additional parameters, the paper's Tables 2–4 beside them (labelled "paper"); the paper's
conclusions as the change of the pooled RMSE ± 2 standard errors.  ``testfield-method-study``: the
pooled RMSE of every method with the spread over the realisations, the RMSE the adjustment predicts
and the paper's Tables 2–5; the conclusions against the paper's percentages.  Every number comes from
the study's result dict (``study["tables"]``, ``["variants"]``, ``["conclusions"]``) or the paper
tables the study modules already hold."""

from __future__ import annotations

import textwrap

import numpy as np

from .paper_tables import PAPER_TABLE2, PAPER_TABLE3, PAPER_TABLE4
from .method_study import BUNDLE, BUNDLE_AP, IM, PAPER_TABLE5, SINGLE_AP, VARIANTS

NO_AP, AP, PAPER = "#1f4e9c", "#c0392b", "k"


def _plt():
    import matplotlib.pyplot as plt

    return plt


def _log_axis(ax):
    """Logarithmic y with plain 1-2-5 labels (0.05, 0.1, 0.2 … rather than 5 × 10⁻²)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    ax.set_yscale("log")
    ax.yaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _p: f"{v:g}"))
    ax.yaxis.set_minor_formatter(NullFormatter())


# ---------------------------------------------------------------------------------------------
# control study


def control_curves(study: dict) -> dict:
    """What :func:`control_cases` draws: per series (``without APs``, ``with APs``, ``paper …``)
    the cases and the values of Sxy, Sz (cm) and σ̂0 (µm; the paper gives it for Table 2 only)."""
    t = study["tables"]
    out = {}
    for name, rows in (("without APs", t["table2"]), ("with APs", t["table3"])):
        out[name] = {"case": [r["case"] for r in rows], **{k: [r[k] for r in rows] for k in ("Sxy", "Sz", "sigma0_um")}}
    c2 = [c for c in out["without APs"]["case"] if c in PAPER_TABLE2]
    c3 = [c for c in out["with APs"]["case"] if c in PAPER_TABLE3]
    out["paper, without APs (Table 2)"] = {"case": c2, "Sxy": [PAPER_TABLE2[c][4] for c in c2],
                                           "Sz": [PAPER_TABLE2[c][5] for c in c2],
                                           "sigma0_um": [PAPER_TABLE2[c][1] for c in c2]}
    out["paper, with APs (Table 3)"] = {"case": c3, "Sxy": [PAPER_TABLE3[c][2] for c in c3],
                                        "Sz": [PAPER_TABLE3[c][3] for c in c3], "sigma0_um": [np.nan] * len(c3)}
    if t.get("single"):
        s = t["single"][0]
        out["single model 4.0 m, with APs"] = {"case": [s["case"]], "Sxy": [s["Sxy"]], "Sz": [s["Sz"]],
                                                "sigma0_um": [s["sigma0_um"]]}
        out["paper, single model (Table 4)"] = {"case": [s["case"]], "Sxy": [PAPER_TABLE4["single model"][2]],
                                                "Sz": [PAPER_TABLE4["single model"][3]], "sigma0_um": [np.nan]}
    return out


_STYLE = {"without APs": dict(color=NO_AP, marker="o", ls="-"),
          "with APs": dict(color=AP, marker="s", ls="-"),
          "paper, without APs (Table 2)": dict(color=NO_AP, marker="o", ls="--", mfc="none"),
          "paper, with APs (Table 3)": dict(color=AP, marker="s", ls="--", mfc="none"),
          "single model 4.0 m, with APs": dict(color="#2c7a3f", marker="*", ls="none", ms=11),
          "paper, single model (Table 4)": dict(color="#2c7a3f", marker="*", ls="none", ms=11, mfc="none")}


def control_cases(study: dict):
    plt = _plt()
    curves = control_curves(study)
    cfg = study["config"]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.3))
    for ax, key, label in zip(axes, ("Sxy", "Sz", "sigma0_um"), ("Sxy (cm)", "Sz (cm)", r"$\hat\sigma_0$ (µm)")):
        for name, c in curves.items():
            v = np.asarray(c[key], float)
            if np.isfinite(v).any():
                ax.plot(c["case"], v, label=name, **{"ms": 6, **_STYLE[name]})
        ax.set_xlabel("control case")
        ax.set_ylabel(label)
        if key != "sigma0_um":
            _log_axis(ax)
        ax.set_xticks(sorted({c for s in curves.values() for c in s["case"]}))
        ax.grid(alpha=0.3, which="both")
    axes[0].set_title("check points: Sxy", fontsize=10)
    axes[1].set_title("check points: Sz", fontsize=10)
    axes[2].set_title(r"$\hat\sigma_0$ (paper: Table 2 only)", fontsize=10)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=8, frameon=False)
    fig.suptitle(f"{cfg['repetitions']} realisation(s), image noise σ = {cfg['sigma_image_um']:g} µm; RMS over the "
                 "realisations (filled) and the paper (hollow, dashed)", fontsize=10)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    return fig


def _claims(ax, texts, keys, values, intervals, verdicts, paper=None, xlabel=""):
    """Horizontal dot plot of the claims: one row per claim and key, the value as a dot, its
    interval ``(lo, hi)`` as a line, the paper's value as a cross."""
    y = np.arange(len(texts))[::-1]
    cols = ["#2c7a3f" if v.startswith("holds") else "#c0392b" for v in verdicts]
    for k in range(len(texts)):
        ax.plot(intervals[k], [y[k], y[k]], "-", color=cols[k], lw=2.5, alpha=0.5, solid_capstyle="butt")
        ax.plot(values[k], y[k], "o", color=cols[k], ms=6)
    if paper is not None:
        ax.plot(paper, y, "x", color=PAPER, ms=8, mew=1.5, label="paper")
        ax.legend(fontsize=8, loc="best")
    ax.axvline(0, color="k", lw=0.7)
    ax.set_yticks(y, ["\n".join(textwrap.wrap(f"{t} [{k}]", 52)) for t, k in zip(texts, keys)], fontsize=8)
    ax.set_ylim(-0.6, len(texts) - 0.4)
    ax.set_xlabel(xlabel)


def control_conclusions(study: dict):
    """The paper's statements: change of the pooled RMSE (%) ± 2 standard errors per key."""
    rows = [(c["claim"], k, c["keys"][k]["change_pct"], c["keys"][k]["se_pct"], c["verdict"])
            for c in study["conclusions"] for k in ("Sxy", "Sz") if k in c["keys"]]
    if not rows:
        return None
    plt = _plt()
    fig, ax = plt.subplots(figsize=(11, 1.0 + 0.42 * len(rows)))
    _claims(ax, [r[0] for r in rows], [r[1] for r in rows], [r[2] for r in rows],
            [(r[2] - 2 * r[3], r[2] + 2 * r[3]) for r in rows], [r[4] for r in rows],
            xlabel="change of the pooled RMSE, first against second configuration (%); line: ± 2 standard errors")
    ax.set_title("the paper's conclusions on the simulation (green: holds, red: does not)", fontsize=10)
    fig.tight_layout()
    return fig


def control_study_figures(study: dict) -> dict:
    out = {"cases": (control_cases(study), "Check-point RMSE Sxy and Sz and σ̂0 against the control case, "
                                           "without and with additional parameters, beside the paper's Tables 2–4")}
    fig = control_conclusions(study)
    if fig is not None:
        out["conclusions"] = (fig, "The paper's conclusions tested on the paired realisations")
    return out


# ---------------------------------------------------------------------------------------------
# method study


def paper_values(cfg) -> dict:
    """The paper's Sxy, Sz (cm) of each method for the study's control case: Tables 2 and 3 for the
    bundle (every case), Tables 4 and 5 for the single model and independent models (case 5 only)."""
    out = {}
    if cfg.case in PAPER_TABLE2:
        out[BUNDLE] = (PAPER_TABLE2[cfg.case][4], PAPER_TABLE2[cfg.case][5])
        out[BUNDLE_AP] = (PAPER_TABLE3[cfg.case][2], PAPER_TABLE3[cfg.case][3])
    if cfg.case == 5:
        out[IM] = (PAPER_TABLE5["independent models"][2], PAPER_TABLE5["independent models"][3])
        out[SINGLE_AP] = (PAPER_TABLE4["single model"][2], PAPER_TABLE4["single model"][3])
    return out


def method_points(study: dict) -> list:
    """Per method that ran: (name, Sxy, Sxy_q10, Sxy_q90, pred_Sxy, Sz, Sz_q10, Sz_q90, pred_Sz,
    paper Sxy or nan, paper Sz or nan) in cm."""
    var = study["variants"]
    paper = paper_values(study["config"])
    out = []
    for v in VARIANTS:
        d = var.get(v, {})
        if not d.get("realisations"):
            continue
        p = paper.get(v, (np.nan, np.nan))
        out.append((v, d["Sxy"], d["Sxy_q10"], d["Sxy_q90"], d["pred_Sxy"], d["Sz"], d["Sz_q10"], d["Sz_q90"],
                    d["pred_Sz"], p[0], p[1]))
    return out


def method_rmse(study: dict):
    plt = _plt()
    pts = method_points(study)
    cfg = study["config"]
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.4))
    x = np.arange(len(pts))
    for ax, off, key in ((axes[0], 1, "Sxy"), (axes[1], 5, "Sz")):
        val = np.array([p[off] for p in pts], float)
        lo = np.array([p[off + 1] for p in pts], float)
        hi = np.array([p[off + 2] for p in pts], float)
        pred = np.array([p[off + 3] for p in pts], float)
        paper = np.array([p[9 if key == "Sxy" else 10] for p in pts], float)
        ax.vlines(x, lo, hi, color=NO_AP, lw=2.5, alpha=0.45, label="baarda: 10–90 % of the realisations")
        ax.plot(x, val, "o", color=NO_AP, ms=7, label="baarda: pooled RMSE")
        ax.plot(x, pred, "D", color="#e67e22", ms=6, mfc="none", mew=1.5, label="predicted by the adjustment")
        if np.isfinite(paper).any():
            ax.plot(x, paper, "x", color=PAPER, ms=9, mew=2, label="paper")
        _log_axis(ax)
        ax.set_xticks(x, ["\n".join(textwrap.wrap(p[0], 14)) for p in pts], fontsize=8)
        ax.set_ylabel(f"{key} (cm)")
        ax.set_xlabel("method")
        ax.grid(alpha=0.3, which="both", axis="y")
        ax.set_title(f"check points: {key}", fontsize=10)
    axes[0].legend(fontsize=8, loc="best")
    fig.suptitle(f"{cfg.repetitions} realisations, control case {cfg.case}, image noise σ = {cfg.sigma_image_um:g} µm",
                 fontsize=10)
    fig.tight_layout()
    return fig


def method_conclusions(study: dict):
    cs = study["conclusions"]
    if not cs:
        return None
    plt = _plt()
    vals = [c["comparison"]["change_pct"] for c in cs]
    # the geometric mean of the per-realisation ratio ± 2 standard errors, as a percentage change
    ivl = [(100 * (c["comparison"]["ratio_lo"] - 1), 100 * (c["comparison"]["ratio_hi"] - 1)) for c in cs]
    fig, ax = plt.subplots(figsize=(11, 1.0 + 0.5 * len(cs)))
    _claims(ax, [c["claim"] for c in cs], [c["key"] for c in cs], vals, ivl, [c["verdict"] for c in cs],
            paper=[c["paper_pct"] for c in cs],
            xlabel="change of the pooled RMSE, first against second method (%)\n"
                   "line: the per-realisation ratio a/b, geometric mean ± 2 standard errors, as a change")
    ax.set_title("the paper's conclusions on the simulation (green: holds, red: does not; ×: the paper)", fontsize=10)
    fig.tight_layout()
    return fig


def method_study_figures(study: dict) -> dict:
    out = {"methods": (method_rmse(study), "Check-point RMSE of every method: pooled over the realisations with "
                                           "their 10–90 % spread, the RMSE the adjustment predicts, and the paper")}
    fig = method_conclusions(study)
    if fig is not None:
        out["conclusions"] = (fig, "The paper's conclusions tested on the paired realisations, against the paper's "
                                   "percentages")
    return out
