"""Reader of DBAT script projects (XML) and the files they name — pure parsing and numerics.

A DBAT (Damped Bundle Adjustment Toolbox, Börlin & Grussenmeyer) script project is an XML file
naming the control points, check points, image list, image measurements ("marks") and the
camera, and listing the operations (initial values, which parameters are estimated, resection,
intersection, bundle).  Format and mapping to baarda: ``docs/dbat.md``.  In short:

* ``<input base_dir="$HERE">`` — relative paths are relative to ``base_dir``; ``$HERE`` is the
  XML file's folder, ``$HOME`` the home folder, ``$DBAT`` DBAT's installation (option ``dbat_dir``).
* ``<ctrl_pts>`` / ``<check_pts>`` — ``<file format="id,label,x,y,z[,sx,sy,sz | ,sxyz]">`` and
  ``<filter id="351,410">keep|remove</filter>``.  Control without σ is fixed.
* ``<images>`` — ``<file format="id,path">``; a listed path that does not exist is looked up by
  its name beside the list (the photos are not needed for the adjustment).
* ``<image_pts>`` — one or more ``<file format="im,id,x,y[,sxy]" sxy="0.5">`` in pixels (x right,
  y down, origin at the image corner: DBAT's ``u · pixel``), σ from the column or the attribute.
* ``<cameras><camera>`` — ``sensor`` (``w,h`` or ``auto,h`` mm), ``image`` (``W,H`` px),
  ``focal``/``cc``, ``pp`` (mm from the image corner, y down), ``K``, ``P``, ``aspect``, ``skew``,
  ``model`` (DBAT lens model 3: the backward Brown model, baarda's ``brown-backward``), ``nK``, ``nP``.
* ``<prior_eo>`` — ``<file format="id,x,y,z,omega,phi,kappa" units="degrees|radian|gon">``: the
  photos' projection centres and DBAT's ω φ κ (image ids as in the image list), used as initial
  values by ``set_initial_values`` ``<eo>loaded</eo>``.  DBAT's ω φ κ are baarda's (its rotation is
  ``R3(κ) R2(φ) R1(ω)``, its camera looks down −z: DBAT's published sxb report gives photo 1 the
  angles baarda adjusts, ``tests/dbat/test_projects.py``), so they are taken as they are.
* ``<operations>`` — ``check_ray_count min_rays``, ``set_initial_values`` (``io`` ``default`` |
  ``loaded``, ``eo`` ``loaded``), ``set_bundle_estimate_params`` (``io``: ``true``/``false`` or per-parameter
  ``<all>``, ``<cc>``, ``<pp>``, ``<aspect>``, ``<skew>``, ``<K>``, ``<P>``; ``eo``), and the
  computations ``spatial_resection``, ``forward_intersection``, ``bundle_adjustment``.

Every malformed line raises :class:`~baarda.pipeline.errors.InputError` naming the file, the line
and the field.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from baarda.pipeline.api import Block, InputError
from baarda.pipeline.errors import quote, read_limited
from baarda.pipeline.errors import finite_number as _num
from baarda.pipeline.geometry import mm_from_pixels
from baarda.pipeline.model import FIXED, FREE, Cameras, FrozenMap, Observations, Photos, Points, SourceInfo

AP_NAMES = ("K1", "K2", "K3", "P1", "P2", "aspect", "skew")
"""Order of the parameters in ``Cameras.ap`` (the ``brown-backward`` model)."""

DBAT_SIGN = np.ones(7)
"""baarda value = DBAT value × sign: DBAT's image y axis points down, so its P2 and skew flip."""

SUPPORTED_LENS_MODELS = {3: "brown-backward"}
SWAP_FRACTION = 0.05
"""A marks file with at least this fraction (and at least 3) of its marks outside the camera's W × H px
image, of which fewer than a tenth lie outside H × W, is refused: x and y swapped in its ``format`` (or in
``<image>``)."""
KNOWN_OPERATIONS = {"check_ray_count", "set_initial_values", "set_bundle_estimate_params",
                    "spatial_resection", "forward_intersection", "bundle_adjustment", "set_datum"}
"""Every operation DBAT's script runner knows (``parseops.m``); any other is refused by name."""
COLUMNS = {"id", "label", "x", "y", "z", "sx", "sy", "sz", "sxyz", "im", "path", "sxy"}


# --------------------------------------------------------------------------------------------
# XML with line numbers (ElementTree drops them)


@dataclass
class Node:
    tag: str
    attrib: dict
    line: int
    children: list = field(default_factory=list)
    text: str = ""

    def find(self, tag: str) -> "Node | None":
        for c in self.children:
            if c.tag == tag:
                return c
        return None

    def findall(self, tag: str) -> list["Node"]:
        return [c for c in self.children if c.tag == tag]

    @property
    def value(self) -> str:
        return self.text.strip()


XML_MAX_BYTES = 16 * 2**20
"""Largest DBAT script read (a script is a few kB; its data are in the files it names)."""


def parse_xml(path: Path) -> Node:
    """The XML file as a tree of :class:`Node` (each with its 1-based line).

    Parsed with defusedxml's hardened expat reader: no entity declarations (no "billion laughs"
    expansion), no external entities or DTDs fetched, and at most :data:`XML_MAX_BYTES` read.
    """
    import xml.sax
    import xml.sax.handler

    from defusedxml import DefusedXmlException
    from defusedxml.sax import make_parser

    data = read_limited(path, XML_MAX_BYTES, what="a DBAT script")
    stack: list[Node] = []
    root: list[Node] = []
    parser = make_parser()
    parser.forbid_dtd, parser.forbid_entities, parser.forbid_external = False, True, True
    parser.setFeature(xml.sax.handler.feature_external_ges, False)
    parser.setFeature(xml.sax.handler.feature_external_pes, False)

    class Handler(xml.sax.handler.ContentHandler):
        def startElement(self, tag, attrib):
            n = Node(tag, dict(attrib), parser._parser.CurrentLineNumber)     # the expat parser's line
            if stack:
                stack[-1].children.append(n)
            else:
                root.append(n)
            stack.append(n)

        def endElement(self, tag):
            stack.pop()

        def characters(self, text):
            if stack:
                stack[-1].text += text

    handler = Handler()
    parser.setContentHandler(handler)
    try:
        parser.feed(data)
        parser.close()
    except xml.sax.SAXParseException as e:
        msg = e.getMessage()
        raise InputError(f"not well-formed XML: {msg}", path=path, line=e.getLineNumber()) from None
    except DefusedXmlException as e:
        expat = getattr(parser, "_parser", None)
        line = getattr(expat, "CurrentLineNumber", None) if expat is not None else None
        what = {"EntitiesForbidden": "an entity declaration", "ExternalReferenceForbidden": "an external reference",
                "DTDForbidden": "a DTD"}.get(type(e).__name__, "a construct")
        name = getattr(e, "name", None)
        raise InputError(f"{what} is refused in a DBAT script (XML entities are not expanded and external "
                         f"references are not read)", path=path, line=line,
                         field=f"<!ENTITY {name}>" if isinstance(name, str) else None) from None
    if not root:
        raise InputError("empty XML document", path=path)
    return root[0]


# --------------------------------------------------------------------------------------------
# parsed records


