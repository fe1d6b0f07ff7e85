"""Stages ``opensfm`` (source: OpenSfM/ODM ``reconstruction.json`` + ``tracks.csv`` → block) and
``opensfm-export`` (block → ``reconstruction.json`` + ``tracks.csv``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from baarda.pipeline.adjustment import reprojection_summary

from baarda.pipeline.api import Context, InputError, SourceStage, StageResult, log_block, option
from baarda.pipeline.exporting import BlockExport
from baarda.pipeline.opensfm import read_opensfm, write_opensfm


@dataclass(frozen=True)
class OpensfmSourceOptions:
    path: Path = field(metadata={"doc": "the reconstruction.json (required), relative to the project file"})
    tracks: Path | None = option(None, "the tracks.csv with the image observations (default: tracks.csv beside "
                                       "the json when present)")
    reconstruction: int = option(0, "which reconstruction of the file (0: the first, the largest in OpenSfM)", ge=0)
    pixel_mm: float = option(0.001, "nominal pixel pitch, mm (OpenSfM has none): c = f_px · pixel_mm")
    sigma_px: float = option(1.0, "a-priori sigma of an image coordinate, pixels")
    intrinsics: Literal["opensfm", "fixed", "free"] = option(
        "opensfm", "unknown interior parameters: 'opensfm' as OpenSfM's bundle (focal and distortion; principal "
                   "point fixed), 'fixed' none, 'free' also the principal point")

    def __post_init__(self):
        if self.pixel_mm <= 0 or self.sigma_px <= 0:
            raise ValueError("pixel_mm and sigma_px must be > 0")


class OpensfmSource(SourceStage):
    """Read an OpenSfM/ODM reconstruction as a block: cameras in mm with the brown AP model."""

    summary = "OpenSfM/ODM reconstruction.json (+ tracks.csv) → block (brown cameras, shots, tie points)"
    reads = ()
    writes = ("block",)
    paths = {"path": "input", "tracks": "input"}
    Options = OpensfmSourceOptions

    def run(self, inputs, options: OpensfmSourceOptions, ctx: Context) -> StageResult:
        if not str(options.path) or str(options.path) == ".":
            raise InputError("option 'path' (the reconstruction.json) is required", field="path",
                             path=ctx.project_file)
        path = ctx.resolve(options.path)
        tracks = ctx.resolve(options.tracks) if options.tracks is not None else None
        block, info = read_opensfm(path, tracks=tracks, pixel_mm=options.pixel_mm, sigma_px=options.sigma_px,
                                   intrinsics=options.intrinsics, which=options.reconstruction)
        for cid in info["inexact_cameras"]:
            ctx.warn(f"camera {cid}: focal_x ≠ focal_y with distortion is not exactly a brown camera "
                     "(docs/metashape-opensfm.md)")
        if info["tracks"] is None:
            ctx.warn("no tracks.csv: the block has points but no observations")
        if info["duplicate_observations"]:
            ctx.warn(f"{info['duplicate_observations']} repeated observation(s) of a point in one shot switched off")
        rep = reprojection_summary(block) if len(block.observations) else None
        summary = {**block.summary(), "tracks": info["tracks"], "reconstructions": info["reconstructions"],
                   "projection_types": info["projection_types"], "reprojection": rep}
        report = (f"Read the OpenSfM reconstruction `{path}`: {len(block.cameras)} camera(s), {len(block.photos)} "
                  f"shots, {len(block.points)} points, {len(block.observations)} observations"
                  + (f" from `{info['tracks']}`" if info["tracks"] else " (no tracks.csv)") + "."
                  + (f"  Reprojection error as read: mean {rep['mean_px']:.4f} px, RMS {rep['rms_px']:.4f} px."
                     if rep else ""))
        return StageResult(artefacts={"block": block}, summary=summary, report=report, data=block)

    def log(self, result, rec, ctx) -> None:
        log_block(rec, result.data, root=f"{ctx.stage_id}/block")


@dataclass(frozen=True)
class OpensfmExportOptions:
    path: Path = field(metadata={"doc": "output folder for reconstruction.json and tracks.csv (relative paths: "
                                        "inside the run directory) (required)"})


class OpensfmExport(BlockExport):
    """Write the block (adjusted, if a bundle ran before) as an OpenSfM reconstruction."""

    summary = "block (adjusted if a bundle of it ran) → OpenSfM reconstruction.json + tracks.csv"
    Options = OpensfmExportOptions
    path_is = "the output folder"
    writer = staticmethod(write_opensfm)
    headline_format = ("OpenSfM reconstruction {path}/ (block {which}): {cameras} camera(s), {shots} shots, "
                       "{points} points, {observations} observations")
