"""A generated corpus of broken inputs: every reader, every kind of option, the project file, the
run directory and ``baarda review``.

Each :class:`Case` is a small project written into a fresh folder from real data (``fixtures/``
and ``../shared/data``) with one thing broken.  :func:`run_case` runs it through the command line
in-process and returns what a user would see; ``test_broken_inputs.py`` asserts for every case:
the exit code, one ``baarda:`` line naming the file, no traceback, nothing outside ``--out``
changed, and the earlier stages' files intact.

Run it by hand to see every message::

    .venv/bin/python tests/corpus/broken_inputs.py [substring]
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import struct
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
SHARED = next((p for p in (Path(os.environ.get("BAARDA_SHARED_DATA") or ROOT.parent / "shared" / "data"),
                            ROOT.parent / "shared" / "data", Path("/work/shared/data")) if p.is_dir()),
              ROOT.parent / "shared" / "data")
DATA1 = (ROOT / "fixtures" / "paper000" / "data1.cmp").read_text(encoding="utf-8")
BAL_FILE = SHARED / "bal" / "bal-ladybug-problem-49-7776-pre-shrink-1800.txt"
LIBMV_FILE = SHARED / "libmv-ba" / "problem_03.bin"
AICON = SHARED / "aicon-closerange"
COLMAP = SHARED / "colmap-model"
CHESS = SHARED / "opencv-chessboard"


@dataclass
class Case:
    name: str
    files: dict[str, bytes | str | Callable[[Path], None]]
    project: str = ""
    command: str = "run"            # run | validate | review | run+validate
    code: int = 2
    names: str = ""                 # the file the message must name (a substring of the error line)
    also: str = ""                  # a second substring it must hold (the field, where names gives file and line)
    earlier: list[str] = field(default_factory=list)   # files of earlier stages that must be in the run
    out: str = "out"
    extra_args: list[str] = field(default_factory=list)
    quick: bool = True              # in `make test`; False: only under the slow marker (`make test-slow`)


# -- projects -------------------------------------------------------------------------------------

def comparator_project(extra_stage: str = "", options: str = "") -> str:
    return (f'[[stage]]\nuse = "comparator"\nid = "source"\n[stage.options]\npath = "data.cmp"\n{options}\n'
            + extra_stage)


SCREENING = '[[stage]]\nuse = "helmert-screening"\nid = "screening"\n[stage.options]\n'


def source_project(use: str, path: str, options: str = "") -> str:
    return f'[[stage]]\nuse = "{use}"\nid = "source"\n[stage.options]\npath = "{path}"\n{options}\n'


def replace_line(text: str, start: str, new: str) -> str:
    lines = text.splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.strip().startswith(start))
    lines[k] = new
    return "\n".join(lines) + "\n"


# -- comparator -----------------------------------------------------------------------------------

def comparator_cases() -> list[Case]:
    c = []
    broken = {
        "nan": replace_line(DATA1, "pt  3", "pt  3   nan   180.618"),
        "inf": replace_line(DATA1, "pt  3", "pt  3   158.014   inf"),
        "huge": replace_line(DATA1, "pt  3", "pt  3   1e300   180.618"),
        "letter": replace_line(DATA1, "pt  3", "pt  3   l58.014   180.618"),
        "comma": replace_line(DATA1, "pt  3", "pt  3   158,014   180.618"),
        "missing-y": replace_line(DATA1, "pt  3", "pt  3   158.014"),
        "extra-value": replace_line(DATA1, "pt  3", "pt  3   158.014   180.618  1 2 3 4 5"),
        "duplicate-point": replace_line(DATA1, "pt  3", "pt  2   158.014   180.618"),
        "duplicate-photo": DATA1 + "\nphoto L\npt 1 1 1\n",
        "unknown-keyword": replace_line(DATA1, "pt  3", "point3 158.014 180.618"),
        "bad-unit": replace_line(DATA1, "unit", "unit inches"),
        "bad-mode": replace_line(DATA1, "mode", "mode laser"),
        "unit-twice": "unit mm\n" + DATA1,
        "negative-sigma": "sigma -0.01\n" + DATA1,
        "zero-sigma": "sigma 0\n" + DATA1,
        "nan-sigma": "sigma nan\n" + DATA1,
        "pt-before-photo": "unit mm\nmode photo\npt 1 1 1\n" + DATA1,
        "no-photo": "unit mm\nmode photo\n",
        "empty": "",
        "camera-zero-c": "camera cam c 0\n" + DATA1,
        "camera-negative-c": "camera cam c -152\n" + DATA1,
        "camera-nan-c": "camera cam c nan\n" + DATA1,
        "camera-bad-format": "camera cam c 152 format -230 230\n" + DATA1,
        "camera-twice": "camera cam c 152\ncamera cam c 153\n" + DATA1,
        "photo-unknown-camera": DATA1.replace("photo L", "photo L camera nocam"),
        "pair-twice": DATA1 + "\npair L R\npair R L\n",
        "pair-same": DATA1 + "\npair L L\n",
        "pair-unknown": DATA1 + "\npair L X\n",
        "point-bad-role": DATA1 + "\npoint 1 hero 1 2 3\n",
        "point-no-xyz": DATA1 + "\npoint 1 full\n",
        "point-twice": DATA1 + "\npoint 1 full 1 2 3\npoint 1 full 1 2 3\n",
        "point-negative-sigma": DATA1 + "\npoint 1 full 1 2 3 -1 1 1\n",
        "fid-in-photo-mode": DATA1.replace("pt  1    97.673", "fid 1 1 1\npt  1    97.673", 1),
        "fiducial-mode-no-camera": DATA1.replace("mode photo", "mode fiducial"),
        "sx-negative": replace_line(DATA1, "pt  3", "pt  3   158.014   180.618  -0.01 0.01"),
    }
    for name, text in broken.items():
        c.append(Case(f"comparator/{name}", {"data.cmp": text}, comparator_project(), names="data.cmp"))
    c.append(Case("comparator/not-utf8", {"data.cmp": DATA1.encode() + b"\xff\xfe\x00bad"},
                  comparator_project(), names="data.cmp"))
    c.append(Case("comparator/binary", {"data.cmp": bytes(range(256)) * 4}, comparator_project(), names="data.cmp"))
    c.append(Case("comparator/system-file", {}, comparator_project().replace('"data.cmp"', '"/etc/passwd"'),
                  names="/etc/passwd"))
    c.append(Case("comparator/missing", {}, comparator_project(), names="project.toml"))
    c.append(Case("comparator/directory", {"data.cmp": lambda d: (d / "data.cmp").mkdir()}, comparator_project(),
                  names="project.toml"))
    for name, text in list(broken.items())[:6]:
        c.append(Case(f"comparator/validate-{name}", {"data.cmp": text}, comparator_project(), command="validate",
                      names="data.cmp"))
    return c


# -- BAL and libmv --------------------------------------------------------------------------------

def bal_cases() -> list[Case]:
    lines = BAL_FILE.read_text().splitlines()
    n_obs = int(lines[0].split()[2])
    cam0 = 1 + n_obs                     # first camera value line (one value per line)

    def with_lines(**edits):
        out = list(lines)
        for k, v in edits.items():
            out[int(k[1:])] = v
        return "\n".join(out) + "\n"

    cases = {
        "nan-observation": with_lines(l5="3 0 nan 2.02e+02"),
        "inf-observation": with_lines(l5="3 0 -2.5e+02 inf"),
        "letter": with_lines(l5="3 0 -2.5e+02 2,02e+02"),
        "nan-camera": with_lines(**{f"l{cam0 + 2}": "nan"}),
        "zero-focal": with_lines(**{f"l{cam0 + 6}": "0.0"}),
        "negative-focal": with_lines(**{f"l{cam0 + 6}": "-400.0"}),
        "nan-point": with_lines(**{f"l{len(lines) - 1}": "nan"}),
        "duplicate-observation": with_lines(l2=lines[1]),
        "camera-out-of-range": with_lines(l3="55 0 1.0 2.0"),
        "point-out-of-range": with_lines(l3="0 99999 1.0 2.0"),
        "header-two-counts": with_lines(l0="49 1800"),
        "header-negative": with_lines(l0=f"49 -1800 {n_obs}"),
        "header-huge-observations": with_lines(l0="49 7776 10000000000"),
        "header-huge-points": with_lines(l0=f"49 9999999999 {n_obs}"),
        "truncated-observations": "\n".join(lines[:101]) + "\n",
        "truncated-cameras": "\n".join(lines[:cam0 + 30]) + "\n",
        "truncated-points": "\n".join(lines[:-2]) + "\n",
        "extra-values": "\n".join(lines) + "\n1.0\n",
        "empty": "",
        "observation-three-values": with_lines(l7="3 0 1.0"),
    }
    c = [Case(f"bal/{n}", {"problem.txt": t}, source_project("bal", "problem.txt"), names="problem.txt")
         for n, t in cases.items()]
    c.append(Case("bal/binary", {"problem.txt": bytes(range(256))}, source_project("bal", "problem.txt"),
                  names="problem.txt"))
    c += [Case(f"bal/validate-{n}", {"problem.txt": cases[n]}, source_project("bal", "problem.txt"),
               command="validate", names="problem.txt")
          for n in ("nan-observation", "zero-focal", "duplicate-observation", "header-huge-observations")]
    c += libmv_cases()
    return c


def libmv_cases() -> list[Case]:
    data = LIBMV_FILE.read_bytes()
    end = "<" if data[:1] == b"v" else ">"
    n_cams = struct.unpack_from(end + "i", data, 34)[0]
    cams_at = 38
    pts_count_at = cams_at + 52 * n_cams
    n_pts = struct.unpack_from(end + "i", data, pts_count_at)[0]
    mk_count_at = pts_count_at + 4 + 16 * n_pts

    def patch(offset, fmt, value):
        b = bytearray(data)
        struct.pack_into(end + fmt, b, offset, value)
        return bytes(b)

    dup = bytearray(data)
    dup[mk_count_at + 4 + 16: mk_count_at + 4 + 32] = dup[mk_count_at + 4: mk_count_at + 4 + 16]
    cases = {
        "nan-focal": patch(2, "f", float("nan")),
        "zero-focal": patch(2, "f", 0.0),
        "negative-focal": patch(2, "f", -1.0),
        "inf-rotation": patch(cams_at + 4 + 4, "f", float("inf")),
        "nan-point": patch(pts_count_at + 4 + 4, "f", float("nan")),
        "nan-marker": patch(mk_count_at + 4 + 8, "f", float("nan")),
        "huge-camera-count": patch(34, "i", 2**31 - 1),
        "negative-point-count": patch(pts_count_at, "i", -5),
        "huge-marker-count": patch(mk_count_at, "i", 2**30),
        "duplicate-camera": patch(cams_at + 52, "i", struct.unpack_from(end + "i", data, cams_at)[0]),
        "duplicate-marker": bytes(dup),
        "truncated": data[: len(data) // 2],
        "extra-bytes": data + b"\0\0\0\0",
        "bad-magic": b"x" + data[1:],
        "normalized": data[:1] + b"N" + data[2:],
        "empty": b"",
    }
    return [Case(f"libmv/{n}", {"problem.bin": b}, source_project("libmv", "problem.bin"), names="problem.bin")
            for n, b in cases.items()]


# -- AICON ----------------------------------------------------------------------------------------

def aicon_cases() -> list[Case]:
    files = {p.suffix: p.read_text(encoding="latin-1") for p in AICON.iterdir()}

    def export(**changes):
        out = {f"ex{suffix}": text for suffix, text in files.items()}
        for suffix, text in changes.items():
            out[f"ex.{suffix}"] = text
        return out

    def first_line(suffix, new):
        lines = files[f".{suffix}"].splitlines()
        return "\n".join([new] + lines[1:]) + "\n"

    phc0 = files[".phc"].splitlines()[0].split()
    eor0 = files[".eor"].splitlines()[0].split()
    obc0 = files[".obc"].splitlines()[0].split()
    cases = {
        "phc-nan": ("phc", first_line("phc", " ".join(phc0[:2] + ["nan"] + phc0[3:]))),
        "phc-letter": ("phc", first_line("phc", " ".join(phc0[:2] + ["7.1l"] + phc0[3:]))),
        "phc-huge": ("phc", first_line("phc", " ".join(phc0[:2] + ["1e300"] + phc0[3:]))),
        "phc-short": ("phc", first_line("phc", " ".join(phc0[:3]))),
        "phc-negative-sigma": ("phc", first_line("phc", " ".join(phc0[:4] + ["-0.0001"] + phc0[5:]))),
        "phc-duplicate": ("phc", files[".phc"].splitlines()[0] + "\n" + files[".phc"]),
        "eor-nan": ("eor", first_line("eor", " ".join(eor0[:2] + ["nan"] + eor0[3:]))),
        "eor-short": ("eor", first_line("eor", " ".join(eor0[:4]))),
        "eor-duplicate": ("eor", files[".eor"].splitlines()[0] + "\n" + files[".eor"]),
        "obc-inf": ("obc", first_line("obc", " ".join(obc0[:1] + ["inf"] + obc0[2:]))),
        "obc-duplicate": ("obc", files[".obc"].splitlines()[0] + "\n" + files[".obc"]),
        "obc-letter": ("obc", first_line("obc", " ".join(["p6"] + obc0[1:]))),
        "ior-zero-c": ("ior", files[".ior"].replace("-28.78507", "0.0", 1)),
        "ior-nan-c": ("ior", files[".ior"].replace("-28.78507", "nan", 1)),
        "ior-empty": ("ior", ""),
        "scale-negative": ("scale", files[".scale"].replace("1389.6880", "-1389.6880")),
        "scale-zero-sigma": ("scale", files[".scale"].replace("0.0100", "0.0000")),
        "scale-unknown-point": ("scale", files[".scale"].replace("506", "999999", 1)),
        "binary-phc": ("phc", "\x00\x01\x02" * 50),
    }
    c = [Case(f"aicon/{n}", export(**{s: t}), source_project("aicon", "ex"), names=f"ex.{s}")
         for n, (s, t) in cases.items()]
    missing = export()
    del missing["ex.eor"]
    c.append(Case("aicon/missing-eor", missing, source_project("aicon", "ex"), names="ex.eor"))
    c += [Case(f"aicon/validate-{n}", export(**{cases[n][0]: cases[n][1]}), source_project("aicon", "ex"),
               command="validate", names=f"ex.{cases[n][0]}") for n in ("phc-nan", "eor-duplicate", "ior-zero-c")]
    return c


# -- COLMAP ---------------------------------------------------------------------------------------

def colmap_cases() -> list[Case]:
    bins = {f"model/{p.name}": p.read_bytes() for p in COLMAP.glob("*.bin")}

    def with_file(name, data):
        return {**bins, f"model/{name}": data}

    cams = bins["model/cameras.bin"]
    images = bins["model/images.bin"]
    points = bins["model/points3D.bin"]
    model_id = struct.unpack_from("<i", cams, 12)[0]

    def cam_patch(offset, fmt, value):
        b = bytearray(cams)
        struct.pack_into("<" + fmt, b, offset, value)
        return bytes(b)

    def text_model(d: Path, edit):
        import pycolmap

        rec = pycolmap.Reconstruction()
        rec.read_binary(str(COLMAP))
        (d / "model").mkdir()
        rec.write_text(str(d / "model"))
        edit(d / "model")

    def edit_cameras_txt(folder: Path, field_index: int, value: str):
        lines = (folder / "cameras.txt").read_text().splitlines()
        k = next(i for i, ln in enumerate(lines) if ln and not ln.startswith("#"))
        toks = lines[k].split()
        toks[field_index] = value
        lines[k] = " ".join(toks)
        (folder / "cameras.txt").write_text("\n".join(lines) + "\n")

    cases = {
        "truncated-images": with_file("images.bin", images[:5000]),
        "truncated-points": with_file("points3D.bin", points[: len(points) // 3]),
        "truncated-cameras": with_file("cameras.bin", cams[:20]),
        "huge-image-count": with_file("images.bin", struct.pack("<Q", 10**12) + images[8:]),
        "huge-point-count": with_file("points3D.bin", struct.pack("<Q", 10**12) + points[8:]),
        "huge-camera-count": with_file("cameras.bin", struct.pack("<Q", 10**9) + cams[8:]),
        "unknown-model": with_file("cameras.bin", cam_patch(12, "i", 99)),
        "zero-width": with_file("cameras.bin", cam_patch(16, "Q", 0)),
        "nan-focal": with_file("cameras.bin", cam_patch(32, "d", float("nan"))),
        "zero-focal": with_file("cameras.bin", cam_patch(32, "d", 0.0)),
        "negative-focal": with_file("cameras.bin", cam_patch(32, "d", -3000.0)),
        "extra-bytes": with_file("points3D.bin", points + b"\0" * 7),
        "garbage-images": with_file("images.bin", b"\xff" * 4000),
    }
    c = [Case(f"colmap/{n}", f, source_project("colmap", "model"), names="model") for n, f in cases.items()]
    missing = dict(bins)
    del missing["model/images.bin"]
    c.append(Case("colmap/missing-images", missing, source_project("colmap", "model"), names="model"))
    # the first image's name starts at byte 72 (count, id, qvec, tvec, camera id): not UTF-8 there
    c.append(Case("colmap/non-utf8-name", with_file("images.bin", images[:72] + b"\x80" + images[73:]),
                  source_project("colmap", "model"), names="name"))
    c.append(Case("colmap/text-nan-focal", {"m": lambda d: text_model(d, lambda f: edit_cameras_txt(f, 4, "nan"))},
                  source_project("colmap", "model"), names="cameras"))
    c.append(Case("colmap/text-zero-width",
                  {"m": lambda d: text_model(d, lambda f: edit_cameras_txt(f, 2, "0"))},
                  source_project("colmap", "model"), names="model"))
    c.append(Case("colmap/text-letters",
                  {"m": lambda d: text_model(d, lambda f: edit_cameras_txt(f, 5, "abc"))},
                  source_project("colmap", "model"), names="model"))
    c.append(Case("colmap/validate-truncated-images", cases["truncated-images"], source_project("colmap", "model"),
                  command="validate", names="images.bin"))
    assert model_id in range(12)
    return c


# -- images (opencv-targets) ----------------------------------------------------------------------

def targets_cases() -> list[Case]:
    import cv2

    def tiny(d: Path):
        (d / "img").mkdir()
        cv2.imwrite(str(d / "img" / "a.png"), np.zeros((1, 1), np.uint8))

    def not_images(d: Path):
        (d / "img").mkdir()
        (d / "img" / "a.png").write_text("not an image")
        (d / "img" / "b.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 20)

    def one_tiny_rest_real(d: Path):
        (d / "img").mkdir()
        cv2.imwrite(str(d / "img" / "00.png"), np.zeros((1, 1), np.uint8))
        (d / "img" / "01.png").write_text("broken")

    proj = ('[[stage]]\nuse = "opencv-targets"\nid = "source"\n[stage.options]\ntarget = "chessboard"\n'
            'images = ["img/*.png"]\nsquares = [9, 6]\nsquare_size = 25.0\n')
    return [
        Case("targets/tiny-image", {"img": tiny}, proj, names="project.toml"),
        Case("targets/not-images", {"img": not_images}, proj, names="project.toml"),
        Case("targets/validate-not-images", {"img": not_images}, proj, command="validate", names="project.toml"),
        Case("targets/tiny-and-broken", {"img": one_tiny_rest_real}, proj, names="project.toml"),
        Case("targets/no-match", {}, proj, names="project.toml"),
        Case("targets/bad-detector-params", {"p.yml": "%YAML:1.0\n---\nadaptiveThreshWinSizeMin: [1, 2\n",
                                             "img": lambda d: (d / "img").mkdir() or cv2.imwrite(
                                                 str(d / "img" / "a.png"), np.zeros((64, 64), np.uint8))},
             proj.replace('"chessboard"', '"charuco"') + 'markers = [5, 3]\nmarker_size = 18.0\n'
             'detector_params = "p.yml"\n', names="p.yml"),
    ]


# -- DBAT script projects -------------------------------------------------------------------------

DBAT_CAMCAL = SHARED / "dbat-camcal"


def dbat_cases() -> list[Case]:
    names = {"p.xml": "camcaldemo.xml", "reference/camcal-fixed.txt": "reference/camcal-fixed.txt",
             "images/images.txt": "images/images.txt", "measurements/markpts.txt": "measurements/markpts.txt"}
    files = {k: (DBAT_CAMCAL / v).read_text(encoding="utf-8") for k, v in names.items()}

    def project(**changes):
        out = dict(files)
        for key, (old, new) in changes.items():
            name = {"xml": "p.xml", "ctrl": "reference/camcal-fixed.txt", "images": "images/images.txt",
                    "marks": "measurements/markpts.txt"}[key]
            assert old in out[name], old
            out[name] = out[name].replace(old, new, 1)
        return out

    mark = " 1,    2, 1429.1871, 1456.4278, 0.1"
    cases = {
        "marks-letter": ("markpts.txt", {"marks": (mark, mark.replace("1429.1871", "14z9.1871"))}),
        "marks-nan": ("markpts.txt", {"marks": (mark, mark.replace("1429.1871", "nan"))}),
        "marks-short": ("markpts.txt", {"marks": (mark, mark.rsplit(",", 1)[0])}),
        "marks-zero-sigma": ("markpts.txt", {"marks": (mark, mark.replace("0.1", "0"))}),
        "marks-unknown-image": ("markpts.txt", {"marks": (mark, mark.replace(" 1,", " 99,", 1))}),
        "marks-twice": ("markpts.txt", {"marks": (" 1,    3, 1217.8557", " 1,    2, 1217.8557")}),
        "marks-far-outside": ("markpts.txt", {"marks": (mark, mark.replace("1429.1871", "91429.1871"))}),
        "marks-binary": ("markpts.txt", {"marks": (files["measurements/markpts.txt"], "\x00\xff\xfe" * 40)}),
        "ctrl-duplicate": ("camcal-fixed.txt", {"ctrl": ("1002,CP2", "1001,CP2")}),
        "ctrl-letter": ("camcal-fixed.txt", {"ctrl": ("1002,CP2,1,1,0", "1002,CP2,1,one,0")}),
        "ctrl-inf": ("camcal-fixed.txt", {"ctrl": ("1002,CP2,1,1,0", "1002,CP2,inf,1,0")}),
        "images-duplicate": ("images.txt", {"images": (" 2, data", " 1, data")}),
        "images-empty": ("images.txt", {"images": (files["images/images.txt"], "# nothing\n")}),
        "xml-malformed": ("p.xml", {"xml": ("<operation>spatial_resection</operation>",
                                            "<operation>spatial_resection</operation")}),
        "xml-not-dbat": ("p.xml", {"xml": (files["p.xml"], "<?xml version='1.0'?>\n<project/>\n")}),
        "xml-lens-model": ("p.xml", {"xml": ("<model>3</model>", "<model>1</model>")}),
        "xml-unknown-column": ("p.xml", {"xml": ('format="id,label,x,y,z"', 'format="id,label,x,y,q"')}),
        "xml-no-sigma": ("p.xml", {"xml": ('format="im,id,x,y,sxy"', 'format="im,id,x,y"')}),
        "xml-missing-file": ("p.xml", {"xml": ("reference/camcal-fixed.txt", "reference/nowhere.txt")}),
        "xml-negative-sensor": ("p.xml", {"xml": ("<sensor>auto,5.43764</sensor>", "<sensor>auto,-5.4</sensor>")}),
        "xml-zero-focal": ("p.xml", {"xml": ("<focal>7.5</focal>", "<focal>0</focal>")}),
        "xml-image-size": ("p.xml", {"xml": ("<image>2272,1704</image>", "<image>2272.5,1704</image>")}),
        "xml-bad-flag": ("p.xml", {"xml": ("<skew>false</skew>", "<skew>nope</skew>")}),
        "xml-unknown-io": ("p.xml", {"xml": ("<skew>false</skew>", "<lens>false</lens>")}),
        "xml-filter-unknown": ("p.xml", {"xml": ("</ctrl_pts>", '<filter id="7777">keep</filter></ctrl_pts>')}),
        "xml-dbat-dir": ("p.xml", {"xml": ('<input base_dir="$HERE">', '<input base_dir="$DBAT/x">')}),
        "xml-min-rays": ("p.xml", {"xml": ('min_rays="2"', 'min_rays="two"')}),
        "xml-two-cameras": ("p.xml", {"xml": ("</cameras>", "<camera><sensor>1,1</sensor></camera></cameras>")}),
    }
    c = [Case(f"dbat/{n}", project(**ch), source_project("dbat", "p.xml"), names=f) for n, (f, ch) in cases.items()]
    not_utf8 = dict(files)
    not_utf8["measurements/markpts.txt"] = files["measurements/markpts.txt"].encode("utf-8") + b"\xff\xfe 1, 2\n"
    c.append(Case("dbat/marks-not-utf8", not_utf8, source_project("dbat", "p.xml"), names="markpts.txt"))
    c.append(Case("dbat/no-path", files, '[[stage]]\nuse = "dbat"\nid = "source"\n', names="project.toml"))
    c.append(Case("dbat/missing-xml", files, source_project("dbat", "nowhere.xml"), names="nowhere.xml"))
    c += [Case(f"dbat/validate-{n}", project(**cases[n][1]), source_project("dbat", "p.xml"), command="validate",
               names=cases[n][0]) for n in ("marks-letter", "xml-malformed", "ctrl-duplicate")]
    # initial orientations (<prior_eo>, what dbat-export writes)
    eo_xml = files["p.xml"].replace("</image_pts>", '</image_pts>\n<prior_eo><file format="id,x,y,z,omega,phi,kappa" '
                                    'units="degrees">prior/eo.txt</file></prior_eo>', 1) \
        .replace("<all>default</all>\n        </io>", "<all>default</all>\n        </io>\n        <eo>loaded</eo>", 1)
    assert "<eo>loaded</eo>" in eo_xml
    eo_row = "1, 0.1, 0.2, 0.9, 180, 0, 0"
    eo_ok = {**files, "p.xml": eo_xml, "prior/eo.txt": eo_row + "\n"}
    eo_cases = {
        "eo-letter": ("eo.txt", {"prior/eo.txt": eo_row.replace("180", "1 80") + "\n"}),
        "eo-unknown-image": ("eo.txt", {"prior/eo.txt": eo_row.replace("1,", "99,", 1) + "\n"}),
        "eo-twice": ("eo.txt", {"prior/eo.txt": eo_row + "\n" + eo_row + "\n"}),
        "eo-no-units": ("p.xml", {"p.xml": eo_xml.replace(' units="degrees"', "")}),
        "eo-loaded-without-file": ("p.xml", {"p.xml": files["p.xml"].replace(
            "<all>default</all>\n        </io>", "<all>default</all>\n        </io>\n        <eo>loaded</eo>", 1)}),
    }
    c += [Case(f"dbat/{n}", {**eo_ok, **ch}, source_project("dbat", "p.xml"), names=f) for n, (f, ch) in eo_cases.items()]
    return c


# -- ODM gcp_list.txt and GNSS centres (gcp-list, gnss-centres) -----------------------------------

ODM_GCP = SHARED / "odm-br-gcp"


def gcp_cases() -> list[Case]:
    text = (ODM_GCP / "gcp_list_floatxy_raw.txt").read_text(encoding="utf-8")
    lines = text.splitlines()
    camera = ('camera = { width = 4000, height = 3000, focal_px = 2904.0, sensor_width_mm = 6.17 }\n'
              'skip_lines = [19, 51, 52, 55, 70]\n')

    def with_line(k, new):
        out = list(lines)
        out[k - 1] = new
        return "\n".join(out) + "\n"

    l2 = lines[1].split()
    broken = {
        "letter": with_line(2, " ".join(l2[:3] + ["24x0.6"] + l2[4:])),
        "nan": with_line(2, " ".join(l2[:4] + ["nan"] + l2[5:])),
        "short": with_line(2, " ".join(l2[:5])),
        "conflicting-target": with_line(3, " ".join(["658528.5"] + lines[2].split()[1:])),
        "no-crs": "\n".join(lines[1:]) + "\n",
        "unknown-crs": with_line(1, "+proj=nowhere +zone=99"),
        "bad-utm-zone": with_line(1, "WGS84 UTM 75S"),
        "outside-image": with_line(2, " ".join(l2[:3] + ["4100.0"] + l2[4:])),
        "only-crs": lines[0] + "\n",
        "binary": "\x00\xff\xfe" * 40,
    }
    c = [Case(f"gcp/{n}", {"gcp_list.txt": t}, source_project("gcp-list", "gcp_list.txt", camera),
              names="gcp_list.txt") for n, t in broken.items()]
    c.append(Case("gcp/missing", {}, source_project("gcp-list", "nowhere.txt", camera), names="nowhere.txt"))
    c.append(Case("gcp/no-camera", {"gcp_list.txt": text},
                  source_project("gcp-list", "gcp_list.txt", "skip_lines = [19, 51, 52, 55, 70]"), names="project.toml"))
    c.append(Case("gcp/skip-not-a-line", {"gcp_list.txt": text},
                  source_project("gcp-list", "gcp_list.txt", camera.replace("70]", "700]")), names="gcp_list.txt"))
    c.append(Case("gcp/validate-letter", {"gcp_list.txt": broken["letter"]},
                  source_project("gcp-list", "gcp_list.txt", camera), command="validate", names="gcp_list.txt"))
    gnss_stage = '[[stage]]\nuse = "gnss-centres"\nid = "gnss"\n[stage.options]\npath = "gnss.csv"\n'
    good = "# crs: EPSG:32722\nphoto,E,N,h,sigma\nIMG_5350.JPG,658530.0,7167000.0,965.0,0.05\n"
    gnss = {
        "gnss-letter": good.replace("965.0", "96x"),
        "gnss-no-photo-column": good.replace("photo,", "image,"),
        "gnss-no-coordinates": good.replace("E,N,h", "a,b,c"),
        "gnss-unknown-photo": good.replace("IMG_5350", "IMG_9999"),
        "gnss-zero-sigma": good.replace(",0.05", ",0"),
        "gnss-twice": good + "IMG_5350.JPG,658530.0,7167000.0,965.0,0.05\n",
        "gnss-bad-crs": good.replace("EPSG:32722", "EPSG:0"),
        "gnss-short": good.replace(",965.0,0.05", ""),
    }
    c += [Case(f"gcp/{n}", {"gcp_list.txt": text, "gnss.csv": t},
               source_project("gcp-list", "gcp_list.txt", camera) + gnss_stage, names="gnss.csv",
               earlier=["source_targets.csv"]) for n, t in gnss.items()]
    return c


# -- options (types and ranges) -------------------------------------------------------------------

def option_cases() -> list[Case]:
    c = []
    bad = {
        "sigma0-nan": "sigma0_mm = nan", "sigma0-inf": "sigma0_mm = inf", "sigma0-zero": "sigma0_mm = 0.0",
        "sigma0-negative": "sigma0_mm = -0.2", "sigma0-string": 'sigma0_mm = "0.2"', "alpha-one": "alpha0 = 1.0",
        "alpha-negative": "alpha0 = -0.001", "beta-big": "beta0 = 80.0", "threshold-zero": "threshold_mm = 0.0",
        "flag-by-unknown": 'flag_by = ["pope", "astrology"]', "action-bad": 'action = "delete"',
        "bool-as-string": 'detect_swaps = "no"', "bool-as-int": "detect_swaps = 1",
        "unknown-option": "sigma0 = 0.2", "old-name": "deactivate = true", "arrow-negative": "arrow_scale = -1.0",
        "list-for-number": "alpha_pope = [0.001]", "table-for-number": "alpha_pope = { a = 1 }",
    }
    for name, line in bad.items():
        c.append(Case(f"options/screening-{name}", {"data.cmp": DATA1},
                      comparator_project(SCREENING + line + "\n"), names="project.toml"))
    bundle_bad = {
        "max-iter-zero": "max_iter = 0", "max-iter-float": "max_iter = 2.5", "tol-negative": "tol_obs = -1e-5",
        "sigma-table-negative": 'ap_model = "brown"\nsigma = { K1 = -0.1 }', "sigma-table-nan": 'sigma = { c = nan }',
        "sigma-eo-inf": "sigma_eo = [inf, 1, 1, 1, 1, 1]", "distance-negative":
            'distances = [{ from = "1", to = "2", distance = -1.0, sigma = 0.1 }]',
        "distance-sigma-zero": 'distances = [{ from = "1", to = "2", distance = 1.0, sigma = 0.0 }]',
        "datum-bad": 'datum = "somewhere"', "rho-max-big": "rho_max = 2.0", "scale-zero": "sigma_image_scale = 0.0",
        "covariance-string": 'covariance = "yes"',
    }
    for name, line in bundle_bad.items():
        c.append(Case(f"options/bundle-{name}", {"data.cmp": DATA1},
                      comparator_project('[[stage]]\nuse = "bundle"\n[stage.options]\n' + line + "\n"),
                      names="project.toml"))
    source_bad = {
        "bal-pixel-zero": source_project("bal", "p.txt", "pixel_mm = 0.0"),
        "bal-sigma-negative": source_project("bal", "p.txt", "sigma_px = -1.0"),
        "bal-sigma-nan": source_project("bal", "p.txt", "sigma_px = nan"),
        "libmv-resolution-zero": source_project("libmv", "p.bin", "resolution = [0, 480]"),
        "colmap-sensor-negative": source_project("colmap", "m", "sensor_width_mm = -1.0"),
        "aicon-sigma-zero": source_project("aicon", "ex", "sigma_image_um = 0.0"),
        "aicon-perturb-negative": source_project("aicon", "ex", "perturb = { sigma_position = -5.0 }"),
        "comparator-tol-zero": comparator_project(options="tol_io_um = 0.0"),
        "comparator-transform-bad": comparator_project(options='transform = "projective"'),
        "testfield-case-bad": '[[stage]]\nuse = "testfield"\n[stage.options]\ncase = 9\n',
        "testfield-sigma-inf": '[[stage]]\nuse = "testfield"\n[stage.options]\nsigma_image_um = inf\n',
        "testfield-blunder-bad": '[[stage]]\nuse = "testfield"\n[stage.options]\nblunders = [{ photo = "1" }]\n',
        "render-folder-absolute": '[[stage]]\nuse = "testfield-render"\n[stage.options]\nfolder = "/tmp/x"\n',
        "render-folder-climbs": '[[stage]]\nuse = "testfield-render"\n[stage.options]\nfolder = "../../x"\n',
        "render-supersample-zero": '[[stage]]\nuse = "testfield-render"\n[stage.options]\nsupersample = 0\n',
        "export-absolute": comparator_project('[[stage]]\nuse = "colmap-export"\n[stage.options]\npath = "/tmp/m"\n'),
        "export-climbs": comparator_project('[[stage]]\nuse = "colmap-export"\n[stage.options]\npath = "../m"\n'),
        "targets-min-points-string": '[[stage]]\nuse = "opencv-targets"\n[stage.options]\nmin_points = "4"\n',
        "blunders-n-sim-negative": comparator_project('[[stage]]\nuse = "blunder-rejection"\n[stage.options]\n'
                                                      'n_sim = -1\n'),
        "blunders-method-bad": comparator_project('[[stage]]\nuse = "blunder-rejection"\n[stage.options]\n'
                                                  'method = "magic"\n'),
    }
    for name, proj in source_bad.items():
        c.append(Case(f"options/{name}", {"data.cmp": DATA1}, proj, names="project.toml"))
        if name in ("bal-sigma-nan", "render-folder-climbs", "export-absolute"):
            c.append(Case(f"options/validate-{name}", {"data.cmp": DATA1}, proj, command="validate",
                          names="project.toml"))
    return c


# -- the project file -----------------------------------------------------------------------------

def project_cases() -> list[Case]:
    good = comparator_project()
    bad = {
        "not-toml": "[[stage]\nuse = 1\n",
        "no-stage": "[project]\nname = 'x'\n",
        "unknown-stage": '[[stage]]\nuse = "helmert"\n',
        "use-missing": "[[stage]]\nid = 'x'\n",
        "use-number": "[[stage]]\nuse = 3\n",
        "enabled-string": good.replace('id = "source"', 'id = "source"\nenabled = "no"'),
        "enabled-int": good.replace('id = "source"', 'id = "source"\nenabled = 0'),
        "id-twice": good + good,
        "id-bad": good.replace('id = "source"', 'id = "a b"'),
        "reads-nothing": '[[stage]]\nuse = "bundle"\n',
        "unknown-table": "[projekt]\nname = 'x'\n" + good,
        "unknown-project-key": "[project]\nnam = 'x'\n" + good,
        "seed-float": "[project]\nseed = 1.5\n" + good,
        "unit-bad": "[project]\nobject_unit = 'furlong'\n" + good,
        "options-not-table": '[[stage]]\nuse = "comparator"\noptions = 3\n',
        "stage-unknown-key": good.replace('id = "source"', 'id = "source"\ncolour = "red"'),
        "path-missing": good.replace("data.cmp", "nothere.cmp"),
    }
    c = [Case(f"project/{n}", {"data.cmp": DATA1}, p, names="project.toml") for n, p in bad.items()]
    c += [Case(f"project/validate-{n}", {"data.cmp": DATA1}, bad[n], command="validate", names="project.toml")
          for n in ("not-toml", "enabled-string", "reads-nothing", "path-missing")]
    c.append(Case("project/not-utf8", {"data.cmp": DATA1, "project.toml": b"[project]\nname = '\xff\xfe'\n"},
                  "", names="project.toml"))
    c.append(Case("project/binary", {"data.cmp": DATA1, "project.toml": bytes(range(256))}, "", names="project.toml"))
    c.append(Case("project/missing", {"project.toml": lambda d: None}, "", names="project.toml"))
    c.append(Case("project/directory", {"project.toml": lambda d: (d / "project.toml").mkdir()}, "",
                  names="project.toml"))
    return c


# -- run directories, later stages, review --------------------------------------------------------

def run_cases() -> list[Case]:
    good = comparator_project(SCREENING)

    def foreign(d: Path):
        (d / "out").mkdir()
        (d / "out" / "thesis.docx").write_text("precious")

    def blocker(d: Path):
        (d / "out").write_text("a file")

    def old_run_with_notes(d: Path):
        (d / "out").mkdir()
        (d / "out" / "results.json").write_text(json.dumps({"baarda_version": "0", "stages": [], "ok": True,
                                                            "files": ["results.json"]}))
        (d / "out" / "notes.txt").write_text("mine")

    c = [
        Case("run/out-is-foreign", {"data.cmp": DATA1, "o": foreign}, good, names="out"),
        Case("run/out-is-a-file", {"data.cmp": DATA1, "o": blocker}, good, names="out"),
        Case("run/out-has-user-file", {"data.cmp": DATA1, "o": old_run_with_notes}, good, names="notes.txt"),
        Case("run/out-under-a-file", {"data.cmp": DATA1, "o": blocker}, good, out="out/run", names="out"),
        # a later stage fails: the earlier stages' files are kept
        Case("run/later-stage-unsolvable", {"data.cmp": DATA1},
             comparator_project('[[stage]]\nuse = "bundle"\n'), code=1, names="",
             earlier=["source_observations.csv"]),
        Case("run/screening-too-few", {"data.cmp": DATA1.replace("photo R", "photo R\n").split("pt  4")[0]},
             comparator_project(SCREENING), names="", earlier=["source_observations.csv"]),
    ]

    def corrupt_results(d: Path):
        (d / "r").mkdir()
        (d / "r" / "results.json").write_text("{not json")
        (d / "r" / "a.rrd").write_bytes(b"RRF2" + b"\0" * 30)

    def corrupt_rrd(d: Path):
        (d / "r").mkdir()
        (d / "r" / "a.rrd").write_bytes(b"\xff" * 100)

    def binary_results(d: Path):
        (d / "r").mkdir()
        (d / "r" / "results.json").write_bytes(b"\xff\xfe\x00")
        (d / "r" / "a.rrd").write_bytes(b"\xff" * 100)

    c += [
        Case("review/corrupt-results", {"r": corrupt_results}, command="review", names="results.json"),
        Case("review/corrupt-rrd", {"r": corrupt_rrd}, command="review", names="a.rrd"),
        Case("review/binary-results", {"r": binary_results}, command="review", names="results.json"),
        Case("review/missing", {}, command="review", names="r"),
        Case("review/empty", {"r": lambda d: (d / "r").mkdir()}, command="review", names="r"),
    ]
    return c


# -- every option of every installed stage (generated from the options' declarations) -----------

BAD_VALUES = {
    "float": ["nan", "inf", "1e300", "1e-320", '"text"'],
    "int": ["2.5", "9223372036854775808", '"text"'],
    "bool": ['"maybe"', "2"],
    "literal": ['"no-such-choice"', "42"],
}


def _kind(tp: str) -> str | None:
    t = tp.replace(" | NoneType", "")
    if t in ("float", "int", "bool"):
        return t
    if t.startswith("'") and "|" in t:
        return "literal"
    return None


def _stage_project(use: str, reads_block: bool, line: str, sid: str = "under_test") -> str:
    stage = f'[[stage]]\nuse = "{use}"\nid = "{sid}"\n[stage.options]\n{line}\n'
    return comparator_project(stage) if reads_block else stage


def generated_option_cases() -> list[Case]:
    """A bad value for every number, flag and choice of every installed stage's options: in the
    project file (validate), and a share of them through ``--set`` (validate and run)."""
    from baarda.pipeline.options import describe
    from baarda.pipeline.plugins import PluginManager

    c, k = [], 0
    for info in PluginManager():
        reads_block = bool(info.cls.reads) and info.name != "comparator"
        for o in describe(info.cls.Options):
            kind = _kind(o["type"])
            if kind is None:
                continue
            for value in BAD_VALUES[kind]:
                k += 1
                name = f"{info.name}-{o['name']}={value.strip(chr(34))[:12]}"
                line = f"{o['name']} = {value}"
                c.append(Case(f"stage-options/{name}", {"data.cmp": DATA1}, _stage_project(info.name, reads_block, line),
                              command="validate", names="project.toml", quick=k % 60 == 0))
                if value in ("nan", "2.5", '"maybe"', '"no-such-choice"'):
                    c.append(Case(f"set/{name}", {"data.cmp": DATA1},
                                  _stage_project(info.name, reads_block, ""), command="validate" if k % 2 else "run",
                                  names="--set", extra_args=["--set", f"under_test.{o['name']}={value}"],
                                  quick=k % 60 == 1))
    return c


WRITERS = ["export", "aicon-export", "bal-export", "colmap-export", "comparator-export", "gcp-export",
           "libmv-export", "dbat-export"]
BAD_OUTPUTS = ["", ".", "./", "a/..", "../x", "/tmp/x", "~/x", "results.json", "project.resolved.toml",
               "source.rrd", "report.md", "under_test.error.txt"]


def writer_stages() -> list[str]:
    """WRITERS and every other installed stage whose option ``path`` is an output (by its
    declaration, whatever the stage is named: a new writer joins the corpus by itself)."""
    from baarda.pipeline.plugins import PluginManager
    from baarda.pipeline.project import path_roles

    pm = PluginManager()
    found = [n for n in pm.names() if path_roles(pm.get(n).cls).get("path") == "output"]
    return WRITERS + sorted(set(found) - set(WRITERS))


def writer_cases() -> list[Case]:
    """Every writer with every kind of output path that must not be written (validate and run)."""
    from baarda.pipeline.plugins import PluginManager

    c = []
    for use in writer_stages():
        cls = PluginManager().get(use).cls         # every writer is installed: a missing one fails here
        adds = getattr(cls, "output_adds", {}).get("path", ("",))
        prefix = adds != ("",)
        for k, bad in enumerate(BAD_OUTPUTS):
            if prefix and "." in bad.strip("./~") and not bad.startswith(("/", "~", "..")):
                continue        # a prefix writer makes results.json.ply: its own file
            proj = _stage_project(use, True, f'path = "{bad}"')
            c.append(Case(f"writers/{use}-{bad or 'empty'}", {"data.cmp": DATA1}, proj,
                          command="validate" if k % 2 else "run", names="field 'path'", quick=k % 4 == 0))
        if prefix and ".csv" not in adds:
            continue            # its files (.ior …) cannot be a table's
        c.append(Case(f"writers/{use}-collides-with-a-table", {"data.cmp": DATA1},
                      _stage_project(use, True, 'path = "source_observations"' if prefix
                                     else 'path = "source_observations.csv"'),
                      names="field 'path'", quick=use == "colmap-export"))
        c.append(Case(f"writers/{use}-collides-with-a-later-table", {"data.cmp": DATA1},
                      _stage_project(use, True, 'path = "later_observations"' if prefix
                                     else 'path = "later_observations.csv"') + SCREENING.replace('"screening"', '"later"'),
                      command="validate", names="stage 'later'", quick=use == "export"))
    return c


def batch_cases() -> list[Case]:
    """Sweep tables: names given twice (as their folders would be named), unknown columns, bad
    values, empty tables — refused with the table's line before anything runs."""
    base = comparator_project(SCREENING)
    tables = {
        "duplicate-name": "name,screening.alpha0\nok,0.01\nok,0.02\n",
        "duplicate-after-sanitising": "name,screening.alpha0\na/b,0.01\na b,0.02\n",
        "unknown-column": "screening.alpha,0.01\n0.01\n",
        "bad-value": "screening.alpha0\n2.0\n",
        "nan-value": "screening.alpha0\nnan\n",
        "empty": "",
        "no-rows": "screening.alpha0\n",
        "cells-missing": "name,screening.alpha0\nx\n",
        "cells-missing-of-two": "name,screening.alpha0,screening.threshold_mm\na,0.01,5\nb,0.02\n",
        "cells-too-many": "name,screening.alpha0\na,0.01,7\n",
        "unknown-stage": "bundle.max_iter\n3\n",
        "project-missing": "project,screening.alpha0\nnope.toml,0.01\n",
        "project-folder": "project,screening.alpha0\n.,0.01\n",
        "project-not-toml": "project,screening.alpha0\ndata.cmp,0.01\n",
        "project-stage-missing": "project,bundle.max_iter\nproject.toml,3\n",
    }
    return [Case(f"batch/{n}", {"data.cmp": DATA1, "sweep.csv": t}, base, command="batch", names="sweep.csv",
                 out="bout") for n, t in tables.items()]


