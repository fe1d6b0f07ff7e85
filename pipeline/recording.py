"""Rerun recordings: one ``.rrd`` per stage, all of a run sharing one recording id.

Writing: :func:`open_recording` returns a :class:`rerun.RecordingStream` that saves to a file
(no viewer), with the automatic log-time timeline off so files are reproducible.  Stages log
into it in their ``log`` method; the runner adds ``/stage/summary`` (the report section) and
``/stage/results`` (the summary values) and closes it.

Reading: :func:`read_recording` opens a file with ``rerun.chunk.RrdReader`` and returns what it
holds — entity paths, archetype columns, row counts, timelines, the stage's summary text — for
``baarda review``.  Because every stage's file shares the run's recording id, opening them
together in the viewer (``rerun run_dir/*.rrd``) merges them into one recording.
"""

from __future__ import annotations

import uuid
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

APP_ID = "baarda"


def new_recording_id() -> str:
    return str(uuid.uuid4())


def open_recording(path: Path, recording_id: str, app_id: str = APP_ID):
    """A recording stream that writes ``path``; close it with ``rec.disconnect()``."""
    import rerun as rr

    rec = rr.RecordingStream(app_id, recording_id=recording_id)
    rec.save(str(path))
    try:
        rr.set_log_time_enabled(False, recording=rec)
    except Exception:  # older/newer SDKs: the timeline is harmless, only less reproducible
        pass
    return rec


def log_text(rec, entity: str, markdown: str) -> None:
    import rerun as rr

    rec.log(entity, rr.TextDocument(markdown, media_type=rr.MediaType.MARKDOWN), static=True)


def log_values(rec, entity: str, values: dict) -> None:
    """Scalar summary values (numbers and strings) as ``AnyValues`` under ``entity``."""
    import rerun as rr

    flat = {}
    for k, v in _flatten(values).items():
        if isinstance(v, (bool, np.bool_)):
            flat[k] = [bool(v)]
        elif isinstance(v, (int, np.integer)):
            flat[k] = np.array([v], dtype=np.int64)  # ints stay ints: rerun keeps one type per name
        elif isinstance(v, (float, np.floating)) and np.isfinite(v):
            flat[k] = [float(v)]
        elif isinstance(v, str):
            flat[k] = [v]
    if flat:
        rec.log(entity, rr.AnyValues(**flat), static=True)


def _flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}".replace("/", "_").replace(" ", "_")
        if isinstance(v, dict):
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


@dataclass
class EntitySummary:
    path: str
    rows: int
    static: bool
    timelines: list[str]
    columns: list[str]


@dataclass
class RecordingSummary:
    file: Path
    application_id: str
    recording_id: str
    entities: list[EntitySummary] = field(default_factory=list)
    summary_text: str | None = None

    @property
    def archetypes(self) -> list[str]:
        arch = set()
        for e in self.entities:
            for c in e.columns:
                if ":" in c:
                    arch.add(c.split(":")[0])
        return sorted(arch)


def _attr(obj, name):
    """Chunk attributes are properties in rerun 0.41 and methods in some other releases."""
    v = getattr(obj, name)
    return v() if callable(v) else v


def read_recording(path: Path) -> RecordingSummary:
    """What a ``.rrd`` file holds, read back with rerun's own reader."""
    from rerun.chunk import RrdReader

    reader = RrdReader(str(path))
    recs = reader.recordings() if callable(getattr(reader, "recordings", None)) else reader.recordings
    rec_entry = next((r for r in recs if getattr(r, "kind", "recording") == "recording"), recs[0])
    out = RecordingSummary(file=Path(path), application_id=rec_entry.application_id,
                           recording_id=rec_entry.recording_id)
    by_path: dict[str, EntitySummary] = {}
    for chunk in reader.stream().to_chunks():
        ep = str(chunk.entity_path)
        batch = chunk.to_record_batch()
        timelines = list(_attr(chunk, "timeline_names"))
        cols = [c for c in batch.schema.names if c not in timelines and not c.startswith("rerun.")]
        e = by_path.setdefault(ep, EntitySummary(ep, 0, bool(_attr(chunk, "is_static")), [], []))
        e.rows += int(_attr(chunk, "num_rows"))
        for t in timelines:
            if t not in e.timelines:
                e.timelines.append(t)
        for c in cols:
            if c not in e.columns:
                e.columns.append(c)
        if ep.endswith("/summary") and "TextDocument:text" in batch.schema.names and out.summary_text is None:
            col = batch.column(batch.schema.names.index("TextDocument:text")).to_pylist()
            val = col[0]
            while isinstance(val, list) and val:
                val = val[0]
            out.summary_text = val if isinstance(val, str) else None
    out.entities = sorted((e for e in by_path.values() if e.path != "/__properties"), key=lambda e: e.path)
    return out


