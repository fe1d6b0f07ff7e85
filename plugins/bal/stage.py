"""Source stages ``bal`` (BAL text problems) and ``libmv`` (libmv/Blender binary problems)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from baarda.pipeline.api import Context, InputError, SourceStage, Stage, StageResult, log_block, option

from baarda.pipeline.adjustment import reprojection_summary

from .bal import behind_camera, block_from_bal, read_bal
from .libmv import block_from_libmv, read_libmv

_PITCH_DOC = ("pixel pitch, mm (the files have none): c = f_px · pixel_mm; the default 1 µm makes µm in "
              "reports read as pixels")


def _check(opts):
    if opts.pixel_mm <= 0 or opts.sigma_px <= 0:
        raise ValueError("pixel_mm and sigma_px must be > 0")


def _path(opts, ctx: Context) -> Path:
    if not str(opts.path) or str(opts.path) == ".":
        raise InputError("option 'path' (the problem file) is required", field="path", path=ctx.project_file)
    return ctx.resolve(opts.path)


def _result(block, path, kind, extra_report="", **extra) -> StageResult:
    rep = reprojection_summary(block)
    summary = {**block.summary(), "reprojection": rep, **extra}
    report = (f"Read the {kind} problem `{path}`: {len(block.cameras)} camera(s), {len(block.photos)} photos, "
              f"{len(block.points)} points, {len(block.observations)} observations.  Reprojection error of the "
              f"values in the file: mean {rep['mean_px']:.4f} px, RMS {rep['rms_px']:.4f} px, max "
              f"{rep['max_px']:.3f} px.{extra_report}")
    return StageResult(artefacts={"block": block}, summary=summary, report=report, data=block)


@dataclass(frozen=True)
class BalOptions:
    path: Path = field(metadata={"doc": "BAL problem file (text), relative to the project file (required)"})
    pixel_mm: float = option(0.001, _PITCH_DOC)
    sigma_px: float = option(1.0, "a-priori sigma of an image coordinate, pixels")
    intrinsics: Literal["free", "fixed"] = option("free", "'free': c, K1, K2 of every camera are unknowns (as BAL "
                                                          "solves them); 'fixed': held")
    object_unit: Literal["m", "mm", "cm", "ft"] = option("m", "unit of the problem's coordinates")
    on_behind: Literal["warn", "skip"] = option(
        "warn", "observations of points behind their camera: 'warn' keeps them (fitted as measured) with a warning; "
                "'skip' switches them off, as Ceres and COLMAP give them no residual (for a like-for-like cross-check)")

    __post_init__ = _check


class BalSource(SourceStage):
    """Read a BAL problem: one camera (f, k1, k2 as c, K1, K2 of brown) and one photo per BAL camera."""

    summary = "BAL problem (text) → block (one brown camera per BAL camera)"
    reads = ()
    writes = ("block",)
    Options = BalOptions

    def run(self, inputs, options: BalOptions, ctx: Context) -> StageResult:
        path = _path(options, ctx)
        problem = read_bal(path)
        block = block_from_bal(problem, pixel_mm=options.pixel_mm, sigma_px=options.sigma_px,
                               intrinsics=options.intrinsics, object_unit=options.object_unit)
        behind = behind_camera(problem)
        extra = ""
        if behind.any():
            n = int(behind.sum())
            if options.on_behind == "skip":
                block = block.replace(observations=block.observations.replace(active=~behind))
                extra = f"  {n} observation(s) of points behind their camera switched off (on_behind = 'skip')."
            else:
                ctx.warnings.append(f"{n} observation(s) of points behind their camera are kept and fitted; Ceres and "
                                    "COLMAP give them no residual (on_behind = 'skip' switches them off)")
        return _result(block, path, "BAL", extra, behind_camera=int(behind.sum()))

    def log(self, result, rec, ctx) -> None:
        log_block(rec, result.data, root=f"{ctx.stage_id}/block")


@dataclass(frozen=True)
class LibmvOptions:
    path: Path = field(metadata={"doc": "libmv problem file (binary), relative to the project file (required)"})
    pixel_mm: float = option(0.001, _PITCH_DOC)
    sigma_px: float = option(1.0, "a-priori sigma of an image coordinate, pixels")
    resolution: list[int] = option([], "image width and height in pixels; default: twice the principal point")
    intrinsics: Literal["free", "fixed"] = option("free", "'free': c, K1, K2 unknowns (as libmv refines f, k1, "
                                                          "k2); 'fixed': held")
    object_unit: Literal["m", "mm", "cm", "ft"] = option("m", "unit of the problem's coordinates")

    def __post_init__(self):
        _check(self)
        if self.resolution and (len(self.resolution) != 2 or min(self.resolution) <= 0):
            raise ValueError("resolution must be [width, height] in pixels")


class LibmvSource(SourceStage):
    """Read a libmv camera-tracking problem: one shared brown camera, one photo per libmv camera."""

    summary = "libmv/Blender tracking problem (binary) → block (one shared brown camera)"
    reads = ()
    writes = ("block",)
    Options = LibmvOptions

    def run(self, inputs, options: LibmvOptions, ctx: Context) -> StageResult:
        path = _path(options, ctx)
        block, info = block_from_libmv(read_libmv(path), pixel_mm=options.pixel_mm, sigma_px=options.sigma_px,
                                       resolution=tuple(options.resolution) or None,
                                       intrinsics=options.intrinsics, object_unit=options.object_unit)
        if info["dropped_markers"]:
            ctx.warn(f"{info['dropped_markers']} marker(s) of images or tracks without a camera/point dropped")
        w, h = info["resolution"]
        return _result(block, path, "libmv", f"  Image size taken as {w} × {h} px.", **info)

    def log(self, result, rec, ctx) -> None:
        log_block(rec, result.data, root=f"{ctx.stage_id}/block")
