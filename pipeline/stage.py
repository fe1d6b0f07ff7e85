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

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Iterable, Iterator, Mapping

import numpy as np

from .errors import InputError
from .options import NoOptions


@dataclass
class TableData:
    """A table for CSV output: ordered columns of equal length, plus a one-line description."""

    columns: dict[str, Any]
    description: str = ""

    def __post_init__(self):
        lengths = {k: len(v) for k, v in self.columns.items()}
        if len(set(lengths.values())) > 1:
            raise ValueError(f"TableData columns of unequal length: {lengths}")

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


class Progress:
    """Progress on long work, printed to stderr (quiet when not a terminal unless forced)."""

    def __init__(self, stage_id: str, stream=None, enabled: bool | None = None):
        self.stage_id = stage_id
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self._last = 0.0

    def message(self, text: str) -> None:
        if self.enabled:
            print(f"  [{self.stage_id}] {text}", file=self.stream, flush=True)

    def track(self, iterable: Iterable, total: int | None = None, what: str = "") -> Iterator:
        """Yield from ``iterable`` while printing ``what i/total`` at most every 0.5 s."""
        total = total if total is not None else (len(iterable) if hasattr(iterable, "__len__") else None)
        for i, item in enumerate(iterable):
            now = time.monotonic()
            if self.enabled and (now - self._last > 0.5 or (total and i + 1 == total)):
                self._last = now
                frac = f"{i + 1}/{total}" if total else f"{i + 1}"
                print(f"\r  [{self.stage_id}] {what} {frac}", end="", file=self.stream, flush=True)
            yield item
        if self.enabled:
            print(file=self.stream, flush=True)


@dataclass(frozen=True)
class EarlierStage:
    """What an earlier stage of the run produced (``Context.previous``)."""

    id: str
    use: str
    result: StageResult


@dataclass
class Context:
    """What the runner gives a stage besides its inputs and options.

    ``previous`` lists the earlier stages of the run in order, with their results, for stages
    that summarise a whole run (e.g. ``comparison``); ordinary stages use their ``inputs``.
    """

    stage_id: str
    project_dir: Path
    run_dir: Path | None = None
    seed: int = 0
    progress: Progress = None  # type: ignore[assignment]
    warnings: list[str] = field(default_factory=list)
    project_file: Path | None = None
    object_unit: str = "m"
    previous: list = field(default_factory=list)
    option_lines: dict[str, int] = field(default_factory=dict)
    """Line of each option the project sets, in ``project_file`` (for :meth:`option_error`)."""
    stage_line: int | None = None
    """Line of the stage's ``[[stage]]`` table in ``project_file``."""
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

    def output_path(self, value: str | Path, key: str) -> Path:
        """Where a stage writes what option ``key`` names: ``value`` inside the run directory.

        Every output stays inside the run directory: an absolute path or one that climbs out of
        it (``..``) is an :class:`InputError` on the option (``load_project`` checks this too).
        """
        from .project import output_problem

        problem = output_problem(value)
        if problem:
            raise self.option_error(problem, key)
        return (self.run_dir if self.run_dir is not None else self.project_dir) / Path(str(value))

    def option_error(self, message: str, key: str) -> InputError:
        """An :class:`InputError` naming the project file, the line of option ``key`` and ``key``.

        For mistakes that belong to an option rather than to a file it names (``raise
        ctx.option_error("comparator file not found: …", "path")``).
        """
        return InputError(message, self.project_file, self.option_lines.get(key, self.stage_line), key)

    def warn(self, text: str) -> None:
        self.warnings.append(text)
        self.progress.message(f"warning: {text}")


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
    import dataclasses

    problems = []
    for attr in REQUIRED_ATTRS:
        if not hasattr(cls, attr):
            problems.append(f"stage '{name}' ({cls!r}) has no '{attr}'")
    if hasattr(cls, "Options") and not dataclasses.is_dataclass(cls.Options):
        problems.append(f"stage '{name}': Options must be a dataclass")
    if hasattr(cls, "summary") and not str(cls.summary).strip():
        problems.append(f"stage '{name}': summary is empty")
    return problems
