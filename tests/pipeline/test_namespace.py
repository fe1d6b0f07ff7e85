"""One import namespace: everything installs under ``baarda.``; nothing claims ``pipeline`` or ``plugins``.

The folders ``pipeline/`` and ``plugins/`` are mapped onto ``baarda.pipeline`` / ``baarda.plugins`` by
``pyproject.toml`` as a src layout: ``src/baarda/pipeline`` and ``src/baarda/plugins`` are symlinks to
them and ``package-dir`` is ``{"" = "src"}`` (so that setuptools' editable install is a plain .pth entry
and prints no warning block).  These tests use the installed distribution as it is: they install
nothing extra.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import tomllib
from importlib.metadata import entry_points
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_every_package_folder_is_listed_in_pyproject():
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(cfg["packages"])
    on_disk = {"baarda." + ".".join(p.parent.relative_to(ROOT).parts)
               for top in ("pipeline", "plugins") for p in (ROOT / top).rglob("__init__.py")
               if "__pycache__" not in p.parts}
    on_disk.add("baarda")  # the namespace package, listed so that setuptools sees a simple layout
    assert on_disk == listed, f"missing: {sorted(on_disk - listed)}; stale: {sorted(listed - on_disk)}"
    assert cfg["package-dir"] == {"": "src"}
    src = ROOT / "src" / "baarda"
    assert sorted(p.name for p in src.iterdir()) == ["pipeline", "plugins"], "src/baarda holds only the two links"
    for top in ("pipeline", "plugins"):
        assert (src / top).is_symlink() and (src / top).resolve() == (ROOT / top).resolve(), top


def test_no_top_level_pipeline_or_plugins_is_installed(tmp_path):
    """Outside the repository (so its folders are not on sys.path) only ``baarda.…`` is importable."""
    code = textwrap.dedent("""
        import importlib.util, json
        from importlib.metadata import distribution
        found = {n: importlib.util.find_spec(n) is not None
                 for n in ("pipeline", "plugins", "baarda.pipeline", "baarda.plugins", "baarda.pipeline.testing")}
        dist = distribution("baarda")
        tops = sorted({str(f).split("/")[0] for f in dist.files or []})
        print(json.dumps({"found": found, "tops": tops}))
    """)
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    import json
    got = json.loads(out.stdout)
    assert got["found"] == {"pipeline": False, "plugins": False, "baarda.pipeline": True,
                            "baarda.plugins": True, "baarda.pipeline.testing": True}
    assert not {"pipeline", "plugins", "pipeline.py", "plugins.py"} & set(got["tops"]), got["tops"]
    for group in ("baarda.stages", "pytest11", "console_scripts"):
        for ep in entry_points(group=group):
            if ep.dist is not None and ep.dist.name == "baarda":
                assert ep.value.startswith("baarda."), (group, ep.name, ep.value)


def test_an_unrelated_project_with_its_own_pipeline_package_runs_pytest(tmp_path):
    """With baarda installed, ``pytest`` in a project that has a ``pipeline/`` package of its own
    starts (baarda's pytest11 plugin loads as ``baarda.pipeline.testing``) and imports *its* pipeline."""
    proj = tmp_path / "other"
    (proj / "pipeline").mkdir(parents=True)
    (proj / "pipeline" / "__init__.py").write_text("NAME = 'the other project'\n")
    (proj / "plugins").mkdir()
    (proj / "plugins" / "__init__.py").write_text("NAME = 'its plugins'\n")
    (proj / "tests").mkdir()
    (proj / "tests" / "test_own.py").write_text(textwrap.dedent("""
        import pipeline, plugins

        def test_own_packages():
            assert pipeline.NAME == 'the other project'
            assert plugins.NAME == 'its plugins'

        def test_baarda_fixture_is_there(baarda_plugins):
            assert len(list(baarda_plugins)) == 0
    """))
    (proj / "pyproject.toml").write_text("[tool.pytest.ini_options]\npythonpath = ['.']\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTEST_", "COV_"))}
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests"], cwd=proj,
                         env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "2 passed" in out.stdout
