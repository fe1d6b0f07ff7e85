"""Property-based fuzzing of every reader with hypothesis (issue 27).

Each reader gets random bytes and mutations of a bundled real file — truncations, flipped bytes,
a token of a line replaced by a troublesome one (nan, inf, 1e300, 1e-320, a letter, a huge
integer …), lines dropped or doubled, other encodings — and must give a block (or its parsed
structure) or one :class:`InputError` that names the file: never another exception, never a hang
(each example runs under a time limit) and never more than a size limit of memory (the readers'
own limits).  The readers with corpora of their own (PhotoModeler exports, Metashape XML, OpenSfM
JSON and tracks) must name the field or element as well.  The quick profile (a few seconds per
reader) runs in ``make test``; the larger one under the ``slow`` marker (``make test-slow``).
``KNOWN`` lists what the fuzzing found in readers other engineers own (expected failures).
"""

from __future__ import annotations

import os
import shutil
import signal
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, Phase, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from broken_inputs import AICON, BAL_FILE, COLMAP, DATA1, DBAT_CAMCAL, LIBMV_FILE, ODM_GCP, SHARED  # noqa: E402

from baarda.pipeline.errors import InputError  # noqa: E402

if not SHARED.is_dir():  # pragma: no cover
    pytest.skip(f"shared data not found at {SHARED}", allow_module_level=True)

TIME_LIMIT_S = 30          # one example of one reader; a hang fails the test
QUICK = settings(max_examples=3, deadline=None, database=None, derandomize=True,
                 suppress_health_check=list(HealthCheck),
                 phases=[Phase.explicit, Phase.reuse, Phase.generate])      # no shrinking in make test
LARGE = settings(max_examples=300, deadline=None, database=None, suppress_health_check=list(HealthCheck))

NASTY = ["nan", "inf", "-inf", "-1", "0", "1e300", "1e-320", "x", "", "99999999999999999999", "1,5", "--", "1e",
         "\x00", "é", "0x10", "-0", "3.4.5", "#", "<", "&lol;", ",", "\t"]


class Hang(Exception):
    pass


@contextmanager
def time_limit(seconds):
    def alarm(signum, frame):
        raise Hang(f"the reader took more than {seconds} s")
    old = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def mutations(seed: bytes, text: bool = True):
    """A strategy of broken versions of ``seed``."""
    n = len(seed)
    lines = seed.split(b"\n")
    strategies = [
        st.binary(max_size=4096),
        st.integers(0, max(n - 1, 0)).map(lambda k: seed[:k]),
        st.lists(st.tuples(st.integers(0, max(n - 1, 0)), st.integers(0, 255)), min_size=1, max_size=8).map(
            lambda flips: bytes(_flip(seed, flips))),
        st.integers(0, max(n - 1, 0)).map(lambda k: seed[:k] + seed[k + 1:]),
    ]
    if text:
        strategies += [
            st.tuples(st.integers(0, len(lines) - 1), st.integers(0, 12), st.sampled_from(NASTY)).map(
                lambda t: _token(lines, *t)),
            st.tuples(st.integers(0, len(lines) - 1), st.booleans()).map(
                lambda t: b"\n".join(lines[:t[0]] + ([lines[t[0]]] * 2 if t[1] else []) + lines[t[0] + 1:])),
            st.sampled_from(["utf-16", "latin-1", "utf-8-sig", "cp1252"]).map(
                lambda enc: seed.decode("utf-8", "replace").replace("1", "é", 1).encode(enc, "replace")),
        ]
    return st.one_of(strategies)


def _flip(seed: bytes, flips):
    b = bytearray(seed)
    for k, v in flips:
        if b:
            b[k % len(b)] = v
    return b


def _token(lines, k, j, new):
    toks = lines[k].replace(b",", b" , ").split()
    if toks:
        toks[j % len(toks)] = new.encode()
    out = list(lines)
    out[k] = b" ".join(toks).replace(b" , ", b",")
    return b"\n".join(out)


def check(call, folder: Path, field: bool = False):
    """``call()`` returns, or raises one InputError naming a file of the input (the broken one, or
    the one a cross-file check blames: a mark naming an image the image list lacks) — and, with
    ``field``, the field (or element) too."""
    try:
        with time_limit(TIME_LIMIT_S):
            call()
    except InputError as e:
        assert e.path is not None and str(e).startswith(str(folder)), f"the message names no input file: {e}"
        if field:
            assert e.field, f"the message names no field or element: {e}"


