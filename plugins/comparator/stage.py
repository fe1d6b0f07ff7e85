"""Source stage ``comparator``: read a mono-comparator file into a block.

Format: docs/comparator-format.md.  Parsing (:mod:`.parser`), interior orientation numerics
(:mod:`.interior`) and block building (:mod:`.block`) live in their own modules; this stage wires
them together, applies the interior-orientation tolerance and writes the recording.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np

from baarda.pipeline.api import Context, InputError, Stage, StageResult, TableData, option
from baarda.pipeline.options import REQUIRED

from .block import build_block, interior_orientation, tolerance_violations
from .parser import parse_comparator


@dataclasses.dataclass(frozen=True)
class ComparatorOptions:
    RENAMED: ClassVar[dict[str, str]] = {"io_tolerance_um": "tol_io_um"}
    RENAMED_VALUES: ClassVar[dict[str, dict[str, str]]] = {"on_tolerance": {"fail": "error"}}
    path: Path = option(REQUIRED, "comparator file (docs/comparator-format.md), relative to the "
                                  "project file (required)")
    transform: Literal["file", "affine", "similarity"] = option(
        "file", "interior orientation machine → fiducial system: 'file' uses the file's "
                "'transform' line (default affine)")
    tol_io_um: float = option(
        20.0, "largest admissible fiducial residual (length of the residual vector, µm) after the "
              "interior orientation")
    on_tolerance: Literal["error", "warn"] = option(
        "error", "what a fiducial beyond the tolerance does: stop with an error naming the photo and "
                "fiducial, or warn and continue")

    def __post_init__(self):
        if not self.tol_io_um > 0:
            raise ValueError(f"tol_io_um must be positive, got {self.tol_io_um}")


class ComparatorSource(Stage):
    summary = "Read mono-comparator measurements (fiducial or photo mode) with interior orientation"
    reads = ()
    writes = ("block",)
    Options = ComparatorOptions

    def validate(self, options: ComparatorOptions, ctx: Context) -> None:
        """``baarda validate``: read and check the file, interior orientation and tolerance included."""
        _, parsed, interior, _, _ = self._read(options, ctx)
        return build_block(parsed, interior)

    def _read(self, options: ComparatorOptions, ctx: Context):
        """Parse the file, fit the interior orientation and apply the tolerance (warnings to ctx)."""
        if str(options.path) in ("", "."):
            raise ctx.option_error("option 'path' is required: the comparator file to read", "path")
        path = ctx.resolve(options.path)
        if not path.exists():
            raise ctx.option_error(f"comparator file not found: {path}", "path")
        if path.is_dir():
            raise ctx.option_error(f"expected a comparator file, got a directory: {path}", "path")
        parsed = parse_comparator(path)
        interior = interior_orientation(parsed, None if options.transform == "file" else options.transform)
        tol_mm = options.tol_io_um / 1000.0
        violations = tolerance_violations(interior, tol_mm)
        warnings = []
        for v in violations:
            fit = interior[v.photo].fit
            msg = v.message(tol_mm, fit.kind, fit.sigma0_hat)
            if options.on_tolerance == "error":
                raise InputError(msg, path, v.line, f"fid {v.fiducial}")
            warnings.append(f"{path}:{v.line}: {msg}")
        for res in interior.values():
            if res.fit.dof == 0:
                warnings.append(f"{path}:{res.photo_line}: photo {res.photo}: {len(res.fiducials)} fiducials give "
                                f"no redundancy for the {res.fit.kind} interior orientation; it cannot be checked")
        for w in warnings:
            ctx.warn(w)
        return path, parsed, interior, violations, warnings

    def run(self, inputs, options: ComparatorOptions, ctx: Context) -> StageResult:
        path, parsed, interior, violations, warnings = self._read(options, ctx)
        tol_mm = options.tol_io_um / 1000.0
        block = build_block(parsed, interior)
        return StageResult(
            artefacts={"block": block},
            summary={**block.summary(), "file": str(path), "mode": parsed.mode, "unit": parsed.unit,
                     "interior_orientation": {k: r.report() for k, r in interior.items()},
                     "tol_io_um": options.tol_io_um,
                     "io_violations": [dataclasses.asdict(v) for v in violations],
                     "warnings": warnings},
            report=_report(parsed, block, interior, violations, options, warnings),
            tables=_tables(block, interior, tol_mm),
            data={"block": block, "interior": interior, "tolerance_mm": tol_mm},
        )

    def log(self, result: StageResult, rec, ctx: Context) -> None:
        import rerun as rr

        from baarda.pipeline.api import entity_part, view_from_photo, view_vectors

        block = result.data["block"]
        obs = block.observations
        for i, pid in enumerate(block.photos.ids):
            path = f"photos/{entity_part(pid)}"
            sel = obs.photo == i
            fmt = block.cameras.format_mm[block.photos.camera[i]]
            fmt = fmt if np.isfinite(fmt).all() else None
            if sel.any():
                rec.log(f"{path}/points", rr.Points2D(view_from_photo(obs.xy[sel], fmt),
                                                      labels=block.points.ids[obs.point[sel]].tolist(), radii=0.5))
            if fmt is not None:
                w, h = fmt / 2
                corners = np.array([[-w, -h], [w, -h], [w, h], [-w, h], [-w, -h]])
                rec.log(f"{path}/format", rr.LineStrips2D([view_from_photo(corners, fmt)]))
            res = result.data["interior"].get(pid)
            if res is not None:
                scale = 1000.0  # residual arrows drawn 1000× (1 µm shown as 1 mm)
                colors = [[220, 40, 40] if n > result.data["tolerance_mm"] else [40, 160, 40]
                          for n in res.fit.residual_norm]
                rec.log(f"{path}/fiducials",
                        rr.Arrows2D(origins=view_from_photo(res.calibrated - res.fit.residuals, fmt),
                                    vectors=view_vectors(res.fit.residuals * scale), labels=list(res.fiducials),
                                    colors=colors))
                rec.log(f"{path}/interior_orientation",
                        rr.AnyValues(sigma0_hat_um=float(res.fit.sigma0_hat * 1000), dof=res.fit.dof,
                                     arrow_scale=scale))


def _report(parsed, block, interior, violations, options, warnings) -> str:
    s = block.summary()
    lines = [f"Read `{parsed.path}` ({parsed.mode} mode, comparator unit {parsed.unit}): "
             f"{s['cameras']} camera(s), {s['photos']} photo(s), {s['points']} point(s), "
             f"{s['observations']} observation(s), {s['pairs']} pair(s).", ""]
    if interior:
        lines += [f"Interior orientation ({next(iter(interior.values())).fit.kind}), tolerance "
                  f"{options.tol_io_um:g} µm:", "",
                  "| photo | fiducials | dof | σ̂0 µm | largest residual µm (fiducial) |",
                  "|---|---|---|---|---|"]
        for r in interior.values():
            k = int(np.argmax(r.fit.residual_norm))
            s0 = "—" if math.isnan(r.fit.sigma0_hat) else f"{r.fit.sigma0_hat * 1000:.1f}"
            lines.append(f"| {r.photo} | {len(r.fiducials)} | {r.fit.dof} | {s0} | "
                         f"{r.fit.residual_norm[k] * 1000:.1f} ({r.fiducials[k]}) |")
        lines.append("")
    else:
        lines += ["Photo-coordinate mode: coordinates are already in mm; no interior orientation.", ""]
    for w in warnings:
        lines.append(f"- warning: {w}")
    return "\n".join(lines)


def _tables(block, interior, tol_mm) -> dict:
    tables = {}
    if interior:
        cols = {k: [] for k in ("photo", "fiducial", "line", "vx_um", "vy_um", "norm_um", "beyond_tolerance")}
        for r in interior.values():
            for f, ln, v, n in zip(r.fiducials, r.lines, r.fit.residuals, r.fit.residual_norm):
                cols["photo"].append(r.photo)
                cols["fiducial"].append(f)
                cols["line"].append(ln)
                cols["vx_um"].append(round(float(v[0]) * 1000, 3))
                cols["vy_um"].append(round(float(v[1]) * 1000, 3))
                cols["norm_um"].append(round(float(n) * 1000, 3))
                cols["beyond_tolerance"].append(bool(n > tol_mm))
        tables["interior"] = TableData(cols, "fiducial residuals of the interior orientation "
                                             "(calibrated − transformed, µm)")
    obs = block.observations
    lines = block.source.lines
    tables["observations"] = TableData({
        "photo": block.photos.ids[obs.photo].tolist(),
        "point": block.points.ids[obs.point].tolist(),
        "x_mm": obs.xy[:, 0].tolist(), "y_mm": obs.xy[:, 1].tolist(),
        "sx_mm": np.sqrt(obs.cov[:, 0, 0]).tolist(), "sy_mm": np.sqrt(obs.cov[:, 1, 1]).tolist(),
        "line": [lines.get((int(p), int(q)), ("", None))[1] for p, q in zip(obs.photo, obs.point)],
    }, "image observations in the image system (mm)", detail=True)
    return tables