def hardening_cases() -> list[Case]:
    """Issue 27: XML bombs and external entities, images whose header claims too many pixels,
    COLMAP text models pycolmap refuses, text a reader must not take."""
    import cv2
    import struct as _st
    import zlib

    names = {"p.xml": "camcaldemo.xml", "reference/camcal-fixed.txt": "reference/camcal-fixed.txt",
             "images/images.txt": "images/images.txt", "measurements/markpts.txt": "measurements/markpts.txt"}
    files = {k: (DBAT_CAMCAL / v).read_text(encoding="utf-8") for k, v in names.items()}
    laughs = ('<?xml version="1.0"?>\n<!DOCTYPE lolz [\n <!ENTITY lol "lol">\n'
              + "".join(f' <!ENTITY lol{k} "{("&lol" + (str(k - 1) if k > 1 else "") + ";") * 10}">\n'
                        for k in range(1, 10)) + ']>\n<document dbat_script_version="1.0.0"><c>&lol9;</c></document>\n')
    external = ('<?xml version="1.0"?>\n<!DOCTYPE d [\n <!ENTITY x SYSTEM "file:///etc/passwd">\n]>\n'
                '<document dbat_script_version="1.0.0"><c>&x;</c></document>\n')
    c = []
    for cmd in ("run", "validate"):
        c.append(Case(f"dbat/billion-laughs-{cmd}", {**files, "p.xml": laughs}, source_project("dbat", "p.xml"),
                      command=cmd, names="p.xml:3"))
        c.append(Case(f"dbat/external-entity-{cmd}", {**files, "p.xml": external}, source_project("dbat", "p.xml"),
                      command=cmd, names="p.xml:3"))

    def png(w, h):
        def chunk(kind, data):
            return _st.pack(">I", len(data)) + kind + data + _st.pack(">I", zlib.crc32(kind + data))
        return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", _st.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
                + chunk(b"IDAT", zlib.compress(b"\0" * 100)) + chunk(b"IEND", b""))

    proj = ('[[stage]]\nuse = "opencv-targets"\nid = "source"\n[stage.options]\ntarget = "chessboard"\n'
            'images = ["img/*.png"]\nsquares = [9, 6]\nsquare_size = 25.0\n')
    for w, h in ((200_000, 200_000), (1_000_000, 300), (65_535, 65_535)):
        c.append(Case(f"targets/huge-header-{w}x{h}", {"img/a.png": png(w, h)}, proj, names="a.png"))
    c.append(Case("targets/missing-listed-image",
                  {"img": lambda d: (d / "img").mkdir() or cv2.imwrite(str(d / "img" / "a.png"),
                                                                      np.zeros((64, 64), np.uint8))},
                  proj.replace('["img/*.png"]', '["img/a.png", "img/gone.png"]'), names="project.toml"))

    def text_model(d: Path, fname, fn):
        import pycolmap

        rec = pycolmap.Reconstruction()
        rec.read_binary(str(COLMAP))
        (d / "model").mkdir()
        rec.write_text(str(d / "model"))
        f = d / "model" / fname
        lines = f.read_text().splitlines()
        k = next(i for i, ln in enumerate(lines) if ln and not ln.startswith("#"))
        t = lines[k].split(" ")
        fn(t)
        lines[k] = " ".join(t)
        f.write_text("\n".join(lines) + "\n")

    edits = {"images-nan-pose": ("images.txt", lambda t: t.__setitem__(5, "nan")),
             "images-bad-number": ("images.txt", lambda t: t.__setitem__(1, "0.7x")),
             "images-missing-camera": ("images.txt", lambda t: t.__setitem__(8, "999")),
             "points-inf": ("points3D.txt", lambda t: t.__setitem__(2, "inf")),
             "points-track-missing-image": ("points3D.txt", lambda t: t.__setitem__(8, "99999")),
             "points-track-missing-2d": ("points3D.txt", lambda t: t.__setitem__(9, "999999"))}
    for n, (fname, fn) in edits.items():
        c.append(Case(f"colmap/text-{n}", {"m": lambda d, fname=fname, fn=fn: text_model(d, fname, fn)},
                      source_project("colmap", "model"), names=f"{fname}:"))
    gnss_stage = '[[stage]]\nuse = "gnss-centres"\nid = "gnss"\n[stage.options]\npath = "gnss.csv"\n'
    good = "# crs: EPSG:32722\nphoto,E,N,h,sigma\nIMG_5350.JPG,658530.0,7167000.0,965.0,0.05\n"
    text = (ODM_GCP / "gcp_list_floatxy_raw.txt").read_text(encoding="utf-8")
    camera = ('camera = { width = 4000, height = 3000, focal_px = 2904.0, sensor_width_mm = 6.17 }\n'
              'skip_lines = [19, 51, 52, 55, 70]\n')
    c.append(Case("gcp/gnss-extra-field", {"gcp_list.txt": text, "gnss.csv": good.replace(",0.05", ",0.05,1")},
                  source_project("gcp-list", "gcp_list.txt", camera) + gnss_stage, command="validate",
                  names="gnss.csv:3"))
    c.append(Case("gcp/not-utf8", {"gcp_list.txt": text.encode("utf-8").replace(b"IMG_5352", b"IMG_\xe95352", 1)},
                  source_project("gcp-list", "gcp_list.txt", camera), names="gcp_list.txt:"))
    c.append(Case("bal/utf8", {"problem.txt": BAL_FILE.read_text().replace("\n", " # café\n", 3)},
                  source_project("bal", "problem.txt"), names="problem.txt:"))
    return c


