"""Plugin discovery is lazy: entry points are read as names and values, and a stage class is
imported when something asks for it.  A broken third-party plugin is still reported where it was
(``baarda stages``, a project that uses it).

The third-party cases build a distribution on a temporary sys.path entry (a ``*.dist-info`` folder
with ``entry_points.txt``), as tests/camera/test_registry.py does: nothing is installed.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from baarda.pipeline.errors import BaardaError
from baarda.pipeline.plugins import GROUP, PluginManager


def _third_party(tmp_path: Path, package: str, body: str, entries: dict[str, str]) -> Path:
    site = tmp_path / "site"
    (site / package).mkdir(parents=True)
    (site / package / "__init__.py").write_text(textwrap.dedent(body))
    info = site / f"{package}-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {package}\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(f"[{GROUP}]\n" + "".join(f"{k} = {v}\n" for k, v in entries.items()))
    return site


BROKEN = """
    raise ImportError("needs libfoo, which is not installed")
"""


def test_discovery_imports_no_plugin_until_asked(tmp_path, monkeypatch):
    site = _third_party(tmp_path, "lazyplug", "import sys\nsys.lazyplug_imported = True\n",
                        {"lazy-stage": "lazyplug:Nothing"})
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.delattr(sys, "lazyplug_imported", raising=False)
    pm = PluginManager()
    assert not hasattr(sys, "lazyplug_imported") and "lazyplug" not in sys.modules
    pm.get("bundle")                                       # another stage: still not imported
    assert not hasattr(sys, "lazyplug_imported")
    with pytest.raises(BaardaError, match="no stage named 'lazy-stage' .*AttributeError"):
        pm.get("lazy-stage")                               # asked for: imported, its error named
    assert sys.lazyplug_imported
    sys.modules.pop("lazyplug", None)


def test_a_broken_third_party_plugin_is_reported_by_stages_and_by_a_project(tmp_path, monkeypatch, capsys):
    from baarda.pipeline.cli import main

    site = _third_party(tmp_path, "brokenplug", BROKEN, {"broken-stage": "brokenplug:BrokenStage"})
    monkeypatch.syspath_prepend(str(site))
    pm = PluginManager()
    assert "bundle" in pm and "broken-stage" not in pm
    assert pm.load_errors == {"broken-stage": "ImportError: needs libfoo, which is not installed"}
    assert "broken-stage" not in pm.names() and "bundle" in pm.names()

    assert main(["stages"]) == 0                          # listed as not loaded, with the reason
    captured = capsys.readouterr()
    assert "broken-stage" not in captured.out and "bundle" in captured.out
    assert re.search(r"^broken-stage +\(not loaded\) +ImportError: needs libfoo", captured.err, re.M), captured.err

    project = tmp_path / "p.toml"
    project.write_text('[project]\nname = "p"\n\n[[stage]]\nuse = "broken-stage"\n')
    assert main(["validate", str(project)]) == 2           # a project that uses it: the reason in the error
    err = capsys.readouterr().err
    assert "no stage named 'broken-stage' (ImportError: needs libfoo, which is not installed)" in err
    sys.modules.pop("brokenplug", None)


def test_a_name_registered_twice_keeps_the_first(tmp_path, monkeypatch):
    site = _third_party(tmp_path, "twiceplug", "from baarda.plugins.bal.stage import BalSource as Bal\n",
                        {"bal": "twiceplug:Bal"})
    monkeypatch.syspath_prepend(str(site))
    pm = PluginManager()
    info = pm.get("bal")
    assert "registered twice" in pm.load_errors["bal"]
    assert pm.get("bal") is info and info.value in pm.load_errors["bal"]


def _bal_project(tmp_path: Path) -> Path:
    from baarda.pipeline.testing import make_block
    from baarda.plugins.bal.writer import bal_from_block, write_bal

    problem, _ = bal_from_block(make_block(n_photos=6, n_points=30), pixel_mm=0.005, drop=True)
    write_bal(problem, tmp_path / "block.txt")
    project = tmp_path / "bal.toml"
    project.write_text(textwrap.dedent("""
        [project]
        name = "a small BAL block"
        object_unit = "m"

        [[stage]]
        use = "bal"
        id = "source"
        [stage.options]
        path = "block.txt"
        pixel_mm = 0.005

        [[stage]]
        use = "bundle"
        [stage.options]
        datum = "free"
        datum_on = "centres"
        solver.covariance = true
    """))
    return project


UNRELATED = ("cv2", "pycolmap", "baarda.plugins.congruence", "baarda.plugins.targets", "baarda.plugins.crosscheck",
             "baarda.plugins.colmap", "baarda.plugins.design", "baarda.plugins.testfield", "baarda.plugins.dbat")


def test_a_bal_run_does_not_import_unrelated_stages(tmp_path):
    """In a fresh process (the test session has imported everything already)."""
    project = _bal_project(tmp_path)
    script = textwrap.dedent(f"""
        import json, sys
        from baarda.pipeline.runner import run_project
        out = run_project({str(project)!r}, {str(tmp_path / "run")!r}, verbose=False)
        print(json.dumps({{"ok": out.ok, "message": out.message,
                           "modules": sorted(m for m in sys.modules if m.split(".")[0] in ("cv2", "pycolmap")
                                             or m.startswith("baarda.plugins."))}}))
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                          env={**__import__("os").environ, "OPENBLAS_NUM_THREADS": "1"})
    assert done.returncode == 0, done.stderr
    found = json.loads(done.stdout.strip().splitlines()[-1])
    assert found["ok"], found["message"]
    assert (tmp_path / "run" / "bundle.rrd").is_file() and (tmp_path / "run" / "results.json").is_file()
    modules = found["modules"]
    assert "baarda.plugins.bal.stage" in modules and "baarda.plugins.bundle.stage" in modules
    unrelated = [m for m in modules if m.startswith(UNRELATED)]
    assert not unrelated, unrelated
