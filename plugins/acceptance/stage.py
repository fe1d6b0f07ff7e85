"""Stage ``length-test``: the length measurement error of VDI/VDE 2634 Part 1.

Calibrated scale bars are measured in several positions and orientations of the measuring volume
(the guideline's seven measuring lines: four space diagonals and three lines parallel to the axes).
For each bar the system's length ``L_meas`` (from the adjusted coordinates of its two end points)
is compared with the calibrated length ``L_cal``: the length measurement error ``ΔL = L_meas − L_cal``
must lie within the maximum permissible error ``MPE(L) = A + B·L`` (µm; capped at ``max`` when given)
stated for the system. Beside each error the stage gives σ of the measured length from the joint
covariance of the two end points, so a reader sees whether an exceedance is significant.

Decision: the quality parameter is confirmed when no more than ``max_exceedances`` (default 0) of the
length errors exceed the MPE. ``docs/monitoring.md`` ("Acceptance test") has the layout.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baarda.pipeline.api import InputError, Stage, StageResult, TableData, option, parameter_covariance
from baarda.pipeline.report import markdown_table
from baarda.pipeline.units import fmt_num, fmt_q

TO_M = {"m": 1.0, "mm": 1e-3}


@dataclass(frozen=True)
class Bar:
    from_: str = option("", "id of the point at one end", key="from")
    to: str = option("", "id of the point at the other end")
    length: float = option(0.0, "calibrated length (object unit)", gt=0.0)
    line: str = option("", "measuring line or position label (e.g. D1 … D4, AX, AY, AZ)")


@dataclass(frozen=True)
class LengthTestOptions:
    bars: list[Bar] = option([], "calibrated bars: a list of tables {from, to, length, line}")
    bars_file: str = option("", "CSV of calibrated bars: from,to,length_<unit>,line (unit m or mm; '#' comments)")
    mpe_a_um: float = option(0.0, "MPE constant term A (µm)", ge=0.0)
    mpe_b_um_per_m: float = option(0.0, "MPE length-proportional term B (µm per m of length)", ge=0.0)
    mpe_max_um: float = option(0.0, "upper bound of the MPE (µm); 0: none", ge=0.0)
    max_exceedances: int = option(0, "length errors allowed beyond the MPE for the test to pass", ge=0, le=1000)


class LengthTest(Stage):
    summary = "VDI/VDE 2634-1 acceptance test: length measurement errors of calibrated bars against the MPE"
    reads = ("bundle",)
    writes = ("length_test",)
    Options = LengthTestOptions

    def run(self, inputs, o: LengthTestOptions, ctx) -> StageResult:
        res = inputs["bundle"]
        unit = ctx.object_unit
        if unit not in TO_M:
            raise ctx.option_error(f"the length test needs an object unit of m or mm, the project has {unit!r}", "bars")
        bars = [(str(b.from_), str(b.to), float(b.length), b.line, ("bars", None)) for b in o.bars]
        if o.bars_file:
            bars += _read_bars(ctx.resolve(o.bars_file), unit)
        if not bars:
            raise ctx.option_error("no bars: give 'bars' or 'bars_file'", "bars")
        if o.mpe_a_um == 0 and o.mpe_b_um_per_m == 0:
            raise ctx.option_error("the MPE is zero: give mpe_a_um and/or mpe_b_um_per_m as the system's "
                                   "specification states them", "mpe_a_um")
        ids = [str(i) for i in res.block.points.ids]
        index = {p: k for k, p in enumerate(ids)}
        est = np.isfinite(res.cov_points).all(axis=(1, 2))
        for f, t, L, line, (src, lineno) in bars:
            for p in (f, t):
                if p not in index:
                    raise _bar_error(ctx, src, lineno, f"bar {f}–{t}: no point {p!r} in the block")
                if not est[index[p]]:
                    raise _bar_error(ctx, src, lineno, f"bar {f}–{t}: point {p!r} was not adjusted")
        X = res.block.points.XYZ
        to_um = TO_M[unit] * 1e6
        Lm = np.array([np.linalg.norm(X[index[t]] - X[index[f]]) for f, t, *_ in bars])
        Lc = np.array([b[2] for b in bars])
        err_um = (Lm - Lc) * to_um
        sig_um = np.empty(len(bars))
        for k, (f, t, *_rest) in enumerate(bars):
            _, C = parameter_covariance(res, [f"point {f}", f"point {t}"])
            u = (X[index[t]] - X[index[f]]) / Lm[k]
            g = np.concatenate([-u, u])
            sig_um[k] = float(np.sqrt(max(g @ C @ g, 0.0))) * to_um
        mpe = o.mpe_a_um + o.mpe_b_um_per_m * Lc * TO_M[unit]
        if o.mpe_max_um > 0:
            mpe = np.minimum(mpe, o.mpe_max_um)
        exceed = np.abs(err_um) > mpe
        passed = int(exceed.sum()) <= o.max_exceedances
        E_max = float(np.max(np.abs(err_um)))
        worst = int(np.argmax(np.abs(err_um) / mpe))        # nearest to (or furthest beyond) its MPE
        big = int(np.argmax(np.abs(err_um)))
        mpe_text = (f"{fmt_num(o.mpe_a_um)} µm + {fmt_num(o.mpe_b_um_per_m)} µm/m · L"
                    + (f", at most {fmt_num(o.mpe_max_um)} µm" if o.mpe_max_um > 0 else ""))
        lines_used = sorted({b[3] for b in bars if b[3]})
        summary = {
            "conclusion": True,
            "bars": len(bars), "lines": lines_used, "mpe": {"a_um": o.mpe_a_um, "b_um_per_m": o.mpe_b_um_per_m,
                                                             "max_um": o.mpe_max_um},
            "max_abs_error_um": E_max, "rms_error_um": float(np.sqrt(np.mean(err_um ** 2))),
            "exceedances": int(exceed.sum()), "max_exceedances": o.max_exceedances, "passed": passed,
            "largest": {"from": bars[big][0], "to": bars[big][1], "error_um": float(err_um[big]),
                        "mpe_um": float(mpe[big])},
            "worst_relative": {"from": bars[worst][0], "to": bars[worst][1], "error_um": float(err_um[worst]),
                               "mpe_um": float(mpe[worst]), "ratio": float(abs(err_um[worst]) / mpe[worst])},
            "headline": (f"length test {'passed' if passed else 'FAILED'}: {len(bars)} bars, largest |ΔL| "
                         f"{fmt_q(E_max, 'µm')}, {int(exceed.sum())} beyond the MPE ({mpe_text})"),
        }
        rows = [[f"{b[0]}–{b[1]}", b[3], fmt_q(Lc[k], unit, 6, rescale=False), fmt_q(err_um[k], "µm", rescale=False),
                 fmt_q(sig_um[k], "µm", rescale=False), fmt_q(mpe[k], "µm", rescale=False),
                 "**exceeds**" if exceed[k] else "ok"]
                for k, b in enumerate(bars)]
        order = np.argsort(-np.abs(err_um) / mpe)[:15]
        report = "\n".join([
            f"VDI/VDE 2634 Part 1 length measurement error: {len(bars)} calibrated bars in "
            f"{len(lines_used) or 'unlabelled'} measuring line(s) ({', '.join(lines_used)}). MPE = {mpe_text}.",
            "",
            f"- Largest |ΔL| = {fmt_q(E_max, 'µm', rescale=False)} ({bars[big][0]}–{bars[big][1]}, MPE there "
            f"{fmt_q(mpe[big], 'µm', rescale=False)}); closest to its MPE: {bars[worst][0]}–{bars[worst][1]} "
            f"({fmt_num(100 * abs(err_um[worst]) / mpe[worst], 3)} % of it); RMS {fmt_q(summary['rms_error_um'], 'µm', rescale=False)}; "
            f"σ of a measured length {fmt_q(float(np.min(sig_um)), 'µm', rescale=False)}–"
            f"{fmt_q(float(np.max(sig_um)), 'µm', rescale=False)}.",
            f"- {int(exceed.sum())} of {len(bars)} errors beyond the MPE ({o.max_exceedances} allowed): "
            f"**{'passed' if passed else 'failed'}**.",
            "", f"Largest errors relative to the MPE ({len(order)} of {len(bars)}; all in the table `bars`):", "",
            markdown_table(["bar", "line", "L_cal", "ΔL", "σ(L)", "MPE", ""], [rows[k] for k in order]),
        ])
        su = {"m": "m", "mm": "mm"}[unit]
        table = TableData({"from": [b[0] for b in bars], "to": [b[1] for b in bars], "line": [b[3] for b in bars],
                           f"length_cal_{su}": Lc, f"length_meas_{su}": Lm, "error_um": err_um, "sigma_um": sig_um,
                           "mpe_um": mpe, "exceeds": exceed},
                          "VDI/VDE 2634-1 length measurement errors ΔL = L_meas − L_cal",
                          units={"from": "", "to": "", "line": "", f"length_cal_{su}": unit,
                                 f"length_meas_{su}": unit, "error_um": "µm", "sigma_um": "µm", "mpe_um": "µm",
                                 "exceeds": ""})
        data = {"Lc": Lc, "err": err_um, "sig": sig_um, "mpe": mpe, "lines": [b[3] for b in bars], "o": o,
                "unit": unit, "passed": passed}
        return StageResult(artefacts={"length_test": summary}, summary=summary, report=report,
                           tables={"bars": table}, data=data)

    def plots(self, result, ctx) -> dict:
        import matplotlib.pyplot as plt

        d = result.data
        L = d["Lc"] * TO_M[d["unit"]]
        fig, ax = plt.subplots(figsize=(7, 4.2))
        grid = np.linspace(0, float(L.max()) * 1.05, 100)
        o = d["o"]
        env = o.mpe_a_um + o.mpe_b_um_per_m * grid
        if o.mpe_max_um > 0:
            env = np.minimum(env, o.mpe_max_um)
        ax.fill_between(grid, -env, env, color="#d5e8d4", label="MPE")
        for line in sorted(set(d["lines"])):
            m = np.array([x == line for x in d["lines"]])
            ax.errorbar(L[m], d["err"][m], yerr=2 * d["sig"][m], fmt="o", ms=4, capsize=2, label=line or "bars")
        ax.axhline(0, color="k", lw=0.6)
        ax.set_xlabel("calibrated length L [m]")
        ax.set_ylabel("length error ΔL [µm]")
        ax.set_title(f"VDI/VDE 2634-1: length measurement errors (±2σ bars) — {'passed' if d['passed'] else 'failed'}",
                     fontsize=9)
        ax.legend(fontsize=7, ncol=4, loc="upper left")
        fig.tight_layout()
        return {"length_errors": (fig, "length measurement errors against the MPE")}


def _bar_error(ctx, src, lineno, msg):
    if src == "bars":
        return ctx.option_error(msg, "bars")
    return InputError(msg, src, lineno, "from")


def _read_bars(path: Path, unit: str):
    if not path.is_file():
        raise InputError("bars file not found", path, None, "bars_file")
    out = []
    with open(path, encoding="utf-8", newline="") as fh:
        lines = [(k + 1, line) for k, line in enumerate(fh) if line.strip() and not line.lstrip().startswith("#")]
    if not lines:
        raise InputError("no header line", path, None, "from")
    head_no, head = lines[0]
    cols = next(csv.reader([head]))
    lcol = [c for c in cols if c.startswith("length_")]
    if "from" not in cols or "to" not in cols or len(lcol) != 1 or lcol[0][7:] not in TO_M:
        raise InputError(f"expected the columns from,to,length_m (or length_mm)[,line], got {','.join(cols)}", path,
                         head_no, "header")
    scale = TO_M[lcol[0][7:]] / TO_M[unit]
    for lineno, line in lines[1:]:
        row = dict(zip(cols, next(csv.reader([line]))))
        try:
            L = float(row[lcol[0]])
        except (KeyError, ValueError):
            raise InputError(f"not a number: {row.get(lcol[0])!r}", path, lineno, lcol[0]) from None
        if not np.isfinite(L) or L <= 0:
            raise InputError(f"a calibrated length must be positive, got {L}", path, lineno, lcol[0])
        out.append((row["from"].strip(), row["to"].strip(), L * scale, row.get("line", "").strip(), (path, lineno)))
    return out
