"""Source stage ``testfield``: the simulated test field of paper 001 as a block.

Numerics in :mod:`baarda.pipeline.synthetic.testfield`, whose :class:`TestFieldConfig` is the stage's
option table; :func:`simulate_field` runs
:func:`~baarda.pipeline.synthetic.testfield.simulate_testfield` (the stage and ``testfield-render`` call it);
writes the geometry summary and logs cameras and targets to the recording.
"""

from __future__ import annotations

import numpy as np

from baarda.pipeline.api import Context, InputError, SourceStage, Stage, StageResult, TableData, role_colors
from baarda.pipeline.geometry import rotation_from_opk_many
from baarda.pipeline.report import markdown_table

from baarda.pipeline.synthetic.testfield import (TestFieldConfig, constraint_count, control_configuration,
                                                degrees_of_freedom, simulate_testfield)


def simulate_field(config: TestFieldConfig, rng: np.random.Generator, project_file=None):
    """``(block, truth)`` of the test field ``config`` describes (the ``testfield`` stage's work,
    also the ``testfield-render`` stage's when it has no input block).  A blunder naming an
    observation that does not exist is an :class:`InputError` naming ``project_file``."""
    try:
        return simulate_testfield(config, rng)
    except ValueError as e:
        field = "displacements" if str(e).startswith("displacement") else "blunders"
        raise InputError(str(e), path=project_file, field=field) from None


class TestFieldSource(SourceStage):
    __test__ = False

    summary = "Simulate the test field of paper 001 (P31, 2 strips × 5 photos or the 4 m pair) as a block"
    reads = ()
    writes = ("block",)
    Options = TestFieldConfig             # the simulator's configuration is the option table

    def run(self, inputs, options: TestFieldConfig, ctx: Context) -> StageResult:
        rng = np.random.default_rng(options.seed) if options.seed is not None else ctx.rng
        block, truth = simulate_field(options, rng, project_file=ctx.project_file)
        geo = block.meta["testfield"]["geometry"]
        dof = degrees_of_freedom(block)
        if geo["min_rays"] < 2:
            ctx.warn(f"a target is seen in fewer than 2 photos (min {geo['min_rays']})")
        summary = {
            **block.summary(), "case": options.case, "block_kind": options.block,
            "dof_without_aps": dof, "constraints": constraint_count(control_configuration(options.case)),
            "min_rays": geo["min_rays"], "distance_m": round(geo["distance_m"], 4),
            "forward_overlap_mean": _mean(geo["forward_overlap"]),
            "side_overlap_mean": _mean(geo["side_overlap"]),
            "sigma_image_um": options.sigma_image_um, "sigma_control_mm": options.sigma_control_mm,
            "with_ap_errors": options.with_ap_errors,
            "systematic_rms_um": float(np.sqrt(np.mean(truth.systematic ** 2)) * 1e3),
            "blunders": len(options.blunders),
            "displacements": {str(d.point): [d.dX, d.dY, d.dZ] for d in options.displacements},
        }
        return StageResult(artefacts={"block": block}, summary=summary,
                           report=_report(block, truth, geo, summary),
                           tables=_tables(block, truth), data={"block": block, "truth": truth})

    def log(self, result: StageResult, rec, ctx: Context) -> None:
        log_testfield(rec, result.data["block"], result.data["truth"])


def _mean(pairs) -> float | None:
    return round(float(np.mean([f for *_, f in pairs])), 4) if pairs else None


def _report(block, truth, geo, s) -> str:
    lines = [
        f"Simulated {'block (2 strips × 5 photos, 1.4 m)' if s['block_kind'] == 'block' else 'single model (A, B at 4.0 m)'}, "
        f"control case {s['case']}: {s['photos']} photos, {s['points']} targets "
        f"({', '.join(f'{n} {r}' for r, n in s['roles'].items() if n)}), {s['observations']} image points; "
        f"mean object distance {geo['distance_m']:.3f} m.",
        "",
        f"Degrees of freedom without additional parameters: **{s['dof_without_aps']}** "
        f"({s['constraints']} control constraints).  Noise: image σ = {s['sigma_image_um']:g} µm, control "
        f"σ = {s['sigma_control_mm']:g} mm; systematic image errors "
        f"{'on' if s['with_ap_errors'] else 'off'} (RMS {s['systematic_rms_um']:.1f} µm at the measured points).",
        "",
    ]
    rows = [[pid, d["n"], " ".join(d["points"]), f"{d['footprint_m'][0]:.3f} × {d['footprint_m'][1]:.3f}"]
            for pid, d in geo["photos"].items()]
    lines += [markdown_table(["photo", "targets", "ids", "footprint m"], rows), ""]
    ov = [[f"{a}–{b}", "forward", f"{100 * f:.1f} %"] for a, b, f in geo["forward_overlap"]]
    ov += [[f"{a}–{b}", "side", f"{100 * f:.1f} %"] for a, b, f in geo["side_overlap"]]
    lines += [markdown_table(["photos", "overlap", "fraction"], ov), ""]
    rays = geo["rays_per_point"]
    lines += [f"Rays per target: {', '.join(f'{k}: {v}' for k, v in rays.items())} (min {geo['min_rays']})."]
    if s["blunders"]:
        lines += ["", f"{s['blunders']} gross error(s) injected (see `truth.blunder`)."]
    if s["displacements"]:
        moved = ", ".join(f"{p} by ({', '.join(f'{v:g}' for v in d)}) mm" for p, d in s["displacements"].items())
        lines += ["", f"Targets moved before imaging and survey (dX, dY, dZ): {moved}."]
    return "\n".join(lines)