def source(use: str, options: dict, folder: Path):
    """The source stage ``use`` reading through its ``validate`` (what ``baarda validate`` runs)."""
    from baarda.pipeline.options import parse_options
    from baarda.pipeline.plugins import PluginManager
    from baarda.pipeline.stage import Context

    cls = PluginManager().get(use).cls
    opts = parse_options(cls.Options, options)
    ctx = Context(stage_id="source", project_dir=folder, project_file=folder / "project.toml")
    return lambda: cls().validate(opts, ctx)


def _with_file(files: dict[str, bytes], name: str, data: bytes):
    d = Path(tempfile.mkdtemp(prefix="baarda-fuzz-"))
    for n, b in {**files, name: data}.items():
        (d / n).parent.mkdir(parents=True, exist_ok=True)
        (d / n).write_bytes(b)
    return d


# -- the readers: (seed files, the file mutated, how to read) ----------------------------------------

def _comparator():
    return {"data.cmp": DATA1.encode()}, "data.cmp", lambda d: source("comparator", {"path": "data.cmp"}, d)


def _bal():
    return {"p.txt": BAL_FILE.read_bytes()}, "p.txt", lambda d: source("bal", {"path": "p.txt"}, d)


def _libmv():
    return {"p.bin": LIBMV_FILE.read_bytes()}, "p.bin", lambda d: source("libmv", {"path": "p.bin"}, d)


def _aicon(suffix):
    def make():
        files = {f"ex{p.suffix}": p.read_bytes() for p in AICON.iterdir()}
        return files, f"ex.{suffix}", lambda d: source("aicon", {"path": "ex"}, d)
    return make


def _dbat(which):
    def make():
        names = {"p.xml": "camcaldemo.xml", "reference/camcal-fixed.txt": "reference/camcal-fixed.txt",
                 "images/images.txt": "images/images.txt", "measurements/markpts.txt": "measurements/markpts.txt"}
        files = {k: (DBAT_CAMCAL / v).read_bytes() for k, v in names.items()}
        return files, which, lambda d: source("dbat", {"path": "p.xml"}, d)
    return make


def _gcp():
    cam = {"width": 4000, "height": 3000, "focal_px": 2904.0, "sensor_width_mm": 6.17}
    return ({"gcp_list.txt": (ODM_GCP / "gcp_list_floatxy_raw.txt").read_bytes()}, "gcp_list.txt",
            lambda d: source("gcp-list", {"path": "gcp_list.txt", "camera": cam,
                                          "skip_lines": [19, 51, 52, 55, 70]}, d))


def _gnss():
    from baarda.plugins.gcp.reader import read_gnss_csv

    good = b"# crs: EPSG:32722\nphoto,E,N,h,sigma\nIMG_5350.JPG,658530.0,7167000.0,965.0,0.05\n" \
           b"IMG_5351.JPG,658531.0,7167001.0,966.0,0.05\n"
    return {"g.csv": good}, "g.csv", lambda d: (lambda: read_gnss_csv(d / "g.csv"))


_COLMAP_TEXT: dict = {}


def _colmap_text(name):
    def make():
        if not _COLMAP_TEXT:
            import pycolmap

            rec = pycolmap.Reconstruction()
            rec.read_binary(str(COLMAP))
            d = Path(tempfile.mkdtemp(prefix="baarda-fuzz-colmap-"))
            rec.write_text(str(d))
            _COLMAP_TEXT.update({f"model/{n}": (d / n).read_bytes()
                                 for n in ("cameras.txt", "images.txt", "points3D.txt")})
            shutil.rmtree(d, ignore_errors=True)
        return dict(_COLMAP_TEXT), f"model/{name}", lambda d: source("colmap", {"path": "model"}, d)
    return make


def _colmap_bin(name):
    def make():
        files = {f"model/{p.name}": p.read_bytes() for p in COLMAP.glob("*.bin")}
        return files, f"model/{name}", lambda d: source("colmap", {"path": "model"}, d)
    return make


def _crs():
    from baarda.pipeline.crs import parse_crs

    return {"crs.txt": b"EPSG:32722"}, "crs.txt", lambda d: (
        lambda: parse_crs((d / "crs.txt").read_bytes().decode("utf-8", "replace"), path=d / "crs.txt"))


CORPORA = Path(__file__).resolve().parent


def _pmexport(which):
    def make():
        pm = CORPORA / "pmexport"
        files = {"export.txt": (pm / "mini.txt").read_bytes(), "control.txt": (pm / "control.txt").read_bytes()}
        return files, which, lambda d: source("pmexport", {"path": "export.txt", "control": "control.txt"}, d)
    return make


