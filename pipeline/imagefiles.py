"""Image files read safely: the header's dimensions are checked before anything is decoded.

A PNG of 100 000 × 100 000 pixels can be a few kilobytes ("decompression bomb"), and a header
may simply lie; OpenCV then allocates gigabytes or stops with an assertion from ``imgcodecs``.
:func:`read_gray` reads the dimensions from the header first (PNG, JPEG, TIFF, BMP; other formats
through OpenCV's own ``CV_IO_MAX_IMAGE_PIXELS`` limit, set here before OpenCV decodes anything)
and refuses more than :data:`MAX_IMAGE_PIXELS` with an :class:`InputError` naming the file.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

from .errors import InputError

MAX_IMAGE_PIXELS = 250_000_000
"""Most pixels an image may have (the largest photogrammetric cameras have ≈ 150 Mpx)."""

os.environ.setdefault("CV_IO_MAX_IMAGE_PIXELS", str(MAX_IMAGE_PIXELS))


def header_size(path: str | Path) -> tuple[int, int] | None:
    """``(width, height)`` from an image file's header (PNG, JPEG, TIFF, BMP), or None when the
    format is not one of these or the header is unreadable."""
    try:
        with open(path, "rb") as f:
            head = f.read(64)
            if head.startswith(b"\x89PNG\r\n\x1a\n") and len(head) >= 24 and head[12:16] == b"IHDR":
                return struct.unpack(">II", head[16:24])
            if head.startswith(b"BM") and len(head) >= 26:
                w, h = struct.unpack("<ii", head[18:26])
                return abs(w), abs(h)
            if head[:4] in (b"II*\0", b"MM\0*"):
                return _tiff_size(f, "<" if head[:2] == b"II" else ">")
            if head.startswith(b"\xff\xd8"):
                return _jpeg_size(f)
    except (OSError, struct.error):
        return None
    return None


def _jpeg_size(f) -> tuple[int, int] | None:
    f.seek(2)
    for _ in range(10_000):
        b = f.read(1)
        while b and b != b"\xff":
            b = f.read(1)
        while b == b"\xff":
            b = f.read(1)
        if not b:
            return None
        marker = b[0]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            continue
        seg = f.read(2)
        if len(seg) < 2:
            return None
        n = struct.unpack(">H", seg)[0]
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            data = f.read(5)
            if len(data) < 5:
                return None
            h, w = struct.unpack(">HH", data[1:5])
            return w, h
        f.seek(n - 2, 1)
    return None


def _tiff_size(f, end: str) -> tuple[int, int] | None:
    f.seek(4)
    off = struct.unpack(end + "I", f.read(4))[0]
    f.seek(off)
    n = struct.unpack(end + "H", f.read(2))[0]
    size = {}
    for _ in range(min(n, 4096)):
        tag, typ, _count = struct.unpack(end + "HHI", f.read(8))
        raw = f.read(4)
        if tag in (256, 257):
            size[tag] = struct.unpack(end + ("H" if typ == 3 else "I"), raw[:2] if typ == 3 else raw)[0]
    return (size[256], size[257]) if 256 in size and 257 in size else None


def check_size(path: str | Path, max_pixels: int | None = None) -> tuple[int, int] | None:
    """The header's ``(width, height)``; :class:`InputError` when it claims more than
    ``max_pixels`` (default :data:`MAX_IMAGE_PIXELS`) — checked before anything is decoded."""
    limit = MAX_IMAGE_PIXELS if max_pixels is None else max_pixels
    size = header_size(path)
    if size is not None and size[0] * size[1] > limit:
        raise InputError(f"the image header claims {size[0]} × {size[1]} pixels ({size[0] * size[1] / 1e6:.0f} Mpx), "
                         f"more than the {limit / 1e6:.0f} Mpx baarda decodes (a damaged file or a decompression "
                         "bomb?)", path=path)
    return size


def read_gray(path: str | Path, max_pixels: int | None = None):
    """The image as an 8-bit grey array, or None when OpenCV cannot read it; an image larger than
    the pixel limit is an :class:`InputError` (:func:`check_size`), never an OpenCV assertion."""
    import cv2

    check_size(path, max_pixels)
    try:
        return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    except cv2.error as e:
        raise InputError(f"OpenCV cannot decode this image ({str(e).strip().splitlines()[-1][:120]})",
                         path=path) from None
