"""The BAL reader's bulk parse gives what the line-by-line reading gives, and leaves every mistake
to the line-by-line reading (which names the line and field)."""

import numpy as np
import pytest

from baarda.pipeline.errors import InputError
from baarda.plugins.bal import bal


def _write(path, lines):
    path.write_text("\n".join(lines) + "\n")
    return path


def _both(path, monkeypatch):
    fast = bal.read_bal(path)
    with monkeypatch.context() as m:
        m.setattr(bal, "_parse_fast", lambda *a: None)
        slow = bal.read_bal(path)
    return fast, slow


SMALL = ["2 3 4", "0 0 1.5 -2.25", "0 1 3e2 4", "1 1 -5 6.125", "1 2 7 8"] \
    + [repr(float(v)) for v in np.linspace(0.1, 1.8, 18)] + ["1 2 3", "4 5 6", "7 8 9"]


def _fast(data: bytes):
    return bal._parse_fast(data, data.decode("ascii"))


def _same(fast, slow):
    for f in ("cam", "pt", "xy", "cameras", "points"):
        a, b = getattr(fast, f), getattr(slow, f)
        assert a.dtype == b.dtype and a.shape == b.shape, f
        assert a.tobytes() == b.tobytes(), f                 # bit for bit (−0.0 too)


def test_bulk_equals_line_by_line(tmp_path, monkeypatch, shared_data):
    bal_dir = shared_data / "bal"
    for path in (_write(tmp_path / "small.txt", SMALL), bal_dir / "bal-ladybug-problem-49-7776-pre-shrink-1800.txt",
                 bal_dir / "problem-49-7776-pre.txt"):
        assert _fast(path.read_bytes()) is not None          # the bulk parse is taken
        _same(*_both(path, monkeypatch))


@pytest.mark.parametrize("text", [
    "\n\n  2 3 4\n0 0 1.5 -2.25\n0 1 3e2 4\n1\t1 -5 6.125\n  1  2   7   8  \n",   # blank lines first, tabs, blanks
    "2 3 4\n0 0 1.5 -2.25\n0 1 3e2 4\n1 1 -5 6.125\n1 2 7 8\n",
])
def test_bulk_reads_any_blanks_as_the_lines_do(tmp_path, monkeypatch, text):
    params = " ".join(repr(float(v)) for v in np.linspace(0.1, 1.8, 18)) + "\n" + "1 2 3\n4 5 6 7 8 9"   # no final newline
    path = tmp_path / "blanks.txt"
    path.write_bytes((text + params).encode())
    assert _fast(path.read_bytes()) is not None
    _same(*_both(path, monkeypatch))


def test_values_are_what_float_reads(tmp_path, monkeypatch):
    """Tokens at the edges of float64 (subnormal, rounding ties, many digits, signs, leading zeros)."""
    odd = ["1e-320", "2.4703282292062328e-324", "1.7976931348623157e308", "-0.0", "+0.5", "1.", ".5", "007",
           "0.30000000000000004441", "123456789012345678901234567890e-10", "-.5e-3", "1E+05", "9007199254740993",
           "0.1", "2.5", "3", "4", "5"]
    lines = ["2 3 4", "0 0 1.5 -2.25", "0 1 3e2 4", "1 1 -5 6.125", "1 2 7 8", *odd, "1 2 3", "4 5 6", "7 8 9"]
    path = _write(tmp_path / "odd.txt", lines)
    fast, slow = _both(path, monkeypatch)
    _same(fast, slow)
    assert fast.cameras.ravel()[:len(odd)].tobytes() == np.array([float(t) for t in odd]).tobytes()


@pytest.mark.parametrize("bad", [
    ["2 3 4", "0 0 1.5 -2.25\r0 1 3e2 4", "1 1 -5 6.125", "1 2 7 8"],       # a lone CR ends a line
    ["2 3 4", "0 0 1.5 -2.25\r", "0 1 3e2 4", "1 1 -5 6.125", "1 2 7 8"],     # CRLF: left to the lines
    ["2 3 4", "0 0 1.5 -2.25", "0 1 3e2 4", "1 1 -5 6.125", "1 2 7 8 9"],     # five values
    ["2 3 4", "0 0 1.5 -2.25", "0 1 3e2", "1 1 -5 6.125 4", "1 2 7 8"],        # three, then five
    ["2 3 4", "0 0 1.5 -2.25", "0 1 3e2 4", "1 1 -5 6.1_25", "1 2 7 8"],       # an underscore (float reads it)
    ["2 3 4", "0 0 1.5 -2.25", "0 1 3e2 4", "1 1 -5 nan", "1 2 7 8"],
    ["2 3 4", "0 0 1.5 -2.25", "0 1 3e2 4", "1 1 -5 1e999", "1 2 7 8"],
    ["2 3 4", "0 0 1.5 -2.25", "0 1 3e2 4", "1 1 -5 1.5-2", "1 2 7 8"],
    ["2 3 4", "0 0 1.5 -2.25", "0 1 3e2 4", "1 1 -5 0x10", "1 2 7 8"],
    ["2 3 4", "", "0 0 1.5 -2.25", "0 1 3e2 4", "1 1 -5 6.125", "1 2 7 8"],   # a blank observation line
    ["2 3 4.0", "0 0 1.5 -2.25", "0 1 3e2 4", "1 1 -5 6.125", "1 2 7 8"],
])
def test_anything_not_plain_is_left_to_the_lines(bad):
    lines = bad + [repr(float(v)) for v in np.linspace(0.1, 1.8, 18)] + ["1 2 3", "4 5 6", "7 8 9"]
    assert _fast(("\n".join(lines) + "\n").encode()) is None


def test_the_underscore_reads_as_python_reads_it(tmp_path, monkeypatch):
    lines = list(SMALL)
    lines[3] = "1 1 -5 6.1_25"                  # float("6.1_25") = 6.125: the lines accept it
    p = bal.read_bal(_write(tmp_path / "u.txt", lines))
    assert p.xy[2, 1] == 6.125


@pytest.mark.parametrize("line, value, field", [
    (2, "0 0 1.5", "observation"),          # three values
    (3, "0 1 abc 4", "x"),                  # not a number
    (4, "1 1 nan 6", "x"),                  # not finite
    (2, "0 9 1 2", "pt"),                   # index out of range
    (3, "0 0 3 4", "observation"),          # repeated observation
    (2, "0.0 0 1 2", "cam"),                # not an integer
    (12, "-1.0", "f"),                      # f of camera 0 ≤ 0 (line 6 + 6 parameters)
])
def test_mistakes_fall_back_and_name_the_line(tmp_path, line, value, field):
    lines = list(SMALL)
    lines[line - 1] = value
    with pytest.raises(InputError) as e:
        bal.read_bal(_write(tmp_path / "bad.txt", lines))
    assert e.value.line == line and e.value.field == field


def test_counts_that_do_not_match_fall_back(tmp_path):
    with pytest.raises(InputError, match="more values"):
        bal.read_bal(_write(tmp_path / "extra.txt", SMALL + ["1.0"]))
    with pytest.raises(InputError, match="file ends"):
        bal.read_bal(_write(tmp_path / "short.txt", SMALL[:-1]))
