"""Text inputs are read with a size limit and decoded strictly where the format is UTF-8/ASCII
(issue 27): an endless stream is a size error (not "out of memory"), a non-UTF-8 gcp list and a
UTF-8 BAL file name the line and the byte, a GNSS row with an extra field is refused."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest

from baarda.pipeline import errors
from baarda.pipeline.errors import InputError, read_limited, read_text_limited
from baarda.plugins.bal.bal import read_bal
from baarda.plugins.gcp.reader import read_gnss_csv

ROOT = Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared" / "data"


def test_an_endless_stream_is_a_size_error():
    with pytest.raises(InputError, match="stream that does not end|MB") as e:
        read_limited("/dev/zero", limit=1 << 20)
    assert e.value.path == "/dev/zero"


def test_a_fifo_that_never_ends_is_a_size_error(tmp_path):
    fifo = tmp_path / "marks.txt"
    os.mkfifo(fifo)
    stop = threading.Event()

    def writer():
        try:                                 # the reader closes the pipe: the write or the close fails
            with open(fifo, "wb") as f:
                while not stop.is_set():
                    f.write(b"1, 2, 3.0, 4.0, 0.1\n" * 1000)
        except BrokenPipeError:
            pass
    t = threading.Thread(target=writer, daemon=True)
    t.start()
    with pytest.raises(InputError, match="does not end"):
        read_limited(fifo, limit=1 << 20)
    stop.set()
    t.join(5)


def test_a_large_file_is_refused_before_it_is_read(tmp_path):
    f = tmp_path / "big.txt"
    with open(f, "wb") as h:
        h.truncate(5 << 20)
    with pytest.raises(InputError, match="5.0 MB"):
        read_limited(f, limit=1 << 20)


def test_not_utf8_names_the_line(tmp_path):
    f = tmp_path / "a.txt"
    f.write_bytes(b"ok\nok\nbad \xff here\n")
    with pytest.raises(InputError, match="0xff") as e:
        read_text_limited(f)
    assert e.value.line == 3


def test_a_utf8_bal_file_names_the_line_not_unicode_decode_error(tmp_path):
    f = tmp_path / "p.txt"
    f.write_text("1 1 1\n0 0 1.0 2.0 # café\n", encoding="utf-8")
    with pytest.raises(InputError) as e:
        read_bal(f)
    assert "UnicodeDecodeError" not in str(e.value) and e.value.line == 2 and "ASCII" in str(e.value)


GOOD = "# crs: EPSG:32722\nphoto,E,N,h,sigma\nIMG_5350.JPG,658530.0,7167000.0,965.0,0.05\n"


def test_a_gnss_row_with_an_extra_field_is_refused(tmp_path):
    f = tmp_path / "g.csv"
    f.write_text(GOOD.replace(",0.05\n", ",0.05,7\n"))
    with pytest.raises(InputError, match="extra field") as e:
        read_gnss_csv(f)
    assert e.value.line == 3


def test_a_gnss_file_not_utf8_is_refused(tmp_path):
    f = tmp_path / "g.csv"
    f.write_bytes(GOOD.encode().replace(b"IMG_5350", b"IMG_\xe95350"))
    with pytest.raises(InputError, match="UTF-8") as e:
        read_gnss_csv(f)
    assert e.value.line == 3


@pytest.mark.skipif(not (SHARED / "odm-br-gcp").is_dir(), reason="shared data not found")
def test_a_gcp_list_not_utf8_is_refused(tmp_path):
    from baarda.plugins.gcp.reader import read_gcp_list

    text = (SHARED / "odm-br-gcp" / "gcp_list_floatxy_raw.txt").read_bytes()
    lines = text.split(b"\n")
    lines[3] = lines[3] + b" \xe9"
    f = tmp_path / "gcp_list.txt"
    f.write_bytes(b"\n".join(lines))
    with pytest.raises(InputError, match="UTF-8") as e:
        read_gcp_list(f)
    assert e.value.line == 4
