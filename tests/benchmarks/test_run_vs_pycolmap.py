"""The whole-run benchmark's machinery at its smallest (``make bench``; never part of ``make test``).

``benchmarks/run_vs_pycolmap.py`` on a 200-photo aerial BAL project: ``baarda run`` in its own
process with every output written, pycolmap's SPARSE_SCHUR-forced and default solves in theirs.
Asserted is what holds on any machine: every child finishes, the run wrote its outputs, each child
reports its peak memory, pycolmap used the solver asked for.  The close-range generator is checked
on its own (size, rays per point, tie points to intersect).  The goals are for ``make bench-run``
(docs/benchmarks.md, "Whole runs").
"""

from __future__ import annotations

import importlib.util
import io
import shutil
import subprocess
import sys

import numpy as np
import pytest

pytestmark = pytest.mark.benchmark


def _module(repo_root):
    path = repo_root / "benchmarks" / "run_vs_pycolmap.py"
    sys.path.insert(0, str(path.parent))
    spec = importlib.util.spec_from_file_location("run_vs_pycolmap", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_whole_run_200_photos(repo_root, tmp_path):
    bench = _module(repo_root)
    buf = io.StringIO()
    out = bench.run([200], closerange=False, timeout=900, mem_gb=8, workdir=tmp_path, floor=True,
                    stream=buf)
    print(buf.getvalue())
    r = out["cases"]["aerial 200"]
    assert r["prepare"]["status"] == r["baarda"]["status"] == "ok", r
    assert r["baarda"]["peak_kb"] > 0 and r["baarda"]["output_mb"] > 0
    assert set(r["baarda"]["stages"]) == {"source", "bundle"}
    assert r["sparse"]["status"] == r["default"]["status"] == r["sparse-own"]["status"] == "ok"
    assert r["sparse"]["linear_solver"] == r["sparse-own"]["linear_solver"] == "SPARSE_SCHUR"
    # pycolmap's own stopping rule (gradient tolerance, no function tolerance) goes on at least as
    # long as the 1e-6 rule, to a cost no higher (the same minimum, to the rule's precision)
    assert r["sparse-own"]["iterations"] >= r["sparse"]["iterations"]
    assert r["sparse-own"]["final_cost"] <= r["sparse"]["final_cost"] * (1 + 1e-6)
    assert (tmp_path / "aerial-200-0-run" / "results.json").exists()
    f = r["floor"]                  # the floor: the same adjustment without outputs, every r computed
    assert f["status"] == "ok" and f["external_reliability"]
    assert abs(f["sum_r"] - f["dof"]) < 1e-6 * f["dof"]
    assert 0 < f["adjust_seconds"] < f["floor_seconds"] and "floor / SPARSE_SCHUR" in buf.getvalue()
    assert len(r["baarda"]["load"]) == 2


def test_closerange_block(repo_root):
    bench = _module(repo_root)
    block = bench.closerange_block(np.random.default_rng(0), n_photos=12, n_points=600, n_control=10)
    obs = block.observations
    rays = np.bincount(obs.point, minlength=len(block.points))
    assert len(block.photos) == 12 and (rays[10:] >= 2).all() and 2.9 < rays[10:].mean() < 4.0
    assert np.isnan(block.points.XYZ[10:]).all() and np.isfinite(block.points.XYZ[:10]).all()
    assert block.photos.has_orientation.all() and str(block.cameras.ap_model[0]) == "brown-backward"


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_find_roma(repo_root, tmp_path):
    """Roma from a DBAT work tree, from a bare git directory (extracted with ``git show``), or
    ``None`` with the places it looked in — then the simulated close-range project stands in."""
    bench = _module(repo_root)
    tree = tmp_path / "dbat"
    demo = tree / bench.ROMA
    (demo / "measurements").mkdir(parents=True)
    (demo / "romabundledemo.xml").write_text("<document/>")
    (demo / "measurements" / "markpts.txt").write_text(" 1, 1, 2.0, 3.0\n")
    xml, where = bench.find_roma(tmp_path / "w1", str(tree))
    assert xml == demo / "romabundledemo.xml" and "work tree" in where
    git = ["git", "-C", str(tree), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run([*git, "init", "-q"], check=True)
    subprocess.run([*git, "add", "."], check=True)
    subprocess.run([*git, "commit", "-qm", "roma"], check=True)
    xml, where = bench.find_roma(tmp_path / "w2", str(tree / ".git"))
    assert xml == tmp_path / "w2" / "romabundledemo" / "romabundledemo.xml" and "git" in where
    assert (xml.parent / "measurements" / "markpts.txt").read_text() == " 1, 1, 2.0, 3.0\n"
    xml, where = bench.find_roma(tmp_path / "w3", str(tmp_path / "nothing"))
    assert xml is None and "nothing" in where
