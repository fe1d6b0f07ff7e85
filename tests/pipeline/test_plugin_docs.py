"""docs/plugins.md runs as written: its stage example and its test example are extracted from the
page and run — on a simulated adjustment, in a project after the built-in stages, and their
recordings read back."""

from __future__ import annotations

import re
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.testing import (check_recording, check_stage, log_stage, make_adjustment, make_block,
                                     make_plugin_manager, run_project_text, run_stage)

DOC = Path(__file__).resolve().parents[2] / "docs" / "plugins.md"


def _blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)


@pytest.fixture(scope="module")
def example():
    code = next(b for b in _blocks() if "class ResidualHistogram" in b)
    mod = types.ModuleType("plugin_doc_example")      # a module of its own, as in a plugin package
    sys.modules[mod.__name__] = mod
    try:
        exec(compile(code, f"{DOC}:ResidualHistogram", "exec"), mod.__dict__)
        yield mod
    finally:
        del sys.modules[mod.__name__]


def test_the_example_uses_one_public_module(example):
    code = next(b for b in _blocks() if "class ResidualHistogram" in b)
    baarda_imports = re.findall(r"^from (baarda\S*) import", code, re.M)
    assert baarda_imports == ["baarda.pipeline.api"]


def test_the_example_stage_runs_on_a_simulated_adjustment(example, tmp_path):
    cls = example.ResidualHistogram
    check_stage(cls)
    art = make_adjustment(make_block(gross={(0, 7): (0.02, 0.0)}))
    result = run_stage(cls, {"adjustment": art}, {"bins": 10}, tmp_path=tmp_path)
    counts, edges = result.artefacts["histogram"]
    snap = art.snapshot
    from baarda.pipeline import stats

    w = stats.w_test(snap)[snap.active & (snap.r > 1e-9)]
    np.testing.assert_array_equal(counts, np.histogram(w, bins=10)[0])     # numpy, independently
    assert abs(w).max() > 4                                                # the 20 µm gross error shows
    rec = check_recording(log_stage(cls, result, tmp_path / "hist.rrd"))
    ts = [v for v in rec.views if v.kind == "TimeSeries"]
    assert [v.origin for v in ts] == ["/hist/histogram"]
    count = next(e for e in rec.entities if e.path == "/hist/histogram/count")
    assert count.rows == 10 and "bin" in count.timelines


def test_the_example_stage_runs_in_a_project_after_the_builtins(example, baarda_plugins, tmp_path):
    baarda_plugins.include_builtins("testfield", "bundle").register("residual-histogram", example.ResidualHistogram)
    assert baarda_plugins.names() == ["bundle", "residual-histogram", "testfield"]
    text = ('[project]\nname = "doc example"\nseed = 7\n'
            '[[stage]]\nuse = "testfield"\nid = "source"\n[stage.options]\ncase = 5\n'
            '[[stage]]\nuse = "bundle"\n'
            '[[stage]]\nuse = "residual-histogram"\nid = "hist"\n[stage.options]\nbins = 8\n')
    out = run_project_text(text, tmp_path, plugins=baarda_plugins)
    assert out.ok, out.message
    assert (out.run_dir / "hist_bins.csv").is_file() and (out.run_dir / "hist_histogram.png").is_file()
    for f in out.run_dir.glob("*.rrd"):
        check_recording(f)


def test_the_test_example_in_the_page_runs(example, tmp_path):
    code = next(b for b in _blocks() if "def test_histogram" in b)
    ns = {"ResidualHistogram": example.ResidualHistogram}
    exec(compile(code, f"{DOC}:test example", "exec"), ns)
    ns["test_histogram"](tmp_path)


def test_builtins_on_request_only():
    assert make_plugin_manager().names() == []
    pm = make_plugin_manager(builtins=True)
    assert {"bundle", "comparator", "helmert-screening", "blunder-rejection"} <= set(pm.names())
    with pytest.raises(KeyError, match="did you mean"):
        make_plugin_manager().include_builtins("bundel")


def test_make_block_gross_errors_are_where_asked():
    clean, bad = make_block(seed=4), make_block(seed=4, gross={(2, 5): (0.01, -0.02)})
    d = bad.observations.xy - clean.observations.xy
    k = np.flatnonzero(np.abs(d).sum(axis=1) > 0)
    assert len(k) == 1
    assert (bad.observations.photo[k[0]], bad.observations.point[k[0]]) == (2, 5)
    np.testing.assert_allclose(d[k[0]], [0.01, -0.02])
