"""Images are checked before decoding (issue 27): a header claiming huge dimensions or a
decompression bomb is an InputError naming the file — never an OpenCV assertion (exit 3); an
explicitly listed image that does not exist is an error, not a skipped file."""

from __future__ import annotations

import contextlib
import io
import struct
import zlib

import cv2
import numpy as np
import pytest

from baarda.pipeline import imagefiles
from baarda.pipeline.cli import main
from baarda.pipeline.errors import InputError
from baarda.pipeline.imagefiles import check_size, header_size, read_gray


def huge_png(path, w=200_000, h=200_000):
    """A PNG whose header claims w × h (CRC fixed), with one tiny IDAT."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(b"\0" * 100)) + chunk(b"IEND", b""))


def bomb_png(path, side=4000):
    """A real PNG of side × side black pixels: a few kB on disk, 16 Mpx decoded."""
    raw = b"".join(b"\0" + b"\0" * side for _ in range(side))
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", side, side, 8, 0, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


@pytest.mark.parametrize("ext", [".png", ".jpg", ".tif", ".bmp"])
def test_header_sizes_of_real_files(tmp_path, ext):
    f = tmp_path / f"a{ext}"
    cv2.imwrite(str(f), np.zeros((37, 53), np.uint8))
    assert header_size(f) == (53, 37)


def test_a_header_claiming_huge_dimensions_is_refused(tmp_path):
    f = tmp_path / "a.png"
    huge_png(f)
    with pytest.raises(InputError, match="200000 × 200000") as e:
        read_gray(f)
    assert e.value.path == str(f)


def test_a_decompression_bomb_is_refused_before_decoding(tmp_path, monkeypatch):
    f = tmp_path / "bomb.png"
    bomb_png(f)
    assert f.stat().st_size < 100_000
    monkeypatch.setattr(imagefiles, "MAX_IMAGE_PIXELS", 10_000_000)
    with pytest.raises(InputError, match="decompression bomb"):
        read_gray(f)
    assert check_size(f, max_pixels=20_000_000) == (4000, 4000)


def run(tmp_path, images):
    p = tmp_path / "p.toml"
    p.write_text('[[stage]]\nuse = "opencv-targets"\nid = "source"\n[stage.options]\ntarget = "chessboard"\n'
                 f'images = {images!r}\nsquares = [9, 6]\nsquare_size = 25.0\n'.replace("'", '"'))
    o, e = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(o), contextlib.redirect_stderr(e):
        code = main(["run", str(p), "--out", str(tmp_path / "out"), "-q"])
    return code, e.getvalue()


def test_a_huge_image_in_a_run_is_an_input_error(tmp_path):
    (tmp_path / "img").mkdir()
    huge_png(tmp_path / "img" / "a.png")
    code, err = run(tmp_path, ["img/*.png"])
    assert code == 2 and "a.png" in err and "Mpx" in err, err


def test_an_explicitly_listed_missing_image_is_an_error(tmp_path):
    (tmp_path / "img").mkdir()
    cv2.imwrite(str(tmp_path / "img" / "a.png"), np.zeros((64, 64), np.uint8))
    code, err = run(tmp_path, ["img/a.png", "img/nothere.png"])
    assert code == 2 and "nothere.png" in err and "field 'images'" in err, err
