"""BAL ("Bundle Adjustment in the Large") text problems → :class:`baarda.pipeline.model.Block`.

File layout (Agarwal et al. 2010): a header ``n_cams n_pts n_obs``; ``n_obs`` lines ``cam pt x y``
(pixels, origin at the image centre, x right, y up); ``9 n_cams`` camera parameters (Rodrigues
``r`` (3), ``t`` (3), ``f``, ``k1``, ``k2``); ``3 n_pts`` point coordinates.  Parameters may be one
per line (the original files) or several per line.

BAL's camera model::

    P = R(r) X + t,   p = −P / P_z,   p' = f (1 + k1 ‖p‖² + k2 ‖p‖⁴) p

Its camera frame is baarda's image-space frame (x right, y up, z back: the camera looks down −Z),
so ``R_cam_from_world = R(r)`` and ``X0 = −R(r)ᵀ t``; with pitch ``s`` (mm per pixel) and
``c = f s`` the radial term is the brown model at the ideal point with ``K1 = k1/c²``,
``K2 = k2/c⁴`` — exactly (``docs/bal-libmv.md``).
"""

from __future__ import annotations

import math
import re
import warnings

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baarda.pipeline.errors import read_text_limited
from baarda.pipeline.geometry.rotations import rotation_from_rotvec

from baarda.pipeline.api import Block, InputError
from baarda.pipeline.errors import quote
from baarda.pipeline.geometry import opk_from_rotation
from baarda.pipeline.model import FIXED, FREE, Cameras, Observations, Photos, Points, SourceInfo

from baarda.pipeline.camera.convert import BROWN


@dataclass(frozen=True, eq=False)
class BalProblem:
    """The arrays of a BAL file, as in the file (pixels, BAL's parameters)."""

    cam: np.ndarray        # (k,) int
    pt: np.ndarray         # (k,) int
    xy: np.ndarray         # (k, 2) pixels, origin image centre, y up
    cameras: np.ndarray    # (n_cams, 9) r, t, f, k1, k2
    points: np.ndarray     # (n_pts, 3)
    path: str = ""


def _number(tok: str, path, line: int, what: str) -> float:
    try:
        v = float(tok)
    except ValueError:
        raise InputError(f"expected a number for {what}, got {quote(tok)}", path=path, line=line, field=what) from None
    if not math.isfinite(v):
        raise InputError(f"{what} must be a finite number, got {quote(tok)}", path=path, line=line, field=what)
    return v


def _int(tok: str, path, line: int, what: str) -> int:
    try:
        v = int(tok)
    except ValueError:
        raise InputError(f"expected an integer for {what}, got {quote(tok)}", path=path, line=line, field=what) from None
    if abs(v) >= 2**62:              # an index or count: numpy's int64 cannot hold it (and no block has it)
        raise InputError(f"{what} = {quote(tok)} is out of range (an index or count below 2^62)", path=path,
                         line=line, field=what)
    return v


_OBS_DTYPE = np.dtype([("cam", np.int64), ("pt", np.int64), ("x", np.float64), ("y", np.float64)])
_PLAIN = b"0123456789.eE+- \t\n"
"""The bytes of the parameter values the bulk parse reads: plain numbers, blanks and newlines."""
_NOT_BLANK = re.compile(r"[^ \t\n]")


