"""What stages hand on travels in declared artefacts and typed block fields (issue 21).

An AST scan of the source (like ``test_import_rules.py``):

* ``Block.meta`` is a namespace private to the plugin that writes it: a plugin reads a top-level
  ``meta`` key only when that plugin writes it (or it is one of :data:`LIBRARY_KEYS`, the test-field
  simulator's behind the ``testfield`` source) — never a key another plugin writes, nor one it
  does not write (a stale read).  ``baarda.pipeline`` reads no key a plugin writes.  What more than one
  plugin needs is a typed field of the block (``crs``, ``source``, ``scale_bars``, ``ap_meta``,
  ``photos.image_path``).
* A stage reaches another stage's output only through the artefacts it declares in ``reads``: no
  plugin touches ``ctx.previous`` (gone: ``ctx.findings`` holds the typed :class:`Finding` of every
  earlier stage) or an earlier result's ``artefacts`` (``st.result.artefacts``; a stage's own
  ``result.artefacts`` in its ``plots``/``log`` is allowed), directly or through
  ``getattr``/``hasattr``.

Reads counted: ``X.meta["k"]``, ``X.meta.get("k")``, ``"k" in X.meta`` and the same on a name bound
to ``X.meta`` / ``dict(X.meta)`` / ``{**X.meta, …}`` or a parameter named ``meta``.  Writes counted:
the keys of a dict literal given as ``meta=`` or bound to a name ``meta``, and ``meta["k"] = …`` /
``meta.setdefault("k", …)`` on such a name.

A source whose specifics :data:`TYPED_META` lists keeps them as a frozen dataclass of its own
(``DbatInfo``, ``AiconInfo``), never a dict: the scan refuses a dict written under such a key, and
the blocks the two readers make are checked (frozen, read-only inside, picklable).
"""

from __future__ import annotations

import ast
import dataclasses
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

LIBRARY_KEYS = {"truth", "testfield", "colmap"}
"""The only ``meta`` keys the engine writes for a plugin to read: the test-field simulator's truth
and configuration (``pipeline/synthetic/testfield.py``, read by ``testfield``'s stages;
``baarda.pipeline.testing.make_block`` writes ``truth`` too), and the COLMAP conversion's model ids
and keypoints (``pipeline/colmap/reader.py``, read back by ``pipeline/colmap/writer.py`` and the
``colmap-export`` stage).  Any other key a plugin reads
it must write itself."""

TYPED_META = {"dbat": "DbatInfo", "aicon": "AiconInfo"}
"""``meta`` keys whose value is a frozen dataclass of the plugin that writes it (its typed
extension of the block), never a dict record read by key."""


