"""Stages ``gcp-list`` (source: an ODM/OpenSfM ``gcp_list.txt`` with a known camera, no photos
needed) and ``gnss-centres`` (GNSS antenna positions with a lever arm as observations of the bundle).

Both read coordinates in a user CRS and work in the block's local east-north-up frame
(:mod:`baarda.pipeline.crs`, ``docs/crs.md``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baarda.pipeline.crs import LocalFrame, frame_of_block, local_frame
from baarda.pipeline.api import Context, InputError, SourceStage, StageResult, TableData, ValidationContext, option
from baarda.pipeline.units import length_suffix
from baarda.pipeline.report import markdown_table

from .block import CameraSpec, apply_gnss, gcp_block
from .reader import read_cameras_json, read_gcp_list, read_gnss_csv


@dataclass(frozen=True)
class CameraOptions:
    width: int = option(0, "image width in pixels of the measurements (required without cameras_json)", ge=0)
    height: int = option(0, "image height in pixels (required without cameras_json)", ge=0)
    focal_px: float = option(0.0, "focal length in pixels (or give focal_mm)")
    focal_mm: float = option(0.0, "focal length in mm (with pixel_mm or sensor_width_mm)")
    pixel_mm: float = option(0.0, "pixel pitch in mm (or give sensor_width_mm)")
    sensor_width_mm: float = option(0.0, "sensor width in mm (pixel pitch = sensor_width_mm / width)")
    principal_point_px: list[float] = option([0.0, 0.0], "principal point offset from the image centre in pixels "
                                                         "(x right, y down; any sign, inside the image)",
                                             ge=-1_000_000.0, le=1_000_000.0)


@dataclass(frozen=True)
class GcpOptions:
    path: Path | None = option(None, "the gcp_list.txt (required), relative to the project file")
    camera: CameraOptions | None = option(None, "the camera: {width, height, focal_px | focal_mm, pixel_mm | "
                                                "sensor_width_mm, principal_point_px}")
    cameras_json: Path | None = option(None, "an OpenSfM/ODM cameras.json with the camera instead (one camera; "
                                             "pixel_mm or sensor_width_mm still from camera)")
    sigma_px: float = option(1.0, "a-priori σ of every pixel coordinate")
    sigma_control_mm: list[float] = option([20.0, 20.0, 30.0], "a-priori σ of the targets' E, N, h (mm)")
    check: list[str] = option([], "targets used as check points (not in the adjustment, compared afterwards)")
    min_points: int = option(4, "photos measuring fewer control targets are left out (4: resection)", ge=3)
    skip_lines: list[int] = option([], "line numbers of measurements in the file to leave out (a known mistake)")
    crs: str | None = option(None, "override the CRS line of the file (EPSG:…, PROJ string, 'local')")

    def __post_init__(self):
        if len(self.sigma_control_mm) != 3:
            raise ValueError(f"sigma_control_mm: expected 3 numbers [E, N, h], got {self.sigma_control_mm!r}")


def _camera_spec(options: GcpOptions, ctx: Context) -> CameraSpec:
    c = options.camera or CameraOptions()
    if options.cameras_json is not None:
        cams = read_cameras_json(ctx.resolve(options.cameras_json))
        if len(cams) != 1:
            raise ctx.option_error(f"cameras_json holds {len(cams)} cameras; a GCP project uses one", "cameras_json")
        s = cams[0]
        width, height, fpx = s.width, s.height, s.fx_px
        pp = (s.cx_px, s.cy_px)
        k1, k2, cid = s.k1, s.k2, s.id
        if abs(s.fx_px - s.fy_px) > 1e-6 * s.fx_px:
            ctx.warn(f"cameras.json: focal_x {s.fx_px:.2f} px and focal_y {s.fy_px:.2f} px differ; baarda uses focal_x "
                     "(an affinity belongs to the bundle's AP model)")
    else:
        width, height, pp, k1, k2, cid = c.width, c.height, tuple(c.principal_point_px), 0.0, 0.0, "camera"
        fpx = c.focal_px
    if not width or not height:
        raise ctx.option_error("the camera needs width and height in pixels (camera = {width = …, height = …})",
                               "camera")
    pixel = c.pixel_mm or (c.sensor_width_mm / width if c.sensor_width_mm else 0.0)
    if not pixel:
        raise ctx.option_error("the camera needs pixel_mm or sensor_width_mm", "camera")
    if not fpx:
        if not c.focal_mm:
            raise ctx.option_error("the camera needs focal_px or focal_mm", "camera")
        fpx = c.focal_mm / pixel
    if len(pp) != 2:
        raise ctx.option_error("principal_point_px: expected 2 numbers", "camera")
    if abs(pp[0]) > width / 2 or abs(pp[1]) > height / 2:
        raise ctx.option_error(f"principal_point_px = [{pp[0]:g}, {pp[1]:g}] px from the image centre lies outside the "
                               f"{width} × {height} pixel image", "camera")
    if c.focal_px and c.focal_mm:
        raise ctx.option_error(f"the camera gives the focal length twice (focal_px = {c.focal_px:g} and focal_mm = "
                               f"{c.focal_mm:g}); give one", "camera")
    return CameraSpec(cid, int(width), int(height), float(fpx), float(pixel), float(pp[0]), float(pp[1]), k1, k2)


class GcpListSource(SourceStage):
    summary = "Read an ODM/OpenSfM gcp_list.txt (CRS, targets, pixel measurements) with a known camera into a block"
    reads = ()
    writes = ("block",)
    Options = GcpOptions

    def run(self, inputs, options: GcpOptions, ctx: Context) -> StageResult:
        if options.path is None or not str(options.path) or str(options.path) == ".":
            raise InputError("the gcp-list stage needs the option 'path' (the gcp_list.txt)", path=ctx.project_file,
                             field="path")
        gcp = read_gcp_list(ctx.resolve(options.path), skip_lines=options.skip_lines)
        camera = _camera_spec(options, ctx)
        if options.crs is not None:
            frame = local_frame(options.crs, gcp.geo, path=ctx.project_file, field="crs")
        else:
            frame = local_frame(gcp.crs, gcp.geo, path=gcp.path, line=gcp.crs_line, field="crs")
        block, info = gcp_block(gcp, camera, frame, sigma_px=options.sigma_px,
                                sigma_control=np.asarray(options.sigma_control_mm) / 1000.0, check=options.check,
                                min_points=options.min_points,
                                check_where={"path": ctx.project_file, "line": ctx.option_lines.get("check")})
        for img, n in info["dropped_photos"].items():
            ctx.warn(f"photo {img} left out: it measures {n} control target(s), resection needs {options.min_points}")
        summary = {**block.summary(), **{k: v for k, v in info.items() if k != "dropped_photos"},
                   "dropped_photos": sorted(info["dropped_photos"]), "crs": gcp.crs if options.crs is None else options.crs,
                   "origin_lon_lat_h": list(frame.origin), "c_mm": float(block.cameras.c[0]),
                   "pixel_mm": camera.pixel_mm}
        return StageResult(artefacts={"block": block}, summary=summary, report=_gcp_report(block, info, frame, camera),
                           tables=_gcp_tables(block, frame), data={"block": block})

    def log(self, result: StageResult, rec, ctx: Context) -> None:
        import rerun as rr

        pts = result.data["block"].points
        colors = np.where((pts.role == "check")[:, None], [[40, 160, 220]], [[230, 60, 60]])
        rec.log("world/points", rr.Points3D(pts.XYZ, labels=pts.ids.tolist(), colors=colors,
                                            radii=rr.Radius.ui_points(4.0)), static=True)


def _gcp_report(block, info, frame: LocalFrame, cam: CameraSpec) -> str:
    pts = block.points
    lines = [
        f"{info['measurements']} measurements of {info['targets']} targets ({info['control']} control, "
        f"{info['check']} check) in {info['photos'] + len(info['dropped_photos'])} photos; "
        f"{info['photos']} photos kept, {info['used_measurements']} measurements used.",
        "",
        f"Camera `{cam.id}`: {cam.width} × {cam.height} px, focal {cam.focal_px:.2f} px = "
        f"c {cam.focal_px * cam.pixel_mm:.4f} mm at {cam.pixel_mm * 1000:.4f} µm/pixel"
        + (f", k1 {cam.k1:g}, k2 {cam.k2:g} (OpenSfM) as Brown K1, K2" if cam.k1 or cam.k2 else "") + ".",
        "",
    ]
    if frame.is_identity:
        lines.append("Coordinates are a local Cartesian system (no CRS): used as they are.")
    else:
        lines.append(f"Local frame: east, north, up (m), origin at lon {frame.origin[0]:.8f}°, "
                     f"lat {frame.origin[1]:.8f}°, h {frame.origin[2]:.3f} m (ellipsoidal).")
    if info["dropped_photos"]:
        lines += ["", "Photos left out (fewer control targets than a resection needs): "
                  + ", ".join(f"{k} ({v})" for k, v in info["dropped_photos"].items()) + "."]
    rays = np.bincount(block.observations.point, minlength=len(pts))
    lines += ["", markdown_table(["target", "role", "E (local)", "N (local)", "U (local)", "rays"],
                                 [[p, r, f"{x:.3f}", f"{y:.3f}", f"{z:.3f}", int(n)]
                                  for p, r, (x, y, z), n in zip(pts.ids, pts.role, pts.XYZ, rays)])]
    return "\n".join(lines)


def _crs_suffixes(frame: LocalFrame, block) -> list[str]:
    """Unit suffixes of the user's coordinate columns: the CRS axes' units, the block's object unit
    without a CRS."""
    from baarda.pipeline.units import crs_axis_suffixes, length_suffix

    return [length_suffix(block.object_unit)] * 3 if frame.is_identity else crs_axis_suffixes(frame)


def _gcp_tables(block, frame: LocalFrame) -> dict:
    pts = block.points
    user = block.meta["gcp"]["user_xyz"]
    names = [n + sfx for n, sfx in zip(frame.axis_names(), _crs_suffixes(frame, block))]
    cols = {"point": pts.ids.tolist(), "role": pts.role.tolist(),
            names[0]: user[:, 0], names[1]: user[:, 1], names[2]: user[:, 2],
            "E_local_m": pts.XYZ[:, 0], "N_local_m": pts.XYZ[:, 1], "U_local_m": pts.XYZ[:, 2]}
    return {"targets": TableData(cols, "targets in the file's CRS and in the local frame (m)")}


# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class GnssOptions:
    path: Path | None = option(None, "the GNSS CSV (required): photo and E,N,h / x,y,z / lon,lat,h, optional sigma "
                                     "columns; '# crs: …' line")
    crs: str | None = option(None, "the CSV's CRS when it has no '# crs:' line; default: the block's CRS")
    sigma_mm: list[float] = option([50.0, 50.0, 80.0], "σ of E, N, h (mm) for rows without sigma columns")
    lever_arm: dict[str, list[float]] = option({}, "camera id → antenna offset [x, y, z] in the camera frame (m; "
                                                   "x right, y up, z back out of the lens)")
    opk_deg: list[float] | None = option(None, "approximate ω φ κ (degrees) for photos without an attitude, so they "
                                               "need no resection (e.g. [0, 0, 0] for nadir photos)")
    on_unknown: str = option("error", "a photo not in the block: 'error' or 'skip'")

    def __post_init__(self):
        if len(self.sigma_mm) != 3:
            raise ValueError(f"sigma_mm: expected 3 numbers [E, N, h], got {self.sigma_mm!r}")
        if self.opk_deg is not None and len(self.opk_deg) != 3:
            raise ValueError(f"opk_deg: expected 3 numbers, got {self.opk_deg!r}")
        for k, v in self.lever_arm.items():
            if len(v) != 3:
                raise ValueError(f"lever_arm.{k}: expected 3 numbers [x, y, z], got {v!r}")
        if self.on_unknown not in ("error", "skip"):
            raise ValueError(f"on_unknown must be 'error' or 'skip', got {self.on_unknown!r}")


LEVER_ARM_MAX_M = 30.0
"""Largest antenna offset from the camera (metres) accepted: larger ones are lever arms in mm."""


def _check_heights(g, crs) -> None:
    """Every GNSS row on the Earth in its CRS: the ellipsoidal height between −1 km and +100 km (as
    :func:`~baarda.pipeline.crs.local_frame` checks a source's points); else heights in mm, or
    coordinates not in this CRS — an InputError naming the CSV line and the column."""
    from baarda.pipeline.crs import WGS84_A, WGS84_F, LocalFrame

    ell = crs.ellipsoid
    a = float(ell.semi_major_metre) if ell is not None else WGS84_A
    inv_f = float(ell.inverse_flattening) if ell is not None else 1.0 / WGS84_F
    frame = LocalFrame(crs.to_wkt(), (0.0, 0.0, 0.0), a, 1.0 / inv_f if inv_f else 0.0)
    ok = np.isfinite(g.xyz).all(axis=1)
    try:
        h = np.full(len(g.xyz), np.nan)
        h[ok] = frame.geodetic(g.xyz[ok])[:, 2]
    except InputError as e:
        raise InputError(f"the GNSS coordinates cannot be placed in their CRS: {e.message}", path=g.path,
                         line=g.crs_line, field="crs") from None
    bad = ok & ~((h > HEIGHT_MIN_M) & (h < HEIGHT_MAX_M))
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        kind = "geocentric" if crs.is_geocentric else ("geographic" if crs.is_geographic else "projected")
        fld = "X, Y, Z" if crs.is_geocentric else g.columns[2]
        raise InputError(f"in the {kind} CRS of the file this row lies {h[k] / 1000:.4g} km from the ellipsoid "
                         f"({int(bad.sum())} of {len(h)} rows outside {HEIGHT_MIN_M / 1000:g} … {HEIGHT_MAX_M / 1000:g} km): "
                         "heights in mm, or coordinates not in this CRS?", path=g.path, line=int(g.line[k]), field=fld)


HEIGHT_MIN_M, HEIGHT_MAX_M = -1_000.0, 100_000.0
"""A GNSS antenna's ellipsoidal height lies between these (m), as a source's points in ``local_frame``."""


class GnssCentres:
    summary = "GNSS antenna positions per photo (CSV, any CRS, lever arm per camera) as observations of the bundle"
    reads = ("block",)
    writes = ("block",)
    outputs = ("antennas",)               # its table <id>_antennas
    Options = GnssOptions

    def validate(self, options: GnssOptions, ctx: Context):
        """Read the GNSS CSV and its CRS, check the lever arms — what ``run`` reads, before any block."""
        self._checked(options, ctx)
        return None

    def validate_with(self, v: ValidationContext) -> None:
        """``baarda validate`` with the block the sources read: every photo of the CSV in the block
        (unless on_unknown = 'skip'), every lever arm's camera a camera of the block."""
        if v.block is None:
            return
        self._matched(self._checked(v.options, v.ctx), v.options, v.block, v.ctx)

    @staticmethod
    def _matched(g, options: GnssOptions, block, ctx: Context) -> list:
        """The CSV's photos against the block (an unknown photo is an error unless on_unknown =
        'skip') and the lever arms' cameras against its cameras — for ``validate`` and ``run`` alike.
        Returns the unknown ``(photo, line)`` rows (skipped)."""
        known = set(block.photos.ids.tolist())
        unknown = [(p, ln) for p, ln in zip(g.photo, g.line) if p not in known]
        if unknown and options.on_unknown == "error":
            p, ln = unknown[0]
            raise InputError(f"photo {p!r} is not in the block ({len(unknown)} unknown; on_unknown = 'skip' ignores "
                             "them)", path=g.path, line=int(ln), field="photo")
        for cid in options.lever_arm:
            if cid not in block.cameras.ids:
                raise ctx.option_error(f"lever_arm: unknown camera {cid!r} (cameras: "
                                       f"{', '.join(block.cameras.ids.tolist())})", "lever_arm")
        return unknown

    def _checked(self, options: GnssOptions, ctx: Context):
        """The CSV read, its CRS and the crs option parsed, the lever arms plausible (in metres)."""
        from baarda.pipeline.crs import parse_crs

        if options.path is None or not str(options.path) or str(options.path) == ".":
            raise InputError("the gnss-centres stage needs the option 'path' (the GNSS CSV)", path=ctx.project_file,
                             field="path")
        g = read_gnss_csv(ctx.resolve(options.path))
        crs_src = None
        if g.crs and str(g.crs).strip().lower() not in ("local", "none"):
            crs_src = parse_crs(g.crs, path=g.path, line=g.crs_line, field="crs")
        if options.crs and str(options.crs).strip().lower() not in ("local", "none"):
            crs_opt = parse_crs(options.crs, path=ctx.project_file, field="crs")
            crs_src = crs_src if g.crs else crs_opt
        if crs_src is not None and len(g.xyz):
            _check_heights(g, crs_src)
        for cid, arm in options.lever_arm.items():
            if max(abs(float(x)) for x in arm) > LEVER_ARM_MAX_M:
                raise ctx.option_error(f"lever_arm.{cid}: an antenna offset of {max(abs(float(x)) for x in arm):g} m "
                                       f"(more than {LEVER_ARM_MAX_M:g} m); the lever arm is in metres — given in mm?",
                                       "lever_arm")
        return g

    def run(self, inputs, options: GnssOptions, ctx: Context) -> StageResult:
        block = inputs["block"]
        g = self._checked(options, ctx)
        frame = frame_of_block(block)
        crs = g.crs or options.crs
        unit = 1000.0 if block.object_unit == "mm" else 1.0
        if crs is None or frame.is_identity and str(crs).strip().lower() in ("local", "none"):
            X = g.xyz.copy()
            if crs is None and not frame.is_identity:
                raise InputError("the GNSS file has no '# crs:' line and no crs option, but the block is in a CRS",
                                 path=g.path, field="crs")
        elif frame.is_identity:
            raise InputError(f"the GNSS file is in {crs!r} but the block has no CRS (a local system): give the "
                             "positions in the block's system with '# crs: local'", path=g.path, field="crs")
        else:
            from baarda.pipeline.crs import parse_crs

            src = parse_crs(crs, path=g.path if g.crs else ctx.project_file, line=g.crs_line if g.crs else None,
                            field="crs")
            user = LocalFrame(src.to_wkt(), frame.origin, frame.a, frame.f)
            X = user.to_local(g.xyz)
        sig = np.where(np.isnan(g.sigma), np.asarray(options.sigma_mm) / 1000.0, g.sigma)
        unknown = self._matched(g, options, block, ctx)
        arms = {k: np.asarray(v, float) * unit for k, v in options.lever_arm.items()}
        out, info = apply_gnss(block, g.photo, X * unit, sig * unit, lever_arm=arms,
                               opk_default=None if options.opk_deg is None else np.radians(options.opk_deg))
        if unknown:
            ctx.warn(f"{len(unknown)} GNSS row(s) for photos not in the block skipped")
        info["file"] = str(g.path)
        info["crs"] = crs
        gn = out.gnss
        u = out.object_unit
        arm_txt = ", ".join(f"camera `{k}` ({', '.join(f'{x:g}' for x in v)})" for k, v in options.lever_arm.items())
        report = (f"{info['photos_with_gnss']} photos get GNSS antenna observations from `{g.path.name}` "
                  f"(CRS {crs!r}), σ E/N/h median {np.median(sig[:, 0]) * 1000:.0f}/{np.median(sig[:, 1]) * 1000:.0f}/"
                  f"{np.median(sig[:, 2]) * 1000:.0f} mm; lever arm (camera frame, m): "
                  + (arm_txt or "none") + ". The bundle adjusts them as observations "
                  "`X_antenna + v = X0 + R_cam_from_worldᵀ · e` of each photo's position and attitude "
                  "(residuals, redundancy numbers and w-tests in its GNSS section; `docs/crs.md`)."
                  + (f" {info['initial_centres']} photo(s) without a projection centre start from the antenna "
                     "reduced with their attitude." if info["initial_centres"] else ""))
        med = np.median(sig, axis=0) * 1000
        arms_txt = "; ".join(f"camera {k} ({', '.join(f'{x:g}' for x in v)}) m" for k, v in options.lever_arm.items())
        info["headline"] = (f"{info['photos_with_gnss']} photo(s) with GNSS antennas from {g.path.name} ({crs}): "
                            f"σ E/N/h median {med[0]:.0f}/{med[1]:.0f}/{med[2]:.0f} mm, range "
                            f"{np.min(sig) * 1000:.0f}–{np.max(sig) * 1000:.0f} mm; lever arm {arms_txt or 'none'}")
        s3 = gn.sigma
        o = length_suffix(u)
        table = TableData({"photo": out.photos.ids[gn.photo].tolist(),
                           **{f"{a}{o}": gn.XYZ[:, i] for i, a in enumerate("XYZ")},
                           **{f"s{a}{o}": s3[:, i] for i, a in enumerate("XYZ")},
                           **{f"arm_{a}{o}": gn.lever_arm[:, i] for i, a in enumerate("xyz")}},
                          f"GNSS antenna observations in the block's frame and lever arms in the camera frame ({u})")
        return StageResult(artefacts={"block": out}, summary=info, report=report, tables={"antennas": table})