FIDUCIAL_CMP = """\
unit um
mode fiducial
transform affine
camera C c 152.0 format 230 230
fiducial A -110 -110
fiducial B  110 -110
fiducial C  110  110
fiducial D -110  110
photo 1
fid A  40000  40000
fid B 150000  40000
fid C 260000  40000
fid D 370000  40002
pt 10 150000 150000
"""


def round_two_cases() -> list[Case]:
    """Issue 27, second round: the inputs that were accepted or misreported (swapped DBAT format, a
    libmv rotation that is not one, collinear fiducials, coordinates beyond any comparator, gcp lists
    no photo of which can be resected, GNSS heights in mm, RRR's rho beyond the redundancy)."""
    c = []
    right = DATA1.splitlines()
    k0 = next(i for i, ln in enumerate(right) if ln.startswith("photo R"))
    for i in range(k0 + 1, len(right)):
        if right[i].startswith("pt"):
            t = right[i].split()
            right[i] = " ".join(t[:2] + ["1e200"] + t[3:])
    c.append(Case("comparator/right-x-1e200", {"data.cmp": "\n".join(right) + "\n"},
                  source_project("comparator", "data.cmp"), names=f"data.cmp:{k0 + 2}, field 'x'"))
    c.append(Case("comparator/collinear-fiducials", {"data.cmp": FIDUCIAL_CMP}, source_project("comparator", "data.cmp"),
                  names="data.cmp:10, field 'fid'"))
    c.append(Case("comparator/collinear-fiducials-validate", {"data.cmp": FIDUCIAL_CMP},
                  source_project("comparator", "data.cmp"), command="validate", names="data.cmp:10, field 'fid'"))
    data = bytearray(LIBMV_FILE.read_bytes())
    for d in (0, 4, 8):                               # camera record 0: image i4, R 9 × f4 (column-major), t
        data[38 + 4 + 4 * d:38 + 8 + 4 * d] = struct.pack("<f" if data[:1] == b"v" else ">f", 0.0)
    c.append(Case("libmv/zero-diagonal-rotation", {"problem.bin": bytes(data)}, source_project("libmv", "problem.bin"),
                  names="problem.bin, field 'cameras.R'"))
    names = {"p.xml": "camcaldemo.xml", "reference/camcal-fixed.txt": "reference/camcal-fixed.txt",
             "images/images.txt": "images/images.txt", "measurements/markpts.txt": "measurements/markpts.txt"}
    files = {k: (DBAT_CAMCAL / v).read_text(encoding="utf-8") for k, v in names.items()}
    line = next(i for i, ln in enumerate(files["p.xml"].splitlines(), 1) if 'format="im,id,x,y,sxy"' in ln)
    files["p.xml"] = files["p.xml"].replace('format="im,id,x,y,sxy"', 'format="im,id,y,x,sxy"')
    for cmd in ("run", "validate"):
        c.append(Case(f"dbat/format-x-y-swapped-{cmd}", files, source_project("dbat", "p.xml"), command=cmd,
                      names=f"p.xml:{line}, field 'format'"))
    text = (ODM_GCP / "gcp_list_floatxy_raw.txt").read_text(encoding="utf-8")
    camera = ('camera = { width = 4000, height = 3000, focal_px = 2904.0, sensor_width_mm = 6.17 }\n'
              'skip_lines = [19, 51, 52, 55, 70]\n')
    c.append(Case("gcp/no-photo-resectable", {"gcp_list.txt": text},
                  source_project("gcp-list", "gcp_list.txt", camera + 'min_points = 500\ncheck = ["NOPE"]\n'),
                  names="no photo can be resected"))
    gnss_stage = '[[stage]]\nuse = "gnss-centres"\nid = "gnss"\n[stage.options]\npath = "gnss.csv"\n'
    mm = "# crs: EPSG:32722\nphoto,E,N,h,sigma\nIMG_5350.JPG,658530.0,7167000.0,965000.0,0.05\n"
    for cmd in ("run", "validate"):
        c.append(Case(f"gcp/gnss-heights-in-mm-{cmd}", {"gcp_list.txt": text, "gnss.csv": mm},
                      source_project("gcp-list", "gcp_list.txt", camera) + gnss_stage, command=cmd,
                      names="gnss.csv:3, field 'h'", earlier=["source_targets.csv"] if cmd == "run" else []))
    c.append(Case("options/rrr-rho-beyond-redundancy", {"data.cmp": DATA1},
                  comparator_project(SCREENING + '[[stage]]\nuse = "blunder-rejection"\nid = "blunders"\n'
                                     '[stage.options]\nmethod = "rrr"\nrho = 36\n'),
                  command="validate", names="field 'rho'"))
    return c


