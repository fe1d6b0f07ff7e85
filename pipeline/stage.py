"""The stage protocol.

A stage is a class with

* ``summary`` — one line: what it does (``baarda stages`` prints it);
* ``reads`` / ``writes`` — the names of the artefacts it takes and produces (``"block"``,
  ``"screening"``, ``"adjustment"``, …).  A name ending in ``?`` is optional input;
* ``Options`` — a dataclass of typed, documented options (see :mod:`baarda.pipeline.options`);
* ``run(inputs, options, ctx) -> StageResult`` — the work.  Pure with respect to its inputs:
  it returns new artefacts, never modifies what it was given;
* ``log(result, rec, ctx)`` (optional) — writes the stage's rerun recording.  Logging lives here,
  never in ``run`` and never in numerical code;
* ``plots(result, ctx)`` (optional) — ``{name: matplotlib figure | (figure, caption)}`` for
  ``report.html``; the engine draws them (Agg) into ``<stage id>_<name>.png`` and embeds them
  (``docs/report.md``).  Plotting lives here, never in ``run`` and never in numerical code;
* ``validate(options, ctx)`` (optional) — what ``baarda validate`` checks beyond the options:
  a source stage reads and checks its input files here (raising :class:`InputError`) with the
  code and messages of ``run``, without adjusting anything, and returns the block it read.
  ``ctx.run_dir`` is None and there are no artefacts;
* ``validate_with(v)`` (optional) — what ``baarda validate`` checks of the options against what
  the earlier stages give: ``v`` is a :class:`ValidationContext` (the options, the context, the
  block the sources read, a block bounding the adjustment's rows, the stage that adjusts, the
  project).  Raise :class:`InputError` for the first mistake (``v.ctx.option_error``).  The two
  hooks of earlier versions, ``validate_block(options, block, ctx)`` and ``validate_rows(options,
  block, adjuster, ctx)``, still run with a ``DeprecationWarning``;
* ``keeps_rows`` (optional) — True (or a function of the options returning True) when the block the
  stage writes has no observation row the block it reads lacks (an adjustment that flags or removes
  rows; a detection that measures the points of its input block): ``baarda validate`` then keeps
  bounding the adjustment's redundancy across it;
* ``outputs`` (optional) — the names of the tables and figures the stage writes (``<id>_<name>``
  .csv/.parquet/.png; ``fnmatch`` patterns such as ``"distortion_*"`` for names made of the data).
  ``baarda validate`` refuses an output option of any stage (a writer's ``path``) that would be
  one of them, whether the stage runs before or after the writer; a stage without the declaration
  owns every name ``<id>_*``.  The runner refuses a table or figure the declaration does not name;
* ``paths`` (optional) — ``{option name: role}`` for options naming files.  An option typed
  ``Path`` (or ``Path | None``, ``list[Path]``) is an ``"input"`` relative to the project file
  that must exist; other roles: ``"glob"`` (list of files or glob patterns), ``"prefix"`` (a
  path or the common prefix of several files, e.g. ``…/example`` for ``example.ior``),
  ``"output"`` (written by the stage, never checked).  See :func:`baarda.pipeline.project.validate_inputs`.

Stages are found through the entry-point group ``baarda.stages`` (see :mod:`baarda.pipeline.plugins`).
The runner gives each stage a :class:`Context` with the project directory, a seeded random
generator, progress reporting and a place for warnings.
"""

from __future__ import annotations

import dataclasses
import re
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Iterable, Iterator, Mapping

import numpy as np

from .errors import InputError
from .model import FrozenMap
from .options import NoOptions, output_problem


