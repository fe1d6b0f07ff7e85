"""DBAT scripts are user XML: parsed with defusedxml (issue 27) — no entity expansion ("billion
laughs" used to hang run and validate), no external entities, a size limit; each a clean InputError."""

from __future__ import annotations

import contextlib
import io
import shutil
import time
from pathlib import Path

import pytest

from baarda.pipeline.cli import main
from baarda.pipeline.errors import InputError
from baarda.plugins.dbat.reader import parse_xml

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"
CAMCAL = SHARED / "dbat-camcal"

LAUGHS = ('<?xml version="1.0"?>\n<!DOCTYPE lolz [\n <!ENTITY lol "lol">\n'
          + "".join(f' <!ENTITY lol{k} "{("&lol" + (str(k - 1) if k > 1 else "") + ";") * 10}">\n' for k in range(1, 10))
          + ']>\n<document dbat_script_version="1.0.0"><c>&lol9;</c></document>\n')
EXTERNAL = ('<?xml version="1.0"?>\n<!DOCTYPE d [\n <!ENTITY x SYSTEM "file:///etc/passwd">\n]>\n'
            '<document dbat_script_version="1.0.0"><c>&x;</c></document>\n')


def test_billion_laughs_is_refused_at_once(tmp_path):
    f = tmp_path / "p.xml"
    f.write_text(LAUGHS)
    t0 = time.perf_counter()
    with pytest.raises(InputError, match="refused") as e:
        parse_xml(f)
    assert time.perf_counter() - t0 < 2.0
    assert e.value.path == str(f) and e.value.line == 3


def test_an_external_entity_is_not_read(tmp_path):
    f = tmp_path / "p.xml"
    f.write_text(EXTERNAL)
    with pytest.raises(InputError, match="refused") as e:
        parse_xml(f)
    assert "root:" not in str(e.value)


def test_a_huge_script_is_refused_by_size(tmp_path, monkeypatch):
    import baarda.plugins.dbat.reader as r

    monkeypatch.setattr(r, "XML_MAX_BYTES", 1000)
    f = tmp_path / "p.xml"
    f.write_text("<document>" + "<c>x</c>" * 500 + "</document>")
    with pytest.raises(InputError, match="MB"):
        parse_xml(f)


def test_malformed_xml_names_the_line(tmp_path):
    f = tmp_path / "p.xml"
    f.write_text("<document>\n<a>\n</document>\n")
    with pytest.raises(InputError, match="not well-formed") as e:
        parse_xml(f)
    assert e.value.line == 3


@pytest.mark.skipif(not CAMCAL.is_dir(), reason="shared data not found")
@pytest.mark.parametrize("command", ["validate", "run"])
def test_billion_laughs_in_a_project_is_an_input_error(tmp_path, command):
    shutil.copytree(CAMCAL, tmp_path / "d")
    (tmp_path / "d" / "camcaldemo.xml").write_text(LAUGHS)
    p = tmp_path / "p.toml"
    p.write_text('[[stage]]\nuse = "dbat"\n[stage.options]\npath = "d/camcaldemo.xml"\n')
    o, e = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(o), contextlib.redirect_stderr(e):
        argv = [command, str(p)] + (["--out", str(tmp_path / "out"), "-q"] if command == "run" else [])
        code = main(argv)
    assert code == 2 and "camcaldemo.xml:3" in e.getvalue(), e.getvalue()


def test_the_real_scripts_still_parse():
    for f in sorted(SHARED.glob("dbat-*/*.xml")):
        assert parse_xml(f).tag
