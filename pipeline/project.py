"""Project files: TOML naming the inputs and the ordered stages with their options.

    [project]
    name = "Paper 000, stereo pair, Data 1"
    description = "..."          # optional
    seed = 0                     # optional: seeds every stage's rng
    object_unit = "m"            # optional

    [run]                        # optional: how the run writes its outputs (RunOptions)
    outputs = "full"             # "summary": skip the per-observation / per-point tables

    [[stage]]
    use = "comparator"           # the stage's entry-point name (``baarda stages`` lists them)
    id = "source"                # optional; default: the ``use`` name (must be unique)
    [stage.options]
    path = "data1.cmp"           # paths are relative to the project file

:func:`load_project` checks the file, that every stage is installed, every option is known and
of the right type, and that every artefact a stage reads is written by an earlier one.
:func:`validate_inputs` (``baarda validate`` runs both) then checks what the options name: every
input path exists, and each stage's own ``validate(options, ctx)`` hook passes (a source stage
parses its files there).  Every mistake is an :class:`~baarda.pipeline.errors.InputError` naming the
file, the line and the key.
"""

from __future__ import annotations

import dataclasses
import difflib
import glob
import json
import re
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Mapping, get_args, get_origin

from .errors import BaardaError, InputError
from .options import Where, declared_outputs, option, output_problem, parse_options, to_plain
from .plausibility import check_block
from .plugins import PluginManager
from .stage import Context, RowBound, ValidationContext, keeps_rows

PROJECT_KEYS = {"name", "description", "seed", "object_unit"}
STAGE_KEYS = {"use", "id", "options", "enabled"}


@dataclass(frozen=True)
class RunOptions:
    """The project's ``[run]`` table: how a run writes its outputs (``--set run.outputs=summary``)."""

    outputs: Literal["full", "summary"] = option(
        "full", "'full': every table; 'summary': skip the per-observation and per-point tables (those "
                "marked detail; the report names them), for batch runs that need the summaries only")


@dataclass
class StageSpec:
    id: str
    use: str
    cls: type
    options: Any
    raw_options: dict
    line: int | None
    package: str = ""
    option_lines: dict[str, int] = field(default_factory=dict)


@dataclass
class Project:
    path: Path
    name: str
    description: str
    seed: int
    object_unit: str
    stages: list[StageSpec] = field(default_factory=list)
    text: str = ""
    data: dict = field(default_factory=dict, repr=False)
    """The file's TOML as parsed (:func:`with_overrides` builds variants from it; never modified)."""
    overrides: Overrides | None = None
    """The options set from outside the file (``--set``, a sweep row), already applied."""
    run: RunOptions = field(default_factory=RunOptions)
    """The ``[run]`` table (``outputs``)."""

    @property
    def directory(self) -> Path:
        return self.path.parent

    def resolved(self) -> dict:
        """The project with every option's default filled in (written to the run directory)."""
        return {
            "project": {"name": self.name, "description": self.description, "seed": self.seed,
                        "object_unit": self.object_unit, "file": str(self.path)},
            "run": to_plain(self.run),
            "stage": [{"use": s.use, "id": s.id, "package": s.package, "options": to_plain(s.options)}
                      for s in self.stages],
        }


