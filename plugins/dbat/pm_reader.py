"""Reader of PhotoModeler's text export ("pmexport"), as DBAT's ``loadpm`` reads it — pure parsing.

The file (``docs/pmexport.md``), line by line:

1. the project's title;
2. tolerance, maximum iterations and, optionally, the image width and height in pixels;
3. the default standard deviations (9 numbers);
4. the default camera: c, xp, yp, format width xs, height ys (mm), K1, K2, K3, P1, P2;
5. their standard deviations;

then one block per photo (N is the zero-based photo number), ended by a blank line::

    N FILE_NAME
    N X Y Z KAPPA PHI OMEGA          (m, degrees)
    N σ of the six
    [N cov xy xz yz]                 (the line may be blank)
    N c xp yp xs ys K1 K2 K3 P1 P2   (this photo's camera)
    N σ of the ten

then the control points ``id x y z sx sy sz`` (ended by a blank line; PhotoModeler leaves the list
empty when it has no control), the object points (same columns) and the marks
``photo id x y sx sy`` (pixels, origin at the image corner, x right, y down; σ in pixels).  What
follows (features and their visibility) is not read, as ``loadpm`` does not by default.

As ``loadpm`` + ``prob2dbatstruct``: the camera is the default one (line 4) with the image size of
line 2; marks of points that are not object points are left out; a zero σ anywhere makes every
mark's σ 1 px; PhotoModeler's "smart points", whose ids restart below the normal points' (marks
with σ 0 0), are renumbered above them.  Every malformed line raises
:class:`~baarda.pipeline.errors.InputError` naming the file, the line and the field.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baarda.pipeline.api import InputError
from baarda.pipeline.errors import finite_number as _num

CAMERA_FIELDS = ("c", "xp", "yp", "xs", "ys", "K1", "K2", "K3", "P1", "P2")
OUTER_FIELDS = ("X", "Y", "Z", "kappa", "phi", "omega")
POINT_FIELDS = ("id", "x", "y", "z", "sx", "sy", "sz")
MARK_FIELDS = ("photo", "id", "x", "y", "sx", "sy")


@dataclass(frozen=True)
class PmPhoto:
    number: int                 # zero-based, as in the file
    name: str                   # the image file as written
    outer: np.ndarray           # X, Y, Z (m), kappa, phi, omega (degrees)
    outer_std: np.ndarray
    inner: np.ndarray           # c, xp, yp, xs, ys, K1..P2
    inner_std: np.ndarray
    line: int


@dataclass(frozen=True)
class PmExport:
    """A PhotoModeler text export as read (PhotoModeler's conventions)."""

    path: Path
    title: str
    tolerance: float
    max_iter: int
    image_size: tuple[int, int] | None      # from line 2 (None: not given)
    default_std: np.ndarray
    camera: np.ndarray                       # c, xp, yp, xs, ys, K1, K2, K3, P1, P2 (mm)
    camera_std: np.ndarray
    photos: list[PmPhoto]
    control: np.ndarray                      # (n, 7) id x y z sx sy sz
    control_lines: np.ndarray
    objects: np.ndarray                      # (n, 7)
    object_lines: np.ndarray
    marks: np.ndarray                        # (k, 6) photo id x y sx sy
    mark_lines: np.ndarray
    renumbered_smart: int                    # shift added to smart-point ids (0: none)
    sigma_reset: bool                        # a zero σ made every mark's σ 1 px


def _numbers(text: str, path, line: int, fields, n: int | tuple[int, ...]) -> list[float]:
    toks = text.split()
    allowed = (n,) if isinstance(n, int) else n
    if len(toks) not in allowed:
        want = " or ".join(str(a) for a in allowed)
        f = fields[min(len(toks), len(fields) - 1)] if fields else None
        raise InputError(f"expected {want} numbers, got {len(toks)}", path=path, line=line, field=f)
    return [_num(t, path, line, fields[i] if i < len(fields) else f"value {i + 1}") for i, t in enumerate(toks)]


def _photo_number(tok: str, path, line: int, want: int | None) -> int:
    try:
        v = int(tok)
    except ValueError:
        raise InputError(f"expected the photo number, got {tok!r}", path=path, line=line, field="photo") from None
    if want is not None and v != want:
        raise InputError(f"the photo block's lines carry photo number {v}, expected {want}", path=path, line=line,
                         field="photo")
    return v


def _table(lines: list[str], start: int, path, fields, what: str) -> tuple[np.ndarray, np.ndarray, int]:
    """Rows of ``len(fields)`` numbers from line index ``start`` up to the first blank line (or the
    end).  Returns (values, 1-based lines, index of the line after the table)."""
    end = start
    n = len(lines)
    while end < n and lines[end].strip():
        end += 1
    if end == start:
        return np.zeros((0, len(fields))), np.zeros(0, int), min(end + 1, n)
    block = lines[start:end]
    try:
        arr = np.array([s.split() for s in block], dtype=float)     # fast path: well-formed rows
        if arr.ndim != 2 or arr.shape[1] != len(fields) or not np.isfinite(arr).all():
            raise ValueError
    except ValueError:
        for i, s in enumerate(block):                                # find the first bad row: its line and field
            _numbers(s, path, start + i + 1, fields, len(fields))
        raise AssertionError("unreachable") from None
    return arr, np.arange(start + 1, end + 1), min(end + 1, n)


def read_pmexport(path: Path, image_size: tuple[int, int] | None = None) -> PmExport:
    """Read a PhotoModeler text export (see the module's docstring)."""
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise InputError("file not found", path=path) from None
    except IsADirectoryError:
        raise InputError("is a folder, not a file", path=path) from None
    except UnicodeDecodeError:
        try:
            text = path.read_bytes().decode("latin-1")
        except Exception:                                            # pragma: no cover
            raise InputError("not a text file", path=path) from None
    except OSError as e:
        raise InputError(f"cannot read: {e.strerror}", path=path) from None
    lines = text.splitlines()
    if len(lines) < 5:
        raise InputError(f"a PhotoModeler export has at least 5 header lines, the file has {len(lines)}", path=path,
                         line=max(len(lines), 1), field="header")
    title = lines[0].strip()
    tol = _numbers(lines[1], path, 2, ("tolerance", "max_iter", "width", "height"), (2, 4))
    if tol[1] != int(tol[1]) or tol[1] < 0:
        raise InputError(f"max_iter must be a whole number, got {tol[1]:g}", path=path, line=2, field="max_iter")
    size = None
    if len(tol) == 4:
        if not (tol[2] >= 1 and tol[3] >= 1 and tol[2] == int(tol[2]) and tol[3] == int(tol[3])):
            raise InputError("the image size must be two positive whole numbers of pixels", path=path, line=2,
                             field="width")
        size = (int(tol[2]), int(tol[3]))
    if image_size is not None:
        size = (int(image_size[0]), int(image_size[1]))
    dstd = np.array(_numbers(lines[2], path, 3, tuple(f"default σ {i + 1}" for i in range(9)), 9))
    cam = np.array(_numbers(lines[3], path, 4, CAMERA_FIELDS, 10))
    cam_std = np.array(_numbers(lines[4], path, 5, tuple("σ " + f for f in CAMERA_FIELDS), 10))
    if not cam[0] > 0:
        raise InputError(f"the camera constant must be positive, got {cam[0]:g} mm", path=path, line=4, field="c")
    if not (cam[3] > 0 and cam[4] > 0):
        raise InputError("the format size (xs, ys) must be positive", path=path, line=4,
                         field="xs" if not cam[3] > 0 else "ys")
    photos: list[PmPhoto] = []
    i = 5
    n = len(lines)
    while i < n:
        s = lines[i]
        toks = s.split(None, 1)
        if not toks:
            i += 1                                   # the blank line ending the photo blocks
            break
        num = _photo_number(toks[0], path, i + 1, len(photos))
        if len(toks) < 2 or not toks[1].strip():
            raise InputError("the photo line needs the image file's name after the photo number", path=path,
                             line=i + 1, field="name")
        name, first = toks[1].strip(), i + 1
        if i + 5 >= n:
            raise InputError("the photo block is cut short (6 lines: name, orientation, σ, covariances, camera, σ)",
                             path=path, line=n, field="photo")

        def row(k, fields, count, allow_blank=False):
            t = lines[i + k].split()
            if not t and allow_blank:
                return None
            if not t:
                raise InputError(f"expected the photo's {fields[0]}… line, got a blank line", path=path,
                                 line=i + k + 1, field=fields[0])
            _photo_number(t[0], path, i + k + 1, num)
            return np.array(_numbers(" ".join(t[1:]), path, i + k + 1, fields, count))

        outer = row(1, OUTER_FIELDS, 6)
        outer_std = row(2, tuple("σ " + f for f in OUTER_FIELDS), 6)
        row(3, ("cov xy", "cov xz", "cov yz"), (0, 3), allow_blank=True)
        inner = row(4, CAMERA_FIELDS, 10)
        inner_std = row(5, tuple("σ " + f for f in CAMERA_FIELDS), 10)
        photos.append(PmPhoto(num, name, outer, outer_std, inner, inner_std, first))
        i += 6
    if not photos:
        raise InputError("no photo blocks after the 5 header lines", path=path, line=6, field="photo")
    ctrl, ctrl_lines, i = _table(lines, i, path, POINT_FIELDS, "control point")
    objs, obj_lines, i = _table(lines, i, path, POINT_FIELDS, "object point")
    marks, mark_lines, i = _table(lines, i, path, MARK_FIELDS, "mark")
    if not len(marks):
        raise InputError("no marks (photo id x y sx sy) after the object points", path=path, line=min(i, n) or 1,
                         field="marks")
    for arr, ln, what in ((ctrl, ctrl_lines, "control point"), (objs, obj_lines, "object point")):
        bad = np.flatnonzero(arr[:, 0] != np.round(arr[:, 0]))
        if len(bad):
            raise InputError(f"a {what} id is a whole number, got {arr[bad[0], 0]:g}", path=path,
                             line=int(ln[bad[0]]), field="id")
        neg = np.flatnonzero((arr[:, 4:] < 0).any(axis=1))
        if len(neg):
            k = int(np.argmax(arr[neg[0], 4:] < 0))
            raise InputError("a standard deviation must not be negative", path=path, line=int(ln[neg[0]]),
                             field=POINT_FIELDS[4 + k])
        u, first = np.unique(arr[:, 0], return_index=True)
        if len(u) != len(arr):
            dup = np.setdiff1d(np.arange(len(arr)), first)[0]
            raise InputError(f"{what} {int(arr[dup, 0])} listed twice", path=path, line=int(ln[dup]), field="id")
    for col, f in ((0, "photo"), (1, "id")):
        bad = np.flatnonzero(marks[:, col] != np.round(marks[:, col]))
        if len(bad):
            raise InputError(f"the mark's {f} is a whole number, got {marks[bad[0], col]:g}", path=path,
                             line=int(mark_lines[bad[0]]), field=f)
    bad = np.flatnonzero((marks[:, 0] < 0) | (marks[:, 0] >= len(photos)))
    if len(bad):
        raise InputError(f"photo {int(marks[bad[0], 0])} has no photo block (photos 0–{len(photos) - 1})", path=path,
                         line=int(mark_lines[bad[0]]), field="photo")
    neg = np.flatnonzero((marks[:, 4:] < 0).any(axis=1))
    if len(neg):
        raise InputError("a mark's standard deviation must not be negative", path=path, line=int(mark_lines[neg[0]]),
                         field="sx" if marks[neg[0], 4] < 0 else "sy")
    key = marks[:, 0] * (marks[:, 1].max() + 1 - min(marks[:, 1].min(), 0)) + marks[:, 1]
    order = np.argsort(key, kind="stable")
    d = np.flatnonzero(np.diff(key[order]) == 0)
    if len(d):
        k = order[d[0] + 1]
        raise InputError(f"point {int(marks[k, 1])} marked twice in photo {int(marks[k, 0])} (first on line "
                         f"{int(mark_lines[order[d[0]]])})", path=path, line=int(mark_lines[k]), field="id")
    # smart points (loadpm): marks with σ 0 0 whose ids restart below the normal points' are shifted
    smart = (marks[:, 4:6] == 0).all(axis=1)
    shift = 0
    split = np.flatnonzero(np.diff(objs[:, 0]) < 0) if len(objs) else np.zeros(0, int)
    if len(split) and smart.any() and (~smart).any():
        normal_ids, smart_ids = np.unique(marks[~smart, 1]), np.unique(marks[smart, 1])
        shift = int(normal_ids.max() + 1 - smart_ids.min())
        marks = marks.copy()
        marks[smart, 1] += shift
        objs = objs.copy()
        is_smart_obj = np.isin(objs[:, 0], smart_ids)
        is_smart_obj[:split[0] + 1] = False
        objs[is_smart_obj, 0] += shift
    reset = bool((marks[:, 4:6] == 0).any())
    if reset:
        marks = marks.copy()
        marks[:, 4:6] = 1.0
    if size is None:
        raise InputError("the image size is not in the export (line 2 has no width and height): give the option "
                         "image_size", path=path, line=2, field="width")
    return PmExport(path=path, title=title, tolerance=tol[0], max_iter=int(tol[1]), image_size=size,
                    default_std=dstd, camera=cam, camera_std=cam_std, photos=photos, control=ctrl,
                    control_lines=ctrl_lines, objects=objs, object_lines=obj_lines, marks=marks,
                    mark_lines=mark_lines, renumbered_smart=shift, sigma_reset=reset)
