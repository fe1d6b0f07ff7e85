"""Stages ``metashape`` (source: Metashape camera XML → block) and ``metashape-export`` (block → XML)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from baarda.pipeline.api import Context, InputError, SourceStage, StageResult, log_block, option
from baarda.pipeline.exporting import BlockExport
from baarda.pipeline.metashape import read_metashape, write_metashape


@dataclass(frozen=True)
class MetashapeSourceOptions:
    path: Path = field(metadata={"doc": "the Metashape camera export (XML) (required), relative to the project file"})
    pixel_mm: float = option(0.001, "pixel pitch, mm, for sensors without a pixel_width property")
    sigma_px: float = option(1.0, "a-priori sigma of a marker projection, pixels")
    sigma_control_mm: list[float] = option([10.0, 10.0, 10.0], "a-priori σ of the markers' reference X, Y, Z (mm)")
    intrinsics: Literal["metashape", "fixed", "free"] = option(
        "metashape", "unknown interior parameters: 'metashape' f and the terms the file calibrates, 'fixed' none, "
                     "'free' all brown terms and the principal point")

    ap_model: Literal["brown", "metashape"] = option(
        "brown", "'brown' (k4, p3, p4, and b1/b2 with distortion refused by name) or 'metashape' (every "
                 "term of Metashape's model, AP model 'metashape')")

    def __post_init__(self):
        if self.pixel_mm <= 0 or self.sigma_px <= 0:
            raise ValueError("pixel_mm and sigma_px must be > 0")
        if len(self.sigma_control_mm) != 3:
            raise ValueError(f"sigma_control_mm: expected 3 numbers, got {self.sigma_control_mm!r}")


class MetashapeSource(SourceStage):
    """Read a Metashape camera export as a block: brown cameras, aligned cameras, markers."""

    summary = "Agisoft Metashape camera XML (sensors, cameras, chunk transform, markers) → block"
    reads = ()
    writes = ("block",)
    paths = {"path": "input"}
    Options = MetashapeSourceOptions

    def run(self, inputs, options: MetashapeSourceOptions, ctx: Context) -> StageResult:
        if not str(options.path) or str(options.path) == ".":
            raise InputError("option 'path' (the Metashape XML) is required", field="path", path=ctx.project_file)
        path = ctx.resolve(options.path)
        block, info = read_metashape(path, pixel_mm=options.pixel_mm, sigma_px=options.sigma_px,
                                     sigma_control_mm=options.sigma_control_mm, intrinsics=options.intrinsics,
                                     ap_model=options.ap_model)
        if info["unaligned_cameras"]:
            ctx.warn(f"{info['unaligned_cameras']} camera(s) without a transform (not aligned) left out")
        summary = {**block.summary(), "crs": info["crs"], "local_crs": info["local_crs"]}
        report = (f"Read the Metashape camera export `{path}`: {len(block.cameras)} sensor(s), {len(block.photos)} "
                  f"aligned cameras, {len(block.points)} markers ({int((block.points.role == 'full').sum())} control), "
                  f"{len(block.observations)} marker projections.")
        return StageResult(artefacts={"block": block}, summary=summary, report=report, data=block)

    def log(self, result, rec, ctx) -> None:
        log_block(rec, result.data, root=f"{ctx.stage_id}/block")


@dataclass(frozen=True)
class MetashapeExportOptions:
    path: Path = field(metadata={"doc": "the XML file to write (relative paths: inside the run directory) (required)"})


class MetashapeExport(BlockExport):
    """Write the block (adjusted, if a bundle ran before) as a Metashape camera XML."""

    summary = "block (adjusted if a bundle of it ran) → Metashape camera XML"
    Options = MetashapeExportOptions
    path_is = "the output file"
    writer = staticmethod(write_metashape)
    headline_format = ("Metashape XML {path} (block {which}): {sensors} sensor(s), {cameras} cameras, {markers} "
                       "markers, {observations} projections")