@dataclass
class TableData:
    """A table for the run directory: ordered columns of equal length, plus a one-line description.

    ``units`` maps a column to its unit as a person writes it ("px", "µm", "mm", "m", "deg", ""
    for unitless); column names carry the same unit as a suffix (``v_px``, ``mdb_um``, ``X_m``).
    ``detail`` marks per-observation / per-point tables (skipped by ``outputs = "summary"``)."""

    columns: dict[str, Any]
    description: str = ""
    units: Mapping[str, str] = field(default_factory=dict)
    detail: bool = False

    def __post_init__(self):
        lengths = {k: len(v) for k, v in self.columns.items()}
        if len(set(lengths.values())) > 1:
            raise ValueError(f"TableData columns of unequal length: {lengths}")
        from .units import column_unit        # a column's unit from its name's suffix where not given
        self.units = {**{c: column_unit(c) for c in self.columns}, **dict(self.units)}

    def __len__(self):
        return len(next(iter(self.columns.values()))) if self.columns else 0

    def rows(self) -> Iterator[dict]:
        keys = list(self.columns)
        for i in range(len(self)):
            yield {k: self.columns[k][i] for k in keys}


@dataclass
class StageResult:
    """What a stage returns.

    artefacts : named outputs (must cover the stage's ``writes``).
    summary : JSON-friendly dict for ``results.json``.
    report : Markdown for the stage's section of ``report.md`` (no heading; the runner adds it).
    tables : CSV tables, written as ``<stage id>_<name>.csv``.
    figures : PNG bytes, written as ``<stage id>_<name>.png`` and linked from the report.
    data : anything the stage's ``log`` needs (not serialised).
    """

    artefacts: dict[str, Any] = field(default_factory=dict)
    summary: dict = field(default_factory=dict)
    report: str = ""
    tables: dict[str, TableData] = field(default_factory=dict)
    figures: dict[str, bytes] = field(default_factory=dict)
    data: Any = None


VERBOSE = {"detail": False}
"""Process-wide progress detail: ``baarda --verbose`` sets ``detail`` (every bundle iteration as a
line, Ceres-style, instead of only the bar)."""


def set_verbose(detail: bool) -> None:
    VERBOSE["detail"] = bool(detail)


