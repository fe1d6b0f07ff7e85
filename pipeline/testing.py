"""Test helpers for plugin authors; also a pytest plugin (registered as ``baarda`` in pytest11).

Typical plugin test::

    from baarda.pipeline.testing import run_stage, check_stage

    def test_my_stage(tmp_path):
        check_stage(MyStage)                      # protocol, documented options, recording
        result = run_stage(MyStage, {"block": block}, {"threshold": 0.5}, tmp_path=tmp_path)
        assert result.summary["flagged"] == 1

    def test_in_a_project(baarda_plugins, tmp_path):
        baarda_plugins.register("my-stage", MyStage)          # discovery is blocked
        outcome = run_project_text(PROJECT_TOML, tmp_path, plugins=baarda_plugins)
        assert outcome.ok

Inputs: :func:`make_block` (a simulated close-range block with control, optionally with gross
errors) and :func:`make_adjustment` (the bundle's ``adjustment`` artefact of a block, what
``blunder-rejection`` and any stage reading ``adjustment`` take).  Recordings:
:func:`log_stage` writes one as the runner does, :func:`check_recording` reads it back and checks
it (blueprint, paths under the stage id, glyphs the viewer renders).

Fixtures: ``baarda_plugins`` — a :class:`TestPlugins` manager with entry-point discovery blocked,
so a test sees exactly the stages it registers; ``baarda_plugins.include_builtins()`` adds
baarda's own stages (all, or the ones named).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Mapping

import pytest

from .options import describe, parse_options
from .plugins import PluginManager
from .stage import Context, StageResult, check_stage_class


class TestPlugins(PluginManager):
    """A plugin manager for tests: only what is registered, plus baarda's stages on request."""

    __test__ = False   # not a pytest test class

    def include_builtins(self, *names: str) -> "TestPlugins":
        """Add baarda's own stages (the ``baarda.stages`` entry points of the baarda package), all of
        them or the ones ``names`` lists; third-party plugins stay out.  Returns the manager."""
        from importlib.metadata import entry_points

        eps = [ep for ep in entry_points(group=self.group) if ep.value.startswith("baarda.plugins")]
        known = {ep.name for ep in eps}
        for name in names:
            if name not in known:
                import difflib

                close = difflib.get_close_matches(name, sorted(known), n=2)
                raise KeyError(f"no built-in stage '{name}'" + (f"; did you mean {close}?" if close else ""))
        for ep in eps:
            if not names or ep.name in names:
                self._register(ep.name, ep.load(), "baarda", ep.value)
        return self


def make_plugin_manager(stages: Mapping[str, type] | None = None, discover: bool = False,
                        builtins: bool = False) -> TestPlugins:
    """A plugin manager with only ``stages`` (and, if ``discover``, every installed one; if
    ``builtins``, baarda's own)."""
    pm = TestPlugins(discover=discover)
    if builtins and not discover:
        pm.include_builtins()
    for name, cls in (stages or {}).items():
        pm.register(name, cls, package="(test)")
    return pm


def make_block(n_photos: int = 8, n_points: int = 40, *, noise_mm: float = 0.001, gross: Mapping | None = None,
               seed: int = 1, model: str = "brown"):
    """A simulated convergent close-range block (mm image coordinates, m object space): photos
    around a 3-D field of points, six full control points, the rest tie points, one camera with
    ``model`` distortion; image noise ``noise_mm`` (σ in the block: 0.001 mm).  ``gross`` adds
    gross errors ``{(photo index, point index): (dx, dy) in mm}`` to those image points.  Returns
    the block; its true values are in ``block.meta["truth"]``."""
    import numpy as np

    from .synthetic.closerange import make_block as _make

    block, truth = _make(n_photos=n_photos, n_points=n_points, model=model, noise_mm=noise_mm,
                         rng=np.random.default_rng(seed + 100), seed=seed)
    if gross:
        obs = block.observations
        xy = obs.xy.copy()
        for (ph, pt), dxy in gross.items():
            k = np.flatnonzero((obs.photo == ph) & (obs.point == pt))
            if not k.size:
                raise ValueError(f"make_block: photo {ph} does not observe point {pt}")
            xy[k[0]] += np.asarray(dxy, float)
        block = block.replace(observations=obs.replace(xy=xy))
    return block.replace(meta={**dict(block.meta), "truth": truth})


def make_adjustment(block=None, **settings):
    """The ``adjustment`` artefact of the bundle adjustment of ``block`` (default :func:`make_block`)
    with :class:`~baarda.pipeline.adjustment.BundleSettings` ``settings`` — what the bundle stage
    hands to ``blunder-rejection``."""
    from .adjustment import BundleSettings, adjust
    from .contracts import AdjustmentArtefact

    block = make_block() if block is None else block
    res = adjust(block, BundleSettings(**settings), covariance=True)
    return AdjustmentArtefact("bundle", res.snapshot, res, res.obs_rows())


