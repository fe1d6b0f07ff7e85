"""Source stage ``pmexport``: a PhotoModeler text export as a block, set up as DBAT's demos do
(``docs/pmexport.md``).  The block carries the ``dbat`` plugin's ``DbatInfo``, so ``dbat-report``
and ``dbat-export`` work on it as on a DBAT script."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from baarda.pipeline.api import Context, InputError, SourceStage, StageResult, option

from .pm_block import parse_estimate, pm_script, read_control
from .pm_reader import read_pmexport
from .reader import dbat_block
from .report import source_report, source_tables


@dataclass(frozen=True)
class PmExportOptions:
    path: Path | None = option(None, "the PhotoModeler text export, relative to the project file (required)")
    control: Path | None = option(None, "a DBAT control-point file (id,label,x,y,z[,σ…]; loadcpt's format); its "
                                        "points that are object points of the export (with an id above "
                                        "control_ids_above) become control, as DBAT's demos match them")
    control_ids_above: int | None = option(1000, "with a control file and no control section in the export: only "
                                                 "object points with a larger id are control (DBAT's demos: 1000)")
    focal: float | None = option(None, "initial camera constant (mm) with camera = 'default' (DBAT's demos: 7.3); "
                                       "none: the export's c", gt=0.0)
    camera: str = option("default", "initial camera: 'default' (focal, principal point at the format centre, no "
                                    "distortion; DBAT's demos) or 'loaded' (the export's camera as "
                                    "prob2dbatstruct converts it)")
    estimate: list[str] = option(["all", "not", "sk"], "the camera parameters estimated, in DBAT's words "
                                                       "(setcamest): cc, pp, px, py, as, sk, K, P, K1…P2, all; "
                                                       "'not' negates the rest")
    min_rays: int = option(2, "points with fewer rays are left out (DBAT's demos do not: its bundle then stops "
                                "with a structural rank deficiency, which the report names)", ge=1)
    image_size: list[int] | None = option(None, "[width, height] in pixels when the export does not give them")


class PmExportSource(SourceStage):
    summary = "Read a PhotoModeler text export (as DBAT's loadpm) with a DBAT control file: a DBAT-style block"
    reads = ()
    writes = ("block", "dbat_marks")
    Options = PmExportOptions

    def run(self, inputs, options: PmExportOptions, ctx: Context) -> StageResult:
        if options.path is None or not str(options.path) or str(options.path) == ".":
            raise InputError("the pmexport stage needs the option 'path' (PhotoModeler's text export)",
                             path=ctx.project_file, field="path")
        if options.image_size is not None and len(options.image_size) != 2:
            raise ctx.option_error("image_size is [width, height] in pixels", "image_size")
        try:
            est = parse_estimate(options.estimate, ctx.project_file)
        except InputError as e:
            raise ctx.option_error(e.message, "estimate") from None
        if options.camera not in ("default", "loaded"):
            raise ctx.option_error(f"camera is 'default' or 'loaded', got {options.camera!r}", "camera")
        pm = read_pmexport(ctx.resolve(options.path), image_size=options.image_size)
        control = read_control(ctx.resolve(options.control)) if options.control is not None else None
        script, info = pm_script(pm, control=control, focal=options.focal, camera=options.camera, estimate=est,
                                 min_rays=options.min_rays, control_ids_above=options.control_ids_above)
        block = dbat_block(script)
        pts = block.points
        summary = {**block.summary(), "export": str(pm.path), "name": pm.title,
                   "control": int((pts.role == "full").sum()), "tie": int((pts.role == "tie").sum()),
                   "dbat_counts": info, "dropped_points": len(block.meta["dbat"].dropped_points),
                   "estimated": [k for k, v in est.items() if v]}
        report = source_report(block)
        report += (f"\n\nAs DBAT counts it (every object point an unknown, whatever its rays): {info['observations']} "
                   f"observations, {info['unknowns']} unknowns ({info['unknowns_io']} IO, {info['unknowns_eo']} EO, "
                   f"{info['unknowns_op']} OP), redundancy {info['redundancy']}.")
        if info["undetermined"]:
            report += (" DBAT's bundle stops here with a structural rank deficiency: point(s) "
                       + ", ".join(f"{p} ({r} ray{'s' if r != 1 else ''})" for p, r in
                                   zip(info["undetermined"], info["rays_of_undetermined"]))
                       + f" cannot be determined; baarda leaves points with fewer than {options.min_rays} rays out.")
        if info["sigma_reset"]:
            report += " A mark had σ 0: every mark's σ is 1 px (as prob2dbatstruct)."
        if info["smart_shift"]:
            report += f" Smart-point ids were shifted by {info['smart_shift']} (as loadpm)."
        return StageResult(artefacts={"block": block, "dbat_marks": block}, summary=summary, report=report,
                           tables=source_tables(block), data={"block": block})
