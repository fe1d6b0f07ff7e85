"""Stage ``testfield-render``: photos of the simulated test field as PNG files (docs/rendered-pipeline.md).

The test field comes from the simulator (:mod:`baarda.pipeline.synthetic.testfield`) — either an earlier
``testfield`` stage's block or a simulation run here with the ``testfield`` option table.  Every
photo is rendered through the true camera with its systematic image errors
(:func:`baarda.plugins.testfield.drawing.render_targets`) and written as ``<photo id>.png``.  The stage
writes

* ``images`` (:class:`RenderedImages`): the files, their photo ids, camera, pixel pitch and size;
* ``block``: the simulated block **without image observations** (those are what a detection
  stage measures in the images), its camera carrying the pixel pitch, resolution and format, the
  photos with the approximate orientations of the paper's Table 1, the targets with their
  surveyed coordinates and roles, the pairs; ``meta["truth"]`` the simulator's truth and
  ``meta["render"]`` the true image position of every rendered target (pixels).
"""

from __future__ import annotations

from typing import Any, ClassVar

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baarda.pipeline.geometry import mm_from_pixels
from baarda.pipeline.api import Context, InputError, RowBound, Stage, StageResult, TableData, ValidationContext, option
from baarda.pipeline.options import parse_options
from baarda.pipeline.report import markdown_table
from baarda.pipeline.synthetic.testfield import TestFieldConfig

from .source import DISPLAY_PIXEL_MM, log_testfield, simulate_field
from .photos import (OBJECT_UNIT_MM, ImageSettings, RenderSettings, image_size, layout_block, partial_targets, render_photo,
                     target_radius_px, true_targets, truth_from_meta)

__all__ = ["TestFieldRender", "RenderOptions", "RenderedImages", "SIMULATION_DEFAULTS"]

SIMULATION_DEFAULTS = {"ap_model": "brown", "calibrate_iop": True}
"""Simulation options that differ from the ``testfield`` stage's defaults: the rendered block is
meant for self-calibration with the model of the simulator's systematic errors."""

NOT_FOR_IMAGES = {
    "sigma_image_um": "image noise is the rendered grey-level noise (sigma_noise) and the detector's own error",
    "blunders": "gross errors of comparator observations do not exist in rendered images",
}


@dataclass(frozen=True)
class RenderedImages:
    """The ``images`` artefact: rendered files and how to read them.

    paths, photo_ids, camera_ids : per image (absolute paths; photo id = file stem);
    pixel_mm : pixel pitch (mm); size : ``(W, H)`` pixels; convention : pixel origin
    (``"opencv"``: ``(0, 0)`` is the centre of the top-left pixel); targets : per photo id the true
    image position ``{point id: (u, v)}`` of every rendered target (ground truth of detection).
    """

    paths: tuple[str, ...]
    photo_ids: tuple[str, ...]
    camera_ids: tuple[str, ...]
    pixel_mm: float
    size: tuple[int, int]
    convention: str = "opencv"
    targets: dict = dataclasses.field(default_factory=dict)
    partial: dict = dataclasses.field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.paths)


@dataclass(frozen=True)
class RenderOptions(ImageSettings):
    RENAMED: ClassVar[dict[str, str]] = {"noise_sigma": "sigma_noise"}
    testfield: dict[str, Any] = option(
        {}, "options of the simulated test field, as the testfield stage takes them (case, block, with_ap_errors, "
            "sigma_control_mm, control_weighted, ap_model, calibrate_iop, seed, margin_mm, systematic_scale); "
            "here ap_model defaults to 'brown' and calibrate_iop to true. Not used when an earlier stage wrote a "
            "simulated block")
    target_radius_mm: float = option(5.0, "radius of the circular targets on the object, mm")
    folder: str = option("images", "folder for the PNG files, inside the run directory (a relative path that "
                                   "does not climb out of it)")

    def __post_init__(self):
        super().__post_init__()      # the bounds of every option
        bad = sorted(set(self.testfield) & set(NOT_FOR_IMAGES))
        if bad:
            raise ValueError(f"testfield.{bad[0]} does not apply to rendered photos: {NOT_FOR_IMAGES[bad[0]]}")
        self.simulation()            # validates the table

    def simulation(self, seed: int | None = None):
        """The ``testfield`` stage's options for the simulation (``seed`` used when none is given)."""
        raw = {**SIMULATION_DEFAULTS, **self.testfield}
        if raw.get("seed") is None and seed is not None:
            raw["seed"] = int(seed)
        try:
            return parse_options(TestFieldConfig, raw, prefix="testfield.")
        except InputError as e:
            raise ValueError(f"{e.field}: {e.message}" if e.field and e.field not in e.message else e.message) from None


