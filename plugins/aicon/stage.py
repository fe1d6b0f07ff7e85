"""Source stage ``aicon``: an AICON 3D Studio export (``.ior .eor .obc .phc .scale``) as a block.

Parsing and conversion live in :mod:`.reader` (format and conventions: ``docs/aicon-format.md``);
this stage resolves the path, optionally disturbs the initial values (to show that the bundle
converges from far away), reports what was read and logs cameras and points.
"""

from __future__ import annotations

from typing import ClassVar

import dataclasses
from pathlib import Path

import numpy as np

from baarda.pipeline.api import Context, InputError, SourceStage, Stage, StageResult, TableData, option
from baarda.pipeline.units import length_suffix
from baarda.pipeline.report import markdown_table

from .reader import (AP_NAMES, VENDOR_FREE_AP, AiconExported, AiconInfo, aicon_block, perturb_initial_values,
                     read_aicon)


@dataclasses.dataclass(frozen=True)
class PerturbOptions:
    RENAMED: ClassVar[dict[str, str]] = {"position_sigma": "sigma_position", "angle_sigma_deg": "sigma_angle_deg", "c_sigma": "sigma_c",
                                           "point_sigma": "sigma_point"}
    sigma_position: float = option(0.0, "standard deviation added to each projection-centre coordinate "
                                        "(object unit, mm for AICON)")
    sigma_angle_deg: float = option(0.0, "standard deviation added to ω, φ, κ (degrees)")
    sigma_c: float = option(0.0, "standard deviation added to the principal distance (mm)")
    sigma_point: float = option(0.0, "standard deviation added to each object-point coordinate (mm)")
    zero_distortion: bool = option(False, "start every additional parameter at 0")
    # the sigmas' range (≥ 0, 0 = no perturbation) comes from their names (pipeline/options.py)


@dataclasses.dataclass(frozen=True)
class AiconOptions:
    RENAMED: ClassVar[dict[str, str]] = {"image_sigma_um": "sigma_image_um"}
    path: Path | None = option(None, "the export (required): its prefix (…/example for example.ior …), one "
                                     "of its files, or a directory holding one export; relative to the "
                                     "project file")
    perturb: PerturbOptions | None = option(None, "disturb the initial values: a table {sigma_position, "
                                                  "sigma_angle_deg, sigma_c, sigma_point, zero_distortion}")
    seed: int | None = option(None, "seed of the perturbation; default: the project's seed for this stage")
    sigma_image_um: float | None = option(None, "a-priori sigma of every image coordinate (µm); default: "
                                                "the .phc columns sx, sy")
    self_calibration: bool = option(True, "c, xp, yp and the parameters in free_ap free (true), or everything fixed")
    free_ap: list[str] = option(list(VENDOR_FREE_AP), "AICON parameters estimated with self_calibration (A1 A2 A3 "
                                                     "B1 B2 C1 C2); the others stay fixed at the exported values. "
                                                     "Default: A1 A2 B1 B2, what AICON estimated for the export")
    keep_unused: bool = option(False, "keep points without .obc coordinates (as unknown tie points) and "
                                      "points with fewer than two active measurements")

    def __post_init__(self):
        bad = [n for n in self.free_ap if n not in AP_NAMES]
        if bad:
            raise ValueError(f"free_ap: {bad[0]!r} is not an AICON parameter ({', '.join(AP_NAMES)})")


class AiconSource(SourceStage):
    summary = "Read an AICON 3D Studio export (.ior .eor .obc .phc .scale) into a block"
    reads = ()
    writes = ("block",)
    paths = {"path": "prefix"}            # an export's common prefix: <path>.ior, .eor, …
    Options = AiconOptions

    def run(self, inputs, options: AiconOptions, ctx: Context) -> StageResult:
        if options.path is None:
            raise InputError("the aicon stage needs the option 'path' (prefix of the export files)",
                             path=ctx.project_file, field="path")
        export = read_aicon(ctx.resolve(options.path))
        exported = aicon_block(export, sigma_image_um=options.sigma_image_um,
                               self_calibration=options.self_calibration, keep_unused=options.keep_unused,
                               free_ap=tuple(options.free_ap))
        block = exported
        if options.perturb is not None:
            rng = np.random.default_rng(options.seed) if options.seed is not None else ctx.rng
            p = options.perturb
            block = perturb_initial_values(block, rng, sigma_position=p.sigma_position,
                                           sigma_angle_deg=p.sigma_angle_deg, sigma_c=p.sigma_c,
                                           sigma_point=p.sigma_point, zero_distortion=p.zero_distortion)
            meta = dict(block.meta)
            meta["aicon"] = dataclasses.replace(
                meta["aicon"], perturbation=p,
                exported=AiconExported(X0=exported.photos.X0, opk=exported.photos.opk, c=exported.cameras.c,
                                       ap=exported.cameras.ap, XYZ=exported.points.XYZ))
            block = block.replace(meta=meta)
        a: AiconInfo = block.meta["aicon"]
        summary = {**block.summary(), "prefix": a.prefix,
                   "disabled_measurements": a.disabled_measurements,
                   "dropped_measurements": a.dropped_measurements,
                   "dropped_points": a.dropped_points,
                   "distances": len(block.scale_bars),
                   "perturbed": options.perturb is not None}
        return StageResult(artefacts={"block": block}, summary=summary,
                           report=_report(block, exported, options), tables=_tables(block),
                           data={"block": block})

    def log(self, result: StageResult, rec, ctx: Context) -> None:
        import rerun as rr

        from baarda.pipeline.geometry import rotation_from_opk_many

        block = result.data["block"]
        pts, ph, cam = block.points, block.photos, block.cameras
        ok = np.isfinite(pts.XYZ).all(axis=1)
        rec.log("world/points", rr.Points3D(pts.XYZ[ok], labels=pts.ids[ok].tolist(), colors=[150, 150, 150],
                                            radii=rr.Radius.ui_points(3.0)), static=True)
        bars = [(a, b) for a, b, *_ in block.scale_bars.rows()]
        if bars:
            idx = {p: k for k, p in enumerate(pts.ids)}
            rec.log("world/scale_bars", rr.LineStrips3D([[pts.XYZ[idx[a]], pts.XYZ[idx[b]]] for a, b in bars],
                                                        colors=[230, 180, 20]), static=True)
        R = rotation_from_opk_many(ph.opk)
        for k, pid in enumerate(ph.ids):
            c = ph.camera[k]
            f = cam.c[c] / cam.pixel_mm[c]
            W, H = cam.resolution[c]
            path = f"world/photos/{pid}"
            rec.log(path, rr.Transform3D(translation=-R[k] @ ph.X0[k], mat3x3=R[k],
                                         relation=rr.TransformRelation.ChildFromParent), static=True)
            rec.log(path, rr.Pinhole(image_from_camera=[[f, 0, (W - 1) / 2 + cam.xp[c] / cam.pixel_mm[c]],
                                                        [0, f, (H - 1) / 2 - cam.yp[c] / cam.pixel_mm[c]],
                                                        [0, 0, 1]],
                                     resolution=[W, H], camera_xyz=rr.ViewCoordinates.RUB,
                                     image_plane_distance=50.0), static=True)


