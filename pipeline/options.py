"""Typed stage options: a dataclass per stage, validated from the project file.

A stage declares ``Options`` as a (frozen) dataclass; every field has a default and a docstring-like
``metadata={"doc": "..."}``.  :func:`parse_options` turns the TOML table of a stage into an
instance, rejecting unknown keys and values of the wrong type with an :class:`InputError` that
names the project file, the line and the key.

Nested tables are typed: ``dict[str, float]`` (keys and values checked), or a dataclass (its
fields, recursively).  Renamed options and values are rejected with their new spelling: an Options
class may declare ``RENAMED = {"old_name": "new_name"}`` and ``RENAMED_VALUES = {"option": {"old":
"new"}}`` (class attributes, ``typing.ClassVar``); an option moved into a nested table is
declared with ``MOVED = {"max_iter": "solver.max_iter"}`` (flat old name → dotted new path) and
rejected with "max_iter is now written as solver.max_iter (in a [stage.options.solver] table)";
any other unknown name gets the closest known ones ("did you mean …?").

One mechanism checks every number (:func:`field_range`): no option takes NaN or infinity, and each
has at most one range — the one declared with ``option(..., ge=, gt=, le=, lt=)``, or by default
the one its name implies in the vocabulary of ``docs/conventions.md`` (:func:`option_range`: a
``sigma_…`` is positive, an ``alpha…`` lies in (0, 1), ``max_iter`` is at least 1 …).
:func:`parse_options` enforces it for a project's values, :func:`check_bounds` for an options
dataclass built in Python (a library's config calls it in ``__post_init__``), :func:`describe`
shows it (``baarda stages -v``).  ``__post_init__`` keeps only rules across fields.

Options and library configs are one definition: a library may declare its config dataclass with
:func:`option` (this module imports only the standard library and :mod:`.errors`), and a stage
uses that class as its ``Options``.
"""

from __future__ import annotations

import dataclasses
import re
import difflib
import fnmatch
import types
import typing
from pathlib import Path
from typing import Any, Iterable, Literal, Mapping, get_args, get_origin

from .errors import InputError


@dataclasses.dataclass(frozen=True)
class NoOptions:
    """The stage takes no options."""


REQUIRED = dataclasses.MISSING
"""Use as ``option(REQUIRED, "doc")`` for an option the project must give."""


def option(default: Any, doc: str, *, key: str | None = None, ge: float | None = None,
           gt: float | None = None, le: float | None = None, lt: float | None = None, **kw) -> Any:
    """A documented option field: ``x: float = option(1.0, "what x does")``.

    A nested table (an option group) takes an instance of its dataclass as the default
    (``solver: Solver = option(Solver(), "…")``; each instance gets its own copy).
    ``option(REQUIRED, doc)`` declares a required option (it must come before optional ones in
    the dataclass, or the dataclass needs ``kw_only=True``).  ``key`` is the name in the project
    file when it cannot be the field's (a Python keyword: ``from_ = option(..., key="from")``).
    ``ge``/``gt``/``le``/``lt`` bound a number (or every number of a list or table) and replace the
    range the option's name implies (:func:`option_range`).
    """
    meta: dict[str, Any] = {"doc": doc} if key is None else {"doc": doc, "key": key}
    bounds = {k: v for k, v in (("ge", ge), ("gt", gt), ("le", le), ("lt", lt)) if v is not None}
    if bounds:
        meta["range"] = bounds
    if default is dataclasses.MISSING:
        return dataclasses.field(metadata=meta, **kw)
    if isinstance(default, (list, dict, set)):
        return dataclasses.field(default_factory=lambda: type(default)(default), metadata=meta, **kw)
    if dataclasses.is_dataclass(default) and not isinstance(default, type):    # a nested table's defaults
        return dataclasses.field(default_factory=lambda: dataclasses.replace(default), metadata=meta, **kw)
    return dataclasses.field(default=default, metadata=meta, **kw)


