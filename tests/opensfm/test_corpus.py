"""The broken OpenSfM inputs of ``tests/corpus/opensfm/``: each is one InputError naming the file,
the line (tracks.csv, JSON syntax) or the element, and the field; ``baarda validate`` reports it
without running."""

from __future__ import annotations

import runpy
import subprocess
import sys
from pathlib import Path

import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.opensfm import read_opensfm

CORPUS = Path(__file__).resolve().parents[1] / "corpus" / "opensfm"
CASES = runpy.run_path(str(CORPUS / "cases.py"))["CASES"]      # two corpora have a cases.py: no import


def test_the_cut_reads():
    blk, info = read_opensfm(CORPUS / "mini.json", tracks=CORPUS / "mini.tracks.csv")
    assert len(blk.photos) == 3 and len(blk.observations) > 20


@pytest.mark.parametrize("name", sorted(CASES))
def test_broken_input(name):
    file, line, field = CASES[name]
    path = CORPUS / file
    js, tr = (path, CORPUS / "mini.tracks.csv") if file.endswith(".json") else (CORPUS / "mini.json", path)
    with pytest.raises(InputError) as e:
        read_opensfm(js, tracks=tr)
    err = e.value
    assert err.path == str(path), str(err)
    assert err.field.endswith(field), str(err)
    if line is not None:
        assert err.line == line, str(err)


@pytest.mark.parametrize("name", ["camera-fisheye", "tracks-x-text"])
def test_validate_names_the_file_and_field(tmp_path, name):
    file, line, field = CASES[name]
    js, tr = ((CORPUS / file, CORPUS / "mini.tracks.csv") if file.endswith(".json")
              else (CORPUS / "mini.json", CORPUS / file))
    proj = tmp_path / "p.toml"
    proj.write_text(f'[project]\nname = "x"\n\n[[stage]]\nuse = "opensfm"\n[stage.options]\n'
                    f'path = "{js}"\ntracks = "{tr}"\n')
    r = subprocess.run([sys.executable, "-m", "baarda.pipeline.cli", "validate", str(proj)], capture_output=True,
                       text=True)
    assert r.returncode == 2, r.stderr
    msg = [ln for ln in r.stderr.splitlines() if ln.startswith("baarda:")][0]
    assert file in msg and field in msg and (line is None or str(line) in msg), msg
    assert "Traceback" not in r.stderr