def _parse_fast(data: bytes, text: str):
    """The file (``data``, decoded as ``text``) parsed in bulk by numpy's C parsers — ``loadtxt``
    for the ``cam pt x y`` lines, one ``fromstring`` of every parameter value —, or ``None`` when
    anything is not exactly as it must be — a line break other than LF (the line-by-line reading
    splits lines as Python does), a header that is not three plain integers, a line with another
    number of values, a token that is not a plain number, a value that is not finite, an index out
    of range, a repeated observation, a count that does not match the header, f ≤ 0 — so that
    :func:`read_bal` reads line by line and names the line and field.  Every value is the number
    Python's ``float`` reads from its token, bit for bit (numpy's parsers round correctly)."""
    import io

    if any(c in text for c in "\r\x0b\x0c\x1c\x1d\x1e"):
        return None
    first = _NOT_BLANK.search(text)            # the header: the first line that is not blank
    if first is None:
        return None
    h0 = text.rfind("\n", 0, first.start()) + 1
    h1 = text.find("\n", h0)
    head = text[h0:h1 if h1 >= 0 else len(text)].split()
    if h1 < 0 or len(head) != 3 or not all(t.isdigit() and len(t) <= 18 for t in head):
        return None
    n_cams, n_pts, n_obs = (int(t) for t in head)
    need = 9 * n_cams + 3 * n_pts
    # the observation lines: the n_obs lines after the header (text is ASCII: byte offsets are offsets)
    nl = np.flatnonzero(np.frombuffer(data, np.uint8, offset=h1 + 1) == 10)
    if n_obs > len(nl) + 1:
        return None
    end = h1 + 1 + (int(nl[n_obs - 1]) + 1 if n_obs <= len(nl) else len(data) - h1 - 1) if n_obs else h1 + 1
    try:
        if n_obs:
            obs = np.loadtxt(io.StringIO(text[h1 + 1:end]), dtype=_OBS_DTYPE, comments=None, ndmin=1)
        else:
            obs = np.zeros(0, _OBS_DTYPE)
        rest = data[end:]
        if len(obs) != n_obs or rest.translate(None, _PLAIN):
            return None
        with warnings.catch_warnings():
            warnings.simplefilter("error")              # a token numpy cannot read to its end
            values = np.fromstring(rest, dtype=np.float64, sep=" ") if rest.strip() else np.zeros(0)
    except (ValueError, OverflowError, DeprecationWarning):
        return None
    # every token one number: as many numbers as tokens
    if len(values) != need or len(rest.split()) != need:
        return None
    cam, pt = obs["cam"].copy(), obs["pt"].copy()
    xy = np.column_stack([obs["x"], obs["y"]])
    if not (np.isfinite(xy).all() and np.isfinite(values).all()):
        return None
    if n_obs and ((cam < 0).any() or (cam >= n_cams).any() or (pt < 0).any() or (pt >= n_pts).any()):
        return None
    key = np.sort(cam * max(n_pts, 1) + pt)
    if (np.diff(key) == 0).any() or (values[6:9 * n_cams:9] <= 0).any():
        return None
    return cam, pt, xy, values[:9 * n_cams].reshape(n_cams, 9), values[9 * n_cams:].reshape(n_pts, 3)