class _Locator:
    """Line numbers of ``[[stage]]`` tables and their keys in the raw TOML text."""

    def __init__(self, text: str):
        self.lines = text.splitlines()
        self.stage_lines = [i + 1 for i, ln in enumerate(self.lines) if re.match(r"\s*\[\[\s*stage\s*\]\]", ln)]

    def stage(self, k: int) -> int | None:
        return self.stage_lines[k] if k < len(self.stage_lines) else None

    def key(self, k: int, key: str | None) -> int | None:
        """The line of option ``key`` of the k-th stage: a dotted path (``solver.max_iter``) is
        found under its table's header (``[stage.options.solver]``) or as a dotted key, else on
        the line of its table; an option not written, on the ``[[stage]]`` line."""
        start = self.stage(k)
        if start is None:
            return None
        if key is None:
            return start
        end = self.stage_lines[k + 1] if k + 1 < len(self.stage_lines) else len(self.lines) + 1
        return self._find(start, end, key) or start

    def _find(self, start: int, end: int, key: str) -> int | None:
        parent, _, last = key.rpartition(".")
        header = re.compile(r"\s*\[\s*stage\s*\.\s*options\s*(\.[^\]]*)?\]")
        table = ""                                   # the nested table the line is in ("" at the top)
        want = re.compile(rf"\s*[\"']?{re.escape(last)}[\"']?\s*=")
        dotted = re.compile(rf"\s*{re.escape(key)}\s*=") if parent else None
        for ln in range(start, end):
            text = self.lines[ln - 1]
            m = header.match(text)
            if m:
                table = re.sub(r"\s+", "", (m.group(1) or "").lstrip("."))
                if table == key:
                    return ln
                continue
            if table == parent and want.match(text):
                return ln
            if dotted is not None and table == "" and dotted.match(text):
                return ln
        return self._find(start, end, parent) if parent else None

    def table_key(self, table: str, key: str | None) -> int | None:
        """The line of ``key`` in the top-level table ``[table]`` (its header's line for None or a
        key not written there)."""
        head = next((i + 1 for i, ln in enumerate(self.lines) if re.match(rf"\s*\[\s*{table}\s*\]", ln)), None)
        if head is None or key is None:
            return head
        pat = re.compile(rf"\s*[\"']?{re.escape(key)}[\"']?\s*=")
        for i in range(head, len(self.lines)):
            if re.match(r"\s*\[", self.lines[i]):
                break
            if pat.match(self.lines[i]):
                return i + 1
        return head

    def top_key(self, key: str) -> int | None:
        pat = re.compile(rf"\s*{re.escape(key)}\s*=")
        for i, ln in enumerate(self.lines):
            if pat.match(ln):
                return i + 1
        return None


@dataclass(frozen=True)
class Overrides:
    """Options set from outside the project file: ``--set`` arguments, or a row of a sweep table.

    ``values`` maps ``"<stage id>.<option>"`` — or a dotted path into a nested table,
    ``"bundle.solver.max_iter"`` — to the value.  Their mistakes name ``source`` (``"--set"``, or
    the sweep table's path) at ``line`` (a value's) or ``name_line`` (where the names are written:
    a CSV's header); every other mistake names the project file and its line.
    """

    values: Mapping[str, Any]
    source: str | Path = "--set"
    line: int | None = None
    name_line: int | None = None

    def where(self, key: str, naming: bool = False) -> dict:
        """path, line and field of an :class:`InputError` on the override ``key``."""
        line = self.name_line if naming and self.name_line is not None else self.line
        return {"path": self.source, "line": line, "field": key}

    def describe(self) -> str:
        """The overrides as ``--set`` arguments (values as TOML/JSON writes them)."""
        return " ".join(f"--set {k}={json.dumps(v, default=str)}" for k, v in self.values.items())


def _split_key(key: str, ids: list[str]) -> tuple[str, str] | None:
    """``"<stage id>.<option path>"`` split at the longest stage id it starts with (ids may hold dots)."""
    for sid in sorted(ids, key=len, reverse=True):
        if key.startswith(sid + ".") and len(key) > len(sid) + 1:
            return sid, key[len(sid) + 1:]
    return None


def apply_override(options: dict, path: str, value: Any) -> dict:
    """A copy of a stage's option table with the option at dotted ``path`` set to ``value`` (the
    tables on the way created; nothing of ``options`` modified).  ValueError when a name on the
    way holds a value that is not a table."""
    out = dict(options)
    head, dot, rest = path.partition(".")
    if not dot:
        out[head] = value
        return out
    inner = out.get(head, {})
    if not isinstance(inner, dict):
        raise ValueError(f"'{head}' is not a table here, so '{path}' cannot be set")
    out[head] = apply_override(inner, rest, value)
    return out


def toml_value(text: str) -> Any:
    """A value written outside a TOML file (``--set``'s, a sweep table's cell) as TOML; a bare word
    that is not TOML is a string."""
    text = text.strip()
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def _read(path: Path) -> tuple[str, dict]:
    """The text of a project file and its TOML data."""
    if not path.is_file():
        raise InputError("project file not found" if not path.exists() else "not a file", path=path)
    try:
        raw_bytes = path.read_bytes()
    except OSError as e:
        raise InputError(f"cannot read the project file: {e.strerror or e}", path=path) from None
    try:
        text = raw_bytes.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw_bytes[:e.start].count(b"\n") + 1
        raise InputError(f"not a UTF-8 text file (byte offset {e.start}); a project file is TOML text",
                         path=path, line=line) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        m = re.search(r"line (\d+)", str(e))
        raise InputError(f"not valid TOML: {e}", path=path, line=int(m.group(1)) if m else None) from None
    return text, data