def _is_dict_value(node) -> bool:
    """A dict literal, comprehension, ``dict(...)`` call or ``{**x, ...}``: an untyped record."""
    return isinstance(node, (ast.Dict, ast.DictComp)) or (
        isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict")


def _is_meta_attr(node) -> bool:
    return isinstance(node, ast.Attribute) and node.attr == "meta"


def _aliases_meta(value) -> bool:
    """``value`` is the block's meta itself or a shallow copy of it (not a value inside it)."""
    if _is_meta_attr(value):
        return True
    if isinstance(value, ast.IfExp):                # block.meta if isinstance(block.meta, dict) else {}
        return _aliases_meta(value.body) or _aliases_meta(value.orelse)
    if isinstance(value, ast.Call) and isinstance(value.func, ast.Name) and value.func.id == "dict" \
            and value.args and _is_meta_attr(value.args[0]):
        return True
    if isinstance(value, ast.Dict):
        return any(k is None and _is_meta_attr(v) for k, v in zip(value.keys, value.values))
    return False


def _str_keys(d: ast.Dict) -> list[str]:
    return [k.value for k in d.keys if isinstance(k, ast.Constant) and isinstance(k.value, str)]


class _Scan(ast.NodeVisitor):
    """Meta keys read and written, and reaches past the declared artefacts, of one module."""

    def __init__(self):
        self.reads: list[tuple[str, int]] = []
        self.writes: list[tuple[str, int]] = []
        self.reaches: list[tuple[str, int]] = []
        self.dict_writes: list[tuple[str, int]] = []       # a key written with a dict as its value
        self.names: list[set[str]] = [set()]

    def _dict_items(self, d: ast.Dict, line: int):
        self.dict_writes += [(k.value, line) for k, v in zip(d.keys, d.values)
                             if isinstance(k, ast.Constant) and isinstance(k.value, str) and _is_dict_value(v)]

    # scopes: names bound to a block's meta, per function
    def _function(self, node):
        params = {a.arg for a in node.args.args + node.args.kwonlyargs + node.args.posonlyargs}
        self.names.append({"meta"} & params)
        self.generic_visit(node)
        self.names.pop()

    visit_FunctionDef = visit_AsyncFunctionDef = visit_Lambda = _function

    def _is_meta(self, node) -> bool:
        return _is_meta_attr(node) or (isinstance(node, ast.Name) and node.id in self.names[-1])

    def visit_Assign(self, node):
        for t in node.targets:
            if isinstance(t, ast.Name):
                if _aliases_meta(node.value):
                    self.names[-1].add(t.id)
                elif t.id in self.names[-1]:
                    self.names[-1].discard(t.id)
                if t.id == "meta" and isinstance(node.value, ast.Dict):
                    self.writes += [(k, node.lineno) for k in _str_keys(node.value)]
                    self._dict_items(node.value, node.lineno)
            if isinstance(t, ast.Subscript) and self._is_meta(t.value) and isinstance(t.slice, ast.Constant):
                self.writes.append((t.slice.value, node.lineno))
                if _is_dict_value(node.value):
                    self.dict_writes.append((t.slice.value, node.lineno))
        self.generic_visit(node)

    def visit_Subscript(self, node):
        if isinstance(node.ctx, ast.Load) and self._is_meta(node.value) and isinstance(node.slice, ast.Constant) \
                and isinstance(node.slice.value, str):
            self.reads.append((node.slice.value, node.lineno))
        self.generic_visit(node)

    def visit_Compare(self, node):
        if isinstance(node.left, ast.Constant) and isinstance(node.left.value, str) \
                and any(isinstance(op, (ast.In, ast.NotIn)) for op in node.ops) \
                and any(self._is_meta(c) for c in node.comparators):
            self.reads.append((node.left.value, node.lineno))
        self.generic_visit(node)

    def visit_Call(self, node):
        f = node.func
        first = node.args[0] if node.args else None
        key = first.value if isinstance(first, ast.Constant) and isinstance(first.value, str) else None
        if isinstance(f, ast.Attribute) and self._is_meta(f.value) and key is not None:
            if f.attr == "get":
                self.reads.append((key, node.lineno))
            elif f.attr == "setdefault":
                self.writes.append((key, node.lineno))
        for kw in node.keywords:
            if kw.arg == "meta" and isinstance(kw.value, ast.Dict):
                self.writes += [(k, node.lineno) for k in _str_keys(kw.value)]
                self._dict_items(kw.value, node.lineno)
        if isinstance(f, ast.Name) and f.id in ("getattr", "hasattr") and len(node.args) >= 2:
            what = node.args[1]
            if isinstance(what, ast.Constant) and what.value in ("previous", "artefacts"):
                self.reaches.append((f"{f.id}(…, {what.value!r})", node.lineno))
        self.generic_visit(node)

    def visit_Attribute(self, node):
        # ctx.previous; another stage's result's artefacts (st.result.artefacts); a stage's own
        # result (``result.artefacts`` in its plots or log) is its own business
        if isinstance(node.ctx, ast.Load) and (node.attr == "previous" or (
                node.attr == "artefacts" and not isinstance(node.value, ast.Name))):
            self.reaches.append((f".{node.attr}", node.lineno))
        self.generic_visit(node)


def scan(root: Path) -> dict:
    """``{"reads": {owner: [(key, file, line)]}, "writes": {owner: {key}}, "reaches": [...]}`` where
    owner is a plugin's name or ``"pipeline"``."""
    reads, writes, reaches, dict_writes = defaultdict(list), defaultdict(set), [], []
    for folder in ("pipeline", "plugins"):
        for path in sorted((root / folder).rglob("*.py")):
            rel = path.relative_to(root)
            owner = "pipeline" if folder == "pipeline" else (rel.parts[1] if len(rel.parts) > 2 else "plugins")
            s = _Scan()
            s.visit(ast.parse(path.read_text(encoding="utf-8"), str(rel)))
            reads[owner] += [(k, str(rel), line) for k, line in s.reads]
            writes[owner] |= {k for k, _ in s.writes}
            dict_writes += [(k, str(rel), line) for k, line in s.dict_writes]
            if folder == "plugins":
                reaches += [(what, str(rel), line) for what, line in s.reaches]
    return {"reads": reads, "writes": writes, "reaches": reaches, "dict_writes": dict_writes}


def violations(root: Path) -> list[str]:
    found = scan(root)
    reads, writes = found["reads"], found["writes"]
    out = []
    for owner, rows in reads.items():
        for key, file, line in rows:
            others = sorted(o for o, keys in writes.items() if key in keys and o not in (owner, "pipeline"))
            if owner == "pipeline":
                if others:
                    out.append(f"{file}:{line}: the engine reads meta[{key!r}], written by plugin(s) {others}")
                continue
            if others:
                out.append(f"{file}:{line}: plugin {owner!r} reads meta[{key!r}], written by plugin(s) {others}")
            elif key not in writes[owner] and not (key in LIBRARY_KEYS and key in writes["pipeline"]):
                out.append(f"{file}:{line}: plugin {owner!r} reads meta[{key!r}], which it does not write")
    out += [f"{file}:{line}: {what} reaches past the declared artefacts (declare them in reads; "
            "ctx.findings for a run's findings)" for what, file, line in found["reaches"]]
    out += [f"{file}:{line}: meta[{key!r}] written as a dict (a typed extension: {TYPED_META[key]})"
            for key, file, line in found["dict_writes"] if key in TYPED_META]
    return out


def test_no_stage_reads_another_plugins_meta_or_undeclared_artefacts():
    problems = violations(ROOT)
    assert not problems, "\n".join(problems)


def test_the_scan_sees_what_it_polices(tmp_path):
    """The scan finds each kind of violation in a made-up tree (so the test above cannot pass by
    seeing nothing), and leaves a plugin's own key alone."""
    (tmp_path / "pipeline").mkdir()
    (tmp_path / "pipeline" / "lib.py").write_text('def f(block):\n    return block.meta.get("own")\n'
                                                  'def g(b):\n    return b.replace(meta={"lib": 1})\n')
    for name, text in {
        "writer": 'def make():\n    return Block(1, meta={"own": 1, "shared": 2})\n'
                  'def again(b):\n    meta = dict(b.meta)\n    meta["more"] = 3\n    return b.meta["own"]\n',
        "reader": 'def use(block, ctx):\n    m = {**block.meta}\n    a = m.get("shared")\n'
                  '    n = block.meta if block else {}\n    z = n["shared"]\n'
                  '    b = "more" in block.meta\n    c = block.meta["gone"]\n'
                  '    d = [s.result.artefacts for s in ctx.previous]\n'
                  '    e = block.meta["lib"]\n'
                  '    return getattr(ctx, "previous")\n',
    }.items():
        (tmp_path / "plugins" / name).mkdir(parents=True)
        (tmp_path / "plugins" / name / "stage.py").write_text(text)
    problems = violations(tmp_path)
    text = "\n".join(problems)
    assert "plugin 'reader' reads meta['shared'], written by plugin(s) ['writer']" in text
    assert "plugin 'reader' reads meta['more'], written by plugin(s) ['writer']" in text
    assert "plugin 'reader' reads meta['gone'], which it does not write" in text
    assert "the engine reads meta['own'], written by plugin(s) ['writer']" in text
    assert sum(".previous" in p for p in problems) == 1 and sum(".artefacts" in p for p in problems) == 1
    assert sum("getattr(…, 'previous')" in p for p in problems) == 1
    assert not any("plugin 'writer'" in p for p in problems)
    assert sum("reads meta['shared']" in p for p in problems) == 2
    assert "plugin 'reader' reads meta['lib'], which it does not write" in text   # a library key off the list
    assert len(problems) == 9
    (tmp_path / "plugins" / "dbat").mkdir()
    (tmp_path / "plugins" / "dbat" / "reader.py").write_text(
        'def make(b):\n    meta = {"dbat": {"script": "x"}}\n    meta = dict(b.meta)\n    meta["dbat"] = dict(a=1)\n'
        '    return Block(1, meta={"dbat": DbatInfo(script="x"), "aicon": {}})\n')
    typed = [p for p in violations(tmp_path) if "written as a dict" in p]
    assert len(typed) == 3 and sum("meta['aicon']" in p for p in typed) == 1, typed


def test_the_context_offers_findings_not_previous_results():
    from baarda.pipeline.stage import Context, Finding, StageResult, TableData

    assert not hasattr(Context("s", Path(".")), "previous")
    f = Finding.of("a", "bundle", StageResult(summary={"n": 1}, report="| x |\n# The finding\n",
                                              tables={"t": TableData({"x": [1]})}))
    assert (f.stage, f.use, f.headline, f.summary["n"], list(f.tables)) == ("a", "bundle", "The finding", 1, ["t"])
    with pytest.raises(TypeError):
        f.summary["n"] = 2                      # read-only: a later stage cannot change what was found


def test_typed_block_fields_are_frozen_survive_selection_and_pickle():
    """The typed fields travel with the block: ``take`` keeps each photo's image, ``replace`` keeps
    the rest, nothing can be changed in place, and a block pickles (worker processes)."""
    import pickle

    import numpy as np

    from baarda.pipeline.crs import LocalFrame, frame_of_block, local_frame
    from baarda.pipeline.model import CrsInfo, ScaleBars, SourceInfo
    from baarda.pipeline.testing import make_block

    blk = make_block(3, 10)
    frame = local_frame("EPSG:32632", [[500000.0, 5000000.0, 100.0]])
    blk = blk.replace(photos=blk.photos.replace(image_path=["a.png", "", "c.png"]), crs=frame.info(),
                      scale_bars=ScaleBars.make([(blk.points.ids[0], blk.points.ids[1], 2.5, 0.01)]),
                      source=SourceInfo(path="x.txt", format="test", lines={(0, 1): ("x.txt", 7)}),
                      ap_meta={"cam": {"b": 8.0}})
    assert blk.photos.images() == {blk.photos.ids[0]: "a.png", blk.photos.ids[2]: "c.png"}
    assert blk.photos.take([2]).image_path.tolist() == ["c.png"]
    again = pickle.loads(pickle.dumps(blk))
    assert isinstance(again.crs, CrsInfo) and again.crs == blk.crs
    assert np.allclose(frame_of_block(again).to_local([[500010.0, 5000000.0, 100.0]]),
                       frame.to_local([[500010.0, 5000000.0, 100.0]]))
    assert LocalFrame.from_info(None).is_identity and LocalFrame(None).info() is None
    assert again.scale_bars.rows() == blk.scale_bars.rows() and again.source.lines[(0, 1)] == ("x.txt", 7)
    assert again.ap_meta["cam"]["b"] == 8.0
    with pytest.raises(TypeError):
        blk.ap_meta["cam"]["b"] = 1.0
    with pytest.raises(TypeError):
        blk.source.lines[(0, 2)] = ("x.txt", 8)
    with pytest.raises(ValueError):
        blk.photos.image_path[0] = "b.png"
    with pytest.raises(dataclasses.FrozenInstanceError):
        blk.source.path = "y"


def _sources(shared_data):
    from baarda.plugins.aicon.reader import aicon_block, read_aicon
    from baarda.plugins.dbat import dbat_block, read_dbat

    yield "dbat", dbat_block(read_dbat(shared_data / "dbat-sxb" / "sxb.xml"))
    d = shared_data / "aicon-closerange"
    if (d / "example.ior").exists():
        yield "aicon", aicon_block(read_aicon(d))


def test_source_specifics_are_frozen_dataclasses_that_pickle(shared_data):
    """The DBAT and AICON readers keep their specifics as the frozen dataclass :data:`TYPED_META`
    names: nothing inside is a dict or a writable array, and it comes back equal, frozen and
    read-only from a pickle (blocks go to worker processes)."""
    import pickle
    from collections.abc import Mapping

    import numpy as np

    def check(value, where):
        for f in dataclasses.fields(value):
            v = getattr(value, f.name)
            assert not isinstance(v, (dict, list)), f"{where}.{f.name} is a {type(v).__name__}"
            if isinstance(v, np.ndarray):
                assert not v.flags.writeable, f"{where}.{f.name} is a writable array"
            if isinstance(v, Mapping):
                with pytest.raises(TypeError):
                    v["new"] = 1
            if dataclasses.is_dataclass(v):
                check(v, f"{where}.{f.name}")
            if isinstance(v, tuple):
                for k, item in enumerate(v):
                    if dataclasses.is_dataclass(item):
                        check(item, f"{where}.{f.name}[{k}]")

    seen = set()
    for key, block in _sources(shared_data):
        value = block.meta[key]
        assert type(value).__name__ == TYPED_META[key]
        assert dataclasses.is_dataclass(value) and type(value).__dataclass_params__.frozen
        again = pickle.loads(pickle.dumps(block)).meta[key]
        assert type(again) is type(value)
        for v in (value, again):
            check(v, f"meta[{key!r}]")
            with pytest.raises(dataclasses.FrozenInstanceError):
                setattr(v, dataclasses.fields(v)[0].name, None)
        seen.add(key)
    assert "dbat" in seen
