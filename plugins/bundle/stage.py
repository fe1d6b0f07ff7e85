"""Stage ``bundle``: self-calibrating bundle block adjustment (see docs/bundle.md).

The stage parses its options (:class:`~baarda.pipeline.adjustment.BundleConfig`, nested tables ``solver``,
``tests``, ``robust``, ``variance_components``, ``ap_selection``, ``output``), runs the workflow
:func:`baarda.pipeline.adjustment.adjust_block` (docs/library.md), and writes what its report holds:
report text, tables and summary (:mod:`.report`), figures and the recording.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from baarda.pipeline.api import (AdjustmentArtefact, AdjustmentError, Block, BundleConfig, Context, InputError,
                                 ValidationContext,
                                 StageResult, TableData, adjust, attach_rigs)
from baarda.pipeline.adjustment import EO_NAMES, release_freed
from baarda.pipeline.units import length_suffix, object_unit_text
from baarda.pipeline.camera import get_ap_model
from baarda.pipeline.tables import write_table

from . import external as bundle_external
from . import report as bundle_report

OPTION_FIELDS = {f.name for f in dataclasses.fields(BundleConfig)} | {"fix/free/sigma"}
"""The names an :class:`InputError` of :func:`baarda.pipeline.api.adjust` may carry for an option (not for the block's data)."""


class BundleAdjustment:
    summary = "Self-calibrating bundle block adjustment: datum, APs, precision, reliability, data snooping"
    reads = ("block",)
    writes = ("bundle", "adjustment", "block")
    Options = BundleConfig          # the stage's option table is the library's config (one schema)

    keeps_rows = True               # its block: the observations it read, some flagged or inactive

    def validate_with(self, v: ValidationContext) -> None:
        """``baarda validate``: the options that name points (datum_points, distances), cameras
        (ap_models) or parameters (fix, free, sigma) must name those of the block the sources read."""
        from baarda.pipeline.adjustment import bundle_settings, configure_block

        if v.block is None:
            return
        options, ctx = v.options, v.ctx
        block = with_rigs(v.block, options, ctx)
        try:
            bundle_settings(options, configure_block(block, options))
        except InputError as e:
            if e.path is None and str(e.field).split(".")[0] in OPTION_FIELDS:
                field = e.field
                if field == "fix/free/sigma":       # the one of them the project sets
                    field = next((k for k in ("fix", "free", "sigma") if k in ctx.option_lines), field)
                raise ctx.option_error(e.message, field) from None
            raise

    def run(self, inputs, options: BundleConfig, ctx: Context) -> StageResult:
        from .progress import iteration_progress

        with iteration_progress(ctx, options.solver.max_iter) as work:
            block = with_rigs(inputs["block"], options, ctx)
            try:
                rep = adjust(block, options, progress=ctx.progress.message, threads=ctx.threads)
            except AdjustmentError as e:
                _save_state(e, getattr(e, "block", block), ctx)
                raise
            except InputError as e:
                if e.path is None and str(e.field).split(".")[0] in OPTION_FIELDS:   # an option that does not
                    field = e.field                                                  # fit the block: file, line
                    if field == "fix/free/sigma":       # the one of them the project sets
                        field = next((k for k in ("fix", "free", "sigma") if k in ctx.option_lines), field)
                    raise ctx.option_error(e.message, field) from None
                raise
            for w in rep.warnings:
                ctx.warn(w)
            res = rep.result
            summary, tables = bundle_report.summary(rep), bundle_report.tables(rep)
            text = bundle_report.report_text(rep, work, summary.get("protocol"))
        artefacts = {"bundle": res, "block": rep.output_block, "adjustment": None}
        if res.snapshot is not None:
            artefacts["adjustment"] = AdjustmentArtefact("bundle", res.snapshot, res, res.obs_rows(),
                                                         linearise=bundle_external.linearisation(res))
        release_freed()              # the report's and tables' temporaries back to the system before the outputs
        return StageResult(artefacts=artefacts, summary=summary, report=text, tables=tables,
                           data={"report": rep, "result": res, "decision": rep.decision, "options": options})

    def plots(self, result: StageResult, ctx: Context) -> dict:
        """Figures for report.html (drawn by the engine; see plugins/bundle/figures.py)."""
        from .figures import bundle_figures

        return bundle_figures(result.data["result"], result.data["decision"],
                              getattr(result.data.get("report"), "eccentricity", None))

    def log(self, result: StageResult, rec, ctx: Context) -> None:
        from .rrlog import log_bundle

        release_freed()              # the figures' freed pages back before the recording's buffers
        log_bundle(rec, result.data["report"], result.report)


# ---------------------------------------------------------------------------------------------
def with_rigs(block: Block, options: BundleConfig, ctx: Context) -> Block:
    """The block with the rigs of the option table ``rig`` (rig table, frame table or frame names,
    docs/rigs.md); the block unchanged without ``rig.table``."""
    rc = options.rig
    if not rc.table:
        return block
    table = ctx.resolve(rc.table)
    frames = ctx.resolve(rc.frames) if rc.frames else None
    try:
        return attach_rigs(block, table, frames=frames, frames_from_name=rc.frames_from_name)
    except InputError as e:
        if e.path is None:
            raise ctx.option_error(e.message, e.field or "rig") from None
        raise


def _save_state(err: AdjustmentError, block: Block, ctx: Context) -> None:
    """Write the last iterate an :class:`AdjustmentError` carries into the run directory
    (``<stage>_last_eo.csv``, ``_last_points.csv``, ``_last_cameras.csv``, each also as ``.parquet``) and
    raise the error again
    with their names.  Returns without doing anything when there is no state or no run directory."""
    st = getattr(err, "state", None)
    if st is None or ctx.run_dir is None:
        return
    tables = _state_tables(st, block)
    names = []
    for name, table in tables.items():
        names.append(write_table(ctx.run_dir, f"{ctx.stage_id}_last_{name}", table, stage=ctx.stage_id)["csv"])
    new = AdjustmentError(f"{err} — the last state is saved in {ctx.run_dir}: {', '.join(names)}", state=st,
                          history=err.history)
    raise new from err


def _state_tables(st, block: Block) -> dict:
    """Exterior orientations (angles in degrees), object points and camera parameters of a state."""
    ph, pts, cams = block.photos, block.points, block.cameras
    eo = {"photo": ph.ids.tolist(), "camera": cams.ids[ph.camera].tolist()}
    ou = object_unit_text(block)
    o = length_suffix(ou)
    for t, n in enumerate(EO_NAMES):
        eo[n + (o if t < 3 else "_deg")] = st.X0[:, t] if t < 3 else np.degrees(st.opk[:, t - 3])
    rows = [(str(cams.ids[j]), name, float(st.cam_params[j, t]))
            for j in range(len(cams))
            for t, name in enumerate(["c", "xp", "yp"] + list(get_ap_model(cams.ap_model[j]).params))]
    return {
        "eo": TableData(eo, "exterior orientation of the last iterate (angles in degrees)"),
        "points": TableData({"point": pts.ids.tolist(), "role": pts.role.tolist(), 'X' + o: st.XYZ[:, 0],
                             "Y" + o: st.XYZ[:, 1], "Z" + o: st.XYZ[:, 2]},
                            f"object points of the last iterate ({ou})"),
        "cameras": TableData({"camera": [r[0] for r in rows], "parameter": [r[1] for r in rows],
                              "value": [r[2] for r in rows]}, "camera parameters of the last iterate"),
    }


