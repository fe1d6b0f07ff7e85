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
        m.setattr(bal, "_parse_body", lambda *a: None)
        slow = bal.read_bal(path)
    return fast, slow


SMALL = ["2 3 4", "0 0 1.5 -2.25", "0 1 3e2 4", "1 1 -5 6.125", "1 2 7 8"] \
    + [repr(float(v)) for v in np.linspace(0.1, 1.8, 18)] + ["1 2 3", "4 5 6", "7 8 9"]


def test_bulk_equals_line_by_line(tmp_path, monkeypatch, shared_data):
    bal_dir = shared_data / "bal"
    for path in (_write(tmp_path / "small.txt", SMALL), bal_dir / "bal-ladybug-problem-49-7776-pre-shrink-1800.txt"):
        calls = []
        real = bal._parse_body
        monkeypatch.setattr(bal, "_parse_body", lambda *a: calls.append(1) or real(*a))
        fast = bal.read_bal(path)
        monkeypatch.setattr(bal, "_parse_body", real)
        assert calls and real(*_args(path)) is not None          # the bulk parse was taken
        fast, slow = _both(path, monkeypatch)
        for f in ("cam", "pt", "xy", "cameras", "points"):
            a, b = getattr(fast, f), getattr(slow, f)
            assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b), f


def _args(path):
    lines = path.read_text().splitlines()
    n = [int(t) for t in lines[0].split()]
    return lines, 1, n[0], n[1], n[2]


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