def load_project(path: str | Path, plugins: PluginManager | None = None,
                 overrides: Overrides | Mapping[str, Any] | None = None) -> Project:
    """Read and validate a project file (stages resolved, options parsed, data flow checked).

    ``overrides`` (``{"stage.option": value}``, or :class:`Overrides` saying where they were
    written) replace options of the file: applied to the parsed TOML in memory — the file is read
    and parsed once — and every mistake names the project file and its line, or the override's
    source (``--set``) for a mistake of an override itself.
    """
    path = Path(path)
    text, data = _read(path)
    return _build(path, text, data, plugins or PluginManager(), overrides)


def with_overrides(project: Project, overrides: Overrides | Mapping[str, Any],
                   plugins: PluginManager | None = None) -> Project:
    """``project`` (from :func:`load_project`) with ``overrides`` applied to the TOML data it was
    built from (nothing is read or parsed again; ``project`` is not modified): a sweep's rows."""
    return _build(project.path, project.text, project.data, plugins or PluginManager(), overrides)


def _build(path: Path, text: str, data: dict, plugins: PluginManager,
           overrides: Overrides | Mapping[str, Any] | None) -> Project:
    if overrides is not None and not isinstance(overrides, Overrides):
        overrides = Overrides(dict(overrides))
    loc = _Locator(text)
    unknown_top = sorted(set(data) - {"project", "run", "stage"})
    if unknown_top:
        raise InputError(f"unknown table '{unknown_top[0]}' (expected [project], [run] and [[stage]])",
                         path=path, line=loc.top_key(unknown_top[0]), field=unknown_top[0])
    proj = data.get("project", {})
    if not isinstance(proj, dict):
        raise InputError("[project] must be a table", path=path, field="project")
    bad = sorted(set(proj) - PROJECT_KEYS)
    if bad:
        raise InputError(f"unknown key '{bad[0]}' in [project]; known: {', '.join(sorted(PROJECT_KEYS))}",
                         path=path, line=loc.top_key(bad[0]), field=f"project.{bad[0]}")
    seed = proj.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise InputError(f"seed must be an integer, got {seed!r}", path=path, line=loc.top_key("seed"),
                         field="project.seed")
    if not 0 <= seed <= 2**63 - 1:
        raise InputError(f"seed must be a whole number from 0 to 2^63 − 1, got {seed}", path=path,
                         line=loc.top_key("seed"), field="project.seed")
    unit = proj.get("object_unit", "m")
    if unit not in ("m", "mm", "cm", "ft"):
        raise InputError(f"object_unit must be one of m, mm, cm, ft; got {unit!r}", path=path,
                         line=loc.top_key("object_unit"), field="project.object_unit")
    description = str(proj.get("description", ""))
    if overrides is not None and overrides.values and overrides.source == "--set":
        description = (description.strip() + f"\n\n(run with {overrides.describe()})").strip()
    project = Project(path=path.resolve(), name=str(proj.get("name", path.stem)), description=description,
                      seed=seed, object_unit=unit, text=text, data=data, overrides=overrides,
                      run=_run_options(data, path, loc, overrides, [s.get("id", s.get("use")) for s in
                                                                    data.get("stage", []) if isinstance(s, dict)]))

    stages = data.get("stage", [])
    if not isinstance(stages, list) or not stages:
        raise InputError("the project has no [[stage]] tables", path=path)
    seen_ids: dict[str, int] = {}
    chosen = []                     # (k, option table, id, StageInfo) of every enabled stage
    for k, st in enumerate(stages):
        line = loc.stage(k)
        bad = sorted(set(st) - STAGE_KEYS)
        if bad:
            raise InputError(f"unknown key '{bad[0]}' in [[stage]] (known: {', '.join(sorted(STAGE_KEYS))})",
                             path=path, line=loc.key(k, bad[0]), field=bad[0])
        enabled = st.get("enabled", True)
        if not isinstance(enabled, bool):
            raise InputError(f"enabled must be true or false, got a {type(enabled).__name__}", path=path,
                             line=loc.key(k, "enabled"), field="enabled")
        if not enabled:
            continue
        use = st.get("use")
        if not isinstance(use, str) or not use:
            raise InputError("[[stage]] needs use = \"<stage name>\"", path=path, line=line, field="use")
        try:
            info = plugins.get(use)
        except BaardaError as e:
            raise InputError(str(e), path=path, line=loc.key(k, "use"), field="use") from None
        sid = st.get("id", use)
        if not isinstance(sid, str) or not re.fullmatch(r"[A-Za-z0-9_.-]+", sid):
            raise InputError(f"stage id must be letters, digits, '-', '_' or '.', got {sid!r}", path=path,
                             line=loc.key(k, "id"), field="id")
        if sid in seen_ids:
            raise InputError(f"stage id '{sid}' used twice (first at line {seen_ids[sid]}); give one an id = \"...\"",
                             path=path, line=line, field="id")
        seen_ids[sid] = line or 0
        raw = st.get("options", {})
        if not isinstance(raw, dict):
            raise InputError("options must be a table ([stage.options])", path=path, line=line, field="options")
        chosen.append((k, raw, sid, info))
    by_id = _overrides_by_stage(overrides, [c[2] for c in chosen], path.name) if overrides is not None else {}

    available: dict[str, str] = {}
    all_ids = tuple(c[2] for c in chosen)
    owners = {c[2]: declared_outputs(c[3].cls) for c in chosen}      # every stage's tables and figures
    outputs: dict[str, str] = {}             # every output name of the project → its stage
    for k, raw, sid, info in chosen:
        use, line = info.name, loc.stage(k)
        mine = by_id.get(sid, {})
        written = raw
        for opt, key in mine.items():
            try:
                raw = apply_override(raw, opt, overrides.values[key])
            except ValueError as e:         # the file's value is no table: its own mistake first
                parse_options(info.cls.Options, written, path=path, line=line, locate=lambda o, k=k: loc.key(k, o))
                raise InputError(str(e), **overrides.where(key)) from None

        def locate(key, k=k, sid=sid, mine=mine):
            """The line of ``key`` in the project file, or a Where in the overrides' source."""
            if key is not None and any(key == o or key.startswith(o + ".") or o.startswith(key + ".") for o in mine):
                return Where(overrides.source, overrides.line, f"{sid}.", overrides.name_line)
            return loc.key(k, key)

        options = parse_options(info.cls.Options, raw, path=path, line=line, locate=locate)
        for name, role in path_roles(info.cls).items():
            problem = (output_problem(getattr(options, name), owners, getattr(info.cls, "output_adds", {}).get(name, ("",)))
                       if role == "output" else None)
            if role == "output" and not problem:      # two writers, one file: the second would fail
                for made in _output_names(getattr(options, name), getattr(info.cls, "output_adds", {}).get(name, ("",))):
                    if made in outputs:
                        problem = (f"'{made}' is written by stage '{outputs[made]}' already (an earlier output "
                                   "option); choose another name")
                        break
                    outputs[made] = sid
            if problem:
                w = locate(name)
                w = w if isinstance(w, Where) else Where(path, w)
                raise InputError(problem, w.path, w.line, w.prefix + name)
        for name in info.cls.reads:
            if name.endswith("?"):
                continue
            if name not in available:
                have = ", ".join(f"'{a}' (from {s})" for a, s in available.items()) or "nothing yet"
                raise InputError(f"stage '{sid}' ({use}) reads '{name}', which no earlier stage writes; "
                                 f"available: {have}", path=path, line=line, field="use")
        for name in info.cls.writes:
            available[name] = sid
        project.stages.append(StageSpec(id=sid, use=use, cls=info.cls, options=options, raw_options=raw,
                                        line=line, package=info.package,
                                        option_lines={key: loc.key(k, key) for key in raw}))
    return project