def _report(block, exported, options) -> str:
    a: AiconInfo = block.meta["aicon"]
    s = block.summary()
    cam = exported.cameras
    lines = [f"Read `{a.prefix}.*`: {s['cameras']} camera(s), {s['photos']} images, {s['points']} object "
             f"points, {s['observations']} image measurements ({a.disabled_measurements} disabled in the "
             f"export → inactive), {len(block.scale_bars)} scale bar(s). Object unit mm.", ""]
    if a.dropped_points:
        lines += [f"Left out: {len(a.dropped_without_coordinates)} point(s) without .obc coordinates and "
                  f"{len(a.dropped_few_rays)} with fewer than two active measurements, with their "
                  f"{a.dropped_measurements} measurement(s) (option `keep_unused`).", ""]
    rows = []
    for k, cid in enumerate(cam.ids):
        rows.append([cid, f"{cam.c[k]:.5f}", f"{a.c_file[cid]:.5f}", f"{cam.xp[k]:.5f}", f"{cam.yp[k]:.5f}",
                     f"{a.r0[cid]:g}"] + [f"{v:.5e}" for v in exported.cameras.ap[k]])
    lines += [markdown_table(["camera", "c (baarda) = −c (AICON)", "c (AICON)", "xp", "yp", "r0", *AP_NAMES], rows), ""]
    for a_, b_, d, sg in block.scale_bars.rows():
        lines.append(f"Scale bar {a_}–{b_}: {d:.4f} ± {sg:.4f} mm.")
    if options.perturb is not None:
        p = options.perturb
        dX = np.linalg.norm(block.photos.X0 - exported.photos.X0, axis=1)
        dA = np.rad2deg(np.abs(block.photos.opk - exported.photos.opk)).max(axis=1)
        lines += ["", f"Initial values perturbed (σ: position {p.sigma_position:g} mm, angles "
                      f"{p.sigma_angle_deg:g}°, c {p.sigma_c:g} mm, points {p.sigma_point:g} mm"
                      f"{', distortion set to 0' if p.zero_distortion else ''}): projection centres moved by "
                      f"up to {dX.max():.1f} mm (RMS {np.sqrt(np.mean(dX ** 2)):.1f}), angles by up to "
                      f"{dA.max():.2f}°, c by {float(block.cameras.c[0] - exported.cameras.c[0]):+.3f} mm."]
    return "\n".join(lines)


def _tables(block) -> dict:
    ph = block.photos
    obs = block.observations
    o = length_suffix(block.object_unit)
    photos = TableData({
        "photo": ph.ids.tolist(), "camera": block.cameras.ids[ph.camera].tolist(),
        **{f"{a}0{o}": ph.X0[:, i] for i, a in enumerate("XYZ")},
        "omega_deg": np.rad2deg(ph.opk[:, 0]), "phi_deg": np.rad2deg(ph.opk[:, 1]),
        "kappa_deg": np.rad2deg(ph.opk[:, 2]),
        "measurements": np.bincount(obs.photo, minlength=len(ph)),
        "active": np.bincount(obs.photo, weights=obs.active, minlength=len(ph)).astype(int),
    }, f"images: initial exterior orientation ({block.object_unit}, degrees) and measurement counts")
    pts = block.points
    points = TableData({
        "point": pts.ids.tolist(), **{f"{a}{o}": pts.XYZ[:, i] for i, a in enumerate("XYZ")},
        "rays": np.bincount(obs.point, minlength=len(pts)),
        "active_rays": np.bincount(obs.point, weights=obs.active, minlength=len(pts)).astype(int),
    }, f"object points: initial coordinates ({block.object_unit}) and measurement counts", detail=True)
    return {"photos": photos, "points": points}
