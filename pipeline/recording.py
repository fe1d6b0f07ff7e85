"""Rerun recordings: one ``.rrd`` per stage, all of a run sharing one recording id.

Writing: :func:`open_recording` returns a :class:`StageRecording` — a :class:`rerun.RecordingStream`
that saves to a file (no viewer), with the automatic log-time timeline off so files are
reproducible.  Stages log into it in their ``log`` method; the runner adds ``<stage>/summary``
(the report section) and ``<stage>/results`` (the summary values) and closes it.

Every entity of a stage's file lies under ``<stage id>/``: a path a stage logs that does not
already start there is put there (``world/points`` of stage ``bundle`` becomes
``bundle/world/points``), so the files of one run never overwrite each other when the viewer
merges them.  When the stream closes, the file gets a blueprint (:func:`stage_blueprint`): one
3-D view of the network, one 2-D view per photo or camera, time series per group of scalars,
and the stage's summary as text — unless the stage sent its own with ``rec.send_blueprint``.
Text goes through :func:`viewer_text` (no combining marks: the viewer panics on ``∇̂``).  See
``docs/recordings.md``.

Reading: :func:`read_recording` opens a file with ``rerun.chunk.RrdReader`` and returns what it
holds — entity paths, archetype columns, row counts, timelines, the stage's summary text — for
``baarda review``.  Because every stage's file shares the run's recording id, opening them
together in the viewer (``rerun run_dir/*.rrd``) merges them into one recording.
"""

from __future__ import annotations

import unicodedata
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

APP_ID = "baarda"


def new_recording_id() -> str:
    return str(uuid.uuid4())


def open_recording(path: Path, recording_id: str, app_id: str = APP_ID, stage_id: str | None = None):
    """A :class:`StageRecording` that writes ``path`` with every entity under ``stage_id``
    (default: the file's stem, ``bundle`` for ``bundle.rrd``); close it with ``rec.disconnect()``,
    which writes the blueprint."""
    import rerun as rr

    stream = rr.RecordingStream(app_id, recording_id=recording_id)
    stream.save(str(path))
    try:
        rr.set_log_time_enabled(False, recording=stream)
    except Exception:  # older/newer SDKs: the timeline is harmless, only less reproducible
        pass
    return StageRecording(stream, stage_id or Path(path).stem, path=Path(path), recording_id=recording_id)


SPATIAL_3D = frozenset({"Points3D", "Transform3D", "Pinhole", "Ellipsoids3D", "LineStrips3D", "Arrows3D",
                        "Boxes3D", "Mesh3D"})
SPATIAL_2D = frozenset({"Points2D", "Arrows2D", "LineStrips2D", "Image", "EncodedImage", "Boxes2D"})
PHOTO_GROUPS = ("photos", "images", "cameras")
"""A 2-D entity below ``…/<group>/<id>/`` (group one of these) belongs to the view of ``<id>``."""


