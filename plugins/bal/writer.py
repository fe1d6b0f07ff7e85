"""Writer of BAL ("Bundle Adjustment in the Large") problem files and the stage ``bal-export``.

The inverse of :func:`.bal.read_bal` / :func:`.bal.block_from_bal`: one BAL camera per photo
(Rodrigues ``r``, ``t``, ``f``, ``k1``, ``k2``), the photo's observations in pixels relative to the
image centre with y up, the points' coordinates.  The camera conversion is the reader's
(:func:`.bal.bal_from_baarda` is the inverse of :func:`.bal.baarda_from_bal`, side by side).

BAL's camera has one focal length, a radial polynomial in ``k1``, ``k2`` and nothing else, with
the principal point at the image centre.  A camera whose model or parameters BAL cannot hold
(another AP model, non-zero brown K3, P1, P2, B1, B2, a principal point off the centre) is
refused with an :class:`InputError` naming the camera and the parameter, unless ``drop = True``:
then K3 … B2 are written as 0 and the principal point is taken into the observations (each one
written relative to the principal point, which keeps the projection exact), each with a warning
(``docs/bal-libmv.md``, *Writing BAL files*).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baarda.pipeline.api import Context, InputError, StageResult, option
from baarda.pipeline.geometry import rotation_from_opk_many

from baarda.pipeline.camera.convert import BROWN

from .bal import BalProblem, bal_from_baarda

_BAL_HOLDS = ("K1", "K2")


def _g(v: float) -> str:
    """Shortest text that reads back as the same float."""
    return repr(float(v))


def bal_from_block(block, *, pixel_mm: float | None = None, drop: bool = False,
                   warn=None) -> tuple[BalProblem, dict]:
    """The BAL problem of ``block``: photos with an orientation become cameras (in photo order),
    points with coordinates and at least one active observation by an oriented photo become points
    (in point order), active observations of those become BAL observations (in the block's order).

    ``pixel_mm`` the pitch (mm) that turns mm into BAL's pixels (default: each camera's own; an
    error when a camera has none).  ``drop`` writes cameras BAL cannot hold without the parameters
    it cannot hold (``warn(text)`` is called for each); without it they raise :class:`InputError`.
    Returns the problem and ``info`` (counts, what was left out, the photo and point ids of the
    BAL indices)."""
    cams, ph, pts, obs = block.cameras, block.photos, block.points, block.observations
    say = warn if warn is not None else (lambda text: None)
    n_cam = len(cams)
    pitch = np.full(n_cam, np.nan) if pixel_mm is None else np.full(n_cam, float(pixel_mm))
    if pixel_mm is None:
        pitch = np.asarray(cams.pixel_mm, float).copy()
    K = np.zeros((n_cam, 2))
    pp = np.column_stack([cams.xp, cams.yp]).astype(float)
    for j, cid in enumerate(cams.ids.tolist()):
        if not (np.isfinite(pitch[j]) and pitch[j] > 0):
            raise InputError(f"camera {cid!r} has no pixel pitch; BAL files are in pixels: give the option "
                             "'pixel_mm'", field="pixel_mm")
        model = str(cams.ap_model[j])
        ap = np.asarray(cams.ap[j], float)
        if model == "none":
            pass
        elif model == "brown":
            K[j] = ap[:2] if ap.size >= 2 else np.r_[ap, np.zeros(2 - ap.size)]
            extra = [(BROWN[i], ap[i]) for i in range(2, min(ap.size, len(BROWN))) if ap[i] != 0.0]
            for name, value in extra:
                what = {"K3": "a third radial term", "P1": "decentring distortion", "P2": "decentring distortion",
                        "B1": "different scales in x and y (fx ≠ fy)", "B2": "shear"}[name]
                if not drop:
                    raise InputError(f"camera {cid!r}: {name} = {value:g} ({what}) cannot be written to a BAL file "
                                     "(f, k1, k2 only); option drop = true writes it as 0", field=name)
                say(f"camera {cid!r}: {name} = {value:g} dropped (BAL holds f, k1, k2 only)")
        else:
            if not drop:
                raise InputError(f"camera {cid!r} uses the {model!r} model; BAL files hold the brown model's K1, K2 "
                                 "(or 'none'); option drop = true writes it without its additional parameters",
                                 field="ap_model")
            if np.any(ap != 0.0):
                say(f"camera {cid!r}: the {model!r} model's additional parameters dropped (BAL holds f, k1, k2 only)")
        for name, value in (("xp", pp[j, 0]), ("yp", pp[j, 1])):
            if value != 0.0:
                if not drop:
                    raise InputError(f"camera {cid!r}: principal point {name} = {value:g} mm is not at the image "
                                     "centre, which BAL assumes; option drop = true writes the observations relative "
                                     "to the principal point", field=name)
                say(f"camera {cid!r}: principal point {name} = {value:g} mm taken into the observations "
                    "(written relative to it)")
    oriented = ph.has_orientation
    if not oriented.any():
        raise InputError("no photo has an orientation; a BAL file needs every camera's pose", field="photo")
    have_xyz = np.isfinite(pts.XYZ).all(axis=1)
    use = np.asarray(obs.active, bool) & oriented[obs.photo] & have_xyz[obs.point]
    pt_used = np.zeros(len(pts), bool)
    pt_used[obs.point[use]] = True
    ph_idx = np.flatnonzero(oriented)
    pt_idx = np.flatnonzero(pt_used)
    ph_new = np.full(len(ph), -1)
    ph_new[ph_idx] = np.arange(ph_idx.size)
    pt_new = np.full(len(pts), -1)
    pt_new[pt_idx] = np.arange(pt_idx.size)
    cam_of = ph.camera[ph_idx]
    R = rotation_from_opk_many(np.asarray(ph.opk[ph_idx], float))
    params = bal_from_baarda(cams.c[cam_of], K[cam_of, 0], K[cam_of, 1], R, ph.X0[ph_idx], pitch[cam_of])
    rows = np.flatnonzero(use)                                      # in the block's order
    cam_r = ph.camera[obs.photo[rows]]
    xy = (np.asarray(obs.xy[rows], float) - pp[cam_r]) / pitch[cam_r][:, None]
    problem = BalProblem(cam=ph_new[obs.photo[rows]], pt=pt_new[obs.point[rows]], xy=xy, cameras=params,
                         points=np.array(pts.XYZ[pt_idx], float))
    info = {"cameras": int(ph_idx.size), "points": int(pt_idx.size), "observations": int(rows.size),
            "skipped_photos": ph.ids[~oriented].tolist(),
            "skipped_points": int(len(pts) - pt_idx.size),
            "skipped_observations": int(len(obs) - rows.size),
            "photo_ids": ph.ids[ph_idx].tolist(), "point_ids": pts.ids[pt_idx].tolist()}
    return problem, info


def write_bal(problem: BalProblem, path: str | Path) -> Path:
    """Write ``problem`` as a BAL text file (one value per line for the parameters, as the original
    files; every number in its shortest round-trip form)."""
    path = Path(path)
    lines = [f"{len(problem.cameras)} {len(problem.points)} {len(problem.cam)}"]
    lines += [f"{int(c)} {int(p)} {_g(x)} {_g(y)}" for c, p, (x, y) in zip(problem.cam, problem.pt, problem.xy)]
    lines += [_g(v) for v in np.asarray(problem.cameras, float).reshape(-1)]
    lines += [_g(v) for v in np.asarray(problem.points, float).reshape(-1)]
    path.write_text("\n".join(lines) + "\n", encoding="ascii")
    return path


# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BalExportOptions:
    path: Path = option(Path("bal/problem.txt"), "output file inside the run directory")
    source: bool = option(False, "write the block as the source stage read it (initial values) instead of the "
                                 "bundle's adjusted block")
    pixel_mm: float = option(0.0, "pixel pitch, mm, that turns image coordinates into BAL's pixels (0: each "
                                  "camera's own)")
    drop: bool = option(False, "write cameras BAL cannot hold without what it cannot hold (K3, P1, P2, B1, B2 as "
                               "0; a principal point off the centre taken into the observations), with a warning "
                               "each; false: such a camera is an error")


class BalExport:
    summary = "block (adjusted when a bundle ran) → BAL problem file (one camera per photo: r, t, f, k1, k2)"
    reads = ("block", "bundle?")
    writes = ()
    paths = {"path": "output"}
    outputs = ()                          # no table or figure: every other name is free for path
    Options = BalExportOptions

    def run(self, inputs, options: BalExportOptions, ctx: Context) -> StageResult:
        bundle = inputs.get("bundle")
        block = inputs["block"] if bundle is None else bundle.block
        if options.source and bundle is not None:
            block = bundle.block_in            # the bundle hands on its adjusted block as 'block'

        out = ctx.output_path(options.path, "path")
        out.parent.mkdir(parents=True, exist_ok=True)
        try:
            problem, info = bal_from_block(block, pixel_mm=options.pixel_mm or None, drop=options.drop, warn=ctx.warn)
        except InputError as e:
            key = e.field if e.field in ("pixel_mm",) else "drop"
            raise ctx.option_error(f"cannot write a BAL file: {e.message}", key) from None
        write_bal(problem, out)
        what = "source" if options.source or bundle is None else "adjusted"
        report = (f"Wrote the {what} block as the BAL problem `{options.path}`: {info['cameras']} cameras (one per "
                  f"photo), {info['points']} points, {info['observations']} observations.")
        if info["skipped_photos"] or info["skipped_points"] or info["skipped_observations"]:
            report += (f"  Left out: {len(info['skipped_photos'])} photo(s) without orientation, "
                       f"{info['skipped_points']} point(s) without coordinates or active rays, "
                       f"{info['skipped_observations']} inactive or unusable observation(s).")
        summary = {k: v for k, v in info.items() if k not in ("photo_ids", "point_ids")}
        left = len(info["skipped_photos"]) + info["skipped_points"] + info["skipped_observations"]
        summary["headline"] = (f"BAL problem {options.path} ({what} block): {info['cameras']} cameras, "
                               f"{info['points']} points, {info['observations']} observations"
                               + (f"; left out {len(info['skipped_photos'])} photo(s), {info['skipped_points']} "
                                  f"point(s), {info['skipped_observations']} observation(s)" if left else ""))
        return StageResult(summary={**summary, "path": str(options.path), "block": what}, report=report)
