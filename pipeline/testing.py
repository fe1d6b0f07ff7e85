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

Fixtures: ``baarda_plugins`` — a :class:`~baarda.pipeline.plugins.PluginManager` with entry-point
discovery blocked, so a test sees exactly the stages it registers.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Mapping

import pytest

from .options import describe, parse_options
from .plugins import PluginManager
from .stage import Context, StageResult, check_stage_class


def make_plugin_manager(stages: Mapping[str, type] | None = None, discover: bool = False) -> PluginManager:
    """A plugin manager with only ``stages`` (and, if ``discover``, the installed ones)."""
    pm = PluginManager(discover=discover)
    for name, cls in (stages or {}).items():
        pm.register(name, cls, package="(test)")
    return pm


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
def baarda_plugins() -> PluginManager:
    """A plugin manager with entry-point discovery blocked."""
    return make_plugin_manager()
