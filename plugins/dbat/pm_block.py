"""A PhotoModeler export as a DBAT project, as DBAT's demos (``camcaldemo.m``, ``camcaldemo_1ray.m``,
``camcaldemo_missing_obs.m``) set it up with ``prob2dbatstruct`` — pure.

The result is a :class:`~baarda.plugins.dbat.reader.DbatScript`, so the ``dbat`` plugin's block,
report and export apply unchanged: one camera (DBAT lens model 3, baarda's ``brown-backward``) with
the pixel size ys / H for both axes, one photo per photo block, the marks in pixels with their σ,
control points from a DBAT control file (``loadcpt``: ``id,label,x,y,z[,σ]``, σ one value σxyz, two
σxy,σz, three σx,σy,σz; none: fixed) and/or the export's control section.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from baarda.pipeline.api import InputError
from baarda.pipeline.errors import finite_number as _num, read_text_limited
from baarda.pipeline.model import FIXED
from .pm_reader import PmExport
from .reader import IO_FLAGS, DbatCamera, DbatScript, MarkFile, PointSet

DBAT_ESTIMATE_NAMES = {"cc": ("cc",), "px": ("px",), "py": ("py",), "pp": ("px", "py"), "as": ("aspect",),
                       "aspect": ("aspect",), "sk": ("skew",), "skew": ("skew",), "K": ("K1", "K2", "K3"),
                       "P": ("P1", "P2"), "K1": ("K1",), "K2": ("K2",), "K3": ("K3",), "P1": ("P1",),
                       "P2": ("P2",), "all": IO_FLAGS}


def read_control(file: Path) -> PointSet:
    """A DBAT control-point file (``loadcpt``): ``id,label,x,y,z`` then 0, 1, 2 or 3 σ values."""
    file = Path(file)
    text = read_text_limited(file, what="the control-point file", field="id")
    ids, labels, XYZ, sig, lines = [], [], [], [], []
    seen = {}
    for i, raw in enumerate(text.splitlines(), start=1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        toks = [t.strip() for t in s.split(",")]
        if len(toks) not in (5, 6, 7, 8):
            raise InputError(f"expected id,label,x,y,z and 0–3 σ values (comma-separated), got {len(toks)} fields",
                             path=file, line=i, field="x" if len(toks) < 5 else "sz")
        try:
            pid = str(int(toks[0]))
        except ValueError:
            raise InputError(f"a control point's id is a whole number, got {toks[0]!r}", path=file, line=i,
                             field="id") from None
        if pid in seen:
            raise InputError(f"point {pid} listed twice (first on line {seen[pid]})", path=file, line=i, field="id")
        seen[pid] = i
        xyz = [_num(t, file, i, c) for t, c in zip(toks[2:5], "xyz")]
        names = {6: ("sxyz",), 7: ("sxy", "sz"), 8: ("sx", "sy", "sz")}.get(len(toks), ())
        sv = [_num(t, file, i, c) for t, c in zip(toks[5:], names)]
        for v, c in zip(sv, names):
            if v < 0:
                raise InputError(f"a standard deviation must not be negative, got {v:g}", path=file, line=i, field=c)
        s3 = ([FIXED] * 3 if not sv else sv * 3 if len(sv) == 1 else [sv[0], sv[0], sv[1]] if len(sv) == 2
              else sv)
        ids.append(pid)
        labels.append(toks[1])
        XYZ.append(xyz)
        sig.append(s3)
        lines.append(i)
    if not ids:
        raise InputError("no control points in the file", path=file, line=1, field="id")
    return PointSet(ids=ids, labels=labels, XYZ=np.asarray(XYZ, float), sigma=np.asarray(sig, float), file=file,
                    filters=[], lines=lines)


def parse_estimate(names, path, field="estimate") -> dict[str, bool]:
    """DBAT's ``setcamest`` in words: a list of names (``cc``, ``pp``, ``px``, ``py``, ``as``, ``sk``, ``K``,
    ``P``, ``K1``…``P2``, ``all``), each optionally preceded by ``not`` (e.g. ``["all", "not", "sk"]``)."""
    est = {k: False for k in IO_FLAGS}
    value = True
    for n in names:
        if n == "not":
            value = False
            continue
        if n not in DBAT_ESTIMATE_NAMES:
            raise InputError(f"unknown camera parameter {n!r} (known: {', '.join(DBAT_ESTIMATE_NAMES)}, and 'not')",
                             path=path, field=field)
        for k in DBAT_ESTIMATE_NAMES[n]:
            est[k] = value
    return est


def pm_camera(pm: PmExport, focal: float | None) -> DbatCamera:
    """The export's default camera in DBAT's terms (``prob2dbatstruct``): pixel size ys / H for both
    axes (``sensor`` ``auto,ys``), pp as written (mm from the image corner, y down), K and P negated,
    aspect 1 − (xs/W)/(ys/H) as DBAT's ``as``."""
    c, xp, yp, xs, ys = pm.camera[:5]
    W, H = pm.image_size
    as_ = 1.0 - (xs / W) / (ys / H)
    return DbatCamera(name=pm.title, unit="mm", sensor=(None, float(ys)), image=(int(W), int(H)),
                      focal=float(focal if focal is not None else c), cc=float(c), pp=(float(xp), float(yp)),
                      K=tuple(-pm.camera[5:8]), P=tuple(-pm.camera[8:10]), aspect=1.0 + as_, skew=0.0,
                      model=3, nK=3, nP=2, line=4)


