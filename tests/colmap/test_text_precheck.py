"""COLMAP text models that pycolmap refuses (or reads wrongly) are checked by baarda's own reader
first (issue 27): file, line and field for a bad number, a missing camera, a track to a missing
image or 2-D point, a NaN pose, an infinite point, a duplicate image."""

from __future__ import annotations

from pathlib import Path

import pytest

from baarda.pipeline.colmap.reader import read_reconstruction
from baarda.pipeline.errors import InputError

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data" / "colmap-model"
pytestmark = pytest.mark.skipif(not SHARED.is_dir(), reason="shared data not found")


@pytest.fixture(scope="module")
def text_model(tmp_path_factory):
    import pycolmap

    rec = pycolmap.Reconstruction()
    rec.read_binary(str(SHARED))
    d = tmp_path_factory.mktemp("model")
    rec.write_text(str(d))
    return {n: (d / n).read_text() for n in ("cameras.txt", "images.txt", "points3D.txt")}


def data_lines(text):
    return [k for k, ln in enumerate(text.splitlines()) if ln.strip() and not ln.startswith("#")]


def edit(files, name, fn):
    lines = files[name].splitlines()
    k = fn(lines)
    return {**files, name: "\n".join(lines) + "\n"}, k + 1


def write(tmp_path, files):
    d = tmp_path / "m"
    d.mkdir()
    for n, t in files.items():
        (d / n).write_text(t)
    return d


def image_line(lines, j=0):
    return data_lines("\n".join(lines))[2 * j]          # header lines of images: every other data line


def set_tok(lines, k, i, value):
    t = lines[k].split(" ")
    t[i] = value
    lines[k] = " ".join(t)
    return k


CASES = {
    "image-bad-number": ("images.txt", lambda L: set_tok(L, image_line(L), 1, "0.7x"), "QW"),
    "image-nan-pose": ("images.txt", lambda L: set_tok(L, image_line(L), 5, "nan"), "TX"),
    "image-missing-camera": ("images.txt", lambda L: set_tok(L, image_line(L), 8, "999"), "CAMERA_ID"),
    "image-duplicate": ("images.txt", lambda L: set_tok(L, image_line(L, 1), 0, L[image_line(L)].split()[0]),
                        "IMAGE_ID"),
    "image-points-not-triples": ("images.txt", lambda L: (L.__setitem__(image_line(L) + 1,
                                                                         L[image_line(L) + 1] + " 1.0"),
                                                           image_line(L) + 1)[1], "POINTS2D"),
    "point-inf": ("points3D.txt", lambda L: set_tok(L, data_lines("\n".join(L))[0], 2, "inf"), "Y"),
    "point-letter": ("points3D.txt", lambda L: set_tok(L, data_lines("\n".join(L))[0], 1, "1.2.3"), "X"),
    "point-duplicate": ("points3D.txt", lambda L: set_tok(L, data_lines("\n".join(L))[1], 0,
                                                           L[data_lines("\n".join(L))[0]].split()[0]), "POINT3D_ID"),
    "track-missing-image": ("points3D.txt", lambda L: set_tok(L, data_lines("\n".join(L))[0], 8, "99999"),
                            "TRACK[0].IMAGE_ID"),
    "track-missing-2d-point": ("points3D.txt", lambda L: set_tok(L, data_lines("\n".join(L))[0], 9, "999999"),
                               "TRACK[0].POINT2D_IDX"),
    "track-odd": ("points3D.txt", lambda L: (L.__setitem__(data_lines("\n".join(L))[0],
                                                           L[data_lines("\n".join(L))[0]] + " 5"),
                                             data_lines("\n".join(L))[0])[1], "TRACK"),
    "camera-duplicate": ("cameras.txt", lambda L: (L.append(L[data_lines("\n".join(L))[0]]), len(L) - 1)[1],
                         "CAMERA_ID"),
}


@pytest.mark.parametrize("name", list(CASES))
def test_a_broken_text_model_names_file_line_field(text_model, tmp_path, name):
    fname, fn, field = CASES[name]
    files, line = edit(text_model, fname, fn)
    d = write(tmp_path, files)
    with pytest.raises(InputError) as e:
        read_reconstruction(d)
    err = e.value
    assert Path(err.path).name == fname and err.line == line and err.field == field, str(err)


def test_the_intact_text_model_reads(text_model, tmp_path):
    rec = read_reconstruction(write(tmp_path, text_model))
    assert len(rec.images) > 0 and len(rec.points3D) > 0
