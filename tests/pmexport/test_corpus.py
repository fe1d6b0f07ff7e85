"""The broken PhotoModeler exports of ``tests/corpus/pmexport/``: each is one InputError naming the
file, the line and the field; ``baarda validate`` reports it without running."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from baarda.pipeline.api import InputError
from baarda.plugins.dbat import pm_script, read_control, read_pmexport

CORPUS = Path(__file__).resolve().parents[1] / "corpus" / "pmexport"
sys.path.insert(0, str(CORPUS))
from cases import CASES  # noqa: E402


def test_the_cut_reads():
    pm = read_pmexport(CORPUS / "mini.txt")
    script, info = pm_script(pm, control=read_control(CORPUS / "control.txt"))
    assert len(pm.photos) == 2 and len(pm.objects) == 6
    assert info["undetermined"] == [] and len(script.control[0].ids) == 4


@pytest.mark.parametrize("name", sorted(CASES))
def test_broken_export(name):
    line, field = CASES[name]
    with pytest.raises(InputError) as e:
        read_pmexport(CORPUS / f"{name}.txt")
    err = e.value
    assert err.path == str(CORPUS / f"{name}.txt")
    assert err.field == field, str(err)
    if line is not None:
        assert err.line == line, str(err)


@pytest.mark.parametrize("name,line,field", [("control-columns", 1, "x"), ("control-sigma", 1, "sxyz"),
                                             ("control-id", 1, "id")])
def test_broken_control(name, line, field):
    with pytest.raises(InputError) as e:
        read_control(CORPUS / f"{name}.txt")
    assert (e.value.path, e.value.line, e.value.field) == (str(CORPUS / f"{name}.txt"), line, field)


def test_validate_names_the_file_line_and_field(tmp_path):
    proj = tmp_path / "p.toml"
    proj.write_text(f'[project]\nname = "x"\n\n[[stage]]\nuse = "pmexport"\n[stage.options]\n'
                    f'path = "{CORPUS / "mark-photo.txt"}"\ncontrol = "{CORPUS / "control.txt"}"\n')
    r = subprocess.run([sys.executable, "-m", "baarda.pipeline.cli", "validate", str(proj)], capture_output=True,
                       text=True)
    assert r.returncode == 2, r.stderr
    msg = [ln for ln in r.stderr.splitlines() if ln.startswith("baarda:")][0]
    assert "mark-photo.txt" in msg and "27" in msg and "photo" in msg, msg
    assert "Traceback" not in r.stderr