def pm_script(pm: PmExport, *, control: PointSet | None = None, focal: float | None = None,
              camera: str = "default", estimate: dict[str, bool] | None = None, min_rays: int = 2,
              control_ids_above: int | None = 1000) -> tuple[DbatScript, dict]:
    """The export as a :class:`DbatScript` and DBAT's own counts (``info``): the redundancy and
    unknowns DBAT's bundle would have (every object point estimated, however few its rays) and the
    points it could not determine (fewer than 2 rays: DBAT's structural rank deficiency)."""
    if camera not in ("default", "loaded"):
        raise InputError(f"camera is 'default' or 'loaded', got {camera!r}", field="camera")
    cam = pm_camera(pm, focal)
    images = {str(p.number + 1): p.name for p in pm.photos}
    files = {}
    for p in pm.photos:
        name = re.split(r"[/\\]", p.name)[-1]
        cands = [pm.path.parent / name, pm.path.parent / p.name.replace("\\", "/")]
        files[str(p.number + 1)] = next((f for f in cands if f.is_file()), None)
    # control: the export's own section, else (as the demos) the control file's points matched by id
    sets = []
    if len(pm.control):
        ps = PointSet(ids=[str(int(i)) for i in pm.control[:, 0]], labels=[""] * len(pm.control),
                      XYZ=pm.control[:, 1:4], sigma=pm.control[:, 4:7], file=pm.path, filters=[],
                      lines=pm.control_lines.tolist())
        sets.append(ps)
    if control is not None:
        known = {i for s in sets for i in s.ids}
        obj_ids = {str(int(i)) for i in pm.objects[:, 0]}
        if control_ids_above is not None and not len(pm.control):
            candidates = {i for i in obj_ids if int(i) > control_ids_above}
        else:
            candidates = obj_ids
        keep = [k for k, i in enumerate(control.ids) if i in candidates and i not in known]
        sets.append(PointSet(ids=[control.ids[k] for k in keep], labels=[control.labels[k] for k in keep],
                             XYZ=control.XYZ[keep], sigma=control.sigma[keep], file=control.file, filters=[],
                             lines=[control.lines[k] for k in keep]))
    # marks of object (or control) points only, as prob2dbatstruct
    op_ids = np.union1d(pm.objects[:, 0], pm.control[:, 0]) if len(pm.control) else pm.objects[:, 0]
    m = pm.marks
    valid = np.isin(m[:, 1], op_ids) if len(op_ids) else np.ones(len(m), bool)
    mv = m[valid]
    marks = MarkFile(file=pm.path, image=[str(int(k) + 1) for k in mv[:, 0]], point=[str(int(k)) for k in mv[:, 1]],
                     uv=mv[:, 2:4].copy(), sigma_px=np.sqrt(0.5 * (mv[:, 4] ** 2 + mv[:, 5] ** 2)),
                     lines=pm.mark_lines[valid].tolist(), sigma_source="column")
    aniso = np.flatnonzero(mv[:, 4] != mv[:, 5])
    if len(aniso):
        raise InputError("baarda reads one σ per mark: sx and sy differ", path=pm.path,
                         line=int(pm.mark_lines[valid][aniso[0]]), field="sy")
    est = estimate if estimate is not None else {k: k != "skew" for k in IO_FLAGS}
    script = DbatScript(path=pm.path, name=pm.title, object_unit="m", control=sets, check=[], images=images,
                        image_files=files, images_list=None, marks=[marks], camera=cam, min_rays=min_rays,
                        io_initial=camera, estimate_io=est, estimate_eo=True,
                        operations=["spatial_resection", "forward_intersection", "bundle_adjustment"],
                        unknown_operations=[])
    # DBAT's counts: every object point is an unknown (fixed control excepted), whatever its rays
    all_ids = np.unique(op_ids).astype(int)
    fixed = {i for s in sets for i, sg in zip(s.ids, s.sigma) if np.all(sg == 0)}
    rays = dict(zip(*np.unique(mv[:, 1].astype(int), return_counts=True)))
    n_op = sum(3 for i in all_ids if str(i) not in fixed)
    n_io = sum(est.values())
    unknowns = n_io + 6 * len(pm.photos) + n_op
    under = [str(i) for i in all_ids if str(i) not in fixed and rays.get(i, 0) < 2]
    info = {"observations": 2 * len(mv), "unknowns": unknowns, "redundancy": 2 * len(mv) - unknowns,
            "unknowns_io": n_io, "unknowns_eo": 6 * len(pm.photos), "unknowns_op": n_op,
            "undetermined": under, "rays_of_undetermined": [int(rays.get(int(i), 0)) for i in under],
            "marks_not_object_points": int((~valid).sum()), "smart_shift": pm.renumbered_smart,
            "sigma_reset": pm.sigma_reset}
    return script, info