def options_problems(options_cls: type) -> list[str]:
    """Mistakes in an options class's declarations (empty when none): a ``MOVED`` name must not
    be an option any more, and its new dotted path must reach an option of a nested table."""
    if not dataclasses.is_dataclass(options_cls):
        return []
    problems = []
    fields = {f.metadata.get("key", f.name) for f in dataclasses.fields(options_cls)}
    groups = _groups(options_cls)
    for old, new in dict(getattr(options_cls, "MOVED", {}) or {}).items():
        if old in fields and old not in groups:
            problems.append(f"{options_cls.__qualname__}.MOVED: '{old}' is still an option")
        cls, parts = options_cls, new.split(".")
        for part in parts:
            hints = typing.get_type_hints(cls) if dataclasses.is_dataclass(cls) else {}
            named = {f.metadata.get("key", f.name): f.name for f in dataclasses.fields(cls)} \
                if dataclasses.is_dataclass(cls) else {}
            if part not in named:
                problems.append(f"{options_cls.__qualname__}.MOVED: '{old}' → '{new}' names no option")
                break
            tp = hints[named[part]]
            real = [a for a in get_args(tp) if a is not type(None)] if get_origin(tp) in (
                typing.Union, types.UnionType) else [tp]
            cls = real[0] if len(real) == 1 else None
    return problems


def _group_type(tp) -> type | None:
    """The dataclass of a nested table's type (``Solver`` or ``Solver | None``), else None."""
    if get_origin(tp) in (typing.Union, types.UnionType):
        real = [a for a in get_args(tp) if a is not type(None)]
        tp = real[0] if len(real) == 1 else None
    return tp if isinstance(tp, type) and dataclasses.is_dataclass(tp) else None


def _groups(options_cls: type) -> dict[str, type]:
    """``{project key: dataclass}`` of the options of ``options_cls`` that are nested tables (groups).

    A ``MOVED`` old name may be the name of a group (an old ``solver = "sparse"`` became
    ``solver.solver`` when the group ``solver`` appeared): such a key is the group when its value is a
    table, and the old flat option — rejected with its new spelling — when it is not."""
    hints = typing.get_type_hints(options_cls)
    out = {}
    for f in dataclasses.fields(options_cls):
        sub = _group_type(hints[f.name])
        if sub is not None:
            out[f.metadata.get("key", f.name)] = sub
    return out


def describe(options_cls: type) -> list[dict]:
    """Name, type, default, doc and range of every option (for ``baarda stages --verbose`` and docs):
    ``range`` as :func:`field_range` gives it (``{"gt": 0}`` or None), ``bounds`` as text (``> 0``).

    A nested table (a group, such as the bundle's ``solver``) is listed as its options, each under
    its dotted name (``solver.max_iter``, as a ``[stage.options.solver]`` table, ``--set`` and a sweep
    column write it), with ``group`` (``"solver"``; ``""`` at the top) and ``group_doc`` (the
    group's doc); ``field`` is the dotted attribute path (:func:`option_value` reads it)."""
    out: list[dict] = []

    def walk(cls: type, name: str, attr: str, group_doc: str, defaults: Any) -> None:
        """``defaults``: the group's default instance (its values are the defaults shown), or None."""
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            key = f.metadata.get("key", f.name)
            required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
            default = _default(f)
            if defaults is not None:
                default, required = getattr(defaults, f.name), False
            sub = _group_type(hints[f.name])
            if sub is not None:
                walk(sub, name + key + ".", attr + f.name + ".", f.metadata.get("doc", ""),
                     default if isinstance(default, sub) else None)
                continue
            rng = field_range(f)
            out.append({"name": name + key, "field": attr + f.name, "type": _type_name(hints[f.name]),
                        "default": default, "required": required, "doc": f.metadata.get("doc", ""),
                        "range": rng, "bounds": range_text(rng), "group": name[:-1], "group_doc": group_doc})

    walk(options_cls, "", "", "", None)
    return out


def option_value(options: Any, field: str) -> Any:
    """The value of the option at the dotted attribute path ``field`` (:func:`describe`'s
    ``field``: ``"solver.max_iter"``) of an options instance; None under a group that is None."""
    for part in field.split("."):
        if options is None:
            return None
        options = getattr(options, part)
    return options


