"""The ``comparison`` stage: what every earlier stage found, and check-point errors per method.

Convention (docs/plugins.md): a stage that compares its results with check points reports
``summary["check_points"] = {"n", "Sx", "Sy", "Sxy", "Sz", "unit"}`` (or a dict of such dicts,
one per variant, for a stage that runs several) and a table ``check_points`` with columns
``point, dX, dY, dZ`` (adjusted minus surveyed). A study that pools several realisations adds
``"realisations"`` to its dict; ``n`` stays the check points of one realisation and the report shows
``n × realisations``. A one-line finding comes from
``summary["headline"]`` or else from the first line of the stage's report
(:func:`baarda.pipeline.stage.headline_of`).  The stage reads no artefact: the engine offers every
earlier stage's finding as a typed record (``ctx.findings``, :class:`~baarda.pipeline.stage.Finding`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from baarda.pipeline.api import Stage, StageResult, TableData, option
from baarda.pipeline.report import markdown_table
from baarda.pipeline.units import length_suffix

from .plot import checkpoint_chart, png_bytes

KEYS = ("Sx", "Sy", "Sxy", "Sz")


def _count(m) -> str:
    """The n column: check points, times the realisations a study pooled (``"6 × 20"``)."""
    if m["n"] is None:
        return ""
    return f"{m['n']} × {m['realisations']}" if m.get("realisations") else str(m["n"])


def _value(x: float) -> str:
    """An RMSE in the report: four significant digits (values range from µm in metres to cm)."""
    return f"{x:.4g}" if np.isfinite(x) else "—"


def _percent(x: float) -> str:
    return f"{x:.1f}" if np.isfinite(x) else "—"


def _is_rmse(d) -> bool:
    return isinstance(d, dict) and all(k in d for k in ("Sx", "Sy", "Sz"))


def collect_methods(findings) -> list[dict]:
    """Check-point RMSE (and per-point errors) of every earlier stage that has them
    (``findings``: the run's :class:`~baarda.pipeline.stage.Finding` records, ``ctx.findings``)."""
    methods = []
    for st in findings:
        cp = st.summary.get("check_points")
        if cp is None:
            continue
        variants = {st.stage: cp} if _is_rmse(cp) else {f"{st.stage}: {k}": v for k, v in cp.items() if _is_rmse(v)}
        table = st.tables.get("check_points")
        for name, d in variants.items():
            if not d.get("n") or not any(np.isfinite(float(d.get(k, np.nan) or np.nan)) for k in ("Sx", "Sy", "Sz")):
                continue  # an adjustment without check points
            m = {"name": name, "stage": st.stage, "use": st.use, "n": d.get("n"),
                 "realisations": d.get("realisations"), "unit": d.get("unit", "")}
            for k in KEYS:
                v = d.get(k)
                m[k] = float(v) if v is not None else float("nan")
            if not np.isfinite(m["Sxy"]) and np.isfinite(m["Sx"]) and np.isfinite(m["Sy"]):
                m["Sxy"] = float(np.sqrt((m["Sx"] ** 2 + m["Sy"] ** 2) / 2))
            dcols = _check_columns(table)
            if dcols is not None and len(variants) == 1:
                m["errors"] = np.column_stack([np.asarray(table.columns[c], float) for c in dcols])
            methods.append(m)
    return methods


def _check_columns(table):
    """Names of the dX, dY, dZ columns of a check-point table (with or without a unit suffix), or None."""
    if table is None:
        return None
    for sfx in ("", "_m", "_mm", "_mu"):
        names = tuple(f"d{a}{sfx}" for a in "XYZ")
        if all(c in table.columns for c in names):
            return names
    return None


class Comparison(Stage):
    summary = "One comparison across all stages of the run: findings and check-point errors per method."
    reads = ()
    writes = ("comparison",)

    @dataclasses.dataclass(frozen=True)
    class Options:
        reference: str = option("", "stage (or 'stage: variant') whose check-point RMSE the others are "
                                    "compared with in percent; default: the first with check points")
        scale: float = option(1.0, "factor applied to check-point errors for the report and plot "
                                   "(e.g. 100 to show m as cm)")
        unit_label: str = option("", "unit shown for check-point errors (default: the object unit, "
                                     "or 'cm' etc. when you set scale)")

    def run(self, inputs, options, ctx):
        found = [(st.stage, st.use, st.headline) for st in ctx.findings]
        methods = collect_methods(ctx.findings)
        unit = options.unit_label or (methods[0]["unit"] if methods and methods[0]["unit"] else ctx.object_unit)
        for m in methods:
            for k in KEYS:
                m[k] *= options.scale
            if "errors" in m:
                m["errors"] = m["errors"] * options.scale
        lines = ["What each stage found:", "",
                 markdown_table(["stage", "uses", "finding"], [[a, b, c.replace("|", "/")] for a, b, c in found]), ""]
        summary = {"stages": len(found), "methods": {}}
        figures = {}
        tables = {}
        if methods:
            ref = next((m for m in methods if m["name"] == options.reference or m["stage"] == options.reference),
                       methods[0])
            rows = []
            for m in methods:
                pct = [100.0 * (m[k] - ref[k]) / ref[k] if ref[k] else float("nan") for k in ("Sxy", "Sz")]
                rows.append([m["name"], _count(m), *(_value(m[k]) for k in KEYS), *map(_percent, pct)])
                summary["methods"][m["name"]] = ({k: m[k] for k in KEYS} | {"n": m["n"]}
                                                 | ({"realisations": m["realisations"]} if m["realisations"] else {}))
            pooled = ["", "n: check points; n × r: n check points in each of r realisations, pooled."] \
                if any(m["realisations"] for m in methods) else []
            lines += [f"Check-point RMSE ({unit}; adjusted minus surveyed; percent relative to **{ref['name']}**):",
                      "", markdown_table(["method", "n", "Sx", "Sy", "Sxy", "Sz", "ΔSxy %", "ΔSz %"], rows),
                      *pooled, "",
                      "![check-point errors per method](comparison_checkpoints.png)", ""]
            img = checkpoint_chart(methods, unit)
            figures["checkpoints"] = png_bytes(img)
            sfx = length_suffix(unit)          # the RMSE columns carry their unit: Sx_cm, Sx_m, Sx_mu
            tables["checkpoints"] = TableData({"method": [m["name"] for m in methods],
                                               **{k + sfx: [m[k] for m in methods] for k in KEYS}},
                                              f"check-point RMSE per method ({unit}; adjusted minus surveyed)")
            best_z = min(methods, key=lambda m: m["Sz"] if np.isfinite(m["Sz"]) else np.inf)
            best_xy = min(methods, key=lambda m: m["Sxy"] if np.isfinite(m["Sxy"]) else np.inf)
            lines.append(f"Best planimetry: **{best_xy['name']}** (Sxy {best_xy['Sxy']:.4g} {unit}); "
                         f"best height: **{best_z['name']}** (Sz {best_z['Sz']:.4g} {unit}).")
            summary["headline"] = f"{len(methods)} method(s) with check points; best Sxy {best_xy['name']}, best Sz {best_z['name']}"
            data = {"methods": methods, "image": img, "unit": unit}
        else:
            lines.append("No stage of this run compared its results with check points.")
            summary["headline"] = "no check points in this run"
            data = {"methods": [], "image": None, "unit": unit}
        return StageResult(artefacts={"comparison": {"found": found, "methods": methods}}, summary=summary,
                           report="\n".join(lines), tables=tables, figures=figures, data=data)

    def log(self, result, rec, ctx):
        import rerun as rr

        d = result.data
        if d["image"] is not None:
            rec.log(f"{ctx.stage_id}/checkpoints_chart", rr.Image(d["image"][:, :, ::-1].copy()), static=True)
        for k in KEYS:
            vals = [m[k] for m in d["methods"]]
            if vals:
                rec.log(f"{ctx.stage_id}/rmse/{k}", rr.BarChart(np.nan_to_num(np.array(vals, float))), static=True)
        if d["methods"]:
            rec.log(f"{ctx.stage_id}/rmse/methods", rr.TextDocument("\n".join(
                f"{i}: {m['name']}" for i, m in enumerate(d["methods"]))), static=True)
