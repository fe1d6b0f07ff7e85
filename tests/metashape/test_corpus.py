"""The broken Metashape camera XMLs of ``tests/corpus/metashape/``: each is one InputError naming the
file, the element and the field (the line for XML syntax); ``baarda validate`` reports it without
running."""

from __future__ import annotations

import runpy
import subprocess
import sys
from pathlib import Path

import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.metashape import read_metashape

CORPUS = Path(__file__).resolve().parents[1] / "corpus" / "metashape"
CASES = runpy.run_path(str(CORPUS / "cases.py"))["CASES"]      # two corpora have a cases.py: no import


def test_the_cut_reads():
    blk, _ = read_metashape(CORPUS / "mini.xml")
    assert len(blk.photos) == 3 and len(blk.observations) > 10


@pytest.mark.parametrize("name", sorted(CASES))
def test_broken_input(name):
    file, field = CASES[name]
    with pytest.raises(InputError) as e:
        read_metashape(CORPUS / file)
    assert e.value.path == str(CORPUS / file), str(e.value)
    assert e.value.field.endswith(field), str(e.value)
    if name == "not-xml":
        assert e.value.line is not None


@pytest.mark.parametrize("name", ["k4-set", "camera-sensor-unknown"])
def test_validate_names_the_file_and_field(tmp_path, name):
    file, field = CASES[name]
    proj = tmp_path / "p.toml"
    proj.write_text(f'[project]\nname = "x"\n\n[[stage]]\nuse = "metashape"\n[stage.options]\n'
                    f'path = "{CORPUS / file}"\n')
    r = subprocess.run([sys.executable, "-m", "baarda.pipeline.cli", "validate", str(proj)], capture_output=True,
                       text=True)
    assert r.returncode == 2, r.stderr
    msg = [ln for ln in r.stderr.splitlines() if ln.startswith("baarda:")][0]
    assert file in msg and field in msg, msg
    assert "Traceback" not in r.stderr
