"""Writer of DBAT script projects and the stage ``dbat-export``.

The inverse of :func:`.reader.read_dbat` / :func:`.reader.dbat_block` (format: ``docs/dbat.md``):
a folder with the script ``<name>.xml`` and the files it names, laid out as DBAT's own demos
(``reference/control.txt``, ``reference/check.txt``, ``images/images.txt``,
``measurements/markpts.txt``), which DBAT and baarda's ``dbat`` source read:

* the camera (one, with the ``brown-backward`` model — PhotoModeler's backward Brown, DBAT lens
  model 3 — any other model is an error) with its values as *loaded* initial values (``<cc>``,
  ``<pp>``, ``<K>``, ``<P>``, ``<aspect>``, ``<skew>``: :func:`.reader.dbat_from_baarda`, the
  inverse of what the reader uses) and which of them are estimated (``set_bundle_estimate_params``);
* control points with their prior values and σ (0: fixed), check points, the photos as an image
  list (DBAT numbers, the photo ids as file names), the active image measurements in pixels
  (origin at the image corner, y down) with their σ.

* the photos' orientations, when every photo has one, as ``<prior_eo>`` (``prior/eo.txt``:
  ``id,x,y,z,omega,phi,kappa`` in degrees; DBAT's ω φ κ are baarda's, ``docs/dbat.md``) and initial
  values (``set_initial_values`` ``<eo>loaded</eo>``), so the project does not resect; otherwise
  it resects every photo (``spatial_resection``).

DBAT scripts have no place for initial tie-point coordinates: the project intersects them
(``forward_intersection``) before the bundle, as the DBAT demos do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np

from baarda.pipeline.api import Context, InputError, StageResult, option
from baarda.pipeline.geometry import pixels_from_mm

from .reader import AP_NAMES, DbatCamera, DbatInfo, dbat_from_baarda

MODEL = "brown-backward"
_IO_TAGS = (("cc", "c"), ("px", "xp"), ("py", "yp"))


def _g(v: float) -> str:
    """Shortest text that reads back as the same float."""
    return repr(float(v))


def _whole(i) -> bool:
    s = str(i).strip()
    return s.isdigit() or (s.startswith("-") and s[1:].isdigit())


def _flag(sigma: float, what: str) -> bool:
    if sigma == 0.0:
        return False
    if math.isinf(sigma):
        return True
    raise InputError(f"{what} has the a-priori σ {sigma:g}; a DBAT script estimates a camera parameter or keeps it "
                     "fixed (σ ∞ or 0), it has no weighted ones", field=what.split()[-1])


def _io_flags(est: dict) -> list[tuple[str, bool]]:
    """``set_bundle_estimate_params`` ``<io>`` children: DBAT's groups (``pp``, ``K``, ``P``) where
    the group agrees, the single parameters (``px``, ``K2``, …; baarda's reader takes them) where not."""
    out = [("cc", est["cc"])]
    for group, names in (("pp", ("px", "py")), ("K", ("K1", "K2", "K3")), ("P", ("P1", "P2"))):
        vals = {est[n] for n in names}
        out += [(group, vals.pop())] if len(vals) == 1 else [(n, est[n]) for n in names]
    return out + [("aspect", est["aspect"]), ("skew", est["skew"])]


def in_user_crs(block):
    """``block`` with its points, projection centres and attitudes back in the user's CRS when a
    source read them in one (``block.crs``; the adjustment's local east-north-up frame,
    ``docs/crs.md``), else ``block`` itself: a DBAT script has no CRS, so its coordinates are the
    user's (the ``dbat`` source's ``crs`` option reads them back).  σ stay metres E/N/U."""
    from baarda.pipeline.crs import frame_of_block
    from baarda.pipeline.geometry import opk_from_rotation_many, rotation_from_opk_many

    frame = frame_of_block(block)
    if frame.is_identity:
        return block
    pts, ph = block.points, block.photos
    XYZ = np.array(pts.XYZ, float)
    known = np.isfinite(XYZ).all(axis=1)
    XYZ[known] = frame.from_local(XYZ[known])
    X0, opk = np.array(ph.X0, float), np.array(ph.opk, float)
    has = np.isfinite(X0).all(axis=1)
    if has.any():
        Rl = frame.rotation_from_local(X0[has])                      # R_cam_from_local = R_cam_from_crs · Rl
        ok = np.isfinite(opk[has]).all(axis=1)
        R = rotation_from_opk_many(np.where(ok[:, None], opk[has], 0.0)) @ np.transpose(Rl, (0, 2, 1))
        opk[has] = np.where(ok[:, None], opk_from_rotation_many(R), opk[has])
        X0[has] = frame.from_local(X0[has])
    return block.replace(points=pts.replace(XYZ=XYZ), photos=ph.replace(X0=X0, opk=opk), crs=None)


def dbat_files(block, *, name: str = "baarda", prior=None) -> tuple[dict[str, str], dict]:
    """The files of a DBAT script project of ``block`` as ``{relative path: text}``, and ``info``.

    ``prior`` a block with the same points holding the surveyed coordinates of control and check
    points (default ``block``: after a bundle pass its ``block_in``, so that the control keeps its
    prior values while the camera carries the adjusted ones).  Raises :class:`InputError` for what
    a DBAT script cannot hold: more than one camera, a model other than ``brown-backward``, ids that
    are not whole numbers, planimetric or height-only control, weighted camera parameters, no pixel
    size."""
    from baarda.pipeline.crs import crs_label, frame_of_block

    crs = frame_of_block(block).crs
    block = in_user_crs(block)
    prior = None if prior is None else in_user_crs(prior)
    cams, ph, pts, obs = block.cameras, block.photos, block.points, block.observations
    if len(cams) != 1:
        raise InputError(f"a DBAT script holds one camera, the block has {len(cams)}", field="camera")
    cid = str(cams.ids[0])
    model = str(cams.ap_model[0])
    if model != MODEL:
        raise InputError(f"camera {cid!r} uses the {model!r} model; DBAT projects use PhotoModeler's backward Brown "
                         f"model ({MODEL!r}, DBAT lens model 3)", field="ap_model")
    W, H = (int(v) for v in cams.resolution[0])
    p = float(cams.pixel_mm[0])
    if not (W > 0 and H > 0 and math.isfinite(p) and p > 0):
        raise InputError(f"camera {cid!r} has no image size or pixel pitch; DBAT's marks are pixels", field="camera")
    bad = [str(i) for i in pts.ids.tolist() if not _whole(i)]
    if bad:
        raise InputError(f"point id {bad[0]!r}: DBAT's point ids are whole numbers", field="point")
    prior = block if prior is None else prior
    k_prior = prior.points.index_of(pts.ids.tolist())
    XYZp = np.asarray(prior.points.XYZ, float)[k_prior]
    sigp = np.asarray(prior.points.sigma, float)[k_prior]
    # the camera: values as loaded initial values, estimate flags
    ap = np.zeros(len(AP_NAMES))
    ap[:min(len(AP_NAMES), cams.ap.shape[1])] = np.asarray(cams.ap[0], float)[:len(AP_NAMES)]
    shell = DbatCamera(name=cid, unit="mm", sensor=(W * p, H * p), image=(W, H), focal=float(cams.c[0]), cc=None,
                       pp=None, K=(), P=(), aspect=1.0, skew=0.0, model=3, nK=3, nP=2, line=0)
    d = dbat_from_baarda(cams.c[0], cams.xp[0], cams.yp[0], ap, shell)
    est = {tag: _flag(float(cams.sigma_iop[0, k]), f"camera {cid!r} {attr}") for k, (tag, attr) in enumerate(_IO_TAGS)}
    sap = np.full(len(AP_NAMES), 0.0)
    sap[:min(len(AP_NAMES), cams.sigma_ap.shape[1])] = np.asarray(cams.sigma_ap[0], float)[:len(AP_NAMES)]
    est.update({n: _flag(float(sap[k]), f"camera {cid!r} {n}") for k, n in enumerate(AP_NAMES)})
    # points
    ctrl = np.flatnonzero(pts.role == "full")
    partial = np.flatnonzero(np.isin(pts.role, ("xy", "z")))
    if partial.size:
        k = partial[0]
        raise InputError(f"point {str(pts.ids[k])!r} is {str(pts.role[k])!r} control; DBAT's control points have all three "
                         "coordinates", field="role")
    chk = np.flatnonzero(pts.role == "check")
    for k in np.r_[ctrl, chk]:
        if not np.isfinite(XYZp[k]).all():
            raise InputError(f"{str(pts.role[k])} point {str(pts.ids[k])!r} has no coordinates", field="point")
    s_ctrl = sigp[ctrl]
    if not np.isfinite(s_ctrl).all():
        k = ctrl[np.flatnonzero(~np.isfinite(s_ctrl).all(axis=1))[0]]
        raise InputError(f"control point {str(pts.ids[k])!r} has a free coordinate; DBAT's control is fixed or "
                         "weighted in X, Y and Z", field="sigma")
    weighted = bool((s_ctrl > 0).any())
    files: dict[str, str] = {}
    head = "# written by baarda (dbat-export)\n"
    if weighted:
        files["reference/control.txt"] = head + "# id, label, x, y, z, sx, sy, sz (σ 0: fixed)\n" + "".join(
            f"{pts.ids[k]}, {pts.ids[k]}, {_g(XYZp[k, 0])}, {_g(XYZp[k, 1])}, {_g(XYZp[k, 2])}, {_g(sigp[k, 0])}, "
            f"{_g(sigp[k, 1])}, {_g(sigp[k, 2])}\n" for k in ctrl)
    else:
        files["reference/control.txt"] = head + "# id, label, x, y, z (fixed)\n" + "".join(
            f"{pts.ids[k]}, {pts.ids[k]}, {_g(XYZp[k, 0])}, {_g(XYZp[k, 1])}, {_g(XYZp[k, 2])}\n" for k in ctrl)
    if chk.size:
        files["reference/check.txt"] = head + "# id, label, x, y, z\n" + "".join(
            f"{pts.ids[k]}, {pts.ids[k]}, {_g(XYZp[k, 0])}, {_g(XYZp[k, 1])}, {_g(XYZp[k, 2])}\n" for k in chk)
    # images: DBAT's numbers (those the block was read with, else 1 … m), the photo id as file name
    dbat: DbatInfo | None = block.meta.get("dbat")
    numbers = dbat.image_numbers if dbat else {}
    paths = dbat.image_paths if dbat else {}
    used = {str(v) for v in numbers.values()}
    nums, nxt = [], 1
    for pid in ph.ids.tolist():
        n = numbers.get(pid)
        if n is None or not _whole(n):
            while str(nxt) in used:
                nxt += 1
            n = str(nxt)
            used.add(n)
        nums.append(str(n))
    img_lines = []
    for pid, n in zip(ph.ids.tolist(), nums):
        path = paths.get(n) if n in paths and Path(str(paths[n]).replace("\\", "/")).stem == pid else f"{pid}.jpg"
        img_lines.append(f"{n}, {path}\n")
    files["images/images.txt"] = head + "# id, path\n" + "".join(img_lines)
    # orientations: all or none (a DBAT project resects every photo or none)
    oriented = bool(len(ph)) and bool(ph.has_orientation.all())
    if oriented:
        opk_d = np.degrees(np.asarray(ph.opk, float))
        files["prior/eo.txt"] = head + "# id, x, y, z, omega, phi, kappa (degrees)\n" \
            + "".join(f"{n}, {_g(x[0])}, {_g(x[1])}, {_g(x[2])}, {_g(a[0])}, {_g(a[1])}, {_g(a[2])}\n"
                      for n, x, a in zip(nums, np.asarray(ph.X0, float), opk_d))
    # marks: active observations, pixels from the image corner, y down
    act = np.flatnonzero(obs.active)
    uv = pixels_from_mm(obs.xy[act], (W, H), p, convention="colmap") if act.size else np.zeros((0, 2))
    vx, vy, cxy = obs.cov[act, 0, 0], obs.cov[act, 1, 1], obs.cov[act, 0, 1]
    sxy = np.sqrt(0.5 * (vx + vy)) / p
    unequal = int((~np.isclose(vx, vy, rtol=1e-9, atol=0) | (cxy != 0)).sum())
    files["measurements/markpts.txt"] = head + "# image id, point id, x, y, sxy (pixels, origin at the corner, y down)\n" \
        + "".join(f"{nums[obs.photo[r]]}, {pts.ids[obs.point[r]]}, {_g(u)}, {_g(v)}, {_g(s)}\n"
                  for r, (u, v), s in zip(act, uv, sxy))
    # the script
    min_rays = dbat.min_rays if dbat else 2
    io = "".join(f"          <{t}>{'true' if v else 'false'}</{t}>\n" for t, v in _io_flags(est))
    ctrl_fmt = "id,label,x,y,z,sx,sy,sz" if weighted else "id,label,x,y,z"
    eo_xml = ("\n    <prior_eo>\n      <file format=\"id,x,y,z,omega,phi,kappa\" units=\"degrees\">prior/eo.txt</file>\n"
              "    </prior_eo>\n" if oriented else "")
    eo_init = "        <eo>loaded</eo>\n" if oriented else ""
    resection = "" if oriented else "    <operation>spatial_resection</operation>\n"
    check_xml = ("    <check_pts>\n      <file format=\"id,label,x,y,z\">reference/check.txt</file>\n    </check_pts>\n"
                 if chk.size else "")
    crs_note = f" Coordinates in {escape(crs_label(crs))}." if crs else ""
    xml = f"""<?xml version="1.0" encoding="UTF-8"?>
<document dbat_script_version="1.0">
  <c>Written by baarda's dbat-export: the camera's values and (when every photo has one) the
  orientations are the initial values (io, eo loaded); DBAT scripts hold no initial tie points,
  so they are intersected before the bundle.{crs_note}</c>
  <meta>
    <name>{escape(name)}</name>
    <project_unit>{escape(block.object_unit)}</project_unit>
    <software>baarda</software>
  </meta>

  <input base_dir="$HERE">
    <ctrl_pts>
      <file format="{ctrl_fmt}">reference/control.txt</file>
    </ctrl_pts>
{check_xml}
    <images>
      <file format="id,path">images/images.txt</file>
    </images>

    <image_pts>
      <file format="im,id,x,y,sxy">measurements/markpts.txt</file>
    </image_pts>
{eo_xml}
    <cameras>
      <camera>
        <name>{escape(cid)}</name>
        <unit>mm</unit>
        <sensor>{_g(W * p)},{_g(H * p)}</sensor>
        <image>{W},{H}</image>
        <focal>{_g(cams.c[0])}</focal>
        <cc>{_g(d['cc'])}</cc>
        <pp>{_g(d['px'])},{_g(d['py'])}</pp>
        <K>{_g(d['K1'])},{_g(d['K2'])},{_g(d['K3'])}</K>
        <P>{_g(d['P1'])},{_g(d['P2'])}</P>
        <aspect>{_g(1.0 + d['as'])}</aspect>
        <skew>{_g(d['sk'])}</skew>
        <model>3</model>
        <nK>3</nK>
        <nP>2</nP>
      </camera>
    </cameras>
  </input>

  <operations>
    <operation min_rays="{min_rays}">check_ray_count</operation>
    <operation>
      <set_initial_values>
        <io>loaded</io>
{eo_init}        <op>loaded</op>
      </set_initial_values>
    </operation>
    <operation>
      <set_bundle_estimate_params>
        <io>
{io}        </io>
        <eo>
          <all>true</all>
        </eo>
        <op>
          <all>default</all>
        </op>
      </set_bundle_estimate_params>
    </operation>
{resection}    <operation>forward_intersection</operation>
    <operation>bundle_adjustment</operation>
  </operations>
</document>
"""
    files[f"{name}.xml"] = xml
    info = {"crs": crs_label(crs) if crs else None, "script": f"{name}.xml", "images": len(ph), "orientations": oriented, "control": int(ctrl.size), "check": int(chk.size),
            "weighted_control": weighted, "marks": int(act.size), "inactive_left_out": int(len(obs) - act.size),
            "marks_with_unequal_sigma": unequal, "estimated": sorted(k for k, v in est.items() if v)}
    return files, info


def write_dbat(block, folder: str | Path, *, name: str = "baarda", prior=None) -> dict:
    """Write :func:`dbat_files` into ``folder`` (created); returns its info with ``files``."""
    folder = Path(folder)
    files, info = dbat_files(block, name=name, prior=prior)
    for rel, text in files.items():
        f = folder / rel
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text(text, encoding="utf-8")
    return {**info, "files": sorted(files)}


# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DbatExportOptions:
    path: Path = option(Path("dbat"), "output folder inside the run directory (the script and its files)")
    name: str = option("baarda", "the script's name: <path>/<name>.xml")
    source: bool = option(False, "write the camera as the source read it instead of the bundle's adjusted values")

    def __post_init__(self):
        if not self.name or any(ch in self.name for ch in "/\\:") or self.name.startswith("."):
            raise ValueError(f"name must be a plain file name, got {self.name!r}")


class DbatExport:
    summary = "block (camera adjusted when a bundle ran) → DBAT script project (XML, control, images, marks)"
    reads = ("block", "bundle?")
    writes = ()
    paths = {"path": "output"}
    outputs = ()                          # no table or figure: every other name is free for path
    Options = DbatExportOptions

    def run(self, inputs, options: DbatExportOptions, ctx: Context) -> StageResult:
        bundle = inputs.get("bundle")
        block, prior = inputs["block"], None
        if bundle is not None:
            prior = getattr(bundle, "block_in", None)
            block = prior if options.source and prior is not None else bundle.block
        out = ctx.output_path(options.path, "path")
        try:
            info = write_dbat(block, out, name=options.name, prior=prior)
        except InputError as e:
            raise ctx.option_error(f"cannot write a DBAT project: {e.message}", "path") from None
        if info["marks_with_unequal_sigma"]:
            ctx.warn(f"{info['marks_with_unequal_sigma']} mark(s) with different σ in x and y or a correlation: "
                     "written with one σ (the root of the mean variance), as DBAT's sxy")
        what = "adjusted" if bundle is not None and not options.source else "source"
        eo = "and orientations " if info["orientations"] else ""
        report = (f"Wrote the DBAT script project `{options.path}/{info['script']}` ({what} camera {eo}as initial values; "
                  f"estimated: {', '.join(info['estimated']) or 'none'}): {info['images']} images, {info['control']} "
                  f"control ({'weighted' if info['weighted_control'] else 'fixed'}) and {info['check']} check points, "
                  f"{info['marks']} marks.")
        if info["crs"]:
            report += (f"  Coordinates in {info['crs']} (the adjustment's local frame converted back; read them with "
                       f"the dbat source's crs = \"{info['crs']}\").")
        if info["inactive_left_out"]:
            report += f"  {info['inactive_left_out']} inactive measurement(s) left out."
        headline = (f"DBAT project {options.path}/{info['script']} ({what} camera): {info['images']} images, "
                    f"{info['control']} control ({'weighted' if info['weighted_control'] else 'fixed'}) and "
                    f"{info['check']} check points, {info['marks']} marks"
                    + (f"; {info['crs']}" if info["crs"] else ""))
        return StageResult(summary={**info, "path": str(options.path), "camera": what, "headline": headline},
                           report=report)
