"""Stages ``opensfm`` (source: OpenSfM/ODM ``reconstruction.json`` + ``tracks.csv`` → block) and
``opensfm-export`` (block → ``reconstruction.json`` + ``tracks.csv``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

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
    gcp: Path | None = option(None, "an ODM/OpenSfM gcp_list.txt: its targets become control points of the block "
                                    "(coordinates from its CRS into the reconstruction's frame at reference_lla)")
    gcp_crs: str | None = option(None, "override the gcp list's CRS line (EPSG:…, PROJ string, 'local': the "
                                       "targets are in the reconstruction's own frame)")
    gcp_sigma_mm: list[float] = option([20.0, 20.0, 30.0], "a-priori σ of the targets' E, N, U (mm)", ge=0.0)
    gcp_sigma_px: float = option(0.0, "a-priori σ of a target's pixel coordinate (0: sigma_px)", ge=0.0)
    gcp_check: list[str] = option([], "targets used as check points (adjusted as tie points, compared afterwards)")

    def __post_init__(self):
        if self.pixel_mm <= 0 or self.sigma_px <= 0:
            raise ValueError("pixel_mm and sigma_px must be > 0")
        if len(self.gcp_sigma_mm) != 3:
            raise ValueError(f"gcp_sigma_mm: expected 3 numbers [E, N, U], got {self.gcp_sigma_mm!r}")


class OpensfmSource(SourceStage):
    """Read an OpenSfM/ODM reconstruction as a block: cameras in mm with the brown AP model."""

    summary = "OpenSfM/ODM reconstruction.json (+ tracks.csv) → block (brown cameras, shots, tie points)"
    reads = ()
    writes = ("block",)
    paths = {"path": "input", "tracks": "input", "gcp": "input"}
    Options = OpensfmSourceOptions

    def run(self, inputs, options: OpensfmSourceOptions, ctx: Context) -> StageResult:
        if not str(options.path) or str(options.path) == ".":
            raise InputError("option 'path' (the reconstruction.json) is required", field="path",
                             path=ctx.project_file)
        path = ctx.resolve(options.path)
        tracks = ctx.resolve(options.tracks) if options.tracks is not None else None
        block, info = read_opensfm(
            path, tracks=tracks, pixel_mm=options.pixel_mm, sigma_px=options.sigma_px, intrinsics=options.intrinsics,
            which=options.reconstruction, gcp=ctx.resolve(options.gcp) if options.gcp is not None else None,
            gcp_crs=options.gcp_crs, gcp_sigma=np.asarray(options.gcp_sigma_mm, float) / 1000.0,
            gcp_check=tuple(options.gcp_check), gcp_sigma_px=options.gcp_sigma_px or None,
            gcp_where={"path": ctx.project_file, "crs_line": ctx.option_lines.get("gcp_crs"),
                       "check_line": ctx.option_lines.get("gcp_check")})
        for cid in info["inexact_cameras"]:
            ctx.warn(f"camera {cid}: focal_x ≠ focal_y with distortion is not exactly a brown camera "
                     "(docs/metashape-opensfm.md)")
        if info["tracks"] is None:
            ctx.warn("no tracks.csv: the block has points but no observations")
        if info["duplicate_observations"]:
            ctx.warn(f"{info['duplicate_observations']} repeated observation(s) of a point in one shot switched off")
        g = info.get("gcp")
        if g and g["images_not_shots"]:
            ctx.warn(f"{g['measurements'] - g['used_measurements']} gcp measurement(s) in image(s) that are not shots "
                     f"of the reconstruction left out: {', '.join(g['images_not_shots'][:5])}")
        tie = block.observations.active & (block.points.role[block.observations.point] == "tie")
        rep = _reprojection(block, tie)
        summary = {**block.summary(), "tracks": info["tracks"], "reconstructions": info["reconstructions"],
                   "projection_types": info["projection_types"], "reprojection": rep}
        if g:
            summary["gcp"] = g
        report = (f"Read the OpenSfM reconstruction `{path}`: {len(block.cameras)} camera(s), {len(block.photos)} "
                  f"shots, {len(block.points)} points, {len(block.observations)} observations"
                  + (f" from `{info['tracks']}`" if info["tracks"] else " (no tracks.csv)") + "."
                  + (f"  Reprojection error as read: mean {rep['mean_px']:.4f} px, RMS {rep['rms_px']:.4f} px."
                     if rep else "")
                  + (_gcp_text(g, block) if g else ""))
        return StageResult(artefacts={"block": block}, summary=summary, report=report, data=block)

    def log(self, result, rec, ctx) -> None:
        log_block(rec, result.data, root=f"{ctx.stage_id}/block")


def _reprojection(block, rows) -> dict | None:
    """Mean, RMS and largest reprojection error (px) of the observations ``rows`` (bool) as read."""
    if not rows.any():
        return None
    return reprojection_summary(block.replace(observations=block.observations.replace(active=rows)))


def _gcp_text(g: dict, block) -> str:
    """The report's paragraph on the gcp list's targets: counts, frame, and how far OpenSfM's
    reconstruction as read projects them from their measurements (control and check alike)."""
    text = (f"\n\nGround control from `{g['path']}` ({g['crs']}): {g['targets']} targets ({g['control']} control, "
            f"{g['check']} check), {g['used_measurements']} of {g['measurements']} measurements in shots of the "
            "reconstruction")
    if g["origin_lon_lat_h"]:
        o = g["origin_lon_lat_h"]
        text += (f"; coordinates turned into the reconstruction's frame (east, north, up at reference_lla: lon "
                 f"{o[0]:.8f}°, lat {o[1]:.8f}°, h {o[2]:.3f} m)")
    text += "."
    gcp_obs = block.observations.active & (block.points.role[block.observations.point] != "tie")
    if gcp_obs.any():
        r = _reprojection(block, gcp_obs)
        text += (f"  The targets' surveyed coordinates projected with OpenSfM's shots miss their measurements by "
                 f"RMS {r['rms_px']:.2f} px (largest {r['max_px']:.2f} px).")
    return text


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
