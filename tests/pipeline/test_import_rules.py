"""The layers' import rules (``docs/architecture.md``), checked on the source with ``ast``.

* ``baarda.pipeline`` (engine and libraries) never imports ``baarda.plugins``;
* the numerical libraries import only the standard library, numpy, scipy and other
  ``baarda.pipeline`` libraries — no rerun, OpenCV, pycolmap, and no engine module that does — and
  write no files;
* a plugin imports the engine, the libraries and its own modules; another plugin only through that
  plugin's public ``__init__`` and only on the allow-list below;
* nothing outside the adjustment core imports its private modules or ``_``-names.

Imports inside functions count like the others.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: numerical libraries (modules or packages under pipeline/)
LIBRARIES = ("geometry", "camera", "adjustment", "stats", "synthetic", "contracts", "accuracy", "model", "options")
#: what a library may import besides the standard library and other libraries
#: (pymetis: the sparse route's fill-reducing ordering; threadpoolctl: its BLAS threads per phase)
LIBRARY_THIRD_PARTY = {"numpy", "scipy", "pymetis", "threadpoolctl"}
#: what one library (and its submodules) may import besides those
#: (numba: the adjustment's compiled per-observation kernels, pipeline/adjustment/kernels.py)
LIBRARY_ONLY = {"numba": "baarda.pipeline.adjustment"}
#: plugin → plugin edges allowed (through the other plugin's ``__init__`` only), and why
ALLOWED_PLUGIN_EDGES = {
    ("testfield", "independent_models"): "the method study compares the bundle with the independent-model block",
    ("crosscheck", "colmap"): "the cross-check writes the COLMAP model pycolmap adjusts",
}
#: the adjustment core's public face: other code imports ``baarda.pipeline.adjustment`` only
CORE = "baarda.pipeline.adjustment"
#: calls and methods that write files
WRITERS = {"write_text", "write_bytes", "savez", "savez_compressed", "save", "savetxt", "to_csv", "mkdir",
           "unlink", "rmtree"}


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return "baarda." + ".".join(parts)


def _imports(path: Path):
    """(line, imported module, names) of every import in ``path``; relative imports resolved."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    mod = _module_name(path)
    package = mod if path.name == "__init__.py" else mod.rsplit(".", 1)[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield node.lineno, a.name, ()
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            names = tuple(a.name for a in node.names)
            if node.level and not node.module:
                for n in names:
                    yield node.lineno, f"{target}.{n}", ()
            else:
                yield node.lineno, target, names


def _files(top: str):
    return sorted(p for p in (ROOT / top).rglob("*.py") if "__pycache__" not in p.parts)


def _where(path: Path, line: int) -> str:
    return f"{path.relative_to(ROOT)}:{line}"


def _is_library(module: str) -> bool:
    parts = module.split(".")
    return len(parts) >= 3 and parts[:2] == ["baarda", "pipeline"] and parts[2] in LIBRARIES


def test_pipeline_never_imports_plugins():
    bad = [f"{_where(p, ln)} imports {m}" for p in _files("pipeline") for ln, m, _ in _imports(p)
           if m == "baarda.plugins" or m.startswith("baarda.plugins.")]
    assert not bad, "the engine and libraries must not import plugins:\n" + "\n".join(bad)


def test_libraries_import_only_numpy_scipy_and_libraries():
    stdlib = set(sys.stdlib_module_names) | {"__future__"}
    bad = []
    for p in _files("pipeline"):
        me = _module_name(p)
        if not _is_library(me):
            continue
        for ln, m, _ in _imports(p):
            top = m.split(".")[0]
            if top in stdlib or top in LIBRARY_THIRD_PARTY:
                continue
            if top in LIBRARY_ONLY and (me + ".").startswith(LIBRARY_ONLY[top] + "."):
                continue
            if m.startswith("baarda.pipeline") and (_is_library(m) or m in ("baarda.pipeline", "baarda.pipeline.errors")):
                continue
            bad.append(f"{_where(p, ln)}: {me} imports {m}")
    assert not bad, "a numerical library imports something else:\n" + "\n".join(bad)


def test_libraries_write_no_files():
    bad = []
    for p in _files("pipeline"):
        if not _is_library(_module_name(p)):
            continue
        tree = ast.parse(p.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if not isinstance(node, ast.Call):
                continue
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
            if name in WRITERS:
                bad.append(f"{_where(p, node.lineno)}: {name}(…)")
            if name == "open" and any(isinstance(a, ast.Constant) and isinstance(a.value, str)
                                      and set(a.value) & set("wax+") for a in node.args[1:2]):
                bad.append(f"{_where(p, node.lineno)}: open(…, {node.args[1].value!r})")
    assert not bad, "a numerical library writes files:\n" + "\n".join(bad)


def test_plugins_import_other_plugins_only_through_the_allow_list():
    bad = []
    for p in _files("plugins"):
        parts = p.relative_to(ROOT / "plugins").parts
        if len(parts) < 2:
            continue
        me = parts[0]
        for ln, m, names in _imports(p):
            mp = m.split(".")
            if mp[:2] != ["baarda", "plugins"] or len(mp) < 3 or mp[2] == me:
                continue
            other = mp[2]
            if (me, other) not in ALLOWED_PLUGIN_EDGES:
                bad.append(f"{_where(p, ln)}: plugin '{me}' imports plugin '{other}' ({m}) — not on the allow-list")
            elif len(mp) > 3:
                bad.append(f"{_where(p, ln)}: '{me}' imports {m}: only '{other}'s public __init__ may be used")
    assert not bad, "\n".join(bad)


def test_nothing_outside_the_core_touches_its_internals():
    bad = []
    for top in ("pipeline", "plugins"):
        for p in _files(top):
            me = _module_name(p)
            if me == CORE or me.startswith(CORE + "."):
                continue
            for ln, m, names in _imports(p):
                if m.startswith(CORE + "."):
                    bad.append(f"{_where(p, ln)}: imports the core's module {m}; use {CORE}")
                elif m == CORE and any(n.startswith("_") for n in names):
                    bad.append(f"{_where(p, ln)}: imports private names {names} of {CORE}")
    assert not bad, "\n".join(bad)


def test_the_allow_list_is_small_and_used():
    assert len(ALLOWED_PLUGIN_EDGES) <= 2
    used = set()
    for p in _files("plugins"):
        parts = p.relative_to(ROOT / "plugins").parts
        for _, m, _ in _imports(p):
            mp = m.split(".")
            if len(parts) >= 2 and mp[:2] == ["baarda", "plugins"] and len(mp) >= 3 and mp[2] != parts[0]:
                used.add((parts[0], mp[2]))
    assert set(ALLOWED_PLUGIN_EDGES) <= used, f"unused allow-list entries: {set(ALLOWED_PLUGIN_EDGES) - used}"


def test_plugins_do_not_reach_into_the_adjustment_problem():
    """A bundle result's ``problem`` (the core's index bookkeeping) is the core's own: plugins use
    the result's public fields and properties instead."""
    bad = []
    for p in _files("plugins"):
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Attribute) and node.attr == "problem":
                bad.append(f"{_where(p, node.lineno)}: .problem")
    assert not bad, "\n".join(bad)
