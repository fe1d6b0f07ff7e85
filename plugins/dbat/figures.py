"""Figures of ``dbat-report`` and ``dbat-marks`` for report.html (matplotlib; the engine draws them
with Agg).  Every number drawn is the stage's (``_quality``'s dict, ``compare_marks``'s pairs) or
DBAT's published report of the same script (:data:`PUBLISHED`, labelled as such)."""

from __future__ import annotations

from pathlib import PurePath

import numpy as np

from baarda.pipeline.units import fmt_num

PUBLISHED = {
    # niclasborlin/dbat data/script/camcaldemo/result/report.txt (commit 08b5c63, DBAT 0.9.0.1)
    "camcaldemo.xml": {
        "source": "DBAT 0.9.0.1's report of camcaldemo.xml", "marks": 2074,
        # parameter: (value, σ) in DBAT's conventions (mm; pp from the image corner, y down)
        "camera": {"cc": (7.457, 0.00105), "px": (3.61546, 0.00082), "py": (2.61329, 0.00098),
                   "K1": (0.00458861, 2.21e-05), "K2": (-4.51351e-05, 2.65e-06), "K3": (-2.05253e-06, 1.01e-07),
                   "P1": (-6.12803e-05, 3.52e-06), "P2": (-4.41171e-05, 3.94e-06), "as": (0.000389598, 2.08e-05)},
    },
    # niclasborlin/dbat data/script/sxb/result/report.txt (commit 0e33f62, DBAT 0.9.1.2)
    "sxb.xml": {
        "source": "DBAT 0.9.1.2's report of sxb.xml", "marks": 1196,
        # control: id -> adjusted X, Y, Z (m)
        "control": {"317": (999604.591, 112344.411, 139.434), "333": (1000134.491, 112591.198, 138.004),
                    "403": (999170.661, 112692.523, 139.636), "492": (999606.884, 112342.389, 139.140),
                    "552": (1000575.046, 112258.182, 139.628), "651": (1000359.451, 112429.750, 139.165)},
        # check: id -> adjusted − surveyed (m)
        "check": {"351": (0.167, 0.008, -0.459), "410": (0.096, -0.296, 0.136)},
    },
}
"""DBAT's published results of the two demo scripts (the numbers tests/dbat/test_projects.py asserts
against), keyed by the script's file name; used only when the script's marks count matches too."""

CAMERA_ORDER = ("cc", "px", "py", "K1", "K2", "K3", "P1", "P2", "as", "sk")


def published(script: str | None, marks: int | None) -> dict | None:
    """DBAT's published report of ``script`` (a path) when its file name and number of marks are
    those of a demo script DBAT published; else None."""
    if not script:
        return None
    ref = PUBLISHED.get(PurePath(str(script)).name)
    return ref if ref is not None and marks == ref["marks"] else None


def _plt():
    import matplotlib.pyplot as plt

    return plt


def camera_comparison(q: dict, reference: dict | None, earlier: dict | None):
    """Camera parameters against DBAT's published values ((baarda − DBAT)/σ_DBAT) and against an
    earlier dbat-report's ((this − earlier)/√(σ² + σ_earlier²)), with the ±1σ band, and the ratio
    of the σ.  None when there is nothing to compare with."""
    rows = {k: v for k, v in q["camera_rows"].items() if v[2] != "fixed"}
    names = [k for k in CAMERA_ORDER if k in rows] + [k for k in rows if k not in CAMERA_ORDER]
    series = []
    if reference is not None and reference.get("camera"):
        ref = reference["camera"]
        n = [k for k in names if k in ref]
        series.append(("DBAT's published report", n, [(rows[k][0] - ref[k][0]) / ref[k][1] for k in n],
                       [rows[k][1] / ref[k][1] for k in n], "#c0392b", "o"))
    if earlier is not None:
        n = [k for k in names if k in earlier["camera"]]
        d = []
        for k in n:
            v0, s0 = earlier["camera"][k]
            s = float(np.hypot(rows[k][1], s0))
            d.append((rows[k][0] - v0) / s if s > 0 else np.nan)
        series.append(("the earlier dbat-report", n, d, [rows[k][1] / earlier["camera"][k][1]
                                                         if earlier["camera"][k][1] > 0 else np.nan for k in n],
                       "#1f4e9c", "s"))
    if not series:
        return None
    from baarda.pipeline.plots import sigma_dots

    plt = _plt()
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 3.9), gridspec_kw={"width_ratios": [1.4, 1]})
    for i, (label, n, d, ratio, col, mk) in enumerate(series):
        x = np.array([names.index(k) for k in n], float)
        off = (i - (len(series) - 1) / 2) * 0.3
        sigma_dots(a, names, d, label=f"this − {label}", color=col, offset=off / 2, marker=mk, positions=x)
        b.bar(x + off / 2, np.asarray(ratio, float) - 1.0, width=0.3, color=col, label=f"σ this / σ {label} − 1")
    a.set_ylabel("difference / σ")
    a.set_xlabel("camera parameter (DBAT's names)")
    lim = max(1.5, float(np.nanmax(np.abs(np.concatenate([np.asarray(s[2], float) for s in series])))) * 1.15)
    a.set_ylim(-lim, lim)
    a.set_title("camera: difference in units of σ (shaded: ±1σ)", fontsize=10)
    b.axhline(0, color="k", lw=0.7)
    b.set_xticks(np.arange(len(names)), names, fontsize=8)
    b.set_xlim(-0.6, len(names) - 0.4)
    from matplotlib.ticker import PercentFormatter

    b.yaxis.set_major_formatter(PercentFormatter(xmax=1.0, decimals=1))
    b.set_ylabel("relative difference of σ")
    b.set_xlabel("camera parameter (DBAT's names)")
    b.set_title("standard deviations", fontsize=10)
    ha, la = a.get_legend_handles_labels()
    hb, lb = b.get_legend_handles_labels()
    fig.legend(ha + hb, la + lb, loc="lower center", ncol=2, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.06 + 0.05 * len(series), 1, 1))
    return fig