def _run_key(key: str, ids: list[str]) -> str | None:
    """The option of the ``[run]`` table an override ``run.<option>`` sets (None for another key,
    and when a stage has the id ``run``: then the key is that stage's)."""
    return key[4:] if key.startswith("run.") and len(key) > 4 and "run" not in ids else None


def _run_options(data: dict, path: Path, loc: _Locator, overrides: Overrides | None, ids: list) -> RunOptions:
    """The ``[run]`` table, with the overrides ``run.<option>`` applied."""
    raw = data.get("run", {})
    if not isinstance(raw, dict):
        raise InputError("[run] must be a table", path=path, line=loc.top_key("run"), field="run")
    mine = {}
    for key in (overrides.values if overrides is not None else {}):
        opt = _run_key(key, ids)
        if opt is not None:
            raw = apply_override(raw, opt, overrides.values[key])
            mine[opt] = key

    def locate(key):
        if key is not None and key in mine:
            return Where(overrides.source, overrides.line, "run.", overrides.name_line)
        return loc.table_key("run", key)

    return parse_options(RunOptions, raw, path=path, locate=locate, prefix="run.")


def _overrides_by_stage(overrides: Overrides, ids: list[str], project_name: str) -> dict[str, dict]:
    """``{stage id: {option path: override key}}``; a key naming no stage of the project is an
    :class:`InputError` on the override, with the closest stage id."""
    out: dict[str, dict] = {}
    for key in overrides.values:
        if _run_key(key, ids) is not None:        # the [run] table's (see _run_options)
            continue
        split = _split_key(key, ids)
        if split is None:                 # the stage id is what the key starts with: up to its first dot
            sid, dot, rest = key.partition(".")
            if not dot or not sid or not rest:
                raise InputError(f"'{key}' must be <stage id>.<option>", **overrides.where(key, naming=True))
            close = difflib.get_close_matches(sid, ids, n=1, cutoff=0.6)
            did = f"did you mean '{close[0]}'? " if close else ""
            raise InputError(f"no stage '{sid}' in {project_name}; {did}its stages: "
                             f"{', '.join(ids)}", **overrides.where(key, naming=True))
        sid, opt = split
        out.setdefault(sid, {})[opt] = key
    return out