def run_stage(cls: type, inputs: Mapping[str, Any] | None = None, options: Any = None, *,
              tmp_path: Path | None = None, seed: int = 0, stage_id: str | None = None,
              project_dir: Path | None = None) -> StageResult:
    """Run one stage the way the runner does: options parsed and validated, a fresh Context.

    ``options`` may be a dict (parsed like the project file's ``[stage.options]``) or an
    instance of ``cls.Options``.
    """
    if options is None or isinstance(options, dict):
        options = parse_options(cls.Options, options or {}, path="<test>")
    sid = stage_id or getattr(cls, "__name__", "stage").lower()
    ctx = Context(stage_id=sid, project_dir=project_dir or tmp_path or Path.cwd(), run_dir=tmp_path, seed=seed)
    result = cls().run(dict(inputs or {}), options, ctx)
    assert isinstance(result, StageResult), f"{cls.__name__}.run returned {type(result).__name__}"
    for w in cls.writes:
        if not w.endswith("?"):
            assert w in result.artefacts, f"{cls.__name__} declares it writes '{w}' but did not"
    result.warnings = list(ctx.warnings)  # type: ignore[attr-defined]
    return result


def log_stage(cls: type, result: StageResult, path: Path, stage_id: str | None = None) -> Path:
    """Write ``result`` into ``path`` (an .rrd) as the runner does — the stage's summary and
    results, then the stage's ``log`` — under ``stage_id`` (default: the file's stem), and return
    the path.  Read it back with :func:`check_recording` or
    :func:`baarda.pipeline.recording.read_recording`."""
    from .recording import log_text, log_values, new_recording_id, open_recording

    sid = stage_id or Path(path).stem
    rec = open_recording(path, new_recording_id(), stage_id=sid)
    try:
        log_text(rec, f"{sid}/summary", f"## {sid} ({getattr(cls, '__name__', 'stage')})\n\n{result.report}")
        log_values(rec, f"{sid}/results", result.summary)
        if hasattr(cls, "log"):
            cls().log(result, rec, Context(stage_id=sid, project_dir=Path(path).parent))
    finally:
        rec.disconnect()
    return path


def check_recording(path: Path, stage_id: str | None = None):
    """Read the recording ``path`` back with rerun's reader and assert what every baarda recording
    must be: a blueprint with at least the stage summary's text view, every entity and view under
    ``/<stage id>`` (default: the file's stem), no text the viewer cannot draw (combining marks).
    Returns the :class:`~baarda.pipeline.recording.RecordingSummary` for further checks."""
    import unicodedata

    from rerun.chunk import RrdReader

    from .recording import read_recording

    sid = stage_id or Path(path).stem
    s = read_recording(path)
    assert s.views, f"{path}: no blueprint"
    root = f"/{sid}"
    for e in s.entities:
        assert e.path == root or e.path.startswith(root + "/"), f"{path}: entity {e.path} not under {root}"
    # the layout also shows the run's earlier stages (recordings beside it with the same id)
    stages = {sid} | {f.stem for f in Path(path).parent.glob("*.rrd")}
    for v in s.views:
        assert v.origin.strip("/").split("/")[0] in stages, f"{path}: view {v.kind} at {v.origin}"
    assert any(v.origin == root or v.origin.startswith(root + "/") for v in s.views), f"{path}: no view of {root}"
    assert any(v.kind == "TextDocument" and v.origin == f"{root}/summary" for v in s.views) or \
        not any(e.path == f"{root}/summary" for e in s.entities), f"{path}: no view of the summary"
    for chunk in RrdReader(str(path)).stream().to_chunks():
        batch = chunk.to_record_batch()
        for i, name in enumerate(batch.schema.names):
            if ":" in name and ("string" in str(batch.column(i).type) or "utf8" in str(batch.column(i).type)):
                stack = batch.column(i).to_pylist()
                while stack:
                    x = stack.pop()
                    if isinstance(x, list):
                        stack.extend(x)
                    elif isinstance(x, str):
                        bad = [c for c in x if unicodedata.combining(c)]
                        assert not bad, f"{path}: text with combining marks at {chunk.entity_path}: {x[:60]!r}"
    return s


def check_stage(cls: type, name: str | None = None) -> None:
    """Assert ``cls`` follows the stage protocol and documents every option."""
    name = name or cls.__name__
    problems = check_stage_class(cls, name)
    assert not problems, "; ".join(problems)
    for o in describe(cls.Options):
        assert o["doc"], f"{name}: option '{o['name']}' has no doc (use baarda.pipeline.options.option)"
    # options without a default are required; all others must make an empty table valid
    required = [f.name for f in dataclasses.fields(cls.Options)
                if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    if not required:
        parse_options(cls.Options, {}, path="<check_stage>")
    assert dataclasses.is_dataclass(cls.Options)


def run_project_text(text: str, tmp_path: Path, *, plugins: PluginManager | None = None,
                     files: Mapping[str, str] | None = None, name: str = "project.toml"):
    """Write ``text`` (and extra ``files``) to ``tmp_path`` and run it; returns the RunOutcome."""
    from .runner import run_project

    for fname, content in (files or {}).items():
        (tmp_path / fname).write_text(content, encoding="utf-8")
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return run_project(path, tmp_path / "run", plugins=plugins, verbose=False)


@pytest.fixture
def baarda_plugins() -> TestPlugins:
    """A plugin manager with entry-point discovery blocked (``.include_builtins()`` adds baarda's stages)."""
    return make_plugin_manager()
