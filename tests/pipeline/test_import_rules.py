"""The layers' import rules (``docs/architecture.md``), checked on the source with ``ast``.

* ``baarda.pipeline`` (engine and libraries) never imports ``baarda.plugins``;
* the numerical libraries import only the standard library, numpy, scipy and other
  ``baarda.pipeline`` libraries — no rerun, OpenCV, pycolmap, and no engine module that does — and
  write no files;
* a plugin imports the engine, the libraries and its own modules — never another plugin (what two
  plugins share is a library or an engine module);
* nothing outside the adjustment core imports its private modules or ``_``-names;
* no import cycle between modules of baarda.

Imports inside functions count like the others (``if TYPE_CHECKING:`` imports do not run and do not
count for cycles).
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: numerical libraries (modules or packages under pipeline/)
LIBRARIES = ("geometry", "camera", "adjustment", "stats", "synthetic", "contracts", "accuracy", "model",
             "imodels", "options", "threads", "jit")
#: what a library may import besides the standard library and other libraries
#: (pymetis: the sparse route's fill-reducing ordering; threadpoolctl: its BLAS threads per phase)
LIBRARY_THIRD_PARTY = {"numpy", "scipy", "pymetis", "threadpoolctl"}
#: what one library (and its submodules) may import besides those
#: (numba: the compiled kernels of the adjustment and the camera models, through pipeline/jit.py)
LIBRARY_ONLY = {"numba": "baarda.pipeline.jit"}
#: plugin → plugin edges allowed (through the other plugin's ``__init__`` only), and why: none —
#: the independent-model numerics and the COLMAP conversion that two plugins shared are
#: ``baarda.pipeline.imodels`` and ``baarda.pipeline.colmap`` now
ALLOWED_PLUGIN_EDGES: dict[tuple[str, str], str] = {}
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


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or \
        (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(path: Path, *, runtime: bool = False, expand: bool = True):
    """(line, imported module, names) of every import in ``path`` (inside functions too); relative
    imports resolved.  ``runtime``: without the bodies of ``if TYPE_CHECKING:``, which never run.
    ``expand``: ``from . import x`` as the module ``package.x`` (else as ``package`` with names)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    mod = _module_name(path)
    package = mod if path.name == "__init__.py" else mod.rsplit(".", 1)[0]
    stack = [tree]
    while stack:
        node = stack.pop()
        if runtime and isinstance(node, ast.If) and _is_type_checking(node.test):
            stack.extend(node.orelse)
            continue
        stack.extend(ast.iter_child_nodes(node))
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
            if expand and node.level and not node.module:
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


def test_the_allow_list_is_empty():
    """No plugin imports another plugin: a third party's plugin could not rely on a built-in one."""
    assert ALLOWED_PLUGIN_EDGES == {}


def test_plugins_do_not_reach_into_the_adjustment_problem():
    """A bundle result's ``problem`` (the core's index bookkeeping) is the core's own: plugins use
    the result's public fields and properties instead."""
    bad = []
    for p in _files("plugins"):
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Attribute) and node.attr == "problem":
                bad.append(f"{_where(p, node.lineno)}: .problem")
    assert not bad, "\n".join(bad)


# --- import cycles ------------------------------------------------------------------------------

def _top_level_names(path: Path) -> set[str]:
    """Names a package's ``__init__`` binds at its top level (imports, definitions, assignments),
    except its own submodules imported under their own names (``from . import x``): those are
    the submodules themselves."""
    me = _module_name(path)
    out = set()
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.ImportFrom) and ((node.level == 1 and not node.module) or node.module == me):
            out |= {a.asname for a in node.names if a.asname and a.asname != a.name}
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            out |= {(a.asname or a.name).split(".")[0] for a in node.names}
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            for t in node.targets if isinstance(node, ast.Assign) else [node.target]:
                out |= {n.id for n in ast.walk(t) if isinstance(n, ast.Name)}
    return out


def _module_graph():
    """{module: {imported module: [file:line, …]}} over every module of baarda.

    ``from P import n`` is an edge to the module ``P.n`` when there is one and ``P``'s ``__init__``
    binds no name ``n`` (else the object comes from the ``__init__``: an edge to ``P``);
    ``import a.b.c`` an edge to the deepest module of baarda it names.  A package's ``__init__`` run
    on the way to a submodule is no edge (every submodule would close a cycle with the ``__init__``
    that re-exports it)."""
    files = {_module_name(p): p for top in ("pipeline", "plugins") for p in _files(top)}
    graph: dict[str, dict[str, list[str]]] = {m: {} for m in files}
    bound = {m: _top_level_names(p) for m, p in files.items() if p.name == "__init__.py"}

    def known(name: str) -> str | None:
        while name and name not in files:
            name = name.rpartition(".")[0]
        return name or None

    for me, path in files.items():
        for line, target, names in _imports(path, runtime=True, expand=False):
            if not target.startswith("baarda."):
                continue
            hits = [f"{target}.{n}" for n in names
                    if f"{target}.{n}" in files and n not in bound.get(target, ())]
            if len(hits) < len(names) or not names:
                hits.append(known(target))
            for other in hits:
                if other and other != me:
                    graph[me].setdefault(other, []).append(_where(path, line))
    return graph