# -- what the options name -------------------------------------------------------------------------

PATH_ROLES = ("input", "glob", "prefix", "output")
"""Roles of options naming files (a stage's ``paths`` class attribute; see pipeline/stage.py)."""


def _output_names(value: Any, adds: tuple[str, ...]) -> list[str]:
    """The names (relative POSIX paths, normalised) an output option makes of ``value``."""
    parts: list[str] = []
    for part in Path(str(value)).parts:
        if part == "..":
            if parts:
                parts.pop()
        elif part != ".":
            parts.append(part)
    if not parts:
        return []
    return ["/".join(parts[:-1] + [parts[-1] + add]) for add in adds]


def path_roles(cls: type) -> dict[str, str]:
    """``{option: role}`` for every option of stage ``cls`` that names files.

    Options typed ``Path``, ``Path | None`` or ``list[Path]`` are inputs; the stage's ``paths``
    attribute adds options or overrides roles.
    """
    hints = typing.get_type_hints(cls.Options)
    roles = {}
    for f in dataclasses.fields(cls.Options):
        tp = hints[f.name]
        args = get_args(tp) if get_origin(tp) in (typing.Union, types.UnionType, list, tuple) else ()
        if tp is Path or Path in args:
            roles[f.name] = "input"
    declared = getattr(cls, "paths", None) or {}
    for name, role in dict(declared).items():
        if role not in PATH_ROLES:
            raise ValueError(f"{cls.__qualname__}.paths: role of '{name}' must be one of "
                             f"{', '.join(PATH_ROLES)}, got {role!r}")
        roles[name] = role
    return roles


def _missing(value: Any, role: str, base: Path) -> str | None:
    """What is missing of an option's value with ``role`` (None when everything exists)."""
    values = [value] if isinstance(value, (str, Path)) else list(value or [])
    full = [p if p.is_absolute() else base / p
            for p in (Path(str(v)).expanduser() for v in values if str(v) not in ("", "."))]
    if role == "glob":
        literal = [p for p in full if not glob.has_magic(str(p))]
        for p in literal:
            if not p.exists():
                return f"file not found: {p}"
        if full and not literal and not any(glob.glob(str(p)) for p in full):
            return "no file matches " + ", ".join(str(p) for p in full)
        return None
    for p in full:
        if p.exists():
            continue
        if role == "prefix" and p.parent.is_dir() and any(q.name.startswith(p.name + ".")
                                                           for q in p.parent.iterdir()):
            continue
        what = "no file or folder starts with" if role == "prefix" else "file or folder not found:"
        return f"{what} {p}"
    return None


def stage_context(project: Project, spec: StageSpec, **kw):
    """The :class:`~baarda.pipeline.stage.Context` of ``spec`` in ``project`` (``kw``: run_dir, progress…)."""
    return Context(stage_id=spec.id, project_dir=project.directory, seed=project.seed,
                   project_file=project.path, object_unit=project.object_unit,
                   option_lines=dict(spec.option_lines), stage_line=spec.line,
                   stage_ids=tuple(s.id for s in project.stages),
                   stage_outputs={s.id: declared_outputs(s.cls) for s in project.stages}, **kw)