# --------------------------------------------------------------------------------------------
# helpers every stage's ``log`` uses
# --------------------------------------------------------------------------------------------

ROLE_COLORS = {"full": (220, 40, 40), "xy": (240, 150, 20), "z": (200, 60, 200), "check": (40, 170, 60),
               "tie": (60, 110, 230), "pc": (30, 30, 30)}
"""One palette for point roles (control ``full``/``xy``/``z``, ``check``, ``tie``; ``pc`` for projection
centres used as model points) in every recording."""
UNKNOWN_ROLE_COLOR = (150, 150, 150)


def role_colors(roles) -> np.ndarray:
    """``(n, 3)`` uint8 colours of point roles (:data:`ROLE_COLORS`; grey for anything else)."""
    return np.array([ROLE_COLORS.get(str(r), UNKNOWN_ROLE_COLOR) for r in roles], dtype=np.uint8).reshape(-1, 3)


def view_from_photo(xy_mm, format_mm) -> np.ndarray:
    """2-D view coordinates of image coordinates ``xy_mm (n, 2)`` (x right, y up, origin at the format
    centre; ``docs/conventions.md``): mm from the format's top-left corner, y down, as rerun's 2-D
    views draw them.  ``format_mm = (width, height)``."""
    xy = np.asarray(xy_mm, float).reshape(-1, 2)
    w, h = np.asarray(format_mm, float)
    return np.column_stack([xy[:, 0] + w / 2.0, h / 2.0 - xy[:, 1]])


def view_vectors(v_mm) -> np.ndarray:
    """Image-space vectors ``(n, 2)`` (y up) as 2-D view vectors (y down)."""
    v = np.asarray(v_mm, float).reshape(-1, 2)
    return np.column_stack([v[:, 0], -v[:, 1]])


def entity_part(text: str) -> str:
    """An entity-path part for an id such as ``"DSC_5305.jpg"``."""
    import rerun as rr

    return rr.escape_entity_path_part(str(text))


def log_block(rec, block, root: str = "block", max_photos: int = 500) -> None:
    """Log points and oriented photos of ``block`` (at most ``max_photos`` photos).

    Photos are logged as ``Transform3D`` (baarda's ``R_cam_from_world``, relation child-from-parent)
    plus ``Pinhole`` with ``camera_xyz = RUB`` (x right, y up, z back: baarda's image-space frame)
    under ``<root>/photos/<id>``; object points as ``Points3D`` under ``<root>/points``.
    """
    import rerun as rr

    from .geometry import rotation_from_opk_many

    pts = block.points
    ok = np.isfinite(pts.XYZ).all(axis=1)
    if ok.any():
        colors = np.where((pts.role[ok] == "tie")[:, None], [[160, 160, 160]], [[230, 60, 40]]).astype(np.uint8)
        rec.log(f"{root}/points", rr.Points3D(pts.XYZ[ok], colors=colors, radii=rr.Radius.ui_points(2.0)),
                static=True)
    ph, cams = block.photos, block.cameras
    oriented = np.flatnonzero(ph.has_orientation)[:max_photos]
    if oriented.size == 0:
        return
    R = rotation_from_opk_many(ph.opk[oriented])
    for k, Rk in zip(oriented, R):
        path = f"{root}/photos/{entity_part(ph.ids[k])}"
        t = -Rk @ ph.X0[k]
        rec.log(path, rr.Transform3D(translation=t, mat3x3=Rk, relation=rr.TransformRelation.ChildFromParent),
                static=True)
        cam = ph.camera[k]
        pitch = cams.pixel_mm[cam]
        w, h = cams.resolution[cam]
        if np.isfinite(pitch) and pitch > 0 and w > 0 and h > 0:
            f = cams.c[cam] / pitch
            cx = (w - 1) / 2 + cams.xp[cam] / pitch
            cy = (h - 1) / 2 - cams.yp[cam] / pitch
            rec.log(path, rr.Pinhole(image_from_camera=[[f, 0, cx], [0, f, cy], [0, 0, 1]], resolution=[w, h],
                                     camera_xyz=rr.ViewCoordinates.RUB, image_plane_distance=None), static=True)