def dry_detection_block(block, options: "RenderOptions"):
    """``block`` (a simulated test field) with one observation per photo and target whose disk
    reaches into the rendered image (in front of the camera, its true centre at most its image
    radius + 1 px outside the frame), at the target's true image position (mm): a detection in the
    rendered photos finds each target at most once per photo, and no target beyond these, so this
    block's rows bound the run's (:class:`RowBound`)."""
    from baarda.pipeline.geometry import pixels_from_mm
    from baarda.pipeline.model import Observations
    from baarda.pipeline.synthetic.testfield import project_truth

    truth = truth_from_meta(block.meta)
    W, H = image_size(block.cameras.format_mm[0], options.pixel_mm)
    radius = options.target_radius_mm / OBJECT_UNIT_MM[block.object_unit]
    xy, depth = project_truth(truth.XYZ, truth.X0, truth.opk, truth.c, truth.xp, truth.yp, truth.distortion)
    ph = block.photos.index_of([str(p) for p in truth.photo_ids])
    pt = block.points.index_of([str(q) for q in truth.point_ids])
    rows_k, rows_j = [], []
    for k in range(len(truth.photo_ids)):
        uv = pixels_from_mm(xy[k], (W, H), options.pixel_mm, "opencv")
        r = np.nan_to_num(target_radius_px(truth, k, radius, options.pixel_mm), nan=0.0) + 1.0
        inside = ((depth[k] > 0) & (uv[:, 0] >= -0.5 - r) & (uv[:, 0] <= W - 0.5 + r)
                  & (uv[:, 1] >= -0.5 - r) & (uv[:, 1] <= H - 0.5 + r))
        j = np.flatnonzero(inside)
        rows_k += [k] * len(j)
        rows_j += j.tolist()
    k, j = np.asarray(rows_k, int), np.asarray(rows_j, int)
    obs = Observations.make(ph[k], pt[j], xy[k, j].reshape(-1, 2))
    return block.replace(observations=obs)


