"""The plugin manager: stages are found through the entry-point group ``baarda.stages``.

Built-in stages register through that same group in baarda's own ``pyproject.toml``; a
third-party package adds ``[project.entry-points."baarda.stages"] my-stage = "pkg.mod:MyStage"``
and is found the same way.  Nothing is discovered at import time: a :class:`PluginManager` is
created by the runner (or by a test, with discovery blocked — see :mod:`baarda.pipeline.testing`).

Discovery is lazy: :meth:`PluginManager.discover` reads the entry points' names and values only
(the installed packages' metadata, no plugin module imported); a stage class is imported and
checked when something asks for it — :meth:`~PluginManager.get` for the stages a project uses,
:meth:`~PluginManager.names`, iteration and :attr:`~PluginManager.load_errors` for all of them
(``baarda stages``, the docs, the tests).  A run of a BAL project imports the BAL and bundle stages
and not OpenCV, pycolmap or the congruence stages.  A plugin that fails to import is reported the
same way as before, when it is loaded: under ``load_errors`` (``baarda stages`` prints them) and in
the error of a project that uses it.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from importlib.metadata import entry_points

from .errors import BaardaError
from .options import options_problems
from .stage import check_stage_class

GROUP = "baarda.stages"


@dataclass(frozen=True)
class StageInfo:
    name: str
    cls: type
    package: str
    value: str

    @property
    def summary(self) -> str:
        return str(getattr(self.cls, "summary", "")).strip().splitlines()[0] if getattr(self.cls, "summary", "") else ""


class PluginManager:
    """Registry of stage classes by name; entry points are loaded when first asked for."""

    def __init__(self, discover: bool = True, group: str = GROUP):
        self.group = group
        self._stages: dict[str, StageInfo] = {}
        self._pending: dict[str, list] = {}          # name -> entry points not loaded yet, in discovery order
        self._errors: dict[str, str] = {}
        if discover:
            self.discover()

    def discover(self) -> None:
        """Find every entry point of the group (names and values; nothing is imported here).  Each
        is loaded by :meth:`get` or, all of them, by :meth:`names`, iteration and :attr:`load_errors`."""
        for ep in entry_points(group=self.group):
            self._pending.setdefault(ep.name, []).append(ep)

    @property
    def load_errors(self) -> dict[str, str]:
        """``{name: why}`` of every stage that could not be registered (a plugin that fails to import,
        a class that breaks the protocol, a name registered twice).  Loads every entry point first."""
        self._load_all()
        return self._errors

    def _load(self, name: str) -> None:
        """Load the entry points of ``name`` not loaded yet; a broken plugin is recorded, not fatal."""
        for ep in self._pending.pop(name, ()):
            try:
                cls = ep.load()
            except Exception as e:  # a third-party plugin that fails to import
                self._errors[ep.name] = f"{type(e).__name__}: {e}"
                continue
            package = ep.dist.name if ep.dist is not None else ep.module.split(".")[0]
            self._register(ep.name, cls, package, ep.value)

    def _load_all(self) -> None:
        for name in list(self._pending):
            self._load(name)

    def register(self, name: str, cls: type, package: str = "(registered in code)") -> None:
        """Register a stage class directly (tests, notebooks)."""
        self._load(name)              # a discovered entry point of the same name comes first, as before
        self._register(name, cls, package, f"{cls.__module__}:{cls.__qualname__}")

    def _register(self, name, cls, package, value):
        problems = check_stage_class(cls, name) + options_problems(getattr(cls, "Options", None))
        if problems:
            self._errors[name] = "; ".join(problems)
            return
        if name in self._stages and self._stages[name].value != value:
            self._errors[name] = (f"stage name '{name}' registered twice: {self._stages[name].value} "
                                  f"and {value}; keeping the first")
            return
        self._stages[name] = StageInfo(name, cls, package, value)

    def get(self, name: str) -> StageInfo:
        """The stage called ``name``; an unknown name is an error that names the stage's new name
        (a stage class's ``formerly``) or the closest installed names."""
        self._load(name)
        try:
            return self._stages[name]
        except KeyError:
            pass
        self._load_all()              # a former or retired name, the closest names: every stage is needed
        for info in self._stages.values():
            if name in tuple(getattr(info.cls, "formerly", ()) or ()):
                raise BaardaError(f"stage '{name}' is now '{info.name}': write use = \"{info.name}\"")
            retired = (getattr(info.cls, "retired", None) or {}).get(name)     # a stage replaced by something else
            if retired:
                raise BaardaError(f"stage '{name}' was retired: {retired}")
        hint = f" ({self._errors[name]})" if name in self._errors else ""
        close = difflib.get_close_matches(name, list(self._stages), n=3, cutoff=0.6)
        did = f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
        known = ", ".join(sorted(self._stages)) or "(none installed)"
        raise BaardaError(f"no stage named '{name}'{hint}{did}; installed stages: {known}")

    def names(self) -> list[str]:
        self._load_all()
        return sorted(self._stages)

    def __iter__(self):
        return iter(self._stages[n] for n in self.names())

    def __contains__(self, name) -> bool:
        self._load(name)
        return name in self._stages