def correlation(q: dict, rho_high: float):
    """The camera parameters' correlation matrix (estimated parameters), |ρ| > rho_high marked."""
    names = list(q["names"])
    free = [i for i, n in enumerate(names) if any(r[3] == n and r[2] != "fixed" for r in q["camera_rows"].values())]
    if len(free) < 2:
        return None
    R = np.asarray(q["correlation"], float)[np.ix_(free, free)]
    label = {r[3]: k for k, r in q["camera_rows"].items()}
    ticks = [f"{label.get(names[i], names[i])}" for i in free]
    plt = _plt()
    fig, ax = plt.subplots(figsize=(1.2 + 0.62 * len(free), 0.9 + 0.55 * len(free)))
    im = ax.imshow(R, cmap="RdBu_r", vmin=-1, vmax=1)
    for i in range(len(free)):
        for j in range(len(free)):
            if i != j and np.isfinite(R[i, j]):
                big = abs(R[i, j]) > rho_high
                ax.text(j, i, f"{R[i, j]:+.2f}", ha="center", va="center", fontsize=7,
                        color="w" if abs(R[i, j]) > 0.6 else "k", weight="bold" if big else "normal")
                if big:
                    ax.add_patch(plt.Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, ec="k", lw=1.5))
    ax.set_xticks(range(len(free)), ticks, fontsize=8)
    ax.set_yticks(range(len(free)), ticks, fontsize=8)
    ax.set_title(f"camera correlations (framed: |ρ| > {rho_high:g})", fontsize=10)
    fig.colorbar(im, ax=ax, shrink=0.8, label="ρ")
    fig.tight_layout()
    return fig


def point_differences(q: dict, reference: dict | None):
    """Weighted control points (adjusted − prior) and check points (adjusted − surveyed) as plan
    vectors and per-coordinate bars with their a-posteriori ±1σ; DBAT's published values as
    crosses.  None without weighted control or check points."""
    from baarda.pipeline.plots import point_errors

    sets, ref_ids, ref_d = [], [], []
    for kind, col, label in (("control", "#c0392b", "control: adjusted − prior"),
                             ("check", "#1f4e9c", "check: adjusted − surveyed")):
        c = q[kind]
        if not c["ids"]:
            continue
        keep = np.ones(len(c["ids"]), bool)
        if kind == "control":
            keep = ~np.all(np.asarray(c["prior_sigma"], float) == 0, axis=1)     # fixed control: 0 by definition
        if not keep.any():
            continue
        ids = [i for i, k in zip(c["ids"], keep) if k]
        sets.append({"label": label, "ids": ids, "xy": np.asarray(c["prior"])[keep, :2],
                     "d": np.asarray(c["diff"])[keep], "sigma": np.asarray(c["sigma"])[keep], "color": col})
        if reference is not None:
            pub = reference.get(kind, {})
            for i, prior in zip(ids, np.asarray(c["prior"])[keep]):
                if str(i) in pub:
                    ref_ids.append(str(i))
                    ref_d.append(np.asarray(pub[str(i)], float) - (prior if kind == "control" else 0.0))
    if not sets:
        return None
    ref = {"label": "DBAT's published report", "ids": ref_ids, "d": np.array(ref_d).reshape(-1, 3)} if ref_ids else None
    u = q["object_unit"]
    return point_errors(sets, u, f"differences ({u}) with the a-posteriori ±1σ", reference=ref)


