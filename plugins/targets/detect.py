"""Target detection in one image with OpenCV: arrays in, ids and pixel positions out.

Every detector takes a grayscale ``uint8`` image and returns a :class:`Detection` with point ids
(strings, see :mod:`baarda.plugins.targets.boards`) and subpixel positions ``uv (n, 2)`` in OpenCV's
pixel convention (``(0, 0)`` is the centre of the top-left pixel, x right, y down).  A detector
that finds nothing returns an empty detection with a ``message``; it never raises for an image.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .boards import BoardGeometry, aruco_dictionary, opencv_board

DEFAULT_SIGMA_PX = {"charuco": 0.05, "chessboard": 0.05, "aruco": 0.2, "circles-grid": 0.07, "circles": 0.07}
"""A-priori sigma of an image coordinate per target type (LIBRARIES.md: measured on rendered boards;
chessboard corners refined like ChArUco corners)."""


@dataclass
class Detection:
    ids: list[str]
    uv: np.ndarray                 # (n, 2) pixels, OpenCV convention
    message: str = ""              # why nothing (or only part) was found
    extra: dict = field(default_factory=dict)

    def __len__(self):
        return len(self.ids)


def _empty(message: str, **extra) -> Detection:
    return Detection([], np.zeros((0, 2)), message, extra)


def detector_parameters(path=None):
    """``cv2.aruco.DetectorParameters`` (defaults with subpixel corner refinement, or read from a YAML file)."""
    import cv2

    params = cv2.aruco.DetectorParameters()
    if path:
        try:
            fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
            ok = fs.isOpened() and params.readDetectorParameters(fs.root())
            fs.release()
        except (cv2.error, SystemError) as e:      # OpenCV's YAML/XML parser on a malformed file
            detail = str(e).strip().splitlines()[-1][:120] if str(e).strip() else type(e).__name__
            raise ValueError(f"{path}: not an OpenCV YAML/XML file of ArUco detector parameters ({detail})") from None
        if not ok:
            raise ValueError(f"{path}: cannot read ArUco detector parameters")
    else:
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return params


def detect_chessboard(gray: np.ndarray, geom: BoardGeometry, method: str = "auto") -> Detection:
    """Inner corners of a chessboard.

    method : ``"sb"`` (``findChessboardCornersSB``, sector-based, accurate), ``"classic"``
        (``findChessboardCorners`` + ``cornerSubPix``) or ``"auto"`` (sb, then classic).
    """
    import cv2

    pattern = geom.inner_corners
    tried = []
    if method in ("sb", "auto"):
        ok, corners = cv2.findChessboardCornersSB(gray, pattern, flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
        tried.append("findChessboardCornersSB")
        if ok:
            return Detection([str(i) for i in range(len(corners))], corners.reshape(-1, 2).astype(float),
                             extra={"method": "sb"})
    if method in ("classic", "auto"):
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        ok, corners = cv2.findChessboardCorners(gray, pattern, flags=flags)
        tried.append("findChessboardCorners")
        if ok:
            crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
            corners = cv2.cornerSubPix(gray, corners, (11, 11), (-1, -1), crit)
            return Detection([str(i) for i in range(len(corners))], corners.reshape(-1, 2).astype(float),
                             extra={"method": "classic"})
    return _empty(f"no {pattern[0]}×{pattern[1]} inner-corner chessboard found ({', '.join(tried)})")


def detect_charuco(gray: np.ndarray, geom: BoardGeometry, params=None) -> Detection:
    """ChArUco corners (ids = OpenCV's ChArUco corner ids); partial boards are fine."""
    import cv2

    board = opencv_board(geom)
    det = cv2.aruco.CharucoDetector(board, cv2.aruco.CharucoParameters(), params or detector_parameters(),
                                    cv2.aruco.RefineParameters())
    corners, ids, _, marker_ids = det.detectBoard(gray)
    n_markers = 0 if marker_ids is None else len(marker_ids)
    if ids is None or len(ids) == 0:
        return _empty(f"no ChArUco corners found ({n_markers} marker(s) seen)", markers=n_markers)
    total = geom.inner_corners[0] * geom.inner_corners[1]
    msg = "" if len(ids) == total else f"partial board: {len(ids)} of {total} corners"
    return Detection([str(int(i)) for i in ids.ravel()], corners.reshape(-1, 2).astype(float), msg,
                     {"markers": n_markers})


def detect_aruco(gray: np.ndarray, geom: BoardGeometry, params=None) -> Detection:
    """Corners of ArUco markers: ids ``marker_id · 4 + k`` (only markers of the board when it has geometry)."""
    import cv2

    det = cv2.aruco.ArucoDetector(aruco_dictionary(geom.dictionary), params or detector_parameters())
    corners, ids, _ = det.detectMarkers(gray)
    if ids is None or len(ids) == 0:
        return _empty("no ArUco markers found")
    ids = ids.ravel().astype(int)
    keep = np.ones(len(ids), bool)
    if geom.has_geometry:
        keep = ids < geom.markers[0] * geom.markers[1]
    dup = {i for i in ids[keep] if (ids[keep] == i).sum() > 1}
    keep &= ~np.isin(ids, list(dup))
    uv = np.concatenate([np.asarray(c, float).reshape(4, 2) for c, k in zip(corners, keep) if k] or [np.zeros((0, 2))])
    out_ids = [str(4 * m + k) for m in ids[keep] for k in range(4)]
    notes = []
    if (~keep).sum() - len(dup):
        notes.append(f"{int((~keep).sum())} marker(s) not on the board ignored")
    if dup:
        notes.append(f"marker id(s) {sorted(int(d) for d in dup)} seen twice: ignored")
    if not out_ids:
        return _empty("; ".join(notes) or "no board markers found")
    return Detection(out_ids, uv, "; ".join(notes), {"markers": int(keep.sum())})


def _subpixel_outline(roi: np.ndarray, centre, axes, level: float, n_rays: int = 90) -> np.ndarray:
    """Points where the bilinear image crosses ``level`` along rays from ``centre`` (roi pixels)."""
    from scipy.ndimage import map_coordinates

    a, b = 0.5 * max(axes), 0.5 * min(axes)
    t = np.linspace(0, 2 * np.pi, n_rays, endpoint=False)
    d = np.column_stack([np.cos(t), np.sin(t)])
    s = np.linspace(max(0.5 * b, b - 3.0), a + 3.0, int(np.ceil((a + 3.0 - max(0.5 * b, b - 3.0)) / 0.05)) + 1)
    xs = centre[0] + d[:, 0:1] * s[None]
    ys = centre[1] + d[:, 1:2] * s[None]
    prof = map_coordinates(roi.astype(float), [ys.ravel(), xs.ravel()], order=1, mode="nearest").reshape(xs.shape)
    inside = prof[:, :1]
    sign = np.sign(prof - level) != np.sign(inside - level)
    pts = []
    for i in range(n_rays):
        j = np.argmax(sign[i])
        if not sign[i, j] or j == 0:
            continue
        f0, f1 = prof[i, j - 1] - level, prof[i, j] - level
        sj = s[j - 1] + (s[j] - s[j - 1]) * f0 / (f0 - f1)
        pts.append(centre + d[i] * sj)
    return np.array(pts, np.float32).reshape(-1, 2)


def refine_ellipse_centres(gray: np.ndarray, uv: np.ndarray, radius_px=None) -> tuple[np.ndarray, np.ndarray]:
    """Subpixel centres of circular targets near ``uv (n, 2)``: ellipse fitted to the blob outline.

    Around each approximate centre a window of ``3 · radius`` (``radius_px`` scalar or per point;
    when None 0.35 × the median nearest-neighbour spacing of the points) is thresholded (Otsu); the connected blob under the centre gives a first
    ellipse (:func:`cv2.fitEllipse` on its pixel outline).  The outline is then located to
    subpixel precision — where the bilinearly interpolated image crosses the mid level between
    blob and background along 90 rays from that centre — and the ellipse is fitted again to those
    points.  Returns ``(uv_refined, ok (n,) bool)``; a point whose blob cannot be isolated keeps its
    input position with ``ok = False``.
    """
    import cv2

    uv = np.asarray(uv, float).reshape(-1, 2)
    out, ok = uv.copy(), np.zeros(len(uv), bool)
    if len(uv) == 0:
        return out, ok
    if radius_px is None:
        if len(uv) > 1:
            d = np.linalg.norm(uv[:, None] - uv[None], axis=2)
            np.fill_diagonal(d, np.inf)
            radius_px = 0.35 * float(np.median(d.min(axis=1)))
        else:
            radius_px = 10.0
    halves = np.maximum(4, np.ceil(1.5 * np.broadcast_to(np.asarray(radius_px, float), (len(uv),)))).astype(int)
    H, W = gray.shape[:2]
    for i, (u, v) in enumerate(uv):
        half = int(halves[i])
        x0, y0 = int(round(u)) - half, int(round(v)) - half
        x1, y1 = x0 + 2 * half + 1, y0 + 2 * half + 1
        if x0 < 0 or y0 < 0 or x1 > W or y1 > H:
            continue
        roi = gray[y0:y1, x0:x1]
        level, bw = cv2.threshold(roi, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        if bw[half, half] == 0:                # dark blob on light ground: outline the dark region
            bw = 255 - bw
        contours, _ = cv2.findContours(bw, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        inside = [c for c in contours if len(c) >= 6 and cv2.pointPolygonTest(c, (float(half), float(half)), False) >= 0]
        if not inside:
            continue
        c = inside[0].reshape(-1, 2)
        if c[:, 0].min() <= 0 or c[:, 1].min() <= 0 or c[:, 0].max() >= 2 * half or c[:, 1].max() >= 2 * half:
            continue                            # blob touches the window: not isolated
        centre, axes, _ = cv2.fitEllipse(c.astype(np.float32))
        blob = roi[bw > 0]
        ground = roi[bw == 0]
        if blob.size and ground.size:
            mid = 0.5 * (float(np.median(blob)) + float(np.median(ground)))
            edge = _subpixel_outline(roi, np.array(centre, float), axes, mid)
            if len(edge) >= 20:
                centre, _, _ = cv2.fitEllipse(edge)
        out[i] = (x0 + centre[0], y0 + centre[1])
        ok[i] = True
    return out, ok


def detect_circles_grid(gray: np.ndarray, geom: BoardGeometry, refine: bool = True) -> Detection:
    """A symmetric or asymmetric circle grid (:func:`cv2.findCirclesGrid`), centres refined by ellipse fits."""
    import cv2

    flags = cv2.CALIB_CB_ASYMMETRIC_GRID if geom.asymmetric else cv2.CALIB_CB_SYMMETRIC_GRID
    found, centres = cv2.findCirclesGrid(gray, tuple(int(v) for v in geom.circles), flags=flags)
    if not found:
        # dark-on-light is what the default blob detector looks for; try the inverted image too
        found, centres = cv2.findCirclesGrid(255 - gray, tuple(int(v) for v in geom.circles), flags=flags)
    if not found:
        return _empty(f"no {geom.circles[0]}×{geom.circles[1]} circle grid found")
    uv = centres.reshape(-1, 2).astype(float)
    msg = ""
    if refine:
        uv_r, ok = refine_ellipse_centres(gray, uv)
        uv = np.where(ok[:, None], uv_r, uv)
        if not ok.all():
            msg = f"{int((~ok).sum())} centre(s) not refined (blob not isolated): blob-detector centres kept"
    return Detection([str(i) for i in range(len(uv))], uv, msg)


def detect_blobs(gray: np.ndarray, polarity: str = "auto", min_area: float = 12.0,
                 max_area: float = 1e5) -> np.ndarray:
    """Centres ``(n, 2)`` of round blobs (``cv2.SimpleBlobDetector``), refined by ellipse fits.

    polarity : ``"dark"`` (dark dots on light ground), ``"light"`` (retro-reflective style) or
        ``"auto"`` (both).
    """
    import cv2

    p = cv2.SimpleBlobDetector_Params()
    p.filterByArea, p.minArea, p.maxArea = True, float(min_area), float(max_area)
    p.filterByCircularity, p.minCircularity = True, 0.6
    p.filterByConvexity, p.minConvexity = True, 0.85
    p.filterByInertia, p.minInertiaRatio = True, 0.2
    p.filterByColor = False
    det = cv2.SimpleBlobDetector_create(p)
    pts, sizes = [], []
    images = {"dark": [gray], "light": [255 - gray], "auto": [gray, 255 - gray]}[polarity]
    for img in images:
        for k in det.detect(img):
            pts.append(k.pt)
            sizes.append(k.size)
    uv = np.array(pts, float).reshape(-1, 2)
    radius = 0.5 * np.array(sizes, float)
    if len(uv) > 1:   # the same blob found in both polarities (or twice): keep one
        d = np.linalg.norm(uv[:, None] - uv[None], axis=2)
        keep = np.ones(len(uv), bool)
        for i in range(len(uv)):
            if keep[i]:
                keep[i + 1:] &= d[i, i + 1:] > 2.0
        uv, radius = uv[keep], radius[keep]
    refined, ok = refine_ellipse_centres(gray, uv, 1.3 * radius + 2.0)
    return np.where(ok[:, None], refined, uv)


def match_to_predicted(uv: np.ndarray, predicted: np.ndarray, ids: list[str], radius_px: float) -> Detection:
    """Ids of detected centres by nearest predicted positions within ``radius_px``, one-to-one.

    A detection or a prediction with two candidates inside the radius is left out (ambiguous).
    """
    uv = np.asarray(uv, float).reshape(-1, 2)
    predicted = np.asarray(predicted, float).reshape(-1, 2)
    if len(uv) == 0 or len(predicted) == 0:
        return _empty("no blobs found" if len(uv) == 0 else "no layout point predicted inside the image")
    d = np.linalg.norm(predicted[:, None] - uv[None], axis=2)
    close = d <= radius_px
    out_ids, out_uv, ambiguous = [], [], 0
    for j in range(len(predicted)):
        cand = np.flatnonzero(close[j])
        if cand.size == 1 and close[:, cand[0]].sum() == 1:
            out_ids.append(ids[j])
            out_uv.append(uv[cand[0]])
        elif cand.size > 1 or (cand.size == 1 and close[:, cand[0]].sum() > 1):
            ambiguous += 1
    msg = f"{ambiguous} layout point(s) ambiguous within {radius_px:g} px: left out" if ambiguous else ""
    if not out_ids:
        return _empty(msg or f"no blob within {radius_px:g} px of a predicted target")
    return Detection(out_ids, np.array(out_uv, float), msg, {"blobs": len(uv)})
