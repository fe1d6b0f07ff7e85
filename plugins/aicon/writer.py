"""Writer of AICON 3D Studio exports (``.ior .eor .obc .phc .scale``) and the stage ``aicon-export``.

The inverse of :mod:`.reader` (file formats: ``docs/aicon-format.md``): a block whose cameras use
the ``aicon`` model (or ``brown``, the same algebra with r0 = 0, or ``none``) and whose ids are
whole numbers, as AICON's files need, is written so that :func:`.reader.read_aicon` and
:func:`.reader.aicon_block` give the same block back (``tests/export/test_aicon_writer.py``).
Lengths in mm (a block in metres is scaled), c negative in the ``.ior`` as AICON writes it,
residuals ``vx vy`` in AICON's sign (computed − observed).  AICON's flag columns, whose meaning
the exports do not document, are written as ``.eor`` ``0 0 0``, ``.obc`` ``1 1 0`` and ``.phc``
``1 active 1``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baarda.pipeline.api import Context, InputError, StageResult, option

WRITABLE_MODELS = {"aicon": 7, "brown": 7, "none": 0}


def _g(v: float) -> str:
    """Shortest text that reads back as the same float."""
    return repr(float(v))


def _check_ids(ids, what: str) -> None:
    for i in ids:
        try:
            ok = float(i) == int(float(i)) and str(i).strip() == str(i)
        except ValueError:
            ok = False
        if not ok:
            raise InputError(f"AICON files need whole-number {what} ids, got {str(i)!r}", field=what)


def write_aicon(block, prefix: str | Path, *, residuals=None, point_sigma=None) -> dict:
    """Write ``block`` as ``prefix.ior/.eor/.obc/.phc`` (and ``.scale`` when
    ``block.scale_bars`` holds scale bars).  ``residuals (k, 2)`` baarda's v (observed −
    computed, mm) for the ``.phc`` (0 without), ``point_sigma (n, 3)`` for the ``.obc`` (0 without).
    Raises :class:`InputError` for ids that are not whole numbers, a camera model AICON cannot
    express, or photos/points without coordinates."""
    prefix = Path(prefix)
    cams, ph, pts, obs = block.cameras, block.photos, block.points, block.observations
    s = 1000.0 if block.object_unit == "m" else 1.0
    for ids, what in ((cams.ids, "camera"), (ph.ids, "photo"), (pts.ids, "point")):
        _check_ids(ids, what)
    ap_meta = block.ap_meta
    lines = []
    for j, cid in enumerate(cams.ids):
        model = str(cams.ap_model[j])
        if model not in WRITABLE_MODELS:
            raise InputError(f"camera {cid!r} uses the {model!r} model; AICON files hold 'aicon', 'brown' "
                             "(r0 = 0) or 'none'", field="ap_model")
        ap = np.zeros(7)
        ap[:WRITABLE_MODELS[model]] = np.asarray(cams.ap[j], float)[:WRITABLE_MODELS[model]]
        r0 = float(ap_meta.get(str(cid), {}).get("r0", 0.0)) if model == "aicon" else 0.0
        fmt = np.asarray(cams.format_mm[j], float)
        res = np.asarray(cams.resolution[j], int)
        if not np.isfinite(fmt).all():
            fmt = res * float(cams.pixel_mm[j]) if np.isfinite(cams.pixel_mm[j]) else np.zeros(2)
        lines += [f"{cid} -999 {_g(-cams.c[j])} {_g(cams.xp[j])} {_g(cams.yp[j])} {_g(ap[0])} {_g(ap[1])} {_g(r0)}",
                  f"    {_g(ap[2])}", f"    {_g(ap[3])} {_g(ap[4])}", f"    {_g(ap[5])} {_g(ap[6])}",
                  f"    {_g(fmt[0])} {_g(fmt[1])} {int(res[0])} {int(res[1])}"]
    files = {}
    files["ior"] = _write(prefix, "ior", lines)
    used_ph = np.zeros(len(ph), bool)
    used_ph[obs.photo] = True
    bad = np.flatnonzero(~ph.has_orientation)
    if bad.size:
        raise InputError(f"photo {ph.ids[bad[0]]!r} has no orientation; AICON's .eor needs X0 and ω φ κ",
                         field="photo")
    files["eor"] = _write(prefix, "eor", [
        f"{pid} {cams.ids[ph.camera[i]]} {_g(ph.X0[i, 0] * s)} {_g(ph.X0[i, 1] * s)} {_g(ph.X0[i, 2] * s)} "
        f"{_g(ph.opk[i, 0])} {_g(ph.opk[i, 1])} {_g(ph.opk[i, 2])} 0 0 0" for i, pid in enumerate(ph.ids)])
    ok = np.isfinite(pts.XYZ).all(axis=1)
    rays = np.bincount(obs.point[obs.active], minlength=len(pts))
    sig = np.zeros((len(pts), 3)) if point_sigma is None else np.nan_to_num(np.asarray(point_sigma, float) * s)
    files["obc"] = _write(prefix, "obc", [
        f"{pts.ids[k]} {_g(pts.XYZ[k, 0] * s)} {_g(pts.XYZ[k, 1] * s)} {_g(pts.XYZ[k, 2] * s)} "
        f"{_g(sig[k, 0])} {_g(sig[k, 1])} {_g(sig[k, 2])} {int(rays[k])} 1 1 0" for k in np.flatnonzero(ok)])
    sxy = np.sqrt(np.stack([obs.cov[:, 0, 0], obs.cov[:, 1, 1]], axis=1))
    vxy = np.zeros((len(obs), 2)) if residuals is None else -np.asarray(residuals, float)   # AICON: computed − observed
    files["phc"] = _write(prefix, "phc", [
        f"{ph.ids[obs.photo[k]]} {pts.ids[obs.point[k]]} {_g(obs.xy[k, 0])} {_g(obs.xy[k, 1])} {_g(sxy[k, 0])} "
        f"{_g(sxy[k, 1])} {_g(vxy[k, 0])} {_g(vxy[k, 1])} 1 {int(bool(obs.active[k]))} 1" for k in range(len(obs))])
    dist = block.scale_bars.rows()
    if dist:
        files["scale"] = _write(prefix, "scale", [
            f'{k} "Scalebar{k}" {a} {b} {_g(d * s)} {_g(sg * s)} 1' for k, (a, b, d, sg) in enumerate(dist)])
    return {"files": {k: str(v) for k, v in files.items()}, "cameras": len(cams), "images": len(ph),
            "points": int(ok.sum()), "measurements": len(obs), "scale_bars": len(dist)}


def _write(prefix: Path, suffix: str, lines: list[str]) -> Path:
    p = prefix.with_name(prefix.name + "." + suffix)
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return p


# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class AiconExportOptions:
    path: Path = option(Path("aicon/export"), "output prefix inside the run directory (<path>.ior, .eor, …)")
    residuals: bool = option(True, "write the bundle's residuals into the .phc (vx vy) and σ into the .obc")


class AiconExportStage:
    summary = "block (adjusted, with residuals and point σ when a bundle ran) → AICON 3D Studio files"
    reads = ("block", "bundle?")
    writes = ()
    paths = {"path": "output"}
    outputs = ()                          # no table or figure: every other name is free for path
    output_adds = {"path": (".ior", ".eor", ".obc", ".phc", ".scale")}   # the files made of the prefix
    Options = AiconExportOptions

    def run(self, inputs, options: AiconExportOptions, ctx: Context) -> StageResult:
        block = inputs["block"]
        bundle = inputs.get("bundle")
        resid = sig = None
        if options.residuals and bundle is not None and len(bundle.block.observations) == len(block.observations) \
                and np.array_equal(bundle.block.points.ids, block.points.ids):
            resid = bundle.residuals
            cov = np.asarray(bundle.cov_points, float)
            sig = np.sqrt(np.clip(np.einsum("kii->ki", cov), 0, None))
        out = ctx.output_path(options.path, "path", adds=self.output_adds["path"])
        out.parent.mkdir(parents=True, exist_ok=True)
        try:
            info = write_aicon(block, out, residuals=resid, point_sigma=sig)
        except InputError as e:
            raise ctx.option_error(f"cannot write AICON files: {e.message}", "path") from None
        report = (f"Wrote AICON files `{out.name}.*` ({', '.join(sorted(info['files']))}): {info['cameras']} camera(s), "
                  f"{info['images']} images, {info['points']} points, {info['measurements']} measurements"
                  + (", residuals and point σ of the bundle" if resid is not None else "") + ".")
        info["headline"] = (f"AICON files {out.name}.* ({', '.join(sorted(info['files']))}): {info['cameras']} "
                            f"camera(s), {info['images']} images, {info['points']} points, {info['measurements']} "
                            "measurements" + (", with the bundle's residuals and σ" if resid is not None else ""))
        return StageResult(summary=info, report=report)
