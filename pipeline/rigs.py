"""Rig tables of a project: read, check, attach to a block, and the table the bundle writes back
(``docs/rigs.md``).

The **rig table** (CSV, ``#`` comments, a header line) has one row per sensor of a rig::

    rig,camera,reference,status,X_mm,Y_mm,Z_mm,omega_deg,phi_deg,kappa_deg,sX_mm,sY_mm,sZ_mm,somega_deg,sphi_deg,skappa_deg
    stereo,left,yes,fixed,0,0,0,0,0,0,,,,,,
    stereo,right,no,estimated,,,,,,,,,,,,

``X, Y, Z`` the sensor's projection centre in the rig frame (the reference camera's image-space
frame: x right, y up, z back out of the lens) in the block's object unit (the suffix must say it:
``_m``, ``_mm`` or ``_mu`` for model units), ``omega, phi, kappa`` of ``R_sensor_from_rig`` in
degrees; ``status`` ``fixed`` (the values are held), ``weighted`` (the values are observations with
the ``s*`` σ) or ``estimated`` (free; with values and ``s*`` σ they are a calibration that the
bundle's stability test compares the estimate with; empty values: start values from the photos).
Columns other than these are ignored, so the ``bundle_rig.csv`` that the bundle writes reads back
as a rig table (its σ then the calibration's).

The **frame table** (CSV ``frame,photo``) puts each photo of a rig into a frame (one exposure of
the rig); ``frames_from_name`` (a regular expression whose first group, or whole match, on the
photo id is the frame) does the same without a file.
"""

from __future__ import annotations

import csv
import io
import re
from pathlib import Path

import numpy as np

from .adjustment import SENSOR_NAMES, rig_structure
from .errors import InputError, finite_number, quote, read_text_limited
from .model import Block, FrameMembers, RigSensors, Rigs
from .units import length_suffix, object_unit_text

__all__ = ["read_rig_table", "read_frame_table", "frames_from_names", "attach_rigs", "STATUSES"]

STATUSES = ("fixed", "weighted", "estimated")
YES = {"yes", "true", "1", "y", "ref", "reference"}
NO = {"no", "false", "0", "n", ""}