def validate_inputs(project: Project) -> list[str]:
    """Check what a loaded project's options name, without running anything.

    For every stage in order: each option naming files (:func:`path_roles`) is resolved against
    the project file and must exist; then the stage's ``validate_with(v)`` hook, if any, gets a
    :class:`~baarda.pipeline.stage.ValidationContext` ``v``: the block the sources before it read
    (as read, before any adjustment; None once a stage changed it in ways validate cannot know),
    a block whose observation rows bound those of the adjustment's block (``v.rows``: the last
    source's block or a source's dry construction, kept across stages that declare
    ``keeps_rows``), the stage that writes the adjustment it reads and the project — for the
    options that must fit them (the bundle's point ids and parameter names, the GNSS CSV's photos,
    RRR's ``rho`` below n − u).  Then the stage's ``validate(options, ctx)`` hook, if any, runs (a
    source stage parses its files there; when it returns the block it read, the checks every
    source's block gets in a run, :func:`~baarda.pipeline.plausibility.check_block`, run too; a
    :class:`~baarda.pipeline.stage.RowBound` is a dry construction that only bounds the rows).
    The first mistake raises :class:`InputError` (the project file, the option's line and name for
    a missing path; the input file's own line and field for a mistake inside it).  Returns the
    warnings of the hooks as ``"[id] text"``.
    """
    warnings = []
    latest = None                   # the block the sources read so far (ValidationContext.block)
    rows = None                     # a block bounding the rows of the block now in the pipeline
    adjuster = None                 # the spec of the stage that wrote the adjustment so far
    for spec in project.stages:
        for name, role in path_roles(spec.cls).items():
            if role == "output":
                continue
            problem = _missing(getattr(spec.options, name), role, project.directory)
            if problem:
                raise InputError(problem, project.path, spec.option_lines.get(name, spec.line), name)
        ctx = stage_context(project, spec)
        reads_block = "block" in [r.rstrip("?") for r in spec.cls.reads]
        v = ValidationContext(options=spec.options, ctx=ctx, block=latest if reads_block else None,
                              rows=rows, adjuster=adjuster, spec=spec, project=project)
        dry = run_validate_with(spec.cls(), v)
        hook = getattr(spec.cls, "validate", None)
        block = spec.cls().validate(spec.options, ctx) if hook is not None else None
        block = dry if isinstance(dry, RowBound) else block
        if isinstance(block, RowBound):                                # a dry construction: rows only
            latest, rows = None, block.block
        elif block is not None and hasattr(block, "observations"):    # a source's block: the runner's checks
            for w in check_block(block):
                ctx.warn(w)
            latest = rows = block
        elif "block" in [w.rstrip("?") for w in spec.cls.writes]:
            latest = None           # a stage changes the block in ways validate cannot know: no guesses
            if not keeps_rows(spec.cls, spec.options):
                rows = None
        if "adjustment" in [w.rstrip("?") for w in spec.cls.writes]:
            adjuster = spec
        warnings += [f"[{spec.id}] {w}" for w in ctx.warnings]
    return warnings


def run_validate_with(stage: Any, v: ValidationContext) -> Any:
    """A stage's ``validate_with(v)`` hook (returns what it returns: None, or a
    :class:`~baarda.pipeline.stage.RowBound` for a block that exists only during the run), or the
    two hooks it replaces (with a DeprecationWarning): ``validate_block(options, block, ctx)`` when
    ``v.block`` is known, ``validate_rows(options, rows, adjuster, ctx)`` when ``v.rows`` is."""
    import warnings as _warnings

    hook = getattr(stage, "validate_with", None)
    if hook is not None:
        return hook(v)
    cls = type(stage).__qualname__
    if getattr(stage, "validate_block", None) is not None:
        _warnings.warn(f"{cls}.validate_block(options, block, ctx) is deprecated: define validate_with(v) "
                       "(baarda.pipeline.api.ValidationContext; docs/plugins.md)", DeprecationWarning, stacklevel=2)
        if v.block is not None:
            stage.validate_block(v.options, v.block, v.ctx)
    if getattr(stage, "validate_rows", None) is not None:
        _warnings.warn(f"{cls}.validate_rows(options, block, adjuster, ctx) is deprecated: define "
                       "validate_with(v) (baarda.pipeline.api.ValidationContext; docs/plugins.md)",
                       DeprecationWarning, stacklevel=2)
        if v.rows is not None:
            stage.validate_rows(v.options, v.rows, v.adjuster, v.ctx)