class TestFieldRender(Stage):
    """Render the simulated test field's photos to PNG files; the block without observations."""

    __test__ = False

    summary = "Render the simulated test field's photos (targets through the distorted camera) to PNG files"
    reads = ("block?",)
    writes = ("images", "block")
    Options = RenderOptions
    paths = {"folder": "output"}           # written inside the run directory

    def validate_with(self, v: ValidationContext) -> RowBound | None:
        """``baarda validate``: the block the run's detection can measure, built dry (no image is
        rendered): the simulated test field (this stage's simulation, with the run's seed, or the
        earlier testfield stage's block) with one observation per photo and target in front of its
        camera — at least every row a detection in the rendered images can give, so that the
        redundancy checks of later stages (RRR's ``rho``) have a bound (:class:`RowBound`)."""
        ctx = v.ctx
        earlier = v.project.stages[:v.project.stages.index(v.spec)] if v.project is not None else []
        if v.block is not None:
            block = self._field(v.block, v.options, 0, ctx)
        elif any("block" in [w.rstrip("?") for w in s.cls.writes] for s in earlier):
            return None             # the run renders a block validate does not know: no bound
        else:
            sim_seed, _ = (int(s) for s in ctx.rng.integers(0, 2**62, size=2))
            block = self._field(None, v.options, sim_seed, ctx)
        return RowBound(dry_detection_block(block, v.options))

    def run(self, inputs, options: RenderOptions, ctx: Context) -> StageResult:
        import cv2

        sim_seed, noise_seed = (int(s) for s in ctx.rng.integers(0, 2**62, size=2))
        block = self._field(inputs.get("block"), options, sim_seed, ctx)
        truth = truth_from_meta(block.meta)
        if len(block.cameras) != 1:
            raise InputError(f"the simulated block has {len(block.cameras)} cameras; one is rendered",
                             path=ctx.project_file)
        settings = RenderSettings(pixel_mm=options.pixel_mm, supersample=options.supersample,
                                  sigma_noise=options.sigma_noise,
                                  target_radius=options.target_radius_mm / OBJECT_UNIT_MM[block.object_unit])
        size = image_size(block.cameras.format_mm[0], settings.pixel_mm)
        folder = self._folder(options, ctx)
        targets = true_targets(truth, settings.pixel_mm, size)
        partial = partial_targets(truth, targets, settings.target_radius, settings.pixel_mm, size)
        rng = np.random.default_rng(noise_seed) if settings.sigma_noise > 0 else None
        cam_id = str(block.cameras.ids[0])

        paths, shown, rows = [], [], []
        t0 = time.perf_counter()
        photo_ids = [str(p) for p in truth.photo_ids]
        for k, pid in enumerate(ctx.progress.track(photo_ids, what="photos")):
            img = render_photo(truth, k, settings, size, rng)
            path = folder / f"{pid}.png"
            if not cv2.imwrite(str(path), img):
                raise InputError(f"cannot write {path}", path=path, field="folder")
            paths.append(str(path.resolve()))
            shown.append(_display_image(img, block))
            radius = dict(zip(truth.point_ids.tolist(), target_radius_px(truth, k, settings.target_radius,
                                                                         settings.pixel_mm)))
            rows += [(pid, q, uv, float(radius[q]), q in partial[pid]) for q, uv in targets[pid].items()]
        seconds = time.perf_counter() - t0
        self._stale_files(folder, photo_ids, options, ctx)

        images = RenderedImages(tuple(paths), tuple(photo_ids), (cam_id,) * len(paths), settings.pixel_mm, size,
                                targets={p: {q: [float(a) for a in uv] for q, uv in t.items()}
                                         for p, t in targets.items()}, partial=partial)
        out = layout_block(block, settings.pixel_mm, size)
        meta = dict(out.meta)
        meta["render"] = {"pixel_mm": settings.pixel_mm, "size": list(size), "convention": "opencv",
                          "target_radius": settings.target_radius, "sigma_noise": settings.sigma_noise,
                          "supersample": settings.supersample, "files": dict(zip(photo_ids, paths)),
                          "targets": images.targets, "partial": partial}
        files = dict(zip(photo_ids, paths))
        out = out.replace(meta=meta, photos=out.photos.replace(
            image_path=[files.get(str(pid), "") for pid in out.photos.ids.tolist()]))
        radii = np.array([r[3] for r in rows])
        summary = {
            "headline": f"{len(paths)} photos of {size[0]} × {size[1]} px rendered, {len(rows)} targets "
                        f"(radius {radii.min():.1f}–{radii.max():.1f} px)",
            "photos": len(paths), "size_px": list(size), "pixel_mm": settings.pixel_mm,
            "format_mm": [size[0] * settings.pixel_mm, size[1] * settings.pixel_mm],
            "targets": len(rows), "targets_per_photo": {p: len(t) for p, t in targets.items()},
            "partial": sum(len(v) for v in partial.values()),
            "target_radius_px": [float(radii.min()), float(radii.max())], "sigma_noise": settings.sigma_noise,
            "folder": str(folder), "render_seconds": round(seconds, 3),
            "block": out.summary(),
        }
        report = _report(summary, folder, ctx, out, truth)
        tables = {"targets": _targets_table(rows, settings.pixel_mm, size), "camera_truth": _camera_table(truth),
                  "points": _points_table(out, truth)}
        figure = _contact_sheet(shown, photo_ids, targets, size, out)
        return StageResult(artefacts={"images": images, "block": out}, summary=summary, report=report,
                           tables=tables, figures={"photos": figure} if figure is not None else {},
                           data={"block": out, "truth": truth, "shown": shown, "targets": targets, "size": size})

    # -- pieces ----------------------------------------------------------------------------------
    def _field(self, block, options: RenderOptions, seed: int, ctx: Context):
        if block is not None:
            if "truth" not in block.meta or "testfield" not in block.meta:
                raise InputError("the input block is not a simulated test field (no meta['truth']); put the "
                                 "testfield stage before testfield-render, or none at all", path=ctx.project_file)
            if len(block.observations):
                ctx.warn(f"the input block's {len(block.observations)} simulated image observations are dropped: "
                         "the rendered images are measured instead")
            return block
        try:
            sim = options.simulation(seed)
        except ValueError as e:
            raise InputError(str(e), path=ctx.project_file, field="testfield") from None
        block, _ = simulate_field(sim, np.random.default_rng(sim.seed), project_file=ctx.project_file)
        if block.meta["testfield"]["geometry"]["min_rays"] < 2:
            ctx.warn(f"a target is seen in fewer than 2 photos (min {block.meta['testfield']['geometry']['min_rays']})")
        return block

    def _folder(self, options: RenderOptions, ctx: Context) -> Path:
        folder = ctx.output_path(options.folder or "images", "folder")
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise InputError(f"cannot create the image folder: {e}", path=folder, field="folder") from None
        return folder

    def _stale_files(self, folder: Path, photo_ids, options: RenderOptions, ctx: Context) -> None:
        """PNG files in the folder that this stage did not write (an earlier stage's): a warning, as a
        glob over the folder would pick them up; never removed."""
        mine = {f"{p}.png" for p in photo_ids}
        stale = sorted(p for p in folder.glob("*.png") if p.name not in mine)
        if stale:
            ctx.warn(f"{len(stale)} other PNG file(s) in {folder} ({', '.join(p.name for p in stale[:5])}"
                     f"{' …' if len(stale) > 5 else ''}): a glob over the folder would read them too")

    def log(self, result: StageResult, rec, ctx: Context) -> None:
        import rerun as rr

        d = result.data
        log_testfield(rec, d["block"], d["truth"])
        W, H = d["size"]
        for pid, img in zip(d["targets"], d["shown"]):
            s = img.shape[1] / W
            path = f"world/cameras/{pid}/image"
            rec.log(path, rr.Image(img), static=True)
            t = d["targets"][pid]
            if t:
                uv = (np.array(list(t.values())) + 0.5) * s - 0.5
                rec.log(f"{path}/true_targets", rr.Points2D(uv, labels=list(t), colors=[[255, 60, 40]],
                                                            radii=rr.Radius.ui_points(4.0)), static=True)