def _type_name(tp) -> str:
    origin = get_origin(tp)
    if origin is Literal:
        return " | ".join(repr(a) for a in get_args(tp))
    if origin in (typing.Union, types.UnionType):
        return " | ".join(_type_name(a) for a in get_args(tp))
    if origin in (list, tuple):
        args = get_args(tp)
        return f"list[{_type_name(args[0])}]" if args else "list"
    if origin is dict:
        args = get_args(tp)
        return f"table[{_type_name(args[0])} → {_type_name(args[1])}]" if len(args) == 2 else "table"
    if dataclasses.is_dataclass(tp):
        return f"table ({', '.join(f.metadata.get('key', f.name) for f in dataclasses.fields(tp))})"
    return getattr(tp, "__name__", str(tp))


# Ranges the option vocabulary implies (docs/conventions.md, "Option names"); the first match wins.
# "pos0": positive, or 0 where 0 is the option's default (a documented "auto" / "off").
_NAME_RANGES: list[tuple[str, Any]] = [
    ("arrow_scale", {"ge": 0}),
    ("format_margin_mm", None),
    ("sigma_noise", {"ge": 0}),
    ("alpha", {"gt": 0, "lt": 1}), ("beta", {"gt": 0, "lt": 1}),
    ("rho_max", {"gt": 0, "le": 1}),
    ("sigma", "pos0"), ("tol_", "pos0"),
    ("max_iter", {"ge": 1}), ("max_rejections", {"ge": 0}), ("repetitions", {"ge": 1}), ("n_sim", {"ge": 0}),
    ("critical", {"ge": 0}),
    ("_scale", "pos0"), ("scale", {"gt": 0}),
    ("pixel_mm", {"gt": 0}), ("_mm", "pos0"), ("_px", "pos0"), ("_um", "pos0"), ("_size", "pos0"),
    ("distance", "pos0"),
]


COUNT_LIMITS: dict[str, int] = {
    "n_sim": 1_000_000, "repetitions": 100_000, "max_iter": 100_000, "iterations": 100_000,
    "max_rejections": 1_000_000, "rho": 1_000_000, "supersample": 64, "grid": 10_000, "smallest_angles": 1_000_000,
    "min_points": 1_000_000, "log_max_size": 100_000, "width": 1_000_000, "height": 1_000_000,
    "num_threads": 4096, "seed": 2**63 - 1,
}
"""Upper bound of every count option by name: a count without one (``n_sim = 2e9``) would run for
ever.  An integer option not named here is bounded by :data:`INT_LIMIT`."""

INT_LIMIT = 2**31 - 1
"""Largest magnitude of an integer option without a bound of its own."""

FLOAT_MAGNITUDE = (1e-30, 1e30)
"""Smallest and largest magnitude (besides 0) of a number in an option: a σ of 1e-320 (a
denormal: 1/σ² overflows) or 1e300 is a typing mistake, never a measurement."""


def option_range(name: str, default: Any = None, declared: dict | None = None) -> dict | None:
    """The range of option ``name`` (``{"gt": 0}`` …): the one declared with :func:`option`, else
    the one its name implies (``sigma…`` and ``tol_…`` positive, ``alpha…``/``beta…`` in (0, 1),
    ``max_iter`` ≥ 1, ``…_mm``/``…_px``/``…_scale`` positive …; 0 allowed where it is the default).

    The name-implied range is only the default of the declared one: one mechanism, whose result
    :func:`field_range` gives for a field, :func:`parse_options` and :func:`check_bounds` enforce
    and :func:`describe` shows."""
    if declared:
        return declared
    base = name.rsplit(".", 1)[-1]
    for pattern, rng in _NAME_RANGES:
        hit = base.endswith(pattern) if pattern.startswith("_") else (
            base.startswith(pattern) or base == pattern)
        if not hit:
            continue
        if rng == "pos0":
            zero_default = isinstance(default, (int, float)) and not isinstance(default, bool) and default == 0
            return {"ge": 0} if zero_default else {"gt": 0}
        return rng
    return None


def field_range(f: dataclasses.Field) -> dict | None:
    """The range of an option field: declared (``option(..., gt=0)``), else implied by its name."""
    default = f.default if f.default is not dataclasses.MISSING else None
    return option_range(f.metadata.get("key", f.name), default, f.metadata.get("range"))