def read_bal(path: str | Path) -> BalProblem:
    """Parse a BAL text file; every format error is an InputError naming the line and field."""
    path = Path(path)
    if not path.exists():
        raise InputError("BAL file not found", path=path)
    text = read_text_limited(path, what="a BAL file", encoding="ascii")
    fast = _parse_fast(text.encode("ascii"), text)
    if fast is not None:
        return BalProblem(*fast, path=str(path))
    # the line-by-line reading below names the line and field of the first mistake
    lines = text.splitlines()
    # skip leading blank lines for the header
    ln = 0
    while ln < len(lines) and not lines[ln].strip():
        ln += 1
    if ln == len(lines):
        raise InputError("empty file; expected the header 'n_cams n_pts n_obs'", path=path, line=1)
    head = lines[ln].split()
    if len(head) != 3:
        raise InputError(f"header must be 'n_cams n_pts n_obs', got {len(head)} value(s)", path=path,
                         line=ln + 1, field="header")
    n_cams, n_pts, n_obs = (_int(t, path, ln + 1, f) for t, f in zip(head, ("n_cams", "n_pts", "n_obs")))
    if min(n_cams, n_pts, n_obs) < 0:
        raise InputError("negative count in the header", path=path, line=ln + 1, field="header")
    # counts that exceed the file must not allocate: arrays are sized by what the file can hold
    # (a line per observation; two characters at least per value) and the loops below report
    # where the file ends
    n_obs_fit = min(n_obs, max(len(lines) - ln - 1, 0))
    ln += 1
    obs_line0 = ln + 1                       # 1-based line of observation 0
    cam = np.empty(n_obs_fit, int)
    pt = np.empty(n_obs_fit, int)
    xy = np.empty((n_obs_fit, 2))
    for i in range(n_obs):
        if ln >= len(lines):
            raise InputError(f"file ends after {i} of {n_obs} observation lines (truncated?)", path=path,
                             line=ln + 1, field="observation")
        tok = lines[ln].split()
        if len(tok) != 4:
            raise InputError(f"observation line must be 'cam pt x y', got {len(tok)} value(s)", path=path,
                             line=ln + 1, field="observation")
        cam[i] = _int(tok[0], path, ln + 1, "cam")
        pt[i] = _int(tok[1], path, ln + 1, "pt")
        xy[i, 0] = _number(tok[2], path, ln + 1, "x")
        xy[i, 1] = _number(tok[3], path, ln + 1, "y")
        if not (0 <= cam[i] < n_cams):
            raise InputError(f"camera index {cam[i]} out of range 0…{n_cams - 1}", path=path, line=ln + 1, field="cam")
        if not (0 <= pt[i] < n_pts):
            raise InputError(f"point index {pt[i]} out of range 0…{n_pts - 1}", path=path, line=ln + 1, field="pt")
        ln += 1

    key = cam * max(n_pts, 1) + pt
    order = np.argsort(key, kind="stable")
    twice = np.flatnonzero(np.diff(key[order]) == 0)
    if twice.size:
        i = int(order[twice[0] + 1])
        raise InputError(f"camera {cam[i]} observes point {pt[i]} twice (first on line {obs_line0 + order[twice[0]]})",
                         path=path, line=obs_line0 + i, field="observation")
    need = 9 * n_cams + 3 * n_pts
    fit = min(need, len(text) // 2 + 1)
    values = np.empty(fit)
    value_line = np.empty(fit, np.int64)
    k = 0
    while k < need:
        if ln >= len(lines):
            what = (f"camera {k // 9} parameter {k % 9 + 1} of 9" if k < 9 * n_cams
                    else f"point {(k - 9 * n_cams) // 3} coordinate {(k - 9 * n_cams) % 3 + 1} of 3")
            raise InputError(f"file ends before {what} (read {k} of {need} parameter values; truncated?)",
                             path=path, line=ln + 1, field="camera" if k < 9 * n_cams else "point")
        for tok in lines[ln].split():
            if k >= need:
                raise InputError("more values than the header announces", path=path, line=ln + 1)
            values[k] = _number(tok, path, ln + 1, "camera parameter" if k < 9 * n_cams else "point coordinate")
            value_line[k] = ln + 1
            k += 1
        ln += 1
    if any(s.strip() for s in lines[ln:]):
        extra = ln + next(i for i, s in enumerate(lines[ln:]) if s.strip()) + 1
        raise InputError("more values than the header announces", path=path, line=extra)
    f = values[6:9 * n_cams:9]
    if (f <= 0).any():
        j = int(np.argmax(f <= 0))
        raise InputError(f"camera {j}: focal length f = {f[j]:g} must be positive", path=path,
                         line=int(value_line[9 * j + 6]), field="f")
    return BalProblem(cam=cam, pt=pt, xy=xy, cameras=values[:9 * n_cams].reshape(n_cams, 9),
                      points=values[9 * n_cams:].reshape(n_pts, 3), path=str(path))


def behind_camera(problem: BalProblem) -> np.ndarray:
    """Per observation: is the point behind its camera?  BAL's cameras look down −Z, so a point is
    in front when its camera-frame Z is negative.  Ceres (and COLMAP) give such an observation no
    residual; a collinearity adjustment fits it as measured."""
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(problem.cameras[:, :3]).as_matrix()[problem.cam]      # once per camera
    depth = np.einsum("kij,kj->ki", R, problem.points[problem.pt])[:, 2]
    return depth + problem.cameras[problem.cam, 5] >= 0


def baarda_from_bal(cameras: np.ndarray, pixel_mm):
    """BAL camera rows ``(n, 9)`` (``r``, ``t``, ``f``, ``k1``, ``k2``) → baarda's ``c`` (mm), brown
    ``K1``, ``K2``, ``R_cam_from_world (n, 3, 3)`` and ``X0 (n, 3)``; ``pixel_mm`` scalar or ``(n,)``.
    The inverse is :func:`bal_from_baarda`; both are the one place BAL's conventions live
    (``docs/bal-libmv.md``): BAL's camera frame is baarda's image-space frame, so
    ``R_cam_from_world = R(r)``, ``X0 = −Rᵀ t``, ``c = f·p``, ``K1 = k1/c²``, ``K2 = k2/c⁴``."""
    P = np.asarray(cameras, float).reshape(-1, 9)
    c = P[:, 6] * np.asarray(pixel_mm, float)
    R = rotation_from_rotvec(P[:, :3]).reshape(-1, 3, 3)
    X0 = -np.einsum("mji,mj->mi", R, P[:, 3:6])
    return c, P[:, 7] / c**2, P[:, 8] / c**4, R, X0


def bal_from_baarda(c, K1, K2, R_cam_from_world, X0, pixel_mm) -> np.ndarray:
    """The inverse of :func:`baarda_from_bal`: BAL camera rows ``(n, 9)`` of baarda's ``c`` (mm),
    brown ``K1``, ``K2``, ``R_cam_from_world (n, 3, 3)``, ``X0 (n, 3)`` and pitch ``pixel_mm``."""
    from scipy.spatial.transform import Rotation

    c = np.asarray(c, float).reshape(-1)
    R = np.asarray(R_cam_from_world, float).reshape(-1, 3, 3)
    out = np.empty((len(c), 9))
    out[:, :3] = Rotation.from_matrix(R).as_rotvec()
    out[:, 3:6] = -np.einsum("mij,mj->mi", R, np.asarray(X0, float).reshape(-1, 3))
    out[:, 6] = c / np.asarray(pixel_mm, float)
    out[:, 7] = np.asarray(K1, float) * c**2
    out[:, 8] = np.asarray(K2, float) * c**4
    return out


def block_from_bal(problem: BalProblem, *, pixel_mm: float = 0.001, sigma_px: float = 1.0,
                   intrinsics: str = "free", object_unit: str = "m") -> Block:
    """One baarda camera and one photo per BAL camera; brown ``K1 = k1/c²``, ``K2 = k2/c⁴``.

    intrinsics : ``"free"`` — c, K1, K2 unknown per camera (as BAL problems are solved), principal
        point fixed at the image centre; ``"fixed"`` — all interior parameters held.
    """
    if intrinsics not in ("free", "fixed"):
        raise ValueError(f"intrinsics must be 'free' or 'fixed', got {intrinsics!r}")
    P = problem.cameras
    m = len(P)
    f = P[:, 6]
    if np.any(f <= 0):
        bad = int(np.flatnonzero(f <= 0)[0])
        raise InputError(f"camera {bad}: focal length f = {f[bad]:g} must be > 0", path=problem.path, field="f")
    c, K1, K2, R, X0 = baarda_from_bal(P, pixel_mm)
    ap = np.zeros((m, len(BROWN)))
    ap[:, 0] = K1
    ap[:, 1] = K2
    free = FREE if intrinsics == "free" else FIXED
    sigma_ap = np.zeros_like(ap)
    sigma_ap[:, :2] = free
    cameras = Cameras.make([str(i) for i in range(m)], c, 0.0, 0.0, ap_model="brown", ap=ap,
                           sigma_iop=[free, FIXED, FIXED], sigma_ap=sigma_ap, pixel_mm=pixel_mm)
    opk = np.array([opk_from_rotation(Rk) for Rk in R]).reshape(-1, 3)
    photos = Photos.make([str(i) for i in range(m)], camera=np.arange(m), X0=X0, opk=opk)
    points = Points.make([str(j) for j in range(len(problem.points))], XYZ=problem.points, role="tie")
    obs = Observations.make(problem.cam, problem.pt, problem.xy * pixel_mm, sigma=sigma_px * pixel_mm)
    return Block(cameras=cameras, photos=photos, points=points, observations=obs, object_unit=object_unit,
                 meta={"bal": {"format": "bal", "pixel_mm": pixel_mm}},
                 source=SourceInfo(path=problem.path, format="BAL", pixel_format="BAL"))


def bal_reprojection(problem: BalProblem) -> np.ndarray:
    """Residuals ``observed − predicted`` (pixels, ``(k, 2)``) with BAL's own camera model."""
    P = problem.cameras[problem.cam]
    R = rotation_from_rotvec(P[:, :3])
    Pc = np.einsum("kij,kj->ki", R, problem.points[problem.pt]) + P[:, 3:6]
    p = -Pc[:, :2] / Pc[:, 2:3]
    r2 = (p**2).sum(axis=1)
    scale = P[:, 6] * (1 + P[:, 7] * r2 + P[:, 8] * r2**2)
    return problem.xy - scale[:, None] * p
