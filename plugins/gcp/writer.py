"""Writer of ODM/OpenSfM ``gcp_list.txt`` files and the stage ``gcp-export``.

The inverse of :func:`.reader.read_gcp_list` (format: ``docs/crs.md``): the first line names the
CRS, then one line ``geo_x geo_y geo_z im_x im_y image_name gcp_name`` per image measurement of a
surveyed point (roles ``full``, ``xy``, ``z``, ``check`` by default), the coordinates in the
user's CRS (the block's local frame converted back, :class:`~baarda.pipeline.crs.LocalFrame`) and
the pixel position with ODM's convention (origin at the centre of the top-left pixel, y down:
:func:`~baarda.pipeline.geometry.pixels_from_mm` with ``"opencv"``, the inverse of what
:func:`.block.gcp_block` uses).  Image names are the photo ids (a GCP-list source names its photos
by the list's image names).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baarda.pipeline.crs import LocalFrame, crs_label, frame_of_block, parse_crs
from baarda.pipeline.api import Context, InputError, StageResult, option
from baarda.pipeline.geometry import pixels_from_mm
from baarda.pipeline.model import ROLES

SURVEYED = ("full", "xy", "z", "check")


def crs_line(frame: LocalFrame, original: str | None = None) -> str:
    """The CRS as ODM's first line: the text the list was read with when given, else
    :func:`~baarda.pipeline.crs.crs_label` (``EPSG:n``, ``EPSG:a+b``, a PROJ string, WKT)."""
    return original.strip() if original else crs_label(frame.crs)


def gcp_lines(block, *, roles=SURVEYED, frame: LocalFrame | None = None, crs_text: str | None = None) -> tuple[list[str], dict]:
    """The lines of a ``gcp_list.txt`` of ``block``'s active image measurements of points with a
    role in ``roles`` and finite coordinates; ``frame`` the block's frame (default its own; it must
    name a CRS).  Returns the lines and ``info`` (counts, what was left out)."""
    frame = frame_of_block(block) if frame is None else frame
    if frame.is_identity:
        raise InputError("the block has no coordinate reference system (a local object system); a gcp_list.txt "
                         "needs one: read the points in a CRS (gcp-list, crs option of the source)", field="crs")
    cams, ph, pts, obs = block.cameras, block.photos, block.points, block.observations
    bad = [str(i) for i in ph.ids.tolist() if not i or any(ch.isspace() for ch in i)]
    if bad:
        raise InputError(f"photo id {bad[0]!r} cannot be an image name in a gcp_list.txt (empty or with spaces)",
                         field="photo")
    bad = [str(i) for i in pts.ids.tolist() if not i or any(ch.isspace() for ch in i)]
    keep_pt = np.isin(pts.role, list(roles)) & np.isfinite(pts.XYZ).all(axis=1)
    if bad and keep_pt[pts.index_of(bad)].any():
        raise InputError(f"point id {bad[0]!r} cannot be a gcp_name (empty or with spaces)", field="point")
    use = np.asarray(obs.active, bool) & keep_pt[obs.point]
    rows = np.flatnonzero(use)
    scale = 1e-3 if block.object_unit == "mm" else 1.0
    geo = frame.from_local(np.asarray(pts.XYZ, float) * scale) if len(pts) else np.zeros((0, 3))
    cam = ph.camera[obs.photo[rows]]
    uv = np.zeros((rows.size, 2))
    for j in np.unique(cam):
        W, H = (int(v) for v in cams.resolution[j])
        p = float(cams.pixel_mm[j])
        if not (W > 0 and H > 0 and np.isfinite(p) and p > 0):
            raise InputError(f"camera {str(cams.ids[j])!r} has no image size or pixel pitch; a gcp_list.txt holds "
                             "pixels", field="camera")
        k = cam == j
        uv[k] = pixels_from_mm(obs.xy[rows[k]], (W, H), p, convention="opencv")
    lines = [crs_text or crs_line(frame)]
    for r, (u, v) in zip(rows, uv):
        X = geo[obs.point[r]]
        lines.append(f"{X[0]:.15g} {X[1]:.15g} {X[2]:.15g} {u:.12g} {v:.12g} {ph.ids[obs.photo[r]]} "
                     f"{pts.ids[obs.point[r]]}")
    info = {"measurements": int(rows.size), "targets": int(np.unique(obs.point[rows]).size),
            "images": int(np.unique(obs.photo[rows]).size),
            "inactive_left_out": int((~np.asarray(obs.active, bool) & keep_pt[obs.point]).sum())}
    return lines, info


def write_gcp_list(block, path: str | Path, **kw) -> dict:
    """Write :func:`gcp_lines` of ``block`` to ``path``; returns its info."""
    lines, info = gcp_lines(block, **kw)
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")
    return info


# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class GcpExportOptions:
    path: Path = option(Path("gcp_list.txt"), "output file inside the run directory")
    points: str = option("surveyed", "'surveyed': the coordinates the source read (after a bundle: its input "
                                     "block); 'adjusted': the bundle's")
    roles: list[str] = option(list(SURVEYED), "roles of the points written (default the surveyed ones: full, xy, "
                                              "z, check)")
    crs: str | None = option(None, "write in this CRS instead of the block's")

    def __post_init__(self):
        if self.points not in ("surveyed", "adjusted"):
            raise ValueError(f"points must be 'surveyed' or 'adjusted', got {self.points!r}")
        bad = [r for r in self.roles if r not in ROLES]
        if bad or not self.roles:
            raise ValueError(f"roles: expected some of {list(ROLES)}, got {self.roles!r}")


class GcpExport:
    summary = "control and check points with their pixel measurements → ODM/OpenSfM gcp_list.txt in the user's CRS"
    reads = ("block", "bundle?")
    writes = ()
    paths = {"path": "output"}
    outputs = ()                          # no table or figure: every other name is free for path
    Options = GcpExportOptions

    def run(self, inputs, options: GcpExportOptions, ctx: Context) -> StageResult:
        block = inputs["block"]
        bundle = inputs.get("bundle")
        if options.points == "adjusted":
            if bundle is None:
                raise ctx.option_error("points = 'adjusted' needs a bundle stage before gcp-export", "points")
            block = bundle.block
        elif bundle is not None and getattr(bundle, "block_in", None) is not None:
            block = bundle.block_in            # the bundle hands on its adjusted block as 'block'
        frame = frame_of_block(block)
        crs_text = None
        if options.crs is not None:
            if frame.is_identity:
                raise ctx.option_error("the block has no CRS to convert from; 'crs' needs a block read in one", "crs")
            crs = parse_crs(options.crs, path=ctx.project_file, line=ctx.option_lines.get("crs"), field="crs")
            frame = LocalFrame(crs.to_wkt(), frame.origin, frame.a, frame.f)
            crs_text = options.crs.strip()
        elif not frame.is_identity:
            crs_text = (block.meta.get("gcp") or {}).get("crs")
        out = ctx.output_path(options.path, "path")
        out.parent.mkdir(parents=True, exist_ok=True)
        try:
            info = write_gcp_list(block, out, roles=tuple(options.roles), frame=frame, crs_text=crs_text)
        except InputError as e:
            raise ctx.option_error(f"cannot write a gcp_list.txt: {e.message}", "path") from None
        report = (f"Wrote `{options.path}` ({options.points} coordinates): {info['measurements']} measurements of "
                  f"{info['targets']} points in {info['images']} images.")
        if info["inactive_left_out"]:
            report += f"  {info['inactive_left_out']} inactive measurement(s) left out."
        headline = (f"{options.path} ({options.points} coordinates, {crs_text or crs_line(frame)}): "
                    f"{info['measurements']} measurements of {info['targets']} points in {info['images']} images"
                    + (f"; {info['inactive_left_out']} inactive left out" if info["inactive_left_out"] else ""))
        return StageResult(summary={**info, "path": str(options.path), "points": options.points,
                                    "headline": headline}, report=report)