def range_text(rng: dict | None) -> str:
    """A range as a reader writes it: ``> 0``, ``≥ 1``, ``in (0, 1)``, ``in (0, 1]``; "" for none."""
    if not rng:
        return ""
    lo = ("(", rng["gt"]) if "gt" in rng else (("[", rng["ge"]) if "ge" in rng else None)
    hi = (")", rng["lt"]) if "lt" in rng else (("]", rng["le"]) if "le" in rng else None)
    if lo and hi:
        return f"in {lo[0]}{lo[1]:g}, {hi[1]:g}{hi[0]}"
    if lo:
        return f"{'>' if lo[0] == '(' else '≥'} {lo[1]:g}"
    return f"{'<' if hi[0] == ')' else '≤'} {hi[1]:g}"


def check_bounds(obj: Any) -> None:
    """Every number of the option dataclass ``obj`` finite and inside its field's range
    (:func:`field_range`), else :class:`ValueError` naming the field.

    :func:`parse_options` checks a project's values (naming file and line); an options dataclass
    that a library also builds from Python (a config) calls this in its ``__post_init__``, so that
    both ways in meet the same bounds."""
    for f in dataclasses.fields(obj):
        name = f.metadata.get("key", f.name)
        try:
            _check_range(getattr(obj, f.name), name, field_range(f), {})
        except InputError as e:
            raise ValueError(f"{name}: {e.message}") from None


def _check_range(value: Any, name: str, rng: dict | None, where: dict) -> None:
    """Every number in ``value`` finite and inside ``rng``."""
    if isinstance(value, bool) or value is None:
        return
    if isinstance(value, (list, tuple)):
        for v in value:
            _check_range(v, name, rng, where)
        return
    if isinstance(value, dict):
        for k, v in value.items():
            _check_range(v, f"{name}.{k}", rng, where)
        return
    if not isinstance(value, (int, float)):
        return
    if value != value or value in (float("inf"), float("-inf")):
        raise InputError(f"must be a finite number, got {value}", field=name, **where)
    if isinstance(value, int) and not (rng and ("le" in rng or "lt" in rng)):     # every count is bounded
        base = name.rsplit(".", 1)[-1]
        cap = COUNT_LIMITS.get(base)
        if cap is not None and value > cap:
            raise InputError(f"must be at most {cap}, got {value}", field=name, **where)
        if base == "seed" and value < 0:
            raise InputError(f"must be at least 0, got {value}", field=name, **where)
        if cap is None and abs(value) > INT_LIMIT:
            raise InputError(f"must be at most {INT_LIMIT} in magnitude, got {value}", field=name, **where)
    if isinstance(value, float) and value != 0 and not FLOAT_MAGNITUDE[0] <= abs(value) <= FLOAT_MAGNITUDE[1]:
        raise InputError(f"must be 0 or between {FLOAT_MAGNITUDE[0]:g} and {FLOAT_MAGNITUDE[1]:g} in magnitude, "
                         f"got {value:g}", field=name, **where)
    if not rng:
        return
    text = {"gt": "greater than", "ge": "at least", "lt": "less than", "le": "at most"}
    ok = {"gt": value > rng.get("gt", 0), "ge": value >= rng.get("ge", 0), "lt": value < rng.get("lt", 0),
          "le": value <= rng.get("le", 0)}
    for k in ("gt", "ge", "lt", "le"):
        if k in rng and not ok[k]:
            limits = " and ".join(f"{text[j]} {_num_text(rng[j])}" for j in ("gt", "ge", "lt", "le") if j in rng)
            raise InputError(f"must be {limits}, got {_num_text(value)}", field=name, **where)


def _num_text(v) -> str:
    """A bound or value for a message: whole numbers in full, others with :g."""
    return str(v) if isinstance(v, int) else f"{v:g}"


