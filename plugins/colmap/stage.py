"""Stages ``colmap`` (source: COLMAP model → block) and ``colmap-export`` (block → COLMAP model)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from baarda.pipeline.adjustment import reprojection_summary
from baarda.pipeline.api import (Context, InputError, SourceStage, Stage, StageResult, log_block, option,
                                 read_colmap, write_colmap)
from baarda.pipeline.camera.convert import COLMAP_PARAMS
from baarda.pipeline.exporting import block_to_export   # one choice of the block for every export


@dataclass(frozen=True)
class ColmapSourceOptions:
    path: Path = field(metadata={"doc": "COLMAP model folder (cameras, images, points3D as .bin or .txt; "
                                        "rigs/frames optional), relative to the project file (required)"})
    pixel_mm: float = option(0.001, "nominal pixel pitch, mm (COLMAP has none): c = f_px · pixel_mm; the "
                                    "default 1 µm makes µm in reports read as pixels")
    sensor_width_mm: float = option(0.0, "sensor width, mm; when > 0 the pitch of each camera is "
                                         "sensor_width_mm / width and pixel_mm is ignored")
    sigma_px: float = option(1.0, "a-priori sigma of an image coordinate, pixels")
    intrinsics: Literal["colmap", "fixed", "free"] = option(
        "colmap", "which interior parameters are unknowns: 'colmap' as COLMAP's bundle (c and the model's "
                  "distortion terms; principal point fixed), 'fixed' none, 'free' also the principal point")
    object_unit: Literal["m", "mm", "cm", "ft"] = option("m", "unit of the model's coordinates")

    def __post_init__(self):
        if self.pixel_mm <= 0 or self.sigma_px <= 0 or self.sensor_width_mm < 0:
            raise ValueError("pixel_mm and sigma_px must be > 0, sensor_width_mm >= 0")


class ColmapSource(SourceStage):
    """Read a COLMAP model (binary or text) as a block: cameras in mm with the brown AP model (pinhole models) or
    the ray model of the same name (fisheye, FOV, EUCM, division, equirectangular)."""

    summary = "COLMAP model (binary or text) → block (cameras in mm, brown distortion, tie points)"
    reads = ()
    writes = ("block",)
    Options = ColmapSourceOptions

    def run(self, inputs, options: ColmapSourceOptions, ctx: Context) -> StageResult:
        if not str(options.path) or str(options.path) == ".":
            raise InputError("option 'path' (the COLMAP model folder) is required", field="path",
                             path=ctx.project_file)
        path = ctx.resolve(options.path)
        block, info = read_colmap(path, pixel_mm=options.pixel_mm, sensor_width_mm=options.sensor_width_mm,
                                  sigma_px=options.sigma_px, intrinsics=options.intrinsics,
                                  object_unit=options.object_unit)
        for cid in info["inexact_cameras"]:
            ctx.warn(f"camera {cid}: OPENCV with fx ≠ fy and distortion is not exactly a brown camera "
                     "(x differs by (fx/fy − 1)·distortion); see docs/colmap.md")
        if info["duplicate_observations"]:
            ctx.warn(f"{info['duplicate_observations']} observation(s) of a point already measured in the same "
                     "image switched off (COLMAP keeps both; baarda one per point and photo)")
        if info["unregistered_images"]:
            ctx.warn(f"{len(info['unregistered_images'])} image(s) without pose skipped")
        rep = reprojection_summary(block)
        models = sorted(set(block.meta["colmap"]["camera_models"]))
        summary = {**block.summary(), "format": info["format"], "camera_models": models,
                   "reprojection": rep, "pixel_mm": sorted(set(block.cameras.pixel_mm.tolist()))}
        report = (f"Read the {info['format']} COLMAP model `{path}`: {len(block.cameras)} camera(s) "
                  f"({', '.join(models)}), {len(block.photos)} images, {len(block.points)} points, "
                  f"{len(block.observations)} observations.  Reprojection error of the model as read: "
                  f"mean {rep['mean_px']:.4f} px, RMS {rep['rms_px']:.4f} px.  Pixel pitch "
                  f"{', '.join(f'{p:g}' for p in summary['pixel_mm'])} mm; cameras use the brown AP model "
                  f"(docs/colmap.md).")
        if "rigs" in info:             # COLMAP ≥ 3.12 rigs of more than one camera (docs/rigs.md)
            summary["rigs"] = info["rigs"]
            report += (f"  Rigs: {info['rigs']['sensors']} cameras in {len(set(block.rigs.sensors.rig.tolist()))} "
                       f"rig(s), {info['rigs']['frames']} frames; the bundle estimates one pose per frame and each "
                       "camera's pose in its rig (docs/rigs.md).")
        return StageResult(artefacts={"block": block}, summary=summary, report=report, data=block)

    def log(self, result, rec, ctx) -> None:
        log_block(rec, result.data, root=f"{ctx.stage_id}/block")


@dataclass(frozen=True)
class ColmapExportOptions:
    path: Path = field(metadata={"doc": "output folder for the COLMAP model (relative paths: inside the run "
                                        "directory) (required)"})
    format: Literal["binary", "text"] = option("binary", "COLMAP file format")
    camera_model: str = option("keep", "'keep' (the model a camera had when read from COLMAP, when it still "
                                       "holds the parameters), 'auto' (the simplest exact model) or one of "
                                       + ", ".join(COLMAP_PARAMS))

    def __post_init__(self):
        if self.camera_model not in ("keep", "auto", *COLMAP_PARAMS):
            raise ValueError(f"camera_model must be 'keep', 'auto' or one of {', '.join(COLMAP_PARAMS)}")


class ColmapExport(Stage):
    """Write the block (adjusted, if a bundle ran before) as a COLMAP model."""

    summary = "block (adjusted if a bundle of it ran) → COLMAP model folder (text or binary)"
    reads = ("block", "bundle?")
    writes = ()
    paths = {"path": "output"}            # the folder written (not checked by validate)
    outputs = ()                          # no table or figure: every other name is free for path
    Options = ColmapExportOptions

    def run(self, inputs, options: ColmapExportOptions, ctx: Context) -> StageResult:
        if not str(options.path) or str(options.path) == ".":
            raise InputError("option 'path' (the output folder) is required", field="path", path=ctx.project_file)
        out = ctx.output_path(options.path, "path")
        block, which = block_to_export(inputs["block"], inputs.get("bundle"))
        info = write_colmap(block, out, fmt=options.format, camera_model=options.camera_model)
        info["block"] = which
        if info["skipped_photos"]:
            ctx.warn(f"{len(info['skipped_photos'])} photo(s) without orientation not written")
        report = (f"Wrote the block ({which}) as a {options.format} COLMAP model to `{out}`: {info['cameras']} camera(s) "
                  f"({', '.join(sorted(set(info['camera_models'])))}), {info['images']} images, "
                  f"{info['points3D']} points, {info['observations']} observations.")
        info["headline"] = (f"{options.format} COLMAP model {options.path}/ (block {which}): {info['cameras']} "
                            f"camera(s) ({', '.join(sorted(set(info['camera_models'])))}), {info['images']} images, "
                            f"{info['points3D']} points, {info['observations']} observations"
                            + (f"; {len(info['skipped_photos'])} photo(s) without orientation left out"
                               if info["skipped_photos"] else ""))
        info["camera_models"] = sorted(set(info["camera_models"]))     # the models used, not one per camera
        return StageResult(summary=info, report=report)