def _rows(path):
    """``(line, {column: value})`` of every data row of a CSV with a header (comments ``#``)."""
    text = read_text_limited(path, what="a rig or frame table")
    lines = [(i + 1, ln) for i, ln in enumerate(text.splitlines()) if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise InputError("empty table: expected a header line and rows", path=path)
    reader = csv.reader(io.StringIO("\n".join(ln for _, ln in lines)))
    header = [h.strip() for h in next(reader)]
    out = []
    for (line, _), cells in zip(lines[1:], reader):
        cells = [c.strip() for c in cells]
        if len(cells) > len(header):
            raise InputError(f"{len(cells)} values for {len(header)} columns", path=path, line=line)
        out.append((line, dict(zip(header, cells + [""] * (len(header) - len(cells))))))
    return header, lines[0][0], out


def read_rig_table(path, block: Block) -> RigSensors:
    """The rig table ``path`` (module docstring) for the cameras of ``block``: an :class:`InputError`
    naming the file, line and field for an unknown camera, a length column in another unit than the
    block's, an unknown status, a value that is not a number, a fixed or weighted sensor without its
    values or σ."""
    path = str(path)
    header, hline, rows = _rows(path)
    unit = object_unit_text(block)
    suf = length_suffix(unit)
    for need in ("rig", "camera", "reference"):
        if need not in header:
            raise InputError(f"the header has no column {need!r} (expected rig, camera, reference, status, "
                             f"X{suf}, …)", path=path, line=hline, field=need)
    for h in header:
        m = re.fullmatch(r"(s?)([XYZ])_(\w+)", h)
        if m and "_" + m.group(3) != suf:
            raise InputError(f"column {h!r}: lengths are in the block's object unit ({unit}): {m.group(1)}{m.group(2)}"
                             f"{suf}", path=path, line=hline, field=h)
    cols = [f"{n}{suf}" for n in "XYZ"] + [f"{n}_deg" for n in SENSOR_NAMES[3:]]
    scols = ["s" + c for c in cols]
    cam_index = {str(c): j for j, c in enumerate(block.cameras.ids.tolist())}
    rig, camera, ref, val, sig, psig, lines = [], [], [], [], [], [], []
    for line, r in rows:
        cid = r["camera"]
        if cid not in cam_index:
            close = [c for c in cam_index if c.lower() == cid.lower()]
            raise InputError(f"unknown camera {quote(cid)} (cameras: {', '.join(list(cam_index)[:8])})"
                             + (f"; did you mean {close[0]!r}?" if close else ""), path=path, line=line, field="camera")
        if not r["rig"]:
            raise InputError("empty rig name", path=path, line=line, field="rig")
        rf = r["reference"].lower()
        if rf not in YES | NO:
            raise InputError(f"expected yes or no, got {quote(r['reference'])}", path=path, line=line, field="reference")
        status = (r.get("status") or ("fixed" if rf in YES else "estimated")).lower()
        if status not in STATUSES:
            raise InputError(f"unknown status {quote(status)}; expected one of {', '.join(STATUSES)}", path=path,
                             line=line, field="status")
        v = np.array([finite_number(r[c], path, line, c) if r.get(c) else np.nan for c in cols])
        s = np.array([finite_number(r[c], path, line, c) if r.get(c) else np.nan for c in scols])
        if (s < 0).any():
            raise InputError("a σ must not be negative", path=path, line=line, field=scols[int(np.argmax(s < 0))])
        v[3:] = np.radians(v[3:])
        s[3:] = np.radians(s[3:])
        is_ref = rf in YES
        if is_ref:
            if np.any(np.nan_to_num(v) != 0):
                raise InputError("the reference sensor is the rig frame: its pose is 0 (or empty)", path=path,
                                 line=line, field=cols[int(np.argmax(np.nan_to_num(v) != 0))])
            v[:] = 0.0
            sigma = np.zeros(6)
        elif status == "fixed":
            if np.isnan(v).any():
                raise InputError("a fixed sensor needs all six values", path=path, line=line,
                                 field=cols[int(np.argmax(np.isnan(v)))])
            sigma = np.zeros(6)
        elif status == "weighted":
            bad = np.isnan(v) | ~(s > 0)
            if bad.any():
                t = int(np.argmax(bad))
                raise InputError("a weighted sensor needs its six values and positive σ", path=path, line=line,
                                 field=cols[t] if np.isnan(v[t]) else scols[t])
            sigma = s
        else:
            sigma = np.full(6, np.inf)
        rig.append(r["rig"])
        camera.append(cam_index[cid])
        ref.append(is_ref)
        val.append(v)
        sig.append(sigma)
        psig.append(np.where(np.isfinite(v) & (status == "estimated") & ~is_ref, s, np.nan))
        lines.append(line)
    if not rows:
        raise InputError("the rig table has no sensor rows", path=path, line=hline)
    val = np.array(val)
    return RigSensors.make(rig, camera, ref, centre=val[:, :3], opk=val[:, 3:], sigma=np.array(sig),
                           prior_sigma=np.array(psig), line=np.array(lines))


def read_frame_table(path, block: Block) -> FrameMembers:
    """The frame table ``path`` (``frame,photo``): an :class:`InputError` naming file, line and field
    for an unknown photo or an empty frame name."""
    path = str(path)
    header, hline, rows = _rows(path)
    for need in ("frame", "photo"):
        if need not in header:
            raise InputError(f"the header has no column {need!r} (expected frame, photo)", path=path, line=hline,
                             field=need)
    ph_index = {str(p): i for i, p in enumerate(block.photos.ids.tolist())}
    frame, photo, lines = [], [], []
    for line, r in rows:
        if not r["frame"]:
            raise InputError("empty frame name", path=path, line=line, field="frame")
        if r["photo"] not in ph_index:
            raise InputError(f"unknown photo {quote(r['photo'])}", path=path, line=line, field="photo")
        frame.append(r["frame"])
        photo.append(ph_index[r["photo"]])
        lines.append(line)
    return FrameMembers(frame=np.array(frame, dtype=str), photo=np.array(photo, int), line=np.array(lines, int))


def frames_from_names(block: Block, pattern: str, sensors: RigSensors) -> FrameMembers:
    """Frames from the photo ids: the first group (or the match) of ``pattern`` on the id of every
    photo whose camera is a sensor of a rig (photos that do not match are in no frame)."""
    rx = re.compile(pattern)
    cams = set(sensors.camera.tolist())
    frame, photo = [], []
    for i, pid in enumerate(block.photos.ids.tolist()):
        if int(block.photos.camera[i]) not in cams:
            continue
        m = rx.search(str(pid))
        if m is None:
            continue
        frame.append(m.group(1) if m.groups() else m.group(0))
        photo.append(i)
    return FrameMembers(frame=np.array(frame, dtype=str), photo=np.array(photo, int))


def attach_rigs(block: Block, table, *, frames=None, frames_from_name: str = "", field: str = "rig") -> Block:
    """``block`` with the rigs of the rig table ``table`` and the frames of the frame table ``frames``
    or of ``frames_from_name`` (neither: the frames the block brings, e.g. a COLMAP model's
    ``frames.txt``); checked (:func:`~baarda.pipeline.adjustment.rig_structure`: a photo in two
    frames, a frame without the reference sensor, …) with the files' lines."""
    sensors = read_rig_table(table, block)
    if frames:
        members = read_frame_table(frames, block)
    elif frames_from_name:
        members = frames_from_names(block, frames_from_name, sensors)
    elif block.rigs and len(block.rigs.frames):
        members = block.rigs.frames              # the frames the source brings (COLMAP frames.txt)
    else:
        raise InputError("a rig needs its frames: give a frame table ('frames') or 'frames_from_name'",
                         field=f"{field}.frames")
    if not len(members):
        raise InputError("no photo of the rig's cameras is in a frame", path=str(frames) if frames else None,
                         field=f"{field}.frames_from_name" if not frames else "photo")
    frames_path = str(frames) if frames else None if frames_from_name else block.rigs.frames_path or block.rigs.path
    out = block.replace(rigs=Rigs(sensors, members, path=str(table), frames_path=frames_path,
                                  reference_name=block.rigs.reference_name))
    rig_structure(out)
    return out


def rig_config_paths(config, resolve) -> tuple[Path | None, Path | None]:
    """The rig table and the frame table of a ``RigConfig`` (``table``/``frames``) resolved with
    ``resolve`` (a context's), None where not given."""
    return (resolve(config.table) if config.table else None, resolve(config.frames) if config.frames else None)