def rays_and_angles(q: dict):
    """Histograms of the intersection angles and of the ray counts per kind of point (DBAT's
    "Point Angles" and ray counts)."""
    plt = _plt()
    ang, rays, role = np.asarray(q["angles_deg"], float), np.asarray(q["rays"]), np.asarray(q["role"])
    kinds = (("control", (role != "tie") & (role != "check"), "#c0392b"), ("check", role == "check", "#1f4e9c"),
             ("tie", role == "tie", "#7f8c8d"))
    used = rays > 0
    from baarda.pipeline.plots import fixed_layout, fixed_titles

    with fixed_titles():
        fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.6))
    fin = ang[used & np.isfinite(ang)]
    top = min(90.0, float(fin.max()) * 1.1 + 1.0) if fin.size else 90.0
    bins = np.linspace(0, top, 46)
    r_used = rays[used]
    values = np.arange(int(r_used.min()), int(r_used.max()) + 1) if r_used.size else np.arange(1, 2)
    drawn = [(name, m & used, col) for name, m, col in kinds if (m & used).any()]
    w = 0.8 / max(len(drawn), 1)
    for n, (name, m, col) in enumerate(drawn):
        a.hist(ang[m & np.isfinite(ang)], bins=bins, color=col, alpha=0.6, label=f"{name} ({int(m.sum())})")
        b.bar(values + (n - (len(drawn) - 1) / 2) * w, [int((rays[m] == k).sum()) for k in values], width=w,
              color=col, label=name)
    b.set_xticks(values)
    a.set_xlabel("largest intersection angle (°)")
    a.set_ylabel("points")
    a.set_title("intersection angles", fontsize=10)
    a.legend(fontsize=8)
    b.set_xlabel("rays per point")
    b.set_ylabel("points")
    b.set_title("rays", fontsize=10)
    b.legend(fontsize=8)
    fixed_layout(fig, left=0.8, right=0.2, bottom=0.55, top=0.3, wspace=0.9)     # counts, one-line titles
    return fig


def report_figures(q: dict, script: str | None, marks: int | None, earlier: dict | None, rho_high: float) -> dict:
    ref = published(script, marks)
    out = {}
    fig = camera_comparison(q, ref, earlier)
    if fig is not None:
        against = " and ".join(x for x, y in (("DBAT's published report", ref is not None and ref.get("camera")),
                                               ("the earlier dbat-report of this run", earlier is not None)) if y)
        out["camera"] = (fig, f"Camera parameters against {against}: difference in units of σ (DBAT's σ for the "
                              "published values; both σ combined as if independent for the earlier report), "
                              "and the σ against theirs")
    fig = correlation(q, rho_high)
    if fig is not None:
        out["correlation"] = (fig, "Correlations of the estimated camera parameters")
    fig = point_differences(q, ref)
    if fig is not None:
        out["points"] = (fig, "Weighted control points (adjusted − prior) and check points (adjusted − surveyed): "
                              "plan vectors and coordinates with ±1σ" + ("; crosses: DBAT's published report"
                                                                         if ref is not None else ""))
    out["angles"] = (rays_and_angles(q), "Intersection angles and rays per point (as DBAT counts them)")
    return out


def marks_figure(cmp: dict, radius_px: float):
    """dbat-marks: the pairs' differences (block − marks, pixels, x right, y down) as vectors over
    the image, their histograms, and their scatter with the RMS."""
    plt = _plt()
    d = cmp["pairs"]
    uv, duv = np.asarray(d["uv_mark"], float), np.asarray(d["duv"], float)
    a_ = cmp["all"]
    fig, (a, b, c) = plt.subplots(1, 3, figsize=(15, 4.4), gridspec_kw={"width_ratios": [1.35, 1, 1]})
    from baarda.pipeline.plots import vector_scale

    k = vector_scale(uv, duv, 0.04)
    if len(uv):
        a.quiver(uv[:, 0], uv[:, 1], k * duv[:, 0], k * duv[:, 1], angles="xy", scale_units="xy", scale=1,
                 color="#1f4e9c", width=0.0025)
    a.set_aspect("equal", adjustable="datalim")
    a.invert_yaxis()
    a.set_xlabel("u (px, mark)")
    a.set_ylabel("v (px, mark; down)")
    a.set_title(f"{len(duv)} pairs, all photos: block − marks × {fmt_num(k, 3)}", fontsize=10)
    lim = max(radius_px * 0.25, float(np.nanmax(np.abs(duv))) if len(duv) else 1.0)
    bins = np.linspace(-lim, lim, 41)
    for j, (name, col) in enumerate((("du", "#1f4e9c"), ("dv", "#c0392b"))):
        b.hist(duv[:, j], bins=bins, color=col, alpha=0.55, label=f"{name}: bias {a_['bias_px'][j]:+.3f}, "
                                                                  f"RMS {a_['rms_px'][j]:.3f} px")
        b.axvline(a_["bias_px"][j], color=col, lw=1.2)
    b.set_xlabel("difference (px)")
    b.set_ylabel("pairs")
    b.set_title("histograms (lines: bias)", fontsize=10)
    b.legend(fontsize=8, loc="upper left")
    c.plot(duv[:, 0], duv[:, 1], ".", ms=2, color="#555")
    t = np.linspace(0, 2 * np.pi, 200)
    r = np.asarray(a_["rms_px"], float)
    c.plot(a_["bias_px"][0] + r[0] * np.cos(t), a_["bias_px"][1] + r[1] * np.sin(t), color="#c0392b", lw=1,
           label="bias ± RMS")
    c.plot(*a_["bias_px"], "+", color="#c0392b", ms=10)
    c.set_aspect("equal", adjustable="datalim")
    c.invert_yaxis()
    c.set_xlabel("du (px)")
    c.set_ylabel("dv (px; down)")
    c.set_title("du against dv", fontsize=10)
    c.legend(fontsize=8)
    fig.tight_layout()
    return fig
