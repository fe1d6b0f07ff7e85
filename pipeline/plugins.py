"""The plugin manager: stages are found through the entry-point group ``baarda.stages``.

Built-in stages register through that same group in baarda's own ``pyproject.toml``; a
third-party package adds ``[project.entry-points."baarda.stages"] my-stage = "pkg.mod:MyStage"``
and is found the same way.  Nothing is discovered at import time: a :class:`PluginManager` is
created by the runner (or by a test, with discovery blocked — see :mod:`baarda.pipeline.testing`).
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
    """Registry of stage classes by name."""

    def __init__(self, discover: bool = True, group: str = GROUP):
        self.group = group
        self._stages: dict[str, StageInfo] = {}
        self.load_errors: dict[str, str] = {}
        if discover:
            self.discover()

    def discover(self) -> None:
        """Load every entry point of the group; a broken plugin is recorded, not fatal."""
        for ep in entry_points(group=self.group):
            try:
                cls = ep.load()
            except Exception as e:  # a third-party plugin that fails to import
                self.load_errors[ep.name] = f"{type(e).__name__}: {e}"
                continue
            package = ep.dist.name if ep.dist is not None else ep.module.split(".")[0]
            self._register(ep.name, cls, package, ep.value)

    def register(self, name: str, cls: type, package: str = "(registered in code)") -> None:
        """Register a stage class directly (tests, notebooks)."""
        self._register(name, cls, package, f"{cls.__module__}:{cls.__qualname__}")

    def _register(self, name, cls, package, value):
        problems = check_stage_class(cls, name) + options_problems(getattr(cls, "Options", None))
        if problems:
            self.load_errors[name] = "; ".join(problems)
            return
        if name in self._stages and self._stages[name].value != value:
            self.load_errors[name] = (f"stage name '{name}' registered twice: {self._stages[name].value} "
                                      f"and {value}; keeping the first")
            return
        self._stages[name] = StageInfo(name, cls, package, value)

    def get(self, name: str) -> StageInfo:
        """The stage called ``name``; an unknown name is an error that names the stage's new name
        (a stage class's ``formerly``) or the closest installed names."""
        try:
            return self._stages[name]
        except KeyError:
            pass
        for info in self._stages.values():
            if name in tuple(getattr(info.cls, "formerly", ()) or ()):
                raise BaardaError(f"stage '{name}' is now '{info.name}': write use = \"{info.name}\"")
            retired = (getattr(info.cls, "retired", None) or {}).get(name)     # a stage replaced by something else
            if retired:
                raise BaardaError(f"stage '{name}' was retired: {retired}")
        hint = f" ({self.load_errors[name]})" if name in self.load_errors else ""
        close = difflib.get_close_matches(name, list(self._stages), n=3, cutoff=0.6)
        did = f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
        known = ", ".join(sorted(self._stages)) or "(none installed)"
        raise BaardaError(f"no stage named '{name}'{hint}{did}; installed stages: {known}")

    def names(self) -> list[str]:
        return sorted(self._stages)

    def __iter__(self):
        return iter(self._stages[n] for n in self.names())

    def __contains__(self, name) -> bool:
        return name in self._stages