def _strongly_connected(graph):
    """Tarjan's strongly connected components (iterative), those of more than one module."""
    index, low, on, stack, out, counter = {}, {}, set(), [], [], [0]
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def _describe(graph, comp) -> str:
    members = set(comp)
    lines = [f"cycle among {len(comp)} modules: {', '.join(comp)}"]
    for a in comp:
        for b in sorted(set(graph[a]) & members):
            lines.append(f"    {a} → {b}  ({'; '.join(graph[a][b])})")
    return "\n".join(lines)


def test_the_cycle_finder_finds_cycles_hidden_in_functions(tmp_path, monkeypatch):
    """The check itself: a cycle closed by an import inside a function, one closed only under
    ``TYPE_CHECKING`` (not a cycle), and a ``from package import module`` edge."""
    pkg = tmp_path / "pipeline" / "toy"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from . import b\n")
    (pkg / "b.py").write_text("def f():\n    from baarda.pipeline.toy.a import x\n")
    (pkg / "c.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .a import y\n")
    (pkg / "d.py").write_text("from .c import z\n")
    (pkg / "e.py").write_text("import baarda.pipeline.toy.f\n")
    (pkg / "f.py").write_text("class K:\n    def m(self):\n        from .. import toy\n        from ..toy import e\n")
    (pkg / "g.py").write_text("def h():\n    from baarda.pipeline.toy import h\n")   # toy's h, not toy.h
    (pkg / "h.py").write_text("")
    (pkg / "__init__.py").write_text("from .g import h\nfrom . import d\n")
    (pkg / "i.py").write_text("from baarda.pipeline.toy import d\n")          # the module toy.d itself
    (tmp_path / "plugins").mkdir()
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    graph = _module_graph()
    assert graph["baarda.pipeline.toy.b"] == {"baarda.pipeline.toy.a": ["pipeline/toy/b.py:2"]}
    assert graph["baarda.pipeline.toy.c"] == {}
    assert graph["baarda.pipeline.toy.g"] == {"baarda.pipeline.toy": ["pipeline/toy/g.py:2"]}
    assert graph["baarda.pipeline.toy.i"] == {"baarda.pipeline.toy.d": ["pipeline/toy/i.py:1"]}
    comps = _strongly_connected(graph)
    assert comps == [["baarda.pipeline.toy", "baarda.pipeline.toy.g"],
                     ["baarda.pipeline.toy.a", "baarda.pipeline.toy.b"],
                     ["baarda.pipeline.toy.e", "baarda.pipeline.toy.f"]]
    assert "pipeline/toy/f.py:4" in _describe(graph, comps[2])


def test_no_import_cycles():
    """No two modules of baarda import each other, directly or round a loop, even when the import
    that closes the loop sits inside a function (it then only hides the cycle until first use)."""
    graph = _module_graph()
    comps = _strongly_connected(graph)
    assert not comps, f"{len(comps)} import cycle(s):\n" + "\n".join(_describe(graph, c) for c in comps)


def test_plugins_take_what_the_public_face_exports_from_it():
    """A built-in plugin imports every name that ``baarda.pipeline.api`` exports from the api, as a
    third-party plugin would (``docs/plugins.md``), not from the engine module behind it; names the
    api does not export may come from the engine and the libraries."""
    import importlib

    api = importlib.import_module("baarda.pipeline.api")
    public = set(api.__all__)
    bad = []
    for p in _files("plugins"):
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if not (isinstance(node, ast.ImportFrom) and node.level == 0 and node.module
                    and node.module.startswith("baarda.pipeline") and node.module != "baarda.pipeline.api"):
                continue
            mod = importlib.import_module(node.module)
            for a in node.names:
                if a.name in public and getattr(mod, a.name, None) is getattr(api, a.name):
                    bad.append(f"{_where(p, node.lineno)}: {a.name} from {node.module}; import it from baarda.pipeline.api")
    assert not bad, "\n".join(bad)