def _hms(seconds: float) -> str:
    if not np.isfinite(seconds):
        return "?"
    seconds = int(round(seconds))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}" if seconds >= 3600 \
        else f"{seconds // 60}:{seconds % 60:02d}"


class ProgressBar:
    """One piece of long work with a known (or unknown) number of steps.

    On a terminal a :mod:`tqdm` bar (rate, elapsed, ETA); elsewhere (logs, CI) plain lines: one
    at most every ``interval`` seconds with ``i/total``, elapsed time and ETA, and one at the end.
    ``update(n, **postfix)`` advances it; ``line(text)`` prints a line above the bar; ``close()``
    (or the ``with`` block) ends it.  Disabled, it does nothing.
    """

    def __init__(self, progress: "Progress", total: int | None, what: str, unit: str = "it"):
        self.progress, self.total, self.what, self.unit = progress, total, what, unit
        self.n = 0
        self.t0 = time.monotonic()
        self._last = self.t0
        self._bar = None
        self.postfix: dict = {}
        if progress.enabled and progress.live:
            from tqdm import tqdm        # lazy: only a live bar needs it (keeps `baarda --help` fast)

            self._bar = tqdm(total=total, desc=f"  [{progress.stage_id}] {what}", unit=unit, file=progress.stream,
                             leave=False, mininterval=0.2,
                             ncols=None if shutil.get_terminal_size((0, 0)).columns else 100)

    def eta(self) -> float:
        """Seconds left at the mean rate so far (nan without a total or a step)."""
        if not self.total or not self.n:
            return float("nan")
        return (time.monotonic() - self.t0) / self.n * max(self.total - self.n, 0)

    def describe(self) -> str:
        el = time.monotonic() - self.t0
        frac = f"{self.n}/{self.total} ({100 * self.n / self.total:.0f} %)" if self.total else f"{self.n}"
        post = "".join(f", {k} {v}" for k, v in self.postfix.items())
        eta = f", ETA {_hms(self.eta())}" if self.total and self.n < self.total else ""
        return f"{self.what} {frac}{post}, {_hms(el)} elapsed{eta}"

    def update(self, n: int = 1, **postfix) -> None:
        self.n += n
        self.postfix.update(postfix)
        if not self.progress.enabled:
            return
        if self._bar is not None:
            if postfix:
                self._bar.set_postfix({k: v for k, v in self.postfix.items()}, refresh=False)
            self._bar.update(n)
            return
        now = time.monotonic()
        if now - self._last >= self.progress.interval:
            self._last = now
            self.progress.message(self.describe())

    def reset(self, total: int | None = None, what: str | None = None) -> None:
        """Start counting again (the next adjustment of a series), keeping the elapsed time."""
        self.n = 0
        self.total = total if total is not None else self.total
        self.what = what or self.what
        self.t0 = time.monotonic()
        if self._bar is not None:
            self._bar.reset(total=self.total)
            self._bar.set_description(f"  [{self.progress.stage_id}] {self.what}", refresh=False)

    def line(self, text: str) -> None:
        if not self.progress.enabled:
            return
        self.progress.message(text)

    def close(self) -> None:
        if self.progress._active is self:
            self.progress._active = None
        long = time.monotonic() - self.t0 >= 1.0     # a line stays only for work that took a while
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        if self.progress.enabled and self.n and long:
            self.progress.message(self.describe())

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class Progress:
    """Progress on long work, printed to stderr.

    ``enabled`` (default: the stream is a terminal) switches it on; ``live`` (default: the stream
    is a terminal) chooses tqdm bars over plain lines, so a log file or CI gets readable lines
    every ``interval`` seconds instead of carriage returns.  :meth:`bar` for work with steps,
    :meth:`track` to iterate with a bar, :meth:`message` for one line.
    """

    def __init__(self, stage_id: str, stream=None, enabled: bool | None = None, live: bool | None = None,
                 interval: float = 10.0):
        self.stage_id = stage_id
        self.stream = stream or sys.stderr
        tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.enabled = tty if enabled is None else enabled
        self.live = tty if live is None else live
        self.interval = interval
        self._active: ProgressBar | None = None

    @property
    def detail(self) -> bool:
        """Whether to print every step as a line (``baarda --verbose``)."""
        return VERBOSE["detail"]

    def message(self, text: str) -> None:
        if not self.enabled:
            return
        if self._active is not None and self._active._bar is not None:   # above the bar, not through it
            self._active._bar.write(f"  [{self.stage_id}] {text}", file=self.stream)
        else:
            print(f"  [{self.stage_id}] {text}", file=self.stream, flush=True)

    def bar(self, total: int | None, what: str = "", unit: str = "it") -> ProgressBar:
        b = ProgressBar(self, total, what, unit)
        self._active = b
        return b

    def mapper(self, base=None, what: str = "task"):
        """A ``map``-like callable for a numerics routine's ``mapper`` argument: ``base`` (e.g. the
        run's Dask engine, :func:`baarda.pipeline.montecarlo.mapper`; default the built-in ``map``)
        with a bar over its tasks.  Results come back in order, as a list."""
        run_base = base or map

        def run(fn, items):
            items = list(items)
            out = []
            with self.bar(len(items), what) as b:
                for r in run_base(fn, items):
                    out.append(r)
                    b.update()
            return out

        return run

    def track(self, iterable: Iterable, total: int | None = None, what: str = "") -> Iterator:
        """Yield from ``iterable`` with a bar (``what i/total``, rate and ETA)."""
        total = total if total is not None else (len(iterable) if hasattr(iterable, "__len__") else None)
        with self.bar(total, what) as b:
            for item in iterable:
                yield item
                b.update()


def headline_of(result: StageResult) -> str:
    """A stage's one-line finding: ``summary["headline"]``, else the first line of its report that
    is not a table row (at most 240 characters)."""
    h = result.summary.get("headline") if isinstance(result.summary, dict) else None
    if h:
        return str(h)
    for line in (result.report or "").splitlines():
        line = line.strip().lstrip("-*# ").strip()
        if line and not line.startswith("|"):
            return re.sub(r"\s+", " ", line)[:240]
    return "(no report)"


@dataclass(frozen=True)
class Finding:
    """What an earlier stage of the run found, as any later stage may read it
    (``Context.findings``): its id and plugin name, its one-line finding, its ``summary`` (the
    dict written to ``results.json``, read-only) and its tables.  A stage that needs another's
    *artefacts* declares them in ``reads``; findings are for stages that summarise a whole run
    (e.g. ``comparison``)."""

    stage: str
    use: str
    headline: str
    summary: Mapping[str, Any]
    tables: Mapping[str, TableData]

    @classmethod
    def of(cls, stage: str, use: str, result: StageResult) -> "Finding":
        summary = result.summary if isinstance(result.summary, dict) else {}
        return cls(stage, use, headline_of(result), FrozenMap(summary), FrozenMap(result.tables))


@dataclass
class Context:
    """What the runner gives a stage besides its inputs and options.

    ``findings`` lists what the earlier stages of the run found, in order (:class:`Finding`), for
    stages that summarise a whole run (e.g. ``comparison``); a stage that needs another's output
    declares the artefact in ``reads`` and gets it in its ``inputs``.
    """

    stage_id: str
    project_dir: Path
    run_dir: Path | None = None
    seed: int = 0
    progress: Progress = None  # type: ignore[assignment]
    warnings: list[str] = field(default_factory=list)
    project_file: Path | None = None
    object_unit: str = "m"
    findings: tuple[Finding, ...] = ()
    option_lines: dict[str, int] = field(default_factory=dict)
    """Line of each option the project sets, in ``project_file`` (for :meth:`option_error`)."""
    stage_line: int | None = None
    """Line of the stage's ``[[stage]]`` table in ``project_file``."""
    stage_ids: tuple[str, ...] = ()
    """Ids of every stage of the project (their tables' names are the run's own; :meth:`output_path`)."""
    stage_outputs: Mapping[str, Any] = field(default_factory=dict)
    """``{stage id: its outputs declaration (names of its tables and figures) or None}`` for every
    stage of the project (:func:`~baarda.pipeline.options.stage_file_patterns`; :meth:`output_path`)."""
    threads: int = 1
    """Cores the stage may use for work that pays (``baarda run --threads``; e.g. the bundle's
    sparse route).  BLAS itself stays single-threaded outside such work."""

    def __post_init__(self):
        if self.progress is None:
            self.progress = Progress(self.stage_id, enabled=False)

    @property
    def rng(self) -> np.random.Generator:
        """A generator seeded from the project seed and the stage id (reproducible per stage)."""
        digest = sum((i + 1) * ord(ch) for i, ch in enumerate(self.stage_id))
        return np.random.default_rng([self.seed, digest])

    def resolve(self, path: str | Path) -> Path:
        """A path from the project file, relative to the project's directory."""
        p = Path(path).expanduser()
        return p if p.is_absolute() else (self.project_dir / p)

    def output_path(self, value: str | Path, key: str, adds: tuple[str, ...] = ("",)) -> Path:
        """Where a stage writes what option ``key`` names: ``value`` inside the run directory.

        The one rule of every writer (:func:`~baarda.pipeline.options.output_problem`): the path
        must be relative, stay inside the run directory, not be empty or ``"."``, and no name the
        writer makes of it (``value`` + each of ``adds``) may be a file the run writes itself or
        a file already in the run directory (a folder may be: writers add files to it) — each an
        :class:`InputError` on the option.
        """
        owners = {**{sid: None for sid in self.stage_ids}, **dict(self.stage_outputs)}
        problem = output_problem(value, owners, adds)
        if problem:
            raise self.option_error(problem, key)
        base = self.run_dir if self.run_dir is not None else self.project_dir
        out = base / Path(str(value))
        if self.run_dir is not None:
            for add in adds:
                f = out.with_name(out.name + add)
                if (f.exists() and not f.is_dir()) or f.is_symlink():    # a folder is shared (rendered images)
                    rel = f.relative_to(base).as_posix()
                    raise self.option_error(f"'{rel}' is already in the run directory (written earlier in this "
                                            f"run); choose another {key}", key)
        return out

    def option_error(self, message: str, key: str) -> InputError:
        """An :class:`InputError` naming the project file, the line of option ``key`` and ``key``.

        For mistakes that belong to an option rather than to a file it names (``raise
        ctx.option_error("comparator file not found: …", "path")``).
        """
        return InputError(message, self.project_file, self.option_lines.get(key, self.stage_line), key)

    def warn(self, text: str) -> None:
        self.warnings.append(text)
        self.progress.message(f"warning: {text}")


@dataclass
class ValidationContext:
    """What ``baarda validate`` gives a stage's ``validate_with(v)`` hook.

    options : the stage's parsed options;
    ctx : its :class:`Context` (``ctx.run_dir`` is None; ``ctx.option_error`` names the project
        file, the option's line and the option);
    block : the block the sources before it read, as read (before any adjustment), or None when a
        stage in between changed it in ways validate cannot know (or no source came before);
    rows : a block with at least every observation row the block of the stage's adjustment can
        have — the last source's block, or a dry construction of a block that exists only during
        the run (the rendered test field: every target in front of every camera), kept across the
        stages that declare ``keeps_rows`` — or None;
    adjuster : the :class:`~baarda.pipeline.project.StageSpec` of the stage that writes the
        ``adjustment`` the stage reads (None when there is none);
    spec, project : the stage's own spec and the whole project (every stage, in order).
    """

    options: Any
    ctx: "Context"
    block: Any = None
    rows: Any = None
    adjuster: Any = None
    spec: Any = None
    project: Any = None


@dataclass(frozen=True)
class RowBound:
    """What a stage's ``validate`` returns for a block that exists only during the run: ``block``
    has at least every observation row (and at most the unknowns) the run's block can have — a
    dry construction (e.g. every target in front of every camera, where the run detects them in
    rendered images).  ``baarda validate`` bounds the redundancy with it (``ValidationContext.rows``)
    but checks no names against it."""

    block: Any


def keeps_rows(cls: type, options: Any) -> bool:
    """Whether stage ``cls`` with ``options`` declares that the block it writes has no observation
    row its input block lacks (its ``keeps_rows`` attribute, a bool or a function of the options)."""
    kr = getattr(cls, "keeps_rows", False)
    return bool(kr(options) if callable(kr) else kr)


class Stage:
    """Base class of stages (subclassing is optional; the runner checks the attributes)."""

    summary: ClassVar[str] = ""
    reads: ClassVar[tuple[str, ...]] = ()
    writes: ClassVar[tuple[str, ...]] = ()
    Options: ClassVar[type] = NoOptions

    def run(self, inputs: Mapping[str, Any], options: Any, ctx: Context) -> StageResult:
        raise NotImplementedError  # pragma: no cover - the protocol's abstract method

    def log(self, result: StageResult, rec: Any, ctx: Context) -> None:
        """Write the stage's recording (default: nothing beyond the runner's summary)."""

    def plots(self, result: StageResult, ctx: Context) -> dict:
        """Figures for ``report.html``: ``{name: figure | (figure, caption)}`` (default: none)."""
        return {}

    def validate(self, options: Any, ctx: Context) -> Any:
        """Check the stage's inputs without running it (``baarda validate``); default: nothing.

        Raise :class:`~baarda.pipeline.errors.InputError` for the first mistake; ``ctx.warn`` for doubts.
        A source returns the block it read (the block checks of a run then apply), or None.
        """


class SourceStage(Stage):
    """A stage that reads input files into a ``block`` (and reads no artefact).

    ``baarda validate`` runs its ``run`` — reading and checking only, with the very code and
    messages of a run — and returns the block, which then gets the checks of every source's block
    (:func:`~baarda.pipeline.plausibility.check_block`).  A source whose ``run`` does expensive work
    beyond reading overrides :meth:`validate`.
    """

    writes: ClassVar[tuple[str, ...]] = ("block",)

    def validate(self, options: Any, ctx: Context) -> Any:
        return self.run({}, options, ctx).artefacts.get("block")


REQUIRED_ATTRS = ("summary", "reads", "writes", "Options", "run")


def check_stage_class(cls: type, name: str) -> list[str]:
    """Problems with a stage class (empty when it follows the protocol)."""
    problems = []
    for attr in REQUIRED_ATTRS:
        if not hasattr(cls, attr):
            problems.append(f"stage '{name}' ({cls!r}) has no '{attr}'")
    if hasattr(cls, "Options") and not dataclasses.is_dataclass(cls.Options):
        problems.append(f"stage '{name}': Options must be a dataclass")
    if hasattr(cls, "summary") and not str(cls.summary).strip():
        problems.append(f"stage '{name}': summary is empty")
    return problems