# -- the readers with corpora of their own: PhotoModeler exports, Metashape XML, OpenSfM -------------

CORPORA = Path(__file__).resolve().parent


def _corpus_cases(reader: str) -> dict:
    """``CASES`` of ``tests/corpus/<reader>/cases.py`` (read as a file: each corpus has one)."""
    import runpy

    return runpy.run_path(str(CORPORA / reader / "cases.py"))["CASES"]


def reader_corpus_cases() -> list[Case]:
    """The broken files of the pmexport, metashape and opensfm corpora through the source stage, in
    ``validate`` and ``run``: the message names the file, the line (where the corpus gives one) and
    the field."""
    c = []
    pm = CORPORA / "pmexport"
    control = (pm / "control.txt").read_bytes()
    for k, (name, (line, fld)) in enumerate(sorted(_corpus_cases("pmexport").items())):
        where = f"export.txt:{line}, field '{fld}'" if line is not None else "export.txt"
        for cmd in ("validate", "run"):
            c.append(Case(f"pmexport/{name}-{cmd}", {"export.txt": (pm / f"{name}.txt").read_bytes(),
                                                     "control.txt": control},
                          source_project("pmexport", "export.txt", 'control = "control.txt"'), command=cmd,
                          names=where, also=f"field '{fld}'", quick=k % 4 == 0))
    for name, line, fld in (("control-columns", 1, "x"), ("control-sigma", 1, "sxyz"), ("control-id", 1, "id")):
        c.append(Case(f"pmexport/{name}", {"export.txt": (pm / "mini.txt").read_bytes(),
                                           "control.txt": (pm / f"{name}.txt").read_bytes()},
                      source_project("pmexport", "export.txt", 'control = "control.txt"'), command="validate",
                      names=f"control.txt:{line}, field '{fld}'", quick=name == "control-id"))
    ms = CORPORA / "metashape"
    for k, (name, (file, fld)) in enumerate(sorted(_corpus_cases("metashape").items())):
        for cmd in ("validate", "run"):
            c.append(Case(f"metashape/{name}-{cmd}", {"cams.xml": (ms / file).read_bytes()},
                          source_project("metashape", "cams.xml"), command=cmd, names="cams.xml",
                          also=f"{fld}'", quick=k % 4 == 0))
    osfm = CORPORA / "opensfm"
    for k, (name, (file, line, fld)) in enumerate(sorted(_corpus_cases("opensfm").items())):
        tracks = file.endswith(".tracks.csv")
        files = {"rec.json": (osfm / ("mini.json" if tracks else file)).read_bytes(),
                 "rec.tracks.csv": (osfm / (file if tracks else "mini.tracks.csv")).read_bytes()}
        broken = "rec.tracks.csv" if tracks else "rec.json"
        where = f"{broken}:{line}" if line is not None else broken
        for cmd in ("validate", "run"):
            c.append(Case(f"opensfm/{name}-{cmd}", files,
                          source_project("opensfm", "rec.json", 'tracks = "rec.tracks.csv"'), command=cmd,
                          names=where, also=f"{fld}'", quick=k % 4 == 0))
    return c