@dataclass(frozen=True)
class DbatCamera:
    """The script's camera as written (mm, DBAT's image frame: origin at the corner, y down)."""

    name: str
    unit: str
    sensor: tuple[float | None, float]      # width (None: "auto"), height
    image: tuple[int, int]                  # W, H pixels
    focal: float
    cc: float | None
    pp: tuple[float, float] | None
    K: tuple[float, ...]
    P: tuple[float, ...]
    aspect: float
    skew: float
    model: int
    nK: int
    nP: int
    line: int

    @property
    def pixel_mm(self) -> float:
        """DBAT's pixel size: sensor width / W (the height decides when the width is ``auto``)."""
        w, h = self.sensor
        return (w / self.image[0]) if w is not None else h / self.image[1]


@dataclass(frozen=True)
class DbatMarksInfo:
    """One marks file as read: its path, number of marks, the distinct σ (px) and where σ came from."""

    file: str
    count: int
    sigma_px: tuple[float, ...]
    sigma_source: str

    def __post_init__(self):
        object.__setattr__(self, "count", int(self.count))
        object.__setattr__(self, "sigma_px", tuple(float(v) for v in self.sigma_px))


@dataclass(frozen=True)
class DbatInfo:
    """What the ``dbat`` source keeps of a script beside the block (``Block.meta["dbat"]``, private to
    this plugin: read by its stages and ``dbat-export``).  Immutable and picklable: sequences are
    tuples, mappings :class:`FrozenMap`.

    ``script`` the XML file, ``name`` the project's name, ``camera`` as written in the script;
    ``io_initial`` / ``eo_initial`` (``"default"`` | ``"loaded"``), ``estimate_io`` DBAT's name of an
    interior parameter (``cc`` … ``skew``) → estimated, ``min_rays`` (``check_ray_count``),
    ``operations`` / ``unknown_operations`` (those baarda does not carry out); ``labels`` point id →
    label; ``images`` image number → the file found (None: not found), ``image_paths`` image number →
    path as listed, ``image_numbers`` photo id → image number; ``marks`` one
    :class:`DbatMarksInfo` per marks file; ``dropped_points`` (fewer than ``min_rays`` rays) and
    their ``dropped_marks``; ``unmeasured_control`` control points without marks;
    ``control_files`` / ``check_files`` the point files read."""

    script: str
    name: str
    camera: DbatCamera
    io_initial: str
    estimate_io: Mapping[str, bool]
    min_rays: int
    operations: tuple[str, ...]
    eo_initial: str
    unknown_operations: tuple[str, ...]
    labels: Mapping[str, str]
    images: Mapping[str, str | None]
    image_paths: Mapping[str, str]
    image_numbers: Mapping[str, str]
    marks: tuple[DbatMarksInfo, ...]
    dropped_points: tuple[str, ...]
    dropped_marks: int
    unmeasured_control: tuple[str, ...]
    control_files: tuple[str, ...]
    check_files: tuple[str, ...]
    marks_outside: tuple = ()          # (count, "file:line" of the first) of marks outside the W × H px image

    def __post_init__(self):
        for name in ("estimate_io", "labels", "images", "image_paths", "image_numbers"):
            object.__setattr__(self, name, FrozenMap(getattr(self, name)))
        for name in ("operations", "unknown_operations", "marks", "dropped_points", "unmeasured_control",
                     "control_files", "check_files"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        object.__setattr__(self, "min_rays", int(self.min_rays))
        object.__setattr__(self, "dropped_marks", int(self.dropped_marks))

    @property
    def images_found(self) -> int:
        """How many listed images were found."""
        return sum(v is not None for v in self.images.values())


@dataclass(frozen=True)
class PointSet:
    """Control or check points read from one file (after the filters)."""

    ids: list[str]
    labels: list[str]
    XYZ: np.ndarray            # (n, 3)
    sigma: np.ndarray          # (n, 3), 0 = fixed (no σ in the file)
    file: Path
    filters: list[tuple[str, list[str]]]
    lines: list[int]


@dataclass(frozen=True)
class MarkFile:
    file: Path
    image: list[str]
    point: list[str]
    uv: np.ndarray             # (k, 2) pixels
    sigma_px: np.ndarray       # (k,)
    lines: list[int]
    sigma_source: str          # "column" | "attribute"
    format_line: int = 0       # the script's line of this file's <file format=...> (0: unknown)


@dataclass(frozen=True)
class DbatScript:
    """Everything read from one script project, in DBAT's own conventions."""

    path: Path
    name: str
    object_unit: str
    control: list[PointSet]
    check: list[PointSet]
    images: dict[str, str]            # image id -> path as listed
    image_files: dict[str, Path | None]
    images_list: Path | None
    marks: list[MarkFile]
    camera: DbatCamera
    min_rays: int
    io_initial: str                    # "default" | "loaded"
    estimate_io: dict[str, bool]       # cc, px, py, K1..K3, P1, P2, aspect, skew
    estimate_eo: bool
    operations: list[str]
    unknown_operations: list[str]
    prior_eo: dict | None = None       # image id -> (X0 (3,), ω φ κ radians (3,), file, line)
    eo_initial: str = "default"        # "default" | "loaded"
    io_overrides: dict = field(default_factory=dict)
    """set_initial_values' per-parameter io values after <all>: name (cc, pp, K, P, aspect, skew) ->
    "default" | "loaded" | tuple of numbers."""
    datum: tuple | None = None
    """set_datum: ("depend", ref image id, ref_base "longest" | "x" | "y" | "z", line) or None."""


# --------------------------------------------------------------------------------------------
# helpers





def _nums(node: Node, path, n: int | tuple[int, ...], name: str | None = None) -> list[float]:
    toks = [t.strip() for t in node.value.split(",")] if node.value else []
    allowed = (n,) if isinstance(n, int) else n
    if len(toks) not in allowed:
        want = " or ".join(str(a) for a in allowed)
        raise InputError(f"expected {want} comma-separated number(s), got {len(toks)}", path=path,
                         line=node.line, field=name or node.tag)
    return [_num(t, path, node.line, name or node.tag) for t in toks]


def _bool(node: Node, path, name: str) -> bool:
    v = node.value.lower()
    if v in ("true", "1", "yes", "on"):
        return True
    if v in ("false", "0", "no", "off"):
        return False
    raise InputError(f"expected true or false, got {quote(node.value)}", path=path, line=node.line, field=name)


def _expand(value: str, here: Path, dbat_dir: Path | None, path, line, name) -> Path:
    """A DBAT path with ``$HERE``, ``$HOME``, ``$DBAT`` expanded."""
    text = value.strip()
    if "$DBAT" in text:
        if dbat_dir is None:
            raise InputError("the path uses $DBAT (DBAT's installation folder): give the stage option "
                             "'dbat_dir'", path=path, line=line, field=name)
        text = text.replace("$DBAT", str(dbat_dir))
    text = text.replace("$HERE", str(here)).replace("$HOME", os.path.expanduser("~"))
    return Path(text)


def _is_absolute(text: str) -> bool:
    return bool(re.match(r"^([/\\]|[A-Za-z]:)", text))


def _resolve(base: Path, value: str, here, dbat_dir, path, line, name) -> Path:
    p = _expand(value, here, dbat_dir, path, line, name)
    return p if _is_absolute(str(p)) else base / p


def _format(node: Node, path, required: set[str], allowed: set[str]) -> list[str]:
    fmt = node.attrib.get("format")
    if fmt is None:
        raise InputError("a <file> needs the attribute format (e.g. \"id,label,x,y,z\")", path=path,
                         line=node.line, field="format")
    cols = [c.strip().lower() for c in fmt.split(",")]
    for c in cols:
        if c not in allowed:
            raise InputError(f"unknown column {quote(c)} in the format (known here: {', '.join(sorted(allowed))})",
                             path=path, line=node.line, field="format")
    if len(set(cols)) != len(cols):
        raise InputError("a column appears twice in the format", path=path, line=node.line, field="format")
    missing = sorted(required - set(cols))
    if missing:
        raise InputError(f"the format lacks the column(s) {', '.join(missing)}", path=path, line=node.line,
                         field="format")
    return cols


def _rows(file: Path, cols: list[str], xml_path, xml_line):
    """``(line, {column: token})`` of a comma-separated text file; ``#`` starts a comment."""
    try:
        text = (read_limited(file, what="a DBAT data file") if file.exists() and not file.is_dir()
                else file.read_bytes()).decode("utf-8")
    except FileNotFoundError:
        raise InputError(f"file not found: {file}", path=xml_path, line=xml_line, field="file") from None
    except IsADirectoryError:
        raise InputError(f"is a folder, not a file: {file}", path=xml_path, line=xml_line, field="file") from None
    except UnicodeDecodeError:
        raise InputError("not a UTF-8 text file", path=file) from None
    except OSError as e:
        raise InputError(f"cannot read: {e.strerror}", path=file) from None
    out = []
    for i, raw in enumerate(text.splitlines(), start=1):
        s = raw.split("#", 1)[0].strip()
        if not s:
            continue
        toks = [t.strip() for t in s.split(",")]
        if len(toks) != len(cols):
            raise InputError(f"expected {len(cols)} comma-separated fields ({','.join(cols)}), got {len(toks)}",
                             path=file, line=i, field=cols[len(toks)] if len(toks) < len(cols) else cols[-1])
        for c, t in zip(cols, toks):
            if not t:
                raise InputError("empty field", path=file, line=i, field=c)
        out.append((i, dict(zip(cols, toks))))
    return out


def _id(tok: str) -> str:
    """DBAT ids are numbers: ``1`` and ``001`` are the same point."""
    try:
        return str(int(tok))
    except ValueError:
        return tok


# --------------------------------------------------------------------------------------------
# the sections


def _points(section: Node, path, base, here, dbat_dir) -> list[PointSet]:
    files = section.findall("file")
    if not files:
        raise InputError(f"<{section.tag}> names no <file>", path=path, line=section.line, field="file")
    filters = []
    for f in section.findall("filter"):
        ids = f.attrib.get("id")
        action = f.value.lower()
        if ids is None:
            raise InputError("a <filter> needs the attribute id (a comma-separated list)", path=path, line=f.line,
                             field="id")
        if action not in ("keep", "remove"):
            raise InputError(f"a filter is 'keep' or 'remove', got {quote(f.value)}", path=path, line=f.line,
                             field="filter")
        filters.append((action, [_id(t.strip()) for t in ids.split(",") if t.strip()], f.line))
    sets = []
    for fn in files:
        cols = _format(fn, path, {"id", "x", "y", "z"}, {"id", "label", "x", "y", "z", "sx", "sy", "sz", "sxyz"})
        s_cols = [c for c in cols if c in ("sx", "sy", "sz", "sxyz")]
        if s_cols and not (s_cols == ["sxyz"] or sorted(s_cols) == ["sx", "sy", "sz"]):
            raise InputError("σ columns are either sxyz or all of sx, sy, sz", path=path, line=fn.line, field="format")
        file = _resolve(base, fn.value, here, dbat_dir, path, fn.line, "file")
        ids, labels, XYZ, sig, lines = [], [], [], [], []
        seen = {}
        for line, r in _rows(file, cols, path, fn.line):
            pid = _id(r["id"])
            if pid in seen:
                raise InputError(f"point {quote(pid)} listed twice (first on line {seen[pid]})", path=file, line=line,
                                 field="id")
            seen[pid] = line
            xyz = [_num(r[c], file, line, c) for c in ("x", "y", "z")]
            if "sxyz" in r:
                s = [_num(r["sxyz"], file, line, "sxyz")] * 3
            elif "sx" in r:
                s = [_num(r[c], file, line, c) for c in ("sx", "sy", "sz")]
            else:
                s = [FIXED] * 3
            for c, v in zip(("sx", "sy", "sz") if "sx" in r else ("sxyz",) * 3, s):
                if v < 0:
                    raise InputError(f"a standard deviation must not be negative, got {v:g}", path=file, line=line,
                                     field=c)
            ids.append(pid)
            labels.append(r.get("label", ""))
            XYZ.append(xyz)
            sig.append(s)
            lines.append(line)
        keep = np.ones(len(ids), bool)
        for action, fids, fline in filters:
            unknown = sorted(set(fids) - set(ids))
            if unknown:
                raise InputError(f"the filter names point(s) not in {file.name}: {', '.join(unknown[:5])}",
                                 path=path, line=fline, field="id")
            inside = np.isin(ids, fids)
            keep &= inside if action == "keep" else ~inside
        k = np.flatnonzero(keep)
        sets.append(PointSet(ids=[ids[i] for i in k], labels=[labels[i] for i in k],
                             XYZ=np.asarray(XYZ, float).reshape(-1, 3)[k],
                             sigma=np.asarray(sig, float).reshape(-1, 3)[k], file=file,
                             filters=[(a, f) for a, f, _ in filters], lines=[lines[i] for i in k]))
    return sets


def _images(section: Node, path, base, here, dbat_dir):
    fns = section.findall("file")
    if len(fns) != 1:
        raise InputError(f"<images> must name exactly one <file>, got {len(fns)}", path=path, line=section.line,
                         field="file")
    fn = fns[0]
    cols = _format(fn, path, {"id", "path"}, {"id", "path"})
    file = _resolve(base, fn.value, here, dbat_dir, path, fn.line, "file")
    img_base_txt = section.attrib.get("image_base_dir")
    img_base = None
    if img_base_txt:
        try:
            img_base = _expand(img_base_txt, here, dbat_dir, path, section.line, "image_base_dir")
        except InputError:
            img_base = None                        # $DBAT unknown: look beside the list instead
    images, files = {}, {}
    for line, r in _rows(file, cols, path, fn.line):
        iid = _id(r["id"])
        if iid in images:
            raise InputError(f"image {quote(iid)} listed twice", path=file, line=line, field="id")
        images[iid] = r["path"]
        cands = []
        p = r["path"].replace("\\", "/")
        if _is_absolute(p):
            cands.append(Path(p))
        elif img_base is not None:
            cands.append(img_base / p)
        cands.append(file.parent / Path(p).name)
        files[iid] = next((c for c in cands if c.is_file()), None)
    if not images:
        raise InputError("the image list is empty", path=file)
    return images, files, file


_BULK_MAX_BYTES = 512 * 2 ** 20          # larger files: the line-by-line reading (and its size check)


def _marks_bulk(file: Path, cols: list[str], s_attr: float | None) -> dict | None:
    """A marks file parsed in bulk (numpy's ``loadtxt`` on the data lines: whole-number image and
    point ids, finite x, y, positive sxy), or ``None`` when anything is not exactly so — a file
    that is not a regular UTF-8 file below the size limit, a line with another number of fields,
    an empty or non-numeric field, an id that is not a whole number (DBAT ids may be names: the
    line-by-line reading keeps them), a value that is not finite, sxy ≤ 0 — so that
    :func:`_marks` reads line by line and names the line and field.  Ids as :func:`_id` makes
    them (``001`` → ``1``)."""
    import io
    import stat

    try:
        st = file.stat()
        if not stat.S_ISREG(st.st_mode) or st.st_size > _BULK_MAX_BYTES:
            return None
        text = file.read_bytes().decode("utf-8")
    except (OSError, UnicodeDecodeError):
        return None
    dtype = np.dtype([(c, np.int64 if c in ("im", "id") else np.float64) for c in cols])
    rows, line_no = _plain_rows(text, dtype), None
    if rows is not None:
        rows, line_no = rows
    else:                                        # comments, other line ends, blank lines of spaces: strip each line
        lines = text.splitlines()
        stripped = (map(str.strip, lines) if "#" not in text
                    else (raw.split("#", 1)[0].strip() for raw in lines))
        numbered = [(i, s) for i, s in enumerate(stripped, start=1) if s]
        if not numbered:
            return None
        try:
            rows = np.loadtxt(io.StringIO("\n".join(s for _, s in numbered)), dtype=dtype, delimiter=",",
                              comments=None, ndmin=1)
        except (ValueError, OverflowError):
            return None
        if len(rows) != len(numbered):
            return None
        line_no = [i for i, _ in numbered]
    uv = np.column_stack([rows["x"], rows["y"]])
    sg = np.full(len(rows), s_attr, float) if s_attr is not None else np.asarray(rows["sxy"], float)
    if not (np.isfinite(uv).all() and np.isfinite(sg).all() and (sg > 0).all()):
        return None
    return {"image": rows["im"].astype(str).tolist(), "point": rows["id"].astype(str).tolist(), "uv": uv,
            "sigma_px": sg, "lines": line_no}


_NOT_PLAIN = re.compile(rb"[\r\x0b\x0c\x1c-\x1e]")
_COMMENT = re.compile(r"#[^\n]*")
_SPACES_ONLY = re.compile(r"(?m)^[ \t]+$")


def _plain_rows(text: str, dtype):
    """``(rows, line numbers)`` of a marks file in ASCII with ``\\n`` line ends: comments and lines of
    only spaces blanked (regular expressions), then parsed by ``loadtxt`` as it is (empty lines
    skipped) and the line numbers found with numpy — no Python loop over the lines.  ``None`` for
    any other file (or when ``loadtxt`` refuses a line), for the line-by-line stripping of
    :func:`_marks_bulk`."""
    import io

    if not text.isascii() or _NOT_PLAIN.search(text.encode("ascii")):
        return None
    if "#" in text:
        text = _COMMENT.sub("", text)
    text = _SPACES_ONLY.sub("", text)
    b = np.frombuffer(text.encode("ascii"), np.uint8)
    nl = np.flatnonzero(b == 10)
    filled = np.diff(np.concatenate([[-1], nl, [len(b)]])) > 1               # lines with a character
    if not filled.any():
        return None
    try:
        rows = np.loadtxt(io.StringIO(text), dtype=dtype, delimiter=",", comments=None, ndmin=1)
    except (ValueError, OverflowError):
        return None
    line_no = np.flatnonzero(filled) + 1
    if len(rows) != len(line_no):
        return None
    return rows, line_no.tolist()


def _marks(section: Node, path, base, here, dbat_dir) -> list[MarkFile]:
    fns = section.findall("file")
    if not fns:
        raise InputError("<image_pts> names no <file>", path=path, line=section.line, field="file")
    out = []
    for fn in fns:
        cols = _format(fn, path, {"im", "id", "x", "y"}, {"im", "id", "x", "y", "sxy"})
        attr = fn.attrib.get("sxy")
        if attr is not None:
            s_attr = _num(attr, path, fn.line, "sxy")
            if not s_attr > 0:
                raise InputError(f"sxy must be positive, got {s_attr:g}", path=path, line=fn.line, field="sxy")
        elif "sxy" not in cols:
            raise InputError("no standard deviation for these marks: give a column sxy or the attribute sxy "
                             "(pixels)", path=path, line=fn.line, field="sxy")
        file = _resolve(base, fn.value, here, dbat_dir, path, fn.line, "file")
        bulk = _marks_bulk(file, cols, s_attr if attr is not None else None)
        if bulk is not None:
            out.append(MarkFile(file=file, **bulk, sigma_source="attribute" if attr is not None else "column",
                                format_line=fn.line or 0))
            continue
        # line by line: names the line and field of the first mistake
        im, pt, uv, sg, lines = [], [], [], [], []
        for line, r in _rows(file, cols, path, fn.line):
            u = _num(r["x"], file, line, "x")
            v = _num(r["y"], file, line, "y")
            if attr is not None:
                s = s_attr
            else:
                s = _num(r["sxy"], file, line, "sxy")
                if not s > 0:
                    raise InputError(f"sxy must be positive, got {s:g}", path=file, line=line, field="sxy")
            im.append(_id(r["im"]))
            pt.append(_id(r["id"]))
            uv.append((u, v))
            sg.append(s)
            lines.append(line)
        out.append(MarkFile(file=file, image=im, point=pt, uv=np.asarray(uv, float).reshape(-1, 2),
                            sigma_px=np.asarray(sg, float), lines=lines,
                            sigma_source="attribute" if attr is not None else "column", format_line=fn.line or 0))
    return out


_ANGLE_UNITS = {"radian": 1.0, "radians": 1.0, "degrees": math.pi / 180, "degree": math.pi / 180,
                "gon": math.pi / 200}


def _prior_eo(section: Node, path, base, here, dbat_dir) -> dict:
    """``<prior_eo><file format="id,x,y,z,omega,phi,kappa" units="degrees">`` → {image id: (X0,
    ω φ κ in radians, file, line)}."""
    fns = section.findall("file")
    if len(fns) != 1:
        raise InputError(f"<prior_eo> must name exactly one <file>, got {len(fns)}", path=path, line=section.line,
                         field="file")
    fn = fns[0]
    ang = ("omega", "phi", "kappa")
    cols = _format(fn, path, {"id", "x", "y", "z", *ang}, {"id", "label", "x", "y", "z", *ang})
    units = fn.attrib.get("units")
    if units is None:
        raise InputError("the <prior_eo> file needs the attribute units (radian, degrees or gon)", path=path,
                         line=fn.line, field="units")
    if units not in _ANGLE_UNITS:
        raise InputError(f"the angles' unit must be radian, degrees or gon, got {quote(units)}", path=path,
                         line=fn.line, field="units")
    file = _resolve(base, fn.value, here, dbat_dir, path, fn.line, "file")
    out = {}
    for line, r in _rows(file, cols, path, fn.line):
        iid = _id(r["id"])
        if iid in out:
            raise InputError(f"image {quote(iid)} listed twice (first on line {out[iid][3]})", path=file, line=line,
                             field="id")
        X0 = np.array([_num(r[c], file, line, c) for c in ("x", "y", "z")])
        opk = np.array([_num(r[c], file, line, c) for c in ang]) * _ANGLE_UNITS[units]
        out[iid] = (X0, opk, file, line)
    return out


def _camera(section: Node, path, base=None, here=None, dbat_dir=None) -> DbatCamera:
    files = section.findall("file")
    if files and not section.findall("camera"):
        # DBAT's demos keep the camera in its own file: <cameras><file>cameras/X.xml</file></cameras>, a
        # <document dbat_camera_version="1.0"><cameras><camera>… (loadcameras)
        if len(files) != 1:
            raise InputError(f"expected exactly one camera <file> (baarda reads single-camera DBAT projects), got "
                             f"{len(files)}", path=path, line=section.line, field="file")
        file = _resolve(base, files[0].value, here, dbat_dir, path, files[0].line, "file")
        if not file.is_file():
            raise InputError(f"camera file not found: {file}", path=path, line=files[0].line, field="file")
        root = parse_xml(file)
        inner = root.find("cameras") if root.tag == "document" else None
        if inner is None:
            raise InputError("expected a DBAT camera file (<document dbat_camera_version=…><cameras><camera>…)",
                             path=file, line=root.line, field=root.tag if root.tag != "document" else "cameras")
        return _camera(inner, file)
    cams = section.findall("camera")
    if len(cams) != 1:
        raise InputError(f"expected exactly one <camera> (baarda reads single-camera DBAT projects), got "
                         f"{len(cams)}", path=path, line=section.line, field="camera")
    c = cams[0]

    def need(tag):
        n = c.find(tag)
        if n is None:
            raise InputError(f"the camera has no <{tag}>", path=path, line=c.line, field=tag)
        return n

    unit = c.find("unit")
    unit_v = unit.value if unit is not None else "mm"
    if unit_v != "mm":
        raise InputError(f"camera unit must be mm, got {quote(unit_v)}", path=path,
                         line=unit.line if unit is not None else c.line, field="unit")
    sn = need("sensor")
    toks = [t.strip() for t in sn.value.split(",")]
    if len(toks) != 2:
        raise InputError("expected sensor as 'width,height' or 'auto,height' (mm)", path=path, line=sn.line,
                         field="sensor")
    sw = None if toks[0].lower() == "auto" else _num(toks[0], path, sn.line, "sensor")
    sh = _num(toks[1], path, sn.line, "sensor")
    if (sw is not None and not sw > 0) or not sh > 0:
        raise InputError("sensor dimensions must be positive", path=path, line=sn.line, field="sensor")
    im = need("image")
    W, H = _nums(im, path, 2)
    if not (W >= 1 and H >= 1 and W == int(W) and H == int(H)):
        raise InputError("image size must be two positive whole numbers of pixels", path=path, line=im.line,
                         field="image")
    focal = _nums(need("focal"), path, 1)[0]
    ccn = c.find("cc")
    cc = _nums(ccn, path, 1)[0] if ccn is not None else None
    for name, v, node in (("focal", focal, c.find("focal")), ("cc", cc, ccn)):
        if v is not None and not v > 0:
            raise InputError(f"{name} must be positive, got {v:g}", path=path, line=node.line, field=name)
    ppn = c.find("pp")
    pp = tuple(_nums(ppn, path, 2)) if ppn is not None else None
    modeln = c.find("model")
    model = int(_nums(modeln, path, 1)[0]) if modeln is not None else 3
    if model not in SUPPORTED_LENS_MODELS:
        raise InputError(f"DBAT lens model {model} is not supported (baarda reads model 3, the backward Brown "
                         "model with aspect and skew)", path=path, line=modeln.line, field="model")

    def count(tag, default, hi):
        n = c.find(tag)
        if n is None:
            return default
        v = _nums(n, path, 1)[0]
        if v != int(v) or not 0 <= v <= hi:
            raise InputError(f"{tag} must be a whole number from 0 to {hi}, got {v:g}", path=path, line=n.line,
                             field=tag)
        return int(v)

    nK = count("nK", 3, 3)
    nP = count("nP", 2, 2)
    Kn, Pn = c.find("K"), c.find("P")
    K = tuple(_nums(Kn, path, (0, 1, 2, 3))) if Kn is not None else ()
    P = tuple(_nums(Pn, path, (0, 2))) if Pn is not None else ()
    an = c.find("aspect")
    aspect = _nums(an, path, 1)[0] if an is not None else 1.0
    if not aspect > 0:
        raise InputError(f"aspect must be positive, got {aspect:g}", path=path, line=an.line, field="aspect")
    skn = c.find("skew")
    skew = _nums(skn, path, 1)[0] if skn is not None else 0.0
    name = c.find("name")
    return DbatCamera(name=name.value if name is not None else "", unit=unit_v, sensor=(sw, sh),
                      image=(int(W), int(H)), focal=focal, cc=cc, pp=pp, K=K, P=P, aspect=aspect, skew=skew,
                      model=model, nK=nK, nP=nP, line=c.line)


IO_FLAGS = ("cc", "px", "py", "K1", "K2", "K3", "P1", "P2", "aspect", "skew")


def _estimate_io(node: Node | None, path, nK, nP) -> dict[str, bool]:
    est = {k: False for k in IO_FLAGS}
    if node is None:
        return est
    if not node.children:
        v = _bool(node, path, "io")
        return {k: v for k in IO_FLAGS}
    groups = {"cc": ("cc",), "pp": ("px", "py"), "px": ("px",), "py": ("py",), "K": ("K1", "K2", "K3"),
              "P": ("P1", "P2"), "aspect": ("aspect",), "skew": ("skew",),
              **{k: (k,) for k in ("K1", "K2", "K3", "P1", "P2")}}
    for ch in node.children:
        if ch.tag == "c":
            continue
        if ch.tag == "all":
            v = _bool(ch, path, "all")
            est = {k: v for k in IO_FLAGS}
        elif ch.tag in groups:
            v = _bool(ch, path, ch.tag)
            for k in groups[ch.tag]:
                est[k] = v
        else:
            raise InputError(f"unknown interior-orientation parameter <{ch.tag}> (known: all, cc, pp, aspect, skew, "
                             "K, P)", path=path, line=ch.line, field=ch.tag)
    for i in range(nK, 3):
        est[f"K{i + 1}"] = False
    for i in range(nP, 2):
        est[f"P{i + 1}"] = False
    return est


def read_dbat(path: Path, *, dbat_dir: Path | None = None) -> DbatScript:
    """Read a DBAT script project and every file it names."""
    path = Path(path)
    root = parse_xml(path)
    if root.tag != "document":
        raise InputError(f"expected a DBAT script (<document dbat_script_version=…>), the root is <{root.tag}>",
                         path=path, line=root.line, field=root.tag)
    here = path.parent.resolve()
    if dbat_dir is None:                             # $DBAT: DBAT's folder (dbatroot's parent), when the script is inside it
        dbat_dir = next((a for a in here.parents if (a / "code").is_dir() and (a / "data" / "script").is_dir()), None)
    meta = root.find("meta")
    name = ""
    unit = "m"
    if meta is not None:
        n = meta.find("name")
        name = n.value if n is not None else ""
        u = meta.find("project_unit")
        if u is not None:
            unit = u.value
            if unit not in ("m", "mm", "cm", "ft"):
                raise InputError(f"project_unit must be m, mm, cm or ft, got {quote(unit)}", path=path, line=u.line,
                                 field="project_unit")
    inp = root.find("input")
    if inp is None:
        raise InputError("the script has no <input> section", path=path, line=root.line, field="input")
    base = _expand(inp.attrib.get("base_dir", "$HERE"), here, dbat_dir, path, inp.line, "base_dir")
    if not _is_absolute(str(base)):
        base = here / base
    cams = inp.find("cameras")
    if cams is None:
        raise InputError("the script has no <cameras> section", path=path, line=inp.line, field="cameras")
    camera = _camera(cams, path, base, here, dbat_dir)
    ctrl = inp.find("ctrl_pts")
    control = _points(ctrl, path, base, here, dbat_dir) if ctrl is not None else []
    chk = inp.find("check_pts")
    check = _points(chk, path, base, here, dbat_dir) if chk is not None else []
    imgs = inp.find("images")
    if imgs is None:
        raise InputError("the script has no <images> section", path=path, line=inp.line, field="images")
    images, image_files, images_list = _images(imgs, path, base, here, dbat_dir)
    ip = inp.find("image_pts")
    if ip is None:
        raise InputError("the script has no <image_pts> section", path=path, line=inp.line, field="image_pts")
    marks = _marks(ip, path, base, here, dbat_dir)
    pe = inp.find("prior_eo")
    prior_eo = _prior_eo(pe, path, base, here, dbat_dir) if pe is not None else None
    eo_initial = "default"
    # operations
    ops_node = root.find("operations")
    operations, unknown = [], []
    min_rays = 2
    io_initial = "default"
    est_io = {k: False for k in IO_FLAGS}
    est_eo = True
    io_overrides: dict = {}
    datum = None
    for op in ops_node.findall("operation") if ops_node is not None else []:
        kids = [k for k in op.children if k.tag != "c"]
        opname = kids[0].tag if kids else op.value
        operations.append(opname)
        if opname not in KNOWN_OPERATIONS:
            raise InputError(f"DBAT operation {quote(opname)} is not one baarda carries out (known: "
                             f"{', '.join(sorted(KNOWN_OPERATIONS))})", path=path, line=op.line, field=opname)
        if opname == "set_datum":
            node = kids[0] if kids else op
            kind = node.value
            if kind != "depend":
                raise InputError(f"set_datum {quote(kind)} is not carried out (DBAT knows 'depend')", path=path,
                                 line=node.line, field="set_datum")
            ref_cam = node.attrib.get("ref_cam", "1")
            base_attr = node.attrib.get("ref_base", "longest")
            if base_attr not in ("longest", "x", "y", "z"):
                raise InputError(f"ref_base is 'longest', 'x', 'y' or 'z', got {quote(base_attr)}", path=path,
                                 line=node.line, field="ref_base")
            datum = ("depend", _id(ref_cam), base_attr, node.line)
        if opname == "check_ray_count":
            mr = op.attrib.get("min_rays", "2")
            v = _num(mr, path, op.line, "min_rays")
            if v != int(v) or v < 1:
                raise InputError(f"min_rays must be a whole number ≥ 1, got {quote(mr)}", path=path, line=op.line,
                                 field="min_rays")
            min_rays = int(v)
        elif opname == "set_initial_values":
            io = kids[0].find("io")
            if io is not None:
                v = (io.find("all").value if io.find("all") is not None else io.value).lower()
                if v not in ("default", "loaded"):
                    raise InputError(f"initial io values are 'default' or 'loaded', got {quote(v)}", path=path,
                                     line=io.line, field="io")
                io_initial = v
                for ch in io.children if io is not None else []:
                    if ch.tag in ("all", "c"):
                        continue
                    if ch.tag not in ("cc", "pp", "K", "P", "aspect", "skew"):
                        raise InputError(f"unknown initial io value <{ch.tag}> (known: all, cc, pp, K, P, aspect, "
                                         "skew)", path=path, line=ch.line, field=ch.tag)
                    t = ch.value.lower()
                    if t in ("default", "loaded") or (ch.tag == "cc" and t == "focal"):
                        io_overrides[ch.tag] = "default" if t == "focal" else t
                    else:
                        n = {"cc": 1, "pp": 2, "K": (1, 2, 3), "P": (1, 2), "aspect": 1, "skew": 1}[ch.tag]
                        io_overrides[ch.tag] = tuple(_nums(ch, path, n))
            eo = kids[0].find("eo")
            if eo is not None:
                v = (eo.find("all").value if eo.find("all") is not None else eo.value).lower()
                if v not in ("default", "loaded"):
                    raise InputError(f"initial eo values are 'loaded', got {quote(v)}", path=path, line=eo.line,
                                     field="eo")
                if v == "loaded" and prior_eo is None:
                    raise InputError("<eo>loaded</eo> needs a <prior_eo> file in the input section", path=path,
                                     line=eo.line, field="eo")
                eo_initial = v
        elif opname == "set_bundle_estimate_params":
            est_io = _estimate_io(kids[0].find("io"), path, camera.nK, camera.nP)
            eo = kids[0].find("eo")
            if eo is not None:
                allv = eo.find("all")
                est_eo = _bool(allv if allv is not None else eo, path, "eo")
                if not est_eo:
                    raise InputError("fixed exterior orientations need given orientations, which DBAT scripts "
                                     "without <eo> files do not have", path=path, line=eo.line, field="eo")
            opn = kids[0].find("op")
            if opn is not None:
                allv = opn.find("all")
                node = allv if allv is not None else opn
                if node.value.lower() != "default" and not _bool(node, path, "op"):
                    raise InputError("fixed object points (<op> false) are not carried out: baarda estimates every "
                                     "tie point", path=path, line=opn.line, field="op")
    return DbatScript(path=path, name=name, object_unit=unit, control=control, check=check, images=images,
                      image_files=image_files, images_list=images_list, marks=marks, camera=camera,
                      min_rays=min_rays, io_initial=io_initial, estimate_io=est_io, estimate_eo=est_eo,
                      operations=operations, unknown_operations=unknown, prior_eo=prior_eo, eo_initial=eo_initial,
                      io_overrides=io_overrides, datum=datum)


# --------------------------------------------------------------------------------------------
# the block


def camera_values(cam: DbatCamera, io_initial: str, overrides: Mapping | None = None) -> dict:
    """Initial interior orientation in baarda's frame: c, xp, yp (mm, y up, origin at the format
    centre) and the ``brown-backward`` parameters (:data:`AP_NAMES`)."""
    p = cam.pixel_mm
    W, H = cam.image
    loaded = io_initial == "loaded"
    c = (cam.cc if cam.cc is not None else cam.focal) if loaded else cam.focal
    if loaded and cam.pp is not None:
        xp, yp = cam.pp[0] - W * p / 2, H * p / 2 - cam.pp[1]
    else:
        xp, yp = 0.0, 0.0
    dbat = np.zeros(7)
    if loaded:
        dbat[:len(cam.K)] = cam.K
        dbat[3:3 + len(cam.P)] = cam.P
        dbat[5] = cam.aspect - 1.0
        dbat[6] = cam.skew
    for name, v in (overrides or {}).items():      # set_initial_values' per-parameter values after <all>
        if name == "cc":
            c = cam.focal if v == "default" else (cam.cc if cam.cc is not None else cam.focal) if v == "loaded" else v[0]
        elif name == "pp":
            if v == "default" or (v == "loaded" and cam.pp is None):
                xp, yp = 0.0, 0.0
            else:
                px, py = cam.pp if v == "loaded" else v
                xp, yp = px - W * p / 2, H * p / 2 - py
        elif name in ("K", "P"):
            sl = slice(0, 3) if name == "K" else slice(3, 5)
            dbat[sl] = 0.0
            vals = () if v == "default" else (cam.K if name == "K" else cam.P) if v == "loaded" else v
            dbat[sl.start:sl.start + len(vals)] = vals
        elif name == "aspect":
            dbat[5] = 0.0 if v == "default" else cam.aspect - 1.0 if v == "loaded" else v[0] - 1.0
        elif name == "skew":
            dbat[6] = 0.0 if v == "default" else cam.skew if v == "loaded" else v[0]
    return {"c": float(c), "xp": float(xp), "yp": float(yp), "ap": dbat * DBAT_SIGN}


def depend_datum(X0: np.ndarray, ref: int, ref_base: str) -> tuple[int, int]:
    """DBAT's dependent relative orientation (``seteoest(s,'depend',…)``): the reference photo's six
    elements are fixed and so is one coordinate of one other projection centre — the largest
    (signed) offset from the reference centre among the coordinates ``ref_base`` names (``longest``:
    x, y and z), the first in MATLAB's column order on a tie.  Returns (photo index, axis)."""
    axes = {"longest": (0, 1, 2), "x": (0,), "y": (1,), "z": (2,)}[ref_base]
    off = X0[:, axes] - X0[ref, axes]
    k = int(np.argmax(off.ravel()))
    return k // len(axes), axes[k % len(axes)]


def dbat_from_baarda(c, xp, yp, ap, cam: DbatCamera) -> dict:
    """baarda's camera values in DBAT's conventions: cc, pp (mm from the image corner, y down), K, P,
    as (aspect − 1), sk."""
    p = cam.pixel_mm
    W, H = cam.image
    d = np.asarray(ap, float) * DBAT_SIGN
    return {"cc": float(c), "px": float(xp + W * p / 2), "py": float(H * p / 2 - yp), "K1": d[0], "K2": d[1],
            "K3": d[2], "P1": d[3], "P2": d[4], "as": d[5], "sk": d[6]}


def photo_ids(images: dict[str, str]) -> list[str]:
    """Photo ids: the image files' names without extension (``P8250021``), as other sources name
    photos; DBAT's image numbers when two files share a name."""
    stems = [re.split(r"[/\\]", p)[-1].rsplit(".", 1)[0] for p in images.values()]
    return stems if len(set(stems)) == len(stems) and all(stems) else list(images)


def dbat_block(script: DbatScript, datum: str = "script") -> Block:
    """The script as a baarda block: one ``brown-backward`` camera, one photo per listed image (id: the
    file name without extension; no orientation: the bundle resects and intersects), control (fixed or weighted), check and tie
    points, marks in mm with their σ.  Tie and check points with fewer than ``min_rays`` rays are left
    out (DBAT's ``check_ray_count``), with their marks."""
    cam = script.camera
    p = cam.pixel_mm
    W, H = cam.image
    iv = camera_values(cam, script.io_initial, script.io_overrides)
    e = script.estimate_io
    s_iop = [FREE if e["cc"] else FIXED, FREE if e["px"] else FIXED, FREE if e["py"] else FIXED]
    s_ap = [FREE if e[k] else FIXED for k in ("K1", "K2", "K3", "P1", "P2", "aspect", "skew")]
    cameras = Cameras.make(["1"], iv["c"], iv["xp"], iv["yp"], ap_model=SUPPORTED_LENS_MODELS[cam.model],
                           ap=iv["ap"][None], sigma_iop=[s_iop], sigma_ap=[s_ap],
                           format_mm=[(W * p, H * p)], pixel_mm=p, resolution=[(W, H)])
    # points: control, check, tie
    ids, XYZ, role, sig, labels = [], [], [], [], {}
    where = {}
    for kind, sets in (("control", script.control), ("check", script.check)):
        for s in sets:
            for k, pid in enumerate(s.ids):
                if pid in where:
                    raise InputError(f"point {quote(pid)} is both {where[pid]} and {kind}" if where[pid] != kind else
                                     f"point {quote(pid)} listed twice as {kind}", path=s.file, line=s.lines[k],
                                     field="id")
                where[pid] = kind
                ids.append(pid)
                XYZ.append(s.XYZ[k])
                role.append("full" if kind == "control" else "check")
                sig.append(s.sigma[k] if kind == "control" else np.full(3, FREE))
                labels[pid] = s.labels[k]
    # marks (vectorised: a 180 000-coordinate project in well under a second)
    img_index = {iid: k for k, iid in enumerate(script.images)}
    if not sum(len(mf.point) for mf in script.marks):
        raise InputError("no image measurements", path=script.marks[0].file)
    m_img = np.concatenate([np.asarray(mf.image, dtype=str).reshape(-1) for mf in script.marks])
    m_pt = np.concatenate([np.asarray(mf.point, dtype=str).reshape(-1) for mf in script.marks])
    m_uv = np.concatenate([np.asarray(mf.uv, float).reshape(-1, 2) for mf in script.marks])
    m_s = np.concatenate([np.asarray(mf.sigma_px, float).reshape(-1) for mf in script.marks])
    m_file = np.concatenate([np.full(len(mf.point), f) for f, mf in enumerate(script.marks)])
    m_line = np.concatenate([np.asarray(mf.lines, int).reshape(-1) for mf in script.marks])

    def where_(k):
        return {"path": script.marks[m_file[k]].file, "line": int(m_line[k])}

    u_img, img_inv = np.unique(m_img, return_inverse=True)
    u_img_index = np.array([img_index.get(i, -1) for i in u_img], int)
    ob_img_all = u_img_index[img_inv]
    bad = np.flatnonzero(ob_img_all < 0)
    if len(bad):
        k = int(bad[0])
        raise InputError(f"image {quote(m_img[k])} is not in the image list", field="im", **where_(k))
    u_pt, first_pt, pt_inv = np.unique(m_pt, return_index=True, return_inverse=True)
    key = ob_img_all.astype(np.int64) * len(u_pt) + pt_inv
    order = np.argsort(key, kind="stable")
    sk = key[order]
    rep = np.flatnonzero(sk[1:] == sk[:-1])
    if len(rep):
        k = int(order[1:][rep].min())                            # the first repeated measurement in file order
        f0 = int(order[np.searchsorted(sk, key[k])])
        raise InputError(f"point {quote(m_pt[k])} measured twice in image {quote(m_img[k])} (first: "
                         f"{script.marks[m_file[f0]].file.name}:{int(m_line[f0])})", field="id", **where_(k))
    out = ~((-0.5 * W <= m_uv[:, 0]) & (m_uv[:, 0] <= 1.5 * W) & (-0.5 * H <= m_uv[:, 1]) & (m_uv[:, 1] <= 1.5 * H))
    if out.any():
        k = int(np.flatnonzero(out)[0])
        u, v = m_uv[k]
        raise InputError(f"mark ({u:g}, {v:g}) px lies far outside the {W} × {H} image", field="x", **where_(k))
    # outside the image on any side alike (u < 0 as u > W); most of a file's marks outside the W × H image
    # but inside H × W: x and y swapped in the file's format (or the camera's image size)
    inside = (m_uv[:, 0] >= 0) & (m_uv[:, 0] <= W) & (m_uv[:, 1] >= 0) & (m_uv[:, 1] <= H)
    inside_t = (m_uv[:, 0] >= 0) & (m_uv[:, 0] <= H) & (m_uv[:, 1] >= 0) & (m_uv[:, 1] <= W)
    if W != H:
        for f, mf in enumerate(script.marks):
            sel = m_file == f
            n_f, n_out, n_out_t = int(sel.sum()), int((~inside[sel]).sum()), int((~inside_t[sel]).sum())
            if n_out >= max(3, SWAP_FRACTION * n_f) and 10 * n_out_t < n_out:
                raise InputError(f"{n_out} of {n_f} marks of {mf.file.name} lie outside the {W} × {H} px image but "
                                 f"{n_f - n_out_t} inside {H} × {W}: x and y are swapped in the format (or in the "
                                 f"camera's <image>)", path=script.path, line=mf.format_line or None, field="format")
    marks_outside = ()
    if not inside.all():
        k = int(np.flatnonzero(~inside)[0])
        marks_outside = (int((~inside).sum()), f"{script.marks[m_file[k]].file.name}:{int(m_line[k])}")
    u_list = u_pt.tolist()
    new = [u_list[q] for q in np.argsort(first_pt, kind="stable").tolist() if u_list[q] not in where]
    for pid in new:                                  # new tie points in order of first appearance
        where[pid] = "tie"
    n_known = len(ids)
    ids = ids + new
    role = role + ["tie"] * len(new)
    XYZ_a = np.vstack([np.asarray(XYZ, float).reshape(-1, 3), np.full((len(new), 3), np.nan)])
    sig_a = np.vstack([np.asarray(sig, float).reshape(-1, 3), np.full((len(new), 3), FREE)])
    counts = np.bincount(pt_inv, minlength=len(u_pt))
    rays = dict.fromkeys(ids, 0)
    rays.update(zip(u_list, counts.tolist()))
    ray_arr = np.array([rays[i] for i in ids], int)
    role_a = np.asarray(role, dtype=object)
    drop_mask = np.isin(role_a, ["tie", "check"]) & (ray_arr < script.min_rays)
    dropped = [ids[k] for k in np.flatnonzero(drop_mask)]
    keep_obs = ~np.isin(m_pt, np.asarray(dropped, dtype=str)) if dropped else np.ones(len(m_pt), bool)
    kp = ~drop_mask
    kept_ids = [i for i, k in zip(ids, kp) if k]
    index = dict(zip(kept_ids, range(len(kept_ids))))
    points = Points.make(kept_ids, XYZ_a[kp], role=role_a[kp].tolist(), sigma=sig_a[kp])
    del n_known
    u_index = np.array([index.get(q, -1) for q in u_list], int)
    uv = m_uv[keep_obs]
    xy = mm_from_pixels(uv, (W, H), p, convention="colmap")
    obs = Observations.make(ob_img_all[keep_obs], u_index[pt_inv[keep_obs]], xy, sigma=m_s[keep_obs] * p)
    photos = Photos.make(photo_ids(script.images), camera=0,
                         image_path=[str(script.image_files.get(k) or "") for k in script.images])
    if script.eo_initial == "loaded" and script.prior_eo:
        X0 = np.full((len(photos), 3), np.nan)
        opk = np.full((len(photos), 3), np.nan)
        for iid, (x0, a, file, line) in script.prior_eo.items():
            if iid not in img_index:
                raise InputError(f"image {quote(iid)} is not in the image list", path=file, line=line, field="id")
            X0[img_index[iid]] = x0
            opk[img_index[iid]] = a
        photos = photos.replace(X0=X0, opk=opk)
    has_control = any(len(s.ids) for s in script.control)
    if datum == "script" and script.datum is not None:
        _, ref_id, ref_base, dline = script.datum
        ref = int(ref_id) - 1 if ref_id.isdigit() else -1       # DBAT's ref_cam: the photo's position (1-based)
        if not 0 <= ref < len(photos):
            raise InputError(f"ref_cam {quote(ref_id)} is not a photo of the list (1 to {len(photos)})",
                             path=script.path, line=dline, field="ref_cam")
        X0 = np.asarray(photos.X0, float)
        if not np.isfinite(X0).all():
            raise InputError("set_datum depend fixes initial orientations: it needs every photo's (a <prior_eo> file "
                             "with <eo>loaded</eo>)", path=script.path, line=dline, field="set_datum")
        j, axis = depend_datum(X0, ref, ref_base)
        sig = np.array(photos.sigma_eo, float)
        sig[ref] = FIXED
        sig[j, axis] = FIXED
        photos = photos.replace(sigma_eo=sig)
    elif not has_control and datum == "script":
        raise InputError("the script has neither control points nor a set_datum operation: no datum (give the dbat "
                         "stage datum = \"free\" and the bundle datum = \"free\" for a free network)",
                         path=script.path, field="ctrl_pts")
    unused_ctrl = [pid for pid, r in zip(ids, role) if r == "full" and rays[pid] == 0]
    info = DbatInfo(
        script=str(script.path), name=script.name, camera=cam, io_initial=script.io_initial,
        estimate_io=script.estimate_io, min_rays=script.min_rays, operations=script.operations,
        eo_initial=script.eo_initial, unknown_operations=script.unknown_operations, labels=labels,
        images={k: (str(v) if v is not None else None) for k, v in script.image_files.items()},
        image_paths=script.images, image_numbers=dict(zip(photo_ids(script.images), script.images)),
        marks=[DbatMarksInfo(file=str(m.file), count=len(m.point), sigma_px=sorted(set(m.sigma_px.tolist())),
                             sigma_source=m.sigma_source) for m in script.marks],
        dropped_points=dropped, dropped_marks=int((~keep_obs).sum()), unmeasured_control=unused_ctrl,
        control_files=[str(s.file) for s in script.control], check_files=[str(s.file) for s in script.check],
        marks_outside=marks_outside)
    meta = {"dbat": info}
    if datum == "script" and script.datum is not None:
        meta["dbat_datum"] = {"ref_photo": str(photos.ids[ref]), "fixed_photo": str(photos.ids[j]),
                              "fixed_axis": "XYZ"[axis], "value": float(X0[j, axis])}
    return Block(cameras, photos, points, obs, object_unit=script.object_unit, meta=meta,
                 source=SourceInfo(path=str(script.path), format="DBAT"))
