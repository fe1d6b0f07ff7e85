"""The camera-model registry: AP models by name, found through the entry-point group
``baarda.camera_models``.

baarda's own models register there in its ``pyproject.toml``; a third-party package adds::

    [project.entry-points."baarda.camera_models"]
    my-model = "my_package.models:MyModel"      # a class (instantiated once) or an instance

and ``ap_model = "my-model"`` works in every stage.  Nothing is registered at import time: the
registry reads the entry points the first time a name is looked up.  :func:`register_ap_model`
adds a model at run time (tests, notebooks).
"""

from __future__ import annotations

import difflib
from importlib.metadata import entry_points

from .models import APModel, adapt_model

__all__ = ["GROUP", "CameraModelRegistry", "REGISTRY", "register_ap_model", "get_ap_model", "ap_model_names"]

GROUP = "baarda.camera_models"


class CameraModelRegistry:
    """AP models by name: those of the entry-point group (read lazily, once) plus registered ones."""

    def __init__(self, group: str = GROUP, discover: bool = True):
        self.group = group
        self._models: dict[str, APModel] = {}
        self._discovered = not discover
        self.load_errors: dict[str, str] = {}

    def _discover(self) -> None:
        if self._discovered:
            return
        self._discovered = True
        for ep in entry_points(group=self.group):
            if ep.name in self._models:
                continue                       # registered in code first: that one stays
            try:
                obj = ep.load()
                self._models[ep.name] = adapt_model(ep.name, obj() if isinstance(obj, type) else obj)
            except Exception as e:             # a broken third-party model is reported when asked for
                self.load_errors[ep.name] = f"{ep.value}: {type(e).__name__}: {e}"

    def register(self, name: str, model, *, replace: bool = False) -> None:
        """Make ``model`` available as ``Cameras.ap_model == name``.

        ``ValueError`` if the name is taken (``replace=True`` overrides) or the model lacks
        ``params`` / ``distortion``."""
        self._discover()
        if name in self._models and not replace:
            raise ValueError(f"AP model {name!r} is already registered")
        self._models[name] = adapt_model(name, model)

    def get(self, name: str) -> APModel:
        """The model ``name``; ``KeyError`` naming the known models (and the closest, and why an
        installed one failed to load)."""
        self._discover()
        try:
            return self._models[str(name)]
        except KeyError:
            pass
        if str(name) in self.load_errors:
            raise KeyError(f"AP model {name!r} failed to load ({self.load_errors[str(name)]})") from None
        close = difflib.get_close_matches(str(name), list(self._models), n=2, cutoff=0.6)
        did = f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
        raise KeyError(f"unknown AP model {name!r}{did}; registered: {', '.join(sorted(self._models))}") from None

    def names(self) -> list[str]:
        self._discover()
        return sorted(self._models)

    def __contains__(self, name) -> bool:
        self._discover()
        return str(name) in self._models


REGISTRY = CameraModelRegistry()
"""The registry every stage uses."""


def register_ap_model(name: str, model, *, replace: bool = False) -> None:
    """Register ``model`` under ``name`` in :data:`REGISTRY` (see :meth:`CameraModelRegistry.register`)."""
    REGISTRY.register(name, model, replace=replace)


def get_ap_model(name: str) -> APModel:
    """The model ``name`` from :data:`REGISTRY`."""
    return REGISTRY.get(name)


def ap_model_names() -> list[str]:
    return REGISTRY.names()