def _coerce(value: Any, tp, name: str, where: dict, nested=None) -> Any:
    """``value`` as type ``tp``; ``nested(tp, value)`` parses a table of a dataclass type."""
    origin = get_origin(tp)
    if tp is Any:
        return value
    if origin is Literal:
        if value not in get_args(tp):
            raise InputError(f"must be one of {', '.join(repr(a) for a in get_args(tp))}, got {value!r}",
                             field=name, **where)
        return value
    if origin in (typing.Union, types.UnionType):
        args = get_args(tp)
        if value is None and type(None) in args:
            return None
        real = [a for a in args if a is not type(None)]
        if len(real) == 1:                      # Optional[X]: X's own message is the useful one
            return _coerce(value, real[0], name, where, nested)
        for a in real:
            try:
                return _coerce(value, a, name, where, nested)
            except InputError:
                continue
        raise InputError(f"expected {_type_name(tp)}, got {value!r}", field=name, **where)
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise InputError(f"expected a list, got {value!r}", field=name, **where)
        args = get_args(tp)
        inner = args[0] if args else Any
        out = [_coerce(v, inner, name, where, nested) for v in value]
        return tuple(out) if origin is tuple else out
    if origin is dict:
        if not isinstance(value, dict):
            raise InputError(f"expected a table, got {value!r}", field=name, **where)
        args = get_args(tp)
        if len(args) != 2:
            return dict(value)
        return {_coerce(k, args[0], f"{name}.{k}", where): _coerce(v, args[1], f"{name}.{k}", where)
                for k, v in value.items()}
    if tp is bool:
        if not isinstance(value, bool):
            raise InputError(f"expected true or false, got {value!r}", field=name, **where)
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise InputError(f"expected an integer, got {value!r}", field=name, **where)
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(f"expected a number, got {value!r}", field=name, **where)
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise InputError(f"expected a string, got {value!r}", field=name, **where)
        return value
    if tp is Path:
        if not isinstance(value, str):
            raise InputError(f"expected a path string, got {value!r}", field=name, **where)
        return Path(value)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise InputError(f"expected a table, got {value!r}", field=name, **where)
        return nested(tp, value)
    return value


class Where(typing.NamedTuple):
    """Where an option was written, for an error message: the file (a project file, a sweep table,
    or ``"--set"``), the line, and the prefix its name carries there (``"bundle."`` for
    ``--set bundle.max_iter=…``; ``""`` inside the stage's ``[stage.options]`` table)."""

    path: Any = None
    line: int | None = None
    prefix: str = ""
    name_line: int | None = None
    """Where the option's name is written, when elsewhere than its value (a sweep table's header)."""


def parse_options(options_cls: type, raw: dict | None, *, path=None, line=None,
                  locate=None, prefix: str = "") -> Any:
    """Validate ``raw`` (a TOML table) against ``options_cls``.

    ``locate(key)`` may be given to point errors at the exact line of a key: ``key`` is the
    option's dotted path (``"solver.max_iter"`` inside a nested table; None for the stage's table
    as a whole); it returns the line, or a :class:`Where` for a key written elsewhere (an
    override), or None (then ``line``).  ``prefix`` is shown before every name (``"bundle."``).
    """
    def where(key: str | None) -> Where:
        got = locate(key) if locate else None
        return got if isinstance(got, Where) else Where(path, got or line, prefix)

    return _parse(options_cls, raw, where, "")


