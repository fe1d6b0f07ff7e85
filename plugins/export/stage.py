"""Stage ``export``: adjusted points with their standard deviations as PLY and CSV in the user's CRS.

The block's points (adjusted, after a bundle) go back from the local frame to the CRS they were
read in (``block.crs``; ``docs/crs.md``), or to another CRS given as ``crs``; their
covariance from the bundle is propagated with the conversion's Jacobian (``docs/export.md``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baarda.pipeline.crs import LocalFrame, crs_label, frame_of_block, parse_crs
from baarda.pipeline.api import Context, InputError, StageResult, option
from baarda.pipeline.model import ROLES

from .writer import export_points, write_csv, write_ply


@dataclass(frozen=True)
class ExportOptions:
    path: Path = option(Path("points"), "output prefix inside the run directory: <path>.ply, <path>.csv")
    formats: list[str] = option(["ply", "csv"], "what to write: 'ply' and/or 'csv'")
    ply: str = option("binary", "PLY encoding: 'binary' (little endian) or 'ascii'")
    roles: list[str] = option([], "roles to write (default all: full, xy, z, check, tie)")
    crs: str | None = option(None, "write in this CRS instead of the block's (needs a block with a CRS)")

    def __post_init__(self):
        bad = [f for f in self.formats if f not in ("ply", "csv")]
        if bad or not self.formats:
            raise ValueError(f"formats: expected 'ply' and/or 'csv', got {self.formats!r}")
        if self.ply not in ("binary", "ascii"):
            raise ValueError(f"ply must be 'binary' or 'ascii', got {self.ply!r}")
        bad = [r for r in self.roles if r not in ROLES]
        if bad:
            raise ValueError(f"roles: unknown {bad}; expected some of {list(ROLES)}")


def covariance_for(block, bundle) -> np.ndarray | None:
    """The bundle's point covariances when they belong to ``block``'s points (same ids), else None."""
    if bundle is None or getattr(bundle, "cov_points", None) is None:
        return None
    b = getattr(bundle, "block", None)
    if b is None or len(b.points) != len(block.points) or not np.array_equal(b.points.ids, block.points.ids):
        return None
    return np.asarray(bundle.cov_points, float)


class PointExport:
    summary = "points (adjusted, with σ from the bundle) → PLY and CSV in the user's CRS"
    reads = ("block", "bundle?")
    writes = ()
    paths = {"path": "output"}
    outputs = ()                          # no table or figure: every other name is free for path
    output_adds = {"path": (".ply", ".csv")}              # the files made of the prefix
    Options = ExportOptions

    def run(self, inputs, options: ExportOptions, ctx: Context) -> StageResult:
        block = inputs["block"]
        frame = frame_of_block(block)
        if options.crs is not None:
            if frame.is_identity:
                raise ctx.option_error("crs: the block has no CRS (a local system); cannot convert", "crs")
            target = parse_crs(options.crs, path=ctx.project_file, field="crs")
            frame = LocalFrame(target.to_wkt(), frame.origin, frame.a, frame.f)
        cov = covariance_for(block, inputs.get("bundle"))
        if cov is None:
            ctx.warn("no bundle result for these points: σ columns are nan")
        ex = export_points(block, frame, cov, roles=options.roles or None)
        out = ctx.output_path(options.path, "path", adds=self.output_adds["path"])
        out.parent.mkdir(parents=True, exist_ok=True)
        written = []
        if "ply" in options.formats:
            written.append(write_ply(out.with_name(out.name + ".ply"), ex, binary=options.ply == "binary"))
        if "csv" in options.formats:
            written.append(write_csv(out.with_name(out.name + ".csv"), ex))
        fin = np.isfinite(ex.sigma).all(axis=1)
        summary = {"points": int(len(ex.ids)), "files": [p.name for p in written],
                   "crs": "local" if ex.crs is None else (options.crs or block.crs.crs[:80]),
                   "axes": list(ex.names), "with_sigma": int(fin.sum())}
        med = np.median(ex.sigma[fin], axis=0) if fin.any() else [np.nan] * 3
        to_mm = 1000.0 if ex.unit == "m" else 1.0
        report = (f"Wrote {len(ex.ids)} points ({', '.join(p.name for p in written)}) with axes "
                  f"{' '.join(ex.names)} and σ {' '.join(ex.sigma_names)} (median "
                  + " / ".join(f"{v * to_mm:.1f}" for v in med) + " mm"
                  + (", in the block's local system" if ex.crs is None else "") + ").")
        sig = (f"{int(fin.sum())} with σ, median " + " / ".join(f"{v * to_mm:.1f}" for v in med) + " mm"
               if fin.any() else "no σ: no bundle for them")
        summary["headline"] = (f"{len(ex.ids)} points ({sig}) → {', '.join(p.name for p in written)}, "
                               + ("the block's local system" if ex.crs is None else
                                  f"{crs_label(ex.crs)} ({' '.join(ex.names)})"))
        return StageResult(summary=summary, report=report)