# ---------------------------------------------------------------------------------------------
def _display_image(img: np.ndarray, block) -> np.ndarray:
    """The image at the testfield recording's display pitch (0.1 mm), so it fills the camera's frustum."""
    import cv2

    w_mm, h_mm = block.cameras.format_mm[0]
    size = (int(round(w_mm / DISPLAY_PIXEL_MM)), int(round(h_mm / DISPLAY_PIXEL_MM)))
    return cv2.resize(img, size, interpolation=cv2.INTER_AREA)


def _contact_sheet(shown, photo_ids, targets, size, block, cols: int = 5, width: int = 585) -> bytes | None:
    """All photos side by side (each ``width`` pixels wide), true targets circled and labelled."""
    import cv2

    if not shown:
        return None
    W, _ = size
    tiles = []
    for pid, img in zip(photo_ids, shown):
        s_disp = img.shape[1] / W
        h = int(round(img.shape[0] * width / img.shape[1]))
        tile = cv2.cvtColor(cv2.resize(img, (width, h), interpolation=cv2.INTER_AREA), cv2.COLOR_GRAY2BGR)
        s = s_disp * width / img.shape[1]
        for q, uv in targets[pid].items():
            c = tuple(int(round(v)) for v in (np.asarray(uv) + 0.5) * s - 0.5)
            cv2.circle(tile, c, 9, (40, 60, 255), 1, cv2.LINE_AA)
            cv2.putText(tile, q, (c[0] + 10, c[1] - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (40, 200, 255), 1, cv2.LINE_AA)
        cv2.putText(tile, f"photo {pid}", (8, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1, cv2.LINE_AA)
        cv2.rectangle(tile, (0, 0), (tile.shape[1] - 1, tile.shape[0] - 1), (90, 90, 90), 1)
        tiles.append(tile)
    rows = []
    for r in range(0, len(tiles), cols):
        row = tiles[r:r + cols]
        row += [np.zeros_like(tiles[0])] * (cols - len(row))
        rows.append(np.hstack(row))
    ok, png = cv2.imencode(".png", np.vstack(rows))
    return png.tobytes() if ok else None


def _targets_table(rows, pixel_mm, size) -> TableData:
    uv = np.array([r[2] for r in rows], float).reshape(-1, 2)
    xy = mm_from_pixels(uv, size, pixel_mm, "opencv")
    return TableData({"photo": [r[0] for r in rows], "point": [r[1] for r in rows], "u_px": uv[:, 0], "v_px": uv[:, 1],
                      "x_mm": xy[:, 0], "y_mm": xy[:, 1], "radius_px": [r[3] for r in rows],
                      "partial": [r[4] for r in rows]},
                     "true image position of every rendered target centre (pixels, OpenCV convention; mm); "
                     "partial: the disk is cut by the image border")


def _camera_table(truth) -> TableData:
    from baarda.pipeline.camera import get_ap_model

    from baarda.pipeline.units import camera_parameter_units

    names = ["c", "xp", "yp"] + list(get_ap_model("brown").params)
    values = [truth.c, truth.xp, truth.yp] + [float(truth.distortion.get(n, 0.0)) for n in names[3:]]
    # one parameter per row, each in its own unit (as bundle_cameras): a `unit` column, not a suffix
    return TableData({"parameter": names, "value": values,
                      "unit": camera_parameter_units("brown", len(names) - 3)},
                     "the true camera: c, xp, yp (mm) and its systematic image errors as brown parameters "
                     "(K1 mm⁻² …); the unit of each row's value in `unit`")


def _points_table(block, truth) -> TableData:
    pts = block.points
    k = [list(truth.point_ids).index(q) for q in pts.ids]
    XYZ = truth.XYZ[k]
    from baarda.pipeline.units import length_suffix
    o = length_suffix(block.object_unit)
    return TableData({"point": pts.ids.tolist(), "role": pts.role.tolist(),
                      f"X{o}": pts.XYZ[:, 0], f"Y{o}": pts.XYZ[:, 1], f"Z{o}": pts.XYZ[:, 2],
                      f"X_true{o}": XYZ[:, 0], f"Y_true{o}": XYZ[:, 1], f"Z_true{o}": XYZ[:, 2]},
                     f"targets: surveyed (X, Y, Z, as in the block) and true coordinates ({block.object_unit}), role")


def _report(s, folder, ctx, block, truth) -> str:
    partial = block.meta["render"]["partial"]
    where = folder
    if ctx.run_dir is not None:
        try:
            where = folder.resolve().relative_to(Path(ctx.run_dir).resolve())
        except ValueError:
            pass
    lines = [
        f"Rendered **{s['photos']} photos** of {s['size_px'][0]} × {s['size_px'][1]} pixels "
        f"(pitch {s['pixel_mm'] * 1000:g} µm, format {s['format_mm'][0]:.3f} × {s['format_mm'][1]:.3f} mm) to "
        f"`{where}/` in {s['render_seconds']:.1f} s: {s['targets']} target images (radius "
        f"{s['target_radius_px'][0]:.1f}–{s['target_radius_px'][1]:.1f} px"
        + (f"; {s['partial']} cut by the image border" if s["partial"] else "")
        + f"), grey-level noise σ = {s['sigma_noise']:g}.",
        "",
        f"True camera: c = {truth.c:.4f} mm, xp = {truth.xp:+.4f} mm, yp = {truth.yp:+.4f} mm; systematic errors "
        + ", ".join(f"{k} = {v:.3g}" for k, v in truth.distortion.items()) + " (brown parameters, mm units).",
        "The block passed on has no image observations: the photos are to be measured "
        "(e.g. `opencv-targets` with `target = \"circles\"`).",
        "",
        markdown_table(["photo", "targets", "cut by the border"],
                       [[p, n, " ".join(partial[p]) or "–"] for p, n in s["targets_per_photo"].items()]),
    ]
    cfg = block.meta.get("testfield", {}).get("config", {})
    roles = ", ".join(f"{n} {r}" for r, n in s["block"]["roles"].items() if n)
    cam = block.cameras
    lines += ["", f"Simulated field: control case {cfg.get('case', '?')} ({roles}), "
                  f"control σ = {cfg.get('sigma_control_mm', float('nan')):g} mm "
                  f"({'weighted' if cfg.get('control_weighted', True) else 'fixed'}); camera "
                  f"'{cam.ids[0]}' starts at c = {cam.c[0]:g} mm, xp = yp = 0 with AP model '{cam.ap_model[0]}' "
                  f"(c, xp, yp {'free' if np.isinf(cam.sigma_iop[0]).all() else 'as given'}); approximate "
                  "orientations from the paper's Table 1 (ω = φ = κ = 0)."]
    return "\n".join(lines)