def _parse(options_cls: type, raw: dict | None, where, sub: str, base: Any = None) -> Any:
    """:func:`parse_options` of one table; ``sub`` is its dotted path (``"solver."``, or ``""``);
    ``base``: the group's default instance, whose values the options not written keep."""
    raw = dict(raw or {})
    hints = typing.get_type_hints(options_cls)
    fields = {f.metadata.get("key", f.name): f for f in dataclasses.fields(options_cls)}

    def at(key: str | None, naming: bool = False) -> tuple[str, dict]:
        """The name to show for ``key`` and the InputError's path and line (``naming``: a mistake
        in the name, not the value)."""
        w = where(sub + key if key is not None else (sub[:-1] or None))
        line = w.name_line if naming and w.name_line is not None else w.line
        return w.prefix + sub + (key or ""), {"path": w.path, "line": line}

    renamed = dict(getattr(options_cls, "RENAMED", {}) or {})
    for key in sorted(set(raw) & set(renamed)):
        name, loc = at(key, naming=True)
        raise InputError(f"option '{name}' is now '{name[:-len(key)]}{renamed[key]}'", field=name, **loc)
    moved = dict(getattr(options_cls, "MOVED", {}) or {})
    groups = _groups(options_cls)
    flat = {k for k in set(raw) & set(moved) if k not in groups or not isinstance(raw[k], dict)}
    for key in sorted(flat):
        name, loc = at(key, naming=True)
        new = name[:-len(key)] + moved[key]
        w = where(sub + key)
        table = f" (in a [stage.options.{sub}{moved[key].rpartition('.')[0]}] table)" if not w.prefix else ""
        raise InputError(f"{name} is now written as {new}{table}", field=name, **loc)
    unknown = sorted(set(raw) - set(fields))
    if unknown:
        key = unknown[0]
        name, loc = at(key, naming=True)
        shown = name[:-len(key)]
        known = ", ".join(sorted(fields)) or "(none)"
        close = difflib.get_close_matches(key, list(fields), n=2, cutoff=0.6)
        did = f"did you mean {' or '.join(repr(shown + c) for c in close)}? " if close else ""
        raise InputError(f"unknown option '{name}'; {did}this stage accepts: {known}", field=name, **loc)
    old_values = dict(getattr(options_cls, "RENAMED_VALUES", {}) or {})
    values = {}
    for key, value in raw.items():
        name, loc = at(key)
        old = old_values.get(key, {})
        if isinstance(value, str) and value in old:
            raise InputError(f"option '{name}': the value {value!r} is now {old[value]!r}", field=name, **loc)
        f = fields[key]
        values[f.name] = _coerce(value, hints[f.name], name, loc,
                                 lambda tp, v, key=key, f=f: _parse(tp, v, where, f"{sub}{key}.", _default(f)))
        _check_range(values[f.name], name, field_range(f), loc)
    if isinstance(base, options_cls):          # a group's own default instance: what is not written
        values = {f.name: getattr(base, f.name) for f in dataclasses.fields(options_cls) if f.init} | values
    missing = [n for n, f in fields.items() if f.name not in values
               and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    if missing:
        name, _ = at(missing[0])
        raise InputError(f"required option '{name}' is missing", field=name, **at(None)[1])
    try:
        return options_cls(**values)
    except (ValueError, TypeError) as e:  # __post_init__ checks of the options class
        msg = str(e)
        head = re.split(r"[\s:]", msg, maxsplit=1)[0]
        if head in raw:                   # "displacements: …", "case must be …": that option's line
            name, loc = at(head)
            raise InputError(msg, field=name, **loc) from None
        raise InputError(msg, **at(None)[1]) from None


def _default(f: dataclasses.Field) -> Any:
    """The default value of field ``f`` (None when it has none)."""
    if f.default is not dataclasses.MISSING:
        return f.default
    return f.default_factory() if f.default_factory is not dataclasses.MISSING else None


def to_plain(obj: Any) -> Any:
    """Options (or anything) as JSON/TOML-friendly plain values."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.metadata.get("key", f.name): to_plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, (list, tuple)):
        return [to_plain(v) for v in obj]
    if isinstance(obj, dict):
        return {str(k): to_plain(v) for k, v in obj.items()}
    return obj


RUN_OWN_FILES = ("report.md", "report.html", "results.json", "project.resolved.toml", ".baarda-incomplete")
"""Files the runner itself writes at the top of every run directory (besides ``*.rrd`` and the
stages' ``<id>.error.txt``; the stages' tables ``<id>_<name>.csv/.png`` are known when they are
written: :meth:`~baarda.pipeline.stage.Context.output_path` refuses a file already in the run)."""


TABLE_SUFFIXES = (".csv", ".parquet", ".png")
"""What the runner makes of a stage's table or figure ``<id>_<name>``: ``.csv`` + ``.parquet``
(tables), ``.png`` (figures)."""


def stage_file_patterns(stage_id: str, outputs: Iterable[str] | None) -> tuple[str, ...]:
    """The names (``fnmatch`` patterns, at the top of the run directory) of the tables and figures
    stage ``stage_id`` writes, from its ``outputs`` declaration — the names (patterns allowed,
    ``"distortion_*"``) of its tables and figures.  A stage without the declaration (None) owns
    every name ``<id>_*``."""
    if outputs is None:
        return (f"{stage_id}_*",)
    return tuple(f"{stage_id}_{o}{suffix}" for o in outputs for suffix in TABLE_SUFFIXES)


def declared_outputs(cls: type) -> tuple[str, ...] | None:
    """A stage class's ``outputs`` declaration (None when it has none)."""
    out = getattr(cls, "outputs", None)
    return None if out is None else tuple(str(o) for o in out)


def _owned(stage_ids) -> dict[str, tuple[str, ...]]:
    """``{stage id: its file patterns}`` from a mapping ``{id: outputs declaration}`` or ids alone
    (then each owns ``<id>_*``)."""
    if isinstance(stage_ids, Mapping):
        return {str(sid): stage_file_patterns(str(sid), outs) for sid, outs in stage_ids.items()}
    return {str(sid): stage_file_patterns(str(sid), None) for sid in stage_ids}


def run_file_clash(name: str, stage_ids=()) -> str | None:
    """Why ``name`` (a POSIX path relative to the run directory) is a file the run writes itself,
    or None.  ``stage_ids``: the project's stage ids, or ``{id: outputs declaration}`` (the names of
    each stage's tables and figures, :func:`stage_file_patterns`)."""
    top = name.split("/")[0]
    for sid, patterns in _owned(stage_ids).items():
        hit = next((p for p in patterns if fnmatch.fnmatchcase(top, p)), None)
        if hit is not None:
            what = (f"a name of stage '{sid}', whose tables and figures are {sid}_<name>.csv/.parquet/.png"
                    if hit == f"{sid}_*" else f"a table or figure of stage '{sid}' ({hit})")
            return f"'{top}' is {what}"
    if "/" in name:
        return None
    if name in RUN_OWN_FILES:
        return f"'{name}' is a file the run writes itself"
    if name.endswith(".rrd"):
        return f"'{name}' would be a recording (*.rrd), which the run writes itself"
    for sid in stage_ids:
        if name in (f"{sid}.error.txt", f"{sid}.plots-error.txt"):
            return f"'{name}' is where the run writes the error of stage '{sid}'"
    return None


def output_problem(value: Any, stage_ids=(), adds=("",)) -> str | None:
    """Why an output path may not be used (None when it is fine) — the one rule of every writer.

    Outputs are written inside the run directory: the path must be relative, must not climb out
    of it, must not be empty or the run directory itself (``""``, ``"."``, ``"a/.."``), and none of
    the names the writer makes of it (``value`` + each of ``adds``, e.g. ``.ply``/``.csv``) may be
    a file the run writes itself (:func:`run_file_clash`): the runner's own files, recordings,
    error files, and every stage's tables and figures (``stage_ids`` as ``{id: outputs
    declaration}``; a stage id alone owns every ``<id>_*``) — whether that stage runs before or
    after the writer.  ``baarda validate`` (project loading) and the writer in the run
    (:meth:`~baarda.pipeline.stage.Context.output_path`) apply this one rule."""
    text = str(value if value is not None else "")
    if not text.strip():
        return "an output path must name a file or folder inside the run directory; got an empty path"
    p = Path(text)
    if p.is_absolute() or text.startswith("~"):
        return (f"an output path must be relative to the run directory (everything a run writes stays "
                f"inside it); got an absolute path")
    parts: list[str] = []
    for part in p.parts:
        if part == "..":
            if not parts:
                return "an output path must stay inside the run directory; this one climbs out of it with '..'"
            parts.pop()
        elif part != ".":
            parts.append(part)
    if not parts:
        return (f"an output path must name a file or folder inside the run directory; {text!r} is the run "
                "directory itself")
    for add in adds:
        clash = run_file_clash("/".join(parts[:-1] + [parts[-1] + add]), stage_ids)
        if clash:
            return f"{clash}; choose another name"
    return None
