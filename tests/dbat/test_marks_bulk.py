"""DBAT marks files are parsed in bulk when every line is plain (whole-number ids, finite numbers),
with exactly what the line-by-line reading gives; anything else is read line by line."""

import shutil

import numpy as np
import pytest

from baarda.pipeline.errors import InputError
from baarda.plugins.dbat import reader


def _read_both(xml, monkeypatch):
    taken = []
    real = reader._marks_bulk
    monkeypatch.setattr(reader, "_marks_bulk", lambda *a: taken.append(real(*a) is not None) or real(*a))
    fast = reader.read_dbat(xml)
    monkeypatch.setattr(reader, "_marks_bulk", lambda *a: None)
    slow = reader.read_dbat(xml)
    monkeypatch.setattr(reader, "_marks_bulk", real)
    return fast, slow, taken


def _same(fast, slow):
    assert len(fast.marks) == len(slow.marks)
    for a, b in zip(fast.marks, slow.marks):
        assert a.image == b.image and a.point == b.point and a.lines == b.lines
        assert a.sigma_source == b.sigma_source
        assert a.uv.dtype == b.uv.dtype and np.array_equal(a.uv, b.uv)
        assert a.sigma_px.dtype == b.sigma_px.dtype and np.array_equal(a.sigma_px, b.sigma_px)


@pytest.mark.parametrize("xml", ["dbat-camcal/camcaldemo.xml", "dbat-sxb/sxb.xml"])
def test_bulk_equals_line_by_line(shared_data, monkeypatch, xml):
    fast, slow, taken = _read_both(shared_data / xml, monkeypatch)
    assert taken and all(taken)
    _same(fast, slow)


@pytest.fixture
def camcal(shared_data, tmp_path):
    src, dst = shared_data / "dbat-camcal", tmp_path / "camcal"
    dst.mkdir()
    shutil.copy(src / "camcaldemo.xml", dst)
    for sub, name in (("reference", "camcal-fixed.txt"), ("images", "images.txt"), ("measurements", "markpts.txt")):
        (dst / sub).mkdir()
        shutil.copy(src / sub / name, dst / sub / name)
    return dst


def test_comments_blank_lines_and_leading_zeros(camcal, monkeypatch):
    marks = camcal / "measurements" / "markpts.txt"
    lines = marks.read_text().splitlines()
    k = next(i for i, s in enumerate(lines) if s.strip() and not s.lstrip().startswith("#"))
    first = lines[k].split(",")
    lines[k] = f"  {int(first[0]):03d},{first[1]}, {first[2].strip()} ,{','.join(first[3:])}   # a comment"
    lines.insert(k + 1, "")
    lines.insert(k + 1, "   # only a comment")
    marks.write_text("\n".join(lines) + "\n")
    fast, slow, taken = _read_both(camcal / "camcaldemo.xml", monkeypatch)
    assert all(taken)
    _same(fast, slow)
    assert fast.marks[0].image[0] == str(int(first[0]))


def test_names_as_ids_are_read_line_by_line(camcal, monkeypatch):
    marks = camcal / "measurements" / "markpts.txt"
    text = marks.read_text()
    lines = text.splitlines()
    k = next(i for i, s in enumerate(lines) if s.strip() and not s.lstrip().startswith("#"))
    f = lines[k].split(",")
    lines[k] = ",".join([f[0], " P7"] + f[2:])              # a point name, not a number
    marks.write_text("\n".join(lines) + "\n")
    fast, slow, taken = _read_both(camcal / "camcaldemo.xml", monkeypatch)
    assert taken == [False]
    _same(fast, slow)
    assert "P7" in fast.marks[0].point


def test_a_bad_line_is_still_named(camcal):
    marks = camcal / "measurements" / "markpts.txt"
    lines = marks.read_text().splitlines()
    k = len(lines) - 1
    f = lines[k].split(",")
    lines[k] = ",".join(f[:2] + [" inf"] + f[3:])
    marks.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as e:
        reader.read_dbat(camcal / "camcaldemo.xml")
    assert e.value.line == k + 1 and e.value.field == "x"


@pytest.mark.parametrize("variant", ["as-is", "spaces-and-comments", "crlf", "tabs-only-line"])
def test_the_plain_path_and_its_fallbacks(camcal, monkeypatch, variant):
    """Plain ASCII files with \\n line ends are parsed without a Python loop over the lines
    (reader._plain_rows: comments and lines of only spaces blanked by regular expressions); other
    line ends fall back to stripping each line.  Either way exactly the line-by-line reading."""
    marks = camcal / "measurements" / "markpts.txt"
    lines = marks.read_text().splitlines()
    k = next(i for i, s in enumerate(lines) if s.strip() and not s.lstrip().startswith("#"))
    end = "\n"
    if variant == "spaces-and-comments":
        lines[k] = "   " + lines[k] + "  # trailing comment"
        lines[k + 2:k + 2] = ["", "    ", "# a comment line", "\t# indented comment"]
    elif variant == "crlf":
        end = "\r\n"
    elif variant == "tabs-only-line":
        lines.insert(k + 1, "\t \t")
    marks.write_bytes((end.join(lines) + end).encode("ascii"))
    plain = []
    real = reader._plain_rows
    monkeypatch.setattr(reader, "_plain_rows", lambda *a: plain.append(real(*a) is not None) or real(*a))
    fast, slow, taken = _read_both(camcal / "camcaldemo.xml", monkeypatch)
    assert all(taken)
    assert plain[0] == (variant != "crlf")
    _same(fast, slow)
