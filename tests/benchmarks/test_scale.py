"""The scale benchmark's machinery on a 200-photo block (``make bench``; never part of ``make test``).

``benchmarks/scale.py`` at its smallest: the block simulated and saved once, baarda and pycolmap
each in its own child process from the same start.  Asserted is what must hold on any machine:
both children finish, reach the same minimum (one cost definition), baarda's redundancy numbers
exist for every observation and sum to the redundancy, and each child reports its own peak
memory.  The goals (solve ratio ≤ 1.0 at 2 000 photos, memory ≤ 2 × pycolmap's) are for the
full run, ``make bench-scale`` (docs/benchmarks.md, "Scale").
"""

from __future__ import annotations

import importlib.util
import io
import sys

import pytest

pytestmark = pytest.mark.benchmark


def _module(repo_root):
    path = repo_root / "benchmarks" / "scale.py"
    sys.path.insert(0, str(path.parent))
    spec = importlib.util.spec_from_file_location("scale", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_scale_benchmark_200_photos(repo_root, tmp_path):
    bench = _module(repo_root)
    assert bench.layout(2000) == (25, 80) and bench.layout(10000) == (50, 200)
    buf = io.StringIO()
    out = bench.run([200], timeout=600, mem_gb=8, workdir=tmp_path, stream=buf)
    print(buf.getvalue())
    r = out["sizes"][200]
    sim, b, p = r["simulate"], r["baarda"], r["pycolmap"]
    assert sim["status"] == b["status"] == p["status"] == "ok", (sim, b, p)
    assert sim["photos"] == 200 and abs(sim["points_per_photo"] - 150) < 15
    # the same minimum from the same start (both stop at a 1e-6 relative decrease)
    assert b["cost"] == pytest.approx(p["cost"], rel=1e-5)
    assert b["cost"] < 1e-3 * sim["start_cost"]
    # redundancy numbers of every observation, summing to the redundancy n − u
    assert b["redundancy_finite"] == b["redundancy_rows"] == sim["observations"]
    assert b["redundancy_sum"] == pytest.approx(b["dof"], rel=1e-6)
    # each child's own high-water mark: more than an interpreter, less than the limit
    for d in (b, p):
        assert 50 * 1024 < d["peak_kb"] < 8 * 1024 ** 2
    assert "| 200 | 8 × 25 |" in buf.getvalue()


def test_scale_benchmark_reports_a_child_out_of_memory(repo_root, tmp_path):
    bench = _module(repo_root)
    out = bench.run([200], pycolmap=False, mem_gb=0.25, workdir=tmp_path, stream=io.StringIO())
    sim = out["sizes"][200]["simulate"]
    assert sim["status"].startswith("out of memory"), sim