def all_cases() -> list[Case]:
    return (comparator_cases() + bal_cases() + aicon_cases() + colmap_cases() + targets_cases()
            + dbat_cases() + gcp_cases() + option_cases() + project_cases() + run_cases()
            + generated_option_cases() + writer_cases() + batch_cases() + hardening_cases() + round_two_cases()
            + reader_corpus_cases())


# -- running a case -------------------------------------------------------------------------------

@dataclass
class Outcome:
    code: int
    out: str
    err: str
    folder: Path
    before: dict
    after: dict


def _snapshot(folder: Path) -> dict:
    """Every file below the case folder, with its bytes."""
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def setup_case(case: Case, folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for name, content in case.files.items():
        target = folder / name
        if callable(content):
            content(folder)
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(content if isinstance(content, bytes) else content.encode("utf-8"))
    if case.project and "project.toml" not in case.files:
        (folder / "project.toml").write_text(case.project, encoding="utf-8")


def run_case(case: Case, folder: Path) -> Outcome:
    from baarda.pipeline.cli import main

    setup_case(case, folder)
    out = folder / case.out
    before = _snapshot(folder)
    if case.command == "review":
        argv = ["review", str(folder / "r")]
    elif case.command == "validate":
        argv = ["validate", str(folder / "project.toml"), *case.extra_args]
    elif case.command == "batch":
        argv = ["batch", str(folder / "project.toml"), "--sweep", str(folder / "sweep.csv"), "--out", str(out),
                "--scheduler", "sync", "--quiet"]
    else:
        argv = ["run", str(folder / "project.toml"), "--out", str(out), "--quiet", *case.extra_args]
    o, e = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(o), contextlib.redirect_stderr(e):
        code = main(argv)
    after = _snapshot(folder)
    return Outcome(code, o.getvalue(), e.getvalue(), folder, before, after)


def main_cli(argv: list[str]) -> int:
    import tempfile

    pattern = argv[0] if argv else ""
    cases = [c for c in all_cases() if pattern in c.name]
    with tempfile.TemporaryDirectory() as tmp:
        for k, case in enumerate(cases):
            res = run_case(case, Path(tmp) / f"case{k}")
            line = [ln for ln in res.err.splitlines() if ln.startswith("baarda:")]
            print(f"{case.name:45s} exit {res.code} (want {case.code}): {line[-1] if line else res.err.strip()[:200]}")
            shutil.rmtree(Path(tmp) / f"case{k}", ignore_errors=True)
    print(f"{len(cases)} cases")
    return 0


if __name__ == "__main__":
    sys.exit(main_cli(sys.argv[1:]))