def _tables(block, truth) -> dict:
    pts = block.points
    rays = np.bincount(block.observations.point, minlength=len(pts))
    points = TableData({
        "point": pts.ids.tolist(), "role": pts.role.tolist(),
        "X_m": pts.XYZ[:, 0], "Y_m": pts.XYZ[:, 1], "Z_m": pts.XYZ[:, 2],
        "X_true_m": truth.XYZ[:, 0], "Y_true_m": truth.XYZ[:, 1], "Z_true_m": truth.XYZ[:, 2],
        "rays": rays,
    }, "targets: surveyed (X, Y, Z) and true coordinates (m), role, number of photos", detail=True)
    ph = block.photos
    photos = TableData({
        "photo": ph.ids.tolist(),
        "X0_approx_m": ph.X0[:, 0], "Y0_approx_m": ph.X0[:, 1], "Z0_approx_m": ph.X0[:, 2],
        "X0_true_m": truth.X0[:, 0], "Y0_true_m": truth.X0[:, 1], "Z0_true_m": truth.X0[:, 2],
        "omega_true_deg": np.rad2deg(truth.opk[:, 0]), "phi_true_deg": np.rad2deg(truth.opk[:, 1]),
        "kappa_true_deg": np.rad2deg(truth.opk[:, 2]),
        "targets": np.bincount(block.observations.photo, minlength=len(ph)),
    }, "photos: approximate (paper's Table 1) and true exterior orientation (m, deg)")
    obs = block.observations
    observations = TableData({
        "photo": ph.ids[obs.photo].tolist(), "point": pts.ids[obs.point].tolist(),
        "x_mm": obs.xy[:, 0], "y_mm": obs.xy[:, 1],
        "sys_x_um": truth.systematic[:, 0] * 1e3, "sys_y_um": truth.systematic[:, 1] * 1e3,
        "noise_x_um": truth.noise[:, 0] * 1e3, "noise_y_um": truth.noise[:, 1] * 1e3,
        "blunder_x_um": truth.blunder[:, 0] * 1e3, "blunder_y_um": truth.blunder[:, 1] * 1e3,
    }, "image observations (mm) with their simulated systematic error, noise and blunder (µm)", detail=True)
    return {"points": points, "photos": photos, "observations": observations}


DISPLAY_PIXEL_MM = 0.1
"""Nominal pixel of the film format in the recording's pinhole (display only)."""


def log_testfield(rec, block, truth, root: str = "world") -> None:
    """Cameras (true orientation, frusta), targets coloured by role, and image points per photo."""
    import rerun as rr

    pts = block.points
    colors = role_colors(pts.role)
    rec.log(f"{root}/targets", rr.Points3D(truth.XYZ, colors=colors, labels=pts.ids.tolist(),
                                           radii=0.012), static=True)
    rec.log(f"{root}/targets/roles", rr.AnyValues(role=pts.role.tolist(), point=pts.ids.tolist()), static=True)
    cam = block.cameras
    w_mm, h_mm = cam.format_mm[0]
    W, H = int(round(w_mm / DISPLAY_PIXEL_MM)), int(round(h_mm / DISPLAY_PIXEL_MM))
    f = cam.c[0] / DISPLAY_PIXEL_MM
    R = rotation_from_opk_many(truth.opk)
    obs = block.observations
    for i, pid in enumerate(block.photos.ids):
        path = f"{root}/cameras/{pid}"
        rec.log(path, rr.Transform3D(translation=-R[i] @ truth.X0[i], mat3x3=R[i],
                                     relation=rr.TransformRelation.ChildFromParent), static=True)
        rec.log(path, rr.Pinhole(image_from_camera=[[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1]],
                                 resolution=[W, H], camera_xyz=rr.ViewCoordinates.RUB,
                                 image_plane_distance=0.25), static=True)
        sel = obs.photo == i
        uv = np.column_stack([obs.xy[sel, 0] / DISPLAY_PIXEL_MM + (W - 1) / 2,
                              -obs.xy[sel, 1] / DISPLAY_PIXEL_MM + (H - 1) / 2])
        rec.log(f"{path}/image/targets", rr.Points2D(uv, colors=colors[obs.point[sel]],
                                                     labels=pts.ids[obs.point[sel]].tolist(), radii=6.0),
                static=True)