def _metashape():
    return ({"cams.xml": (CORPORA / "metashape" / "mini.xml").read_bytes()}, "cams.xml",
            lambda d: source("metashape", {"path": "cams.xml"}, d))


def _opensfm(which):
    def make():
        o = CORPORA / "opensfm"
        files = {"rec.json": (o / "mini.json").read_bytes(), "rec.tracks.csv": (o / "mini.tracks.csv").read_bytes()}
        return files, which, lambda d: source("opensfm", {"path": "rec.json", "tracks": "rec.tracks.csv"}, d)
    return make


READERS = {
    "comparator": (_comparator, True), "bal": (_bal, True), "libmv": (_libmv, False),
    "aicon-ior": (_aicon("ior"), True), "aicon-eor": (_aicon("eor"), True), "aicon-obc": (_aicon("obc"), True),
    "aicon-phc": (_aicon("phc"), True), "aicon-scale": (_aicon("scale"), True),
    "dbat-xml": (_dbat("p.xml"), True), "dbat-marks": (_dbat("measurements/markpts.txt"), True),
    "dbat-control": (_dbat("reference/camcal-fixed.txt"), True), "dbat-images": (_dbat("images/images.txt"), True),
    "gcp-list": (_gcp, True), "gnss-csv": (_gnss, True),
    "colmap-cameras-txt": (_colmap_text("cameras.txt"), True), "colmap-images-txt": (_colmap_text("images.txt"), True),
    "colmap-points-txt": (_colmap_text("points3D.txt"), True),
    "colmap-images-bin": (_colmap_bin("images.bin"), False), "colmap-cameras-bin": (_colmap_bin("cameras.bin"), False),
    "colmap-points-bin": (_colmap_bin("points3D.bin"), False),
    "crs": (_crs, True),
    "pmexport": (_pmexport("export.txt"), True), "pmexport-control": (_pmexport("control.txt"), True),
    "metashape-xml": (_metashape, True),
    "opensfm-json": (_opensfm("rec.json"), True), "opensfm-tracks": (_opensfm("rec.tracks.csv"), True),
}
KNOWN: dict[str, str] = {}
"""Targets whose fuzzing finds a mistake in a reader another engineer owns: expected to fail until
that reader is fixed (not strict: a fix makes them pass)."""
NAMES_FIELD = {"pmexport", "pmexport-control", "metashape-xml", "opensfm-json", "opensfm-tracks"}
"""Readers whose every InputError must name the field (or element) as well as the file."""


def _fuzz(name, profile):
    make, text = READERS[name]
    files, target, reader = make()

    @profile
    @given(mutations(files[target], text=text))
    def run(data):
        d = _with_file(files, target, data)
        try:
            check(reader(d), d, field=name in NAMES_FIELD)
        finally:
            shutil.rmtree(d, ignore_errors=True)

    run()


def _targets():
    return [pytest.param(n, marks=pytest.mark.xfail(reason=KNOWN[n], strict=False)) if n in KNOWN else n
            for n in READERS]


@pytest.mark.parametrize("name", _targets())
def test_fuzz_reader_quick(name):
    _fuzz(name, QUICK)


@pytest.mark.slow
@pytest.mark.parametrize("name", _targets())
def test_fuzz_reader_large(name):
    _fuzz(name, LARGE)


FOUND = {
    "aicon-obc-id-not-an-integer": ("aicon-obc", lambda seed: _token(seed.split(b"\n"), 0, 0, "1e300")),
    "colmap-image-name-not-utf8": ("colmap-images-bin", lambda seed: bytes(_flip(seed, [(72, 128)]))),
}
"""Inputs the slow fuzzing found to crash a reader (fixed since): replayed in every ``make test``."""


@pytest.mark.parametrize("case", sorted(FOUND))
def test_what_the_fuzzing_found(case):
    name, mutate = FOUND[case]
    make, _text = READERS[name]
    files, target, reader = make()
    d = _with_file(files, target, mutate(files[target]))
    try:
        check(reader(d), d, field=name in NAMES_FIELD)
    finally:
        shutil.rmtree(d, ignore_errors=True)


def test_the_unbroken_files_read():
    for name, (make, _text) in READERS.items():
        files, target, reader = make()
        d = _with_file(files, target, files[target])
        try:
            reader(d)()
        finally:
            shutil.rmtree(d, ignore_errors=True)