class StageRecording:
    """A stage's recording: a :class:`rerun.RecordingStream` whose entities lie under the stage id.

    ``log`` roots the path (see the module docstring) and notes which archetypes each entity
    holds; ``disconnect`` sends :func:`stage_blueprint` of what was logged unless a blueprint was
    sent already, then closes the file.  Everything else is the stream's (``set_time``, …);
    ``stream`` is the stream itself for ``recording=`` arguments.
    """

    def __init__(self, stream, stage_id: str, path: Path | None = None, recording_id: str | None = None):
        self.stream = stream
        self.path_on_disk = path
        self.recording_id = recording_id
        self.stage_id = str(stage_id).strip("/")
        self.logged: dict[str, set[str]] = {}
        self.notes: list[str] = []
        self._blueprint_sent = False

    def path(self, entity: str) -> str:
        """``entity`` rooted at the stage id."""
        p = str(entity).strip("/")
        if p == self.stage_id or p.startswith(self.stage_id + "/"):
            return p
        return f"{self.stage_id}/{p}" if p else self.stage_id

    def log(self, entity: str, *entities, **kwargs) -> None:
        p = self.path(entity)
        kinds = self.logged.setdefault(p, set())
        for e in entities:
            kinds.add(type(e).__name__)
        self.stream.log(p, *entities, **kwargs)

    def send_columns(self, entity: str, indexes, columns, **kwargs) -> None:
        """:func:`rerun.send_columns` on the rooted path; notes the archetypes of the columns."""
        p = self.path(entity)
        columns = list(columns)
        kinds = self.logged.setdefault(p, set())
        for c in columns:
            arch = getattr(c.component_descriptor(), "archetype", None)
            if arch:
                kinds.add(str(arch).rsplit(".", 1)[-1])
        self.stream.send_columns(p, indexes=indexes, columns=columns, **kwargs)

    def note(self, text: str) -> None:
        """Say in the recording (``<stage>/notes``) that something was thinned or left out."""
        self.notes.append(text)

    def send_blueprint(self, blueprint, **kwargs) -> None:
        self._blueprint_sent = True
        self.stream.send_blueprint(blueprint, **kwargs)

    def disconnect(self) -> None:
        try:
            if self.notes:
                log_text(self, "notes", "\n".join(f"- {n}" for n in self.notes))
            if not self._blueprint_sent:
                earlier = earlier_stages(self.path_on_disk, self.recording_id) if self.path_on_disk else []
                self.send_blueprint(run_blueprint(earlier + [(self.stage_id, self.logged)]), make_active=True,
                                    make_default=True)
        finally:
            self.stream.disconnect()
            if self.path_on_disk is not None:
                _remember_manifest(self.path_on_disk, self.recording_id, self.logged)

    def __getattr__(self, name):
        return getattr(self.stream, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.disconnect()


def photo_root(entity: str) -> str:
    """The view a 2-D entity belongs to: ``a/photos/L/points`` → ``a/photos/L``; otherwise itself
    (``comparison/checkpoints_chart``)."""
    parts = entity.strip("/").split("/")
    for k in range(len(parts) - 2, -1, -1):
        if parts[k] in PHOTO_GROUPS:
            return "/".join(parts[:k + 2])
    return "/".join(parts)


_MANIFESTS: dict[str, tuple[int, int, str | None, dict[str, set[str]]]] = {}
"""What this process wrote into each closed ``.rrd`` file (resolved path → mtime, size, recording
id, entity path → archetype names), so that a later stage's layout does not read a big earlier
file back (about 2 s for 50 MB).  A file that changed since (other mtime or size) is read again."""


def _file_key(path: Path) -> tuple[str, int, int] | None:
    try:
        st = Path(path).stat()
        return str(Path(path).resolve()), st.st_mtime_ns, st.st_size
    except OSError:
        return None


def _remember_manifest(path: Path, recording_id: str | None, logged: dict[str, set[str]]) -> None:
    key = _file_key(path)
    if key is not None:
        _MANIFESTS[key[0]] = (key[1], key[2], recording_id, {p: set(k) for p, k in logged.items()})


def _known_manifest(path: Path):
    """``(recording id, logged)`` of a file this process wrote and that is unchanged, else ``None``."""
    key = _file_key(path)
    got = _MANIFESTS.get(key[0]) if key else None
    if got is None or got[:2] != key[1:]:
        return None
    return got[2], got[3]


def earlier_stages(path: Path, recording_id: str | None) -> list[tuple[str, dict[str, set[str]]]]:
    """The stages recorded before ``path`` in its folder with the same recording id (the run's
    earlier stages, in the order they were written): ``(stage id, entity path → archetype names)``
    from each file's manifest (no data is read; what this process wrote itself is remembered, not
    read back).  Files that cannot be read are left out."""
    from rerun.chunk import RrdReader

    out = []
    path = Path(path)
    try:
        siblings = sorted((f for f in path.parent.glob("*.rrd") if f.resolve() != path.resolve()),
                          key=lambda f: (f.stat().st_mtime_ns, f.name))
    except OSError:
        return out
    for f in siblings:
        known = _known_manifest(f)
        if known is not None:
            if recording_id is None or known[0] == recording_id:
                out.append((f.stem, {p: set(k) for p, k in known[1].items() if not p.startswith("__")}))
            continue
        try:
            reader = RrdReader(str(f))
            recs = reader.recordings()
            if not recs or (recording_id is not None and recs[0].recording_id != recording_id):
                continue
            logged: dict[str, set[str]] = {}
            for c in reader.store().schema().component_columns():
                ep = str(c.entity_path).strip("/")
                arch = str(c.archetype or "").rsplit(".", 1)[-1]
                if ep and not ep.startswith("__") and arch:
                    logged.setdefault(ep, set()).add(arch)
        except Exception:  # a damaged or foreign file: its layout is simply not included
            continue
        out.append((f.stem, logged))
    return out


def run_blueprint(stages: list[tuple[str, dict[str, set[str]]]]):
    """The layout of a run's recordings: the last stage's layout (:func:`stage_layout`) when it is
    alone, otherwise one tab per stage in run order, the last one shown.  Every stage's file gets
    the layout of the stages up to it, so the file of the last stage holds the whole run's — open
    the files in run order (``baarda view RUN_DIR`` does) and the viewer uses it."""
    import rerun.blueprint as rrb

    if len(stages) == 1:
        return _blueprint(stage_layout(*stages[0]))
    tabs = [stage_layout(sid, logged, name=sid) for sid, logged in stages]
    return _blueprint(rrb.Tabs(*tabs, active_tab=len(tabs) - 1))


def _blueprint(layout):
    import rerun.blueprint as rrb

    return rrb.Blueprint(layout, rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
                         auto_views=False, auto_layout=False)


def stage_blueprint(stage_id: str, logged: dict[str, set[str]]):
    """The blueprint of one stage's recording alone (:func:`stage_layout`)."""
    return _blueprint(stage_layout(stage_id, logged))


def stage_layout(stage_id: str, logged: dict[str, set[str]], name: str | None = None):
    """The layout of a stage's recording from what it logged (entity path → archetype names).

    Left: the 3-D network (one view rooted at the stage, of the 3-D entities) above the photos
    (one 2-D view per photo or camera: side by side up to four, tabs beyond).  Right: one time
    series per group of ``Scalars`` (their parent entity), the bar charts, then the text
    documents (the summary first).  Static ``AnyValues`` are left to the selection panel.
    ``name`` names the container (a stage's tab in :func:`run_blueprint`).
    """
    import rerun.blueprint as rrb

    root = "/" + stage_id.strip("/")
    three = sorted(p for p, k in logged.items() if k & SPATIAL_3D)
    two = sorted(p for p, k in logged.items() if k & SPATIAL_2D)
    photos: dict[str, list[str]] = {}
    for p in two:
        photos.setdefault(photo_root(p), []).append(p)
    series: dict[str, list[str]] = {}
    for p in sorted(p for p, k in logged.items() if "Scalars" in k):
        series.setdefault("/".join(p.split("/")[:-1]) or p, []).append(p)
    bars = sorted(p for p, k in logged.items() if "BarChart" in k)
    texts = sorted((p for p, k in logged.items() if "TextDocument" in k),
                   key=lambda p: (not p.endswith("/summary"), p))

    left = []
    if three:
        tops = top_entities(three)
        left.append(rrb.Spatial3DView(origin=root, contents=[f"/{p}/**" for p in tops], name=f"{stage_id}: 3-D"))
    if photos:
        views = [rrb.Spatial2DView(origin=f"/{ph}", contents=["$origin/**"], name=_view_name(ph, stage_id))
                 for ph in sorted(photos)]
        left.append(rrb.Grid(*views) if len(views) <= 4 else rrb.Tabs(*views, name="photos"))
    right = [rrb.TimeSeriesView(origin=f"/{g}", contents=["$origin/**"], name=g.removeprefix(stage_id + "/"))
             for g in sorted(series)]
    right += [rrb.BarChartView(origin=f"/{p}", contents=["$origin"], name=p.removeprefix(stage_id + "/"))
              for p in bars]
    right += [rrb.TextDocumentView(origin=f"/{p}", contents=["$origin"], name=p.removeprefix(stage_id + "/"))
              for p in texts]
    cols = [rrb.Vertical(*c) if len(c) > 1 else c[0] for c in (left, right) if c]
    if len(cols) == 1 and name is None:
        return cols[0]
    return rrb.Horizontal(*cols, column_shares=[3, 2] if len(cols) == 2 else None, name=name)


def top_entities(paths) -> list[str]:
    """The paths of ``paths`` that have no ancestor among them, sorted (``a/b`` and ``a/b/c`` → ``a/b``).
    Linear in the number of paths (each path's ancestors are looked up in a set), not quadratic."""
    given = set(paths)
    out = []
    for p in sorted(given):
        parts = p.split("/")
        if not any("/".join(parts[:k]) in given for k in range(1, len(parts))):
            out.append(p)
    return out


def _view_name(entity: str, stage_id: str) -> str:
    """``L`` for ``screening/photos/L``; ``images/1`` and ``cameras/1`` when a stage has both groups."""
    parts = entity.split("/")
    if len(parts) >= 2 and parts[-2] in PHOTO_GROUPS and parts[-2] != "photos":
        return "/".join(parts[-2:])
    return parts[-1] if len(parts) > 1 else entity.removeprefix(stage_id + "/")


def viewer_text(text: str) -> str:
    """``text`` with only glyphs the viewer renders: composed (NFC), and a combining mark left
    over (``∇̂``, ``σ̂``: the viewer panics on them) written after its letter as ``^`` (hat),
    ``~`` (tilde), ``-`` (bar) or dropped."""
    out = []
    for ch in unicodedata.normalize("NFC", str(text)):
        if unicodedata.combining(ch):
            out.append({"\u0302": "^", "\u0303": "~", "\u0304": "-", "\u0305": "-"}.get(ch, ""))
        else:
            out.append(ch)
    return "".join(out)


class _Arrow:
    """A ready Arrow array as a component batch (what :class:`rerun.ComponentColumn` reads)."""

    def __init__(self, array):
        self.array = array

    def as_arrow_array(self):
        return self.array


def log_per_entity(rec, paths, lengths, *archetype_columns) -> None:
    """Static data of many entities of the same kind — the observed points of every photo, every
    photo's camera — sent with rerun's columnar API, one message per entity.

    ``archetype_columns`` are ``rr.<Archetype>.columns(...)`` built *once* over the instances of all
    entities concatenated in the order of ``paths`` (entity ``k`` has ``lengths[k]`` of them: its
    observations, or 1 for a camera), so every array is converted to Arrow once, not once per
    entity; each entity then gets its slice of every component (zero-copy) in one static row,
    exactly what ``rec.log(path, rr.<Archetype>(…), static=True)`` would have written.  A component
    with one value in all (a radius for every point) is given whole to every entity.
    """
    import rerun as rr

    paths = list(paths)
    lengths = np.asarray(lengths, np.int64).reshape(-1)
    if lengths.size != len(paths):
        raise ValueError(f"{len(paths)} entities but {lengths.size} lengths")
    offsets = np.concatenate([[0], np.cumsum(lengths)])
    total = int(offsets[-1])
    comps = []
    for cols in archetype_columns:
        for c in cols:
            values = c.component_batch.as_arrow_array()
            if len(values) == total:
                comps.append((c.descriptor, values, True))
            elif len(values) == 1:
                comps.append((c.descriptor, values, False))
            else:
                raise ValueError(f"{c.descriptor.component}: {len(values)} values for {total} instances "
                                 f"of {len(paths)} entities")
    send = rec.send_columns
    for k, path in enumerate(paths):
        a, n = int(offsets[k]), int(lengths[k])
        send(path, indexes=[], columns=[
            rr.ComponentColumn(d, _Arrow(v.slice(a, n) if per else v), lengths=[n if per else 1])
            for d, v, per in comps])


ENTITIES_MAX = 1000
"""Above this many photos (or cameras) a stage logs their 2-D data as one entity over a timeline
(:func:`log_on_timeline`) instead of one entity each: an ``.rrd`` file's footer lists every chunk,
and with tens of thousands of entities it outgrows what rerun's reader accepts (``TooManyTables``:
the file of a 10 000-photo bundle could not be opened), besides one view per photo being no use."""


def log_on_timeline(rec, entity: str, timeline: str, lengths, *archetype_columns) -> None:
    """Many groups of instances — the image points of 10 000 photos — as *one* entity with one row per
    group on the sequence timeline ``timeline`` (step ``k`` = group ``k``), sent in a single
    ``rr.send_columns`` call; the viewer shows the group at the time cursor.  ``archetype_columns``
    as for :func:`log_per_entity` (a component with one value in all is repeated on every step)."""
    import rerun as rr

    lengths = np.asarray(lengths, np.int64).reshape(-1)
    n, total = lengths.size, int(lengths.sum())
    columns = []
    for cols in archetype_columns:
        for c in cols:
            values = c.component_batch.as_arrow_array()
            if len(values) == total:
                columns.append(rr.ComponentColumn(c.descriptor, _Arrow(values), lengths=lengths))
            elif len(values) == 1:
                columns.append(rr.ComponentColumn(c.descriptor, _Arrow(values.take(np.zeros(n, np.int64))),
                                                  lengths=np.ones(n, np.int64)))
            else:
                raise ValueError(f"{c.descriptor.component}: {len(values)} values for {total} instances "
                                 f"in {n} steps")
    rec.send_columns(entity, indexes=[rr.TimeColumn(timeline, sequence=np.arange(n))], columns=columns)


def log_text(rec, entity: str, markdown: str) -> None:
    import rerun as rr

    rec.log(entity, rr.TextDocument(viewer_text(markdown), media_type=rr.MediaType.MARKDOWN), static=True)


STATISTIC_STYLE = {"colors": [31, 78, 156], "widths": 2.0}
"""How a statistic's time series is drawn (:func:`log_series`): a blue line with round markers."""
THRESHOLD_STYLE = {"colors": [192, 57, 43], "widths": 1.0, "interpolation_mode": "StepAfter"}
"""How a critical value that changes during the run is drawn: a thin red step line in its statistic's view."""
CONSTANTS = "constants"
"""The child of a series group holding, as static ``AnyValues``, what did not change during the run."""


def is_constant(values) -> bool:
    """True when the finite values of a series are fewer than two or all equal (to 1e-12 relative)."""
    v = np.asarray(values, float).reshape(-1)
    v = v[np.isfinite(v)]
    return v.size < 2 or float(np.ptp(v)) <= 1e-12 * max(1.0, float(np.max(np.abs(v))))


def log_series(rec, group: str, steps, statistics: dict, thresholds: dict | None = None, *,
               timeline: str = "iteration") -> dict[str, float]:
    """Statistics over ``steps`` as time series under ``group`` (one parent: the layout draws them in
    one view), each critical value that changes as a threshold line beside them (same view, styled by
    :data:`THRESHOLD_STYLE`); a series that is constant over the run — a critical value that never
    changed, a damping factor that stayed 0, anything logged only once — is not drawn as a flat line:
    it goes to ``<group>/constants`` as a static value.  ``statistics`` and ``thresholds`` map a name
    to one value per step (nan: no value at that step).  Returns the constants (name → value)."""
    import rerun as rr

    steps = np.asarray(steps, int).reshape(-1)
    drawn: dict[str, tuple[np.ndarray, dict]] = {}
    constants: dict[str, float] = {}
    for table, style in ((statistics, STATISTIC_STYLE), (thresholds or {}, THRESHOLD_STYLE)):
        for name, values in table.items():
            v = np.asarray(values, float).reshape(-1)
            if v.size != steps.size:
                raise ValueError(f"series {group}/{name}: {v.size} values for {steps.size} steps")
            fin = v[np.isfinite(v)]
            if is_constant(v):
                if fin.size:
                    constants[name] = float(fin[0])
                continue
            drawn[name] = (v, style)
    for name, (v, style) in drawn.items():
        path = f"{group}/{name}"
        parts = [rr.SeriesLines(names=viewer_text(name), **style)]
        if style is STATISTIC_STYLE:
            parts.append(rr.SeriesPoints(colors=style["colors"], markers="circle", marker_sizes=4.0))
        rec.log(path, *parts, static=True)
        for s, x in zip(steps, v):
            if np.isfinite(x):
                rec.set_time(timeline, sequence=int(s))
                rec.log(path, rr.Scalars([float(x)]))
    if drawn:
        rec.reset_time()
    if constants:
        rec.log(f"{group}/{CONSTANTS}", rr.AnyValues(**constants), static=True)
    return constants


def read_series(path: Path) -> dict[str, np.ndarray]:
    """Every ``Scalars`` series in a ``.rrd`` file: entity path → its values (in the file's chunk order)."""
    from rerun.chunk import RrdReader

    out: dict[str, list[float]] = {}
    for chunk in RrdReader(str(path)).stream().to_chunks():
        batch = chunk.to_record_batch()
        if "Scalars:scalars" not in batch.schema.names:
            continue
        vals = batch.column(batch.schema.names.index("Scalars:scalars")).to_pylist()
        out.setdefault(str(chunk.entity_path), []).extend(float(_first(x)) for x in vals if _first(x) is not None)
    return {k: np.asarray(v, float) for k, v in out.items()}


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
            flat[k] = [viewer_text(v)]
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
class ViewSummary:
    kind: str
    """rerun's view class: ``3D``, ``2D``, ``TimeSeries``, ``TextDocument``, …"""
    origin: str
    name: str | None
    contents: list[str]


def _first(val):
    while isinstance(val, list) and val:
        val = val[0]
    return val


def read_blueprint(reader) -> list[ViewSummary]:
    """The views of the blueprint stored in a file (``RrdReader``), in no particular order."""
    entries = reader.blueprints() if callable(getattr(reader, "blueprints", None)) else []
    if not entries:
        return []
    views: dict[str, dict] = {}
    for chunk in reader.store(store=entries[-1]).stream().to_chunks():
        ep = str(chunk.entity_path).strip("/")
        if not ep.startswith("view/"):
            continue
        batch = chunk.to_record_batch()
        cols = {n: batch.column(i).to_pylist() for i, n in enumerate(batch.schema.names) if ":" in n}
        v = views.setdefault(ep.split("/")[1], {})
        for key, col in (("kind", "ViewBlueprint:class_identifier"), ("origin", "ViewBlueprint:space_origin"),
                         ("name", "ViewBlueprint:display_name")):
            if col in cols:
                v[key] = _first(cols[col])
        if "ViewContents:query" in cols:
            q = cols["ViewContents:query"][0]
            v["contents"] = [x for x in (q[0] if q and isinstance(q[0], list) else q or [])]
    return [ViewSummary(v.get("kind", "?"), v.get("origin", "/"), v.get("name"), v.get("contents", []))
            for v in views.values()]


@dataclass
class RecordingSummary:
    file: Path
    application_id: str
    recording_id: str
    entities: list[EntitySummary] = field(default_factory=list)
    summary_text: str | None = None
    views: list["ViewSummary"] = field(default_factory=list)
    """The views of the file's blueprint (empty when it has none)."""

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
    out.views = read_blueprint(reader)
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


def view_from_photo(xy_mm, format_mm=None) -> np.ndarray:
    """2-D view coordinates of image coordinates ``xy_mm (n, 2)`` (x right, y up, origin at the format
    centre; ``docs/conventions.md``): mm from the format's top-left corner, y down, as rerun's 2-D
    views draw them.  ``format_mm = (width, height)``; without one (or with a non-finite one) the
    origin stays at the centre and only y turns down.  Every photo of every recording goes through
    this one conversion (``tests/pipeline/test_recordings.py`` checks the orientation)."""
    xy = np.asarray(xy_mm, float).reshape(-1, 2)
    fmt = np.zeros(2) if format_mm is None else np.asarray(format_mm, float).reshape(2)
    w, h = np.where(np.isfinite(fmt), fmt, 0.0)
    return np.column_stack([xy[:, 0] + w / 2.0, h / 2.0 - xy[:, 1]])


def view_vectors(v_mm) -> np.ndarray:
    """Image-space vectors ``(n, 2)`` (y up) as 2-D view vectors (y down)."""
    v = np.asarray(v_mm, float).reshape(-1, 2)
    return np.column_stack([v[:, 0], -v[:, 1]])


def entity_part(text: str) -> str:
    """An entity-path part for an id such as ``"DSC_5305.jpg"``."""
    import rerun as rr

    return rr.escape_entity_path_part(str(text))


def log_block(rec, block, root: str = "block", max_photos: int | None = None) -> None:
    """Log points and oriented photos of ``block`` (every photo; with ``max_photos``, every k-th so
    that at most that many are logged, and the recording says so).

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
    oriented = thin(rec, np.flatnonzero(ph.has_orientation), max_photos, "oriented photos")
    if oriented.size == 0:
        return
    paths = [f"{root}/photos/{entity_part(i)}" for i in np.asarray(ph.ids)[oriented].tolist()]
    if oriented.size > ENTITIES_MAX:      # one entity per photo would make the file unreadable
        rec.note(f"{oriented.size} oriented photos (more than {ENTITIES_MAX}): drawn as their projection "
                 f"centres ({root}/photos, labelled), not as one camera entity each")
        rec.log(f"{root}/photos", rr.Points3D(ph.X0[oriented], labels=[entity_part(i) for i in
                                                                       np.asarray(ph.ids)[oriented].tolist()],
                                              radii=rr.Radius.ui_points(3.0)), static=True)
        return
    R = rotation_from_opk_many(ph.opk[oriented])
    t = -np.einsum("kij,kj->ki", R, ph.X0[oriented])
    log_per_entity(rec, paths, np.ones(oriented.size, int),
                   rr.Transform3D.columns(translation=t, mat3x3=R, relation=np.full(
                       oriented.size, rr.TransformRelation.ChildFromParent)))
    cam = np.asarray(ph.camera)[oriented]
    pitch = np.asarray(cams.pixel_mm, float)[cam]
    wh = np.asarray(cams.resolution, float).reshape(-1, 2)[cam]
    ok = np.isfinite(pitch) & (pitch > 0) & (wh[:, 0] > 0) & (wh[:, 1] > 0)
    if ok.any():
        f = np.asarray(cams.c, float)[cam][ok] / pitch[ok]
        K = np.zeros((int(ok.sum()), 3, 3))
        K[:, 0, 0] = K[:, 1, 1] = f
        K[:, 0, 2] = (wh[ok, 0] - 1) / 2 + np.asarray(cams.xp, float)[cam][ok] / pitch[ok]
        K[:, 1, 2] = (wh[ok, 1] - 1) / 2 - np.asarray(cams.yp, float)[cam][ok] / pitch[ok]
        K[:, 2, 2] = 1.0
        log_per_entity(rec, [p for p, k in zip(paths, ok) if k], np.ones(int(ok.sum()), int),
                       rr.Pinhole.columns(image_from_camera=K, resolution=wh[ok], camera_xyz=rr.ViewCoordinates.RUB))


def thin(rec, index, most: int | None, what: str) -> np.ndarray:
    """``index`` itself, or every k-th of it when there are more than ``most``; the recording's
    notes say what was left out (:meth:`StageRecording.note`)."""
    index = np.asarray(index)
    if most is None or index.size <= most:
        return index
    step = int(np.ceil(index.size / most))
    kept = index[::step]
    msg = f"{what}: {kept.size} of {index.size} logged (every {step}th)"
    if hasattr(rec, "note"):
        rec.note(msg)
    return kept


def point_ellipsoids(XYZ, cov, confidence: float | None = None, extent: float | None = None):
    """Error ellipsoids of points for :class:`rerun.Ellipsoids3D`: ``(centers, half_sizes,
    quaternions xyzw, scale)``.  Semi-axes from :func:`baarda.pipeline.stats.ellipses.error_ellipsoids`
    (1 σ by default) multiplied by ``scale``, chosen so that the median largest semi-axis is 1 % of
    ``extent`` (the network's size; default the points' bounding-box diagonal) — the factor is
    returned so a recording can state it.  Points without a finite covariance are left out."""
    from scipy.spatial.transform import Rotation

    from .stats.ellipses import error_ellipsoids

    XYZ = np.asarray(XYZ, float).reshape(-1, 3)
    semi, axes = error_ellipsoids(cov, confidence)
    ok = np.isfinite(semi).all(axis=1) & np.isfinite(XYZ).all(axis=1)
    if not ok.any():
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 4)), 1.0
    if extent is None:
        extent = float(np.linalg.norm(np.ptp(XYZ[ok], axis=0))) if ok.sum() > 1 else 1.0
    big = float(np.median(semi[ok, 0]))
    scale = 0.01 * extent / big if big > 0 and extent > 0 else 1.0
    q = Rotation.from_matrix(axes[ok]).as_quat()
    return XYZ[ok], semi[ok] * scale, q, scale
