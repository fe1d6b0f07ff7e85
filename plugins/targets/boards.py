"""Planar calibration targets: geometry, point ids and object coordinates.

Board frame
-----------
OpenCV puts a board's x axis to the right along the first row, y *down* the printed board and z into
it.  baarda's object system is right-handed with Z toward the cameras (``docs/conventions.md``), so
the board frame used for control points is OpenCV's rotated by 180° about x::

    X = x_cv,   Y = −y_cv,   Z = −z_cv (= 0 on the board)

Point ids (strings)
-------------------
* chessboard: ``row · (squares_x − 1) + col`` over the inner corners (OpenCV's corner order);
* ChArUco: OpenCV's ChArUco corner id (the same formula: inner corners row by row);
* ArUco: ``marker_id · 4 + k``, ``k`` = 0…3 the marker's corners in OpenCV's order (top-left,
  top-right, bottom-right, bottom-left of the marker as printed);
* circle grid: ``row · cols + col`` in :func:`cv2.findCirclesGrid`'s order.

Coordinates are computed in float64 from the geometry (OpenCV's own board objects hold float32).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TARGETS = ("chessboard", "charuco", "aruco", "circles-grid", "circles")

F_BOARD = np.diag([1.0, -1.0, -1.0])
"""OpenCV board frame → baarda board frame (and back: it is its own inverse)."""


@dataclass(frozen=True)
class BoardGeometry:
    """What is known about the target; lengths in the block's object unit.

    target : one of :data:`TARGETS`.
    squares : (squares_x, squares_y) of a chessboard or ChArUco board (OpenCV's 9 × 6 inner-corner
        sample board is 10 × 7 squares).
    square_size : side of a square; for a circle grid the centre-to-centre spacing.
    marker_size : side of an ArUco marker (ChArUco, ArUco grid).
    marker_separation : gap between markers of an ArUco grid board.
    markers : (markers_x, markers_y) of an ArUco grid board; empty: single markers, no geometry.
    circles : (cols, rows) of a circle grid.
    asymmetric : circle grid with every other row offset by half a spacing.
    dictionary : ArUco dictionary name, e.g. ``"DICT_6X6_250"``.
    legacy_pattern : ChArUco boards printed with OpenCV < 4.6 (matters for an even number of rows).
    """

    target: str
    squares: tuple[int, int] = (0, 0)
    square_size: float = 0.0
    marker_size: float = 0.0
    marker_separation: float = 0.0
    markers: tuple[int, int] = (0, 0)
    circles: tuple[int, int] = (0, 0)
    asymmetric: bool = False
    dictionary: str = "DICT_6X6_250"
    legacy_pattern: bool = False

    def __post_init__(self):
        if self.target not in TARGETS:
            raise ValueError(f"target must be one of {', '.join(TARGETS)}, got {self.target!r}")
        need = {"chessboard": ("squares", "square_size"), "charuco": ("squares", "square_size", "marker_size"),
                "circles-grid": ("circles", "square_size")}.get(self.target, ())
        for name in need:
            v = getattr(self, name)
            if (min(v) if isinstance(v, tuple) else v) <= 0:
                raise ValueError(f"target '{self.target}' needs option '{name}' (> 0)")
        if self.target in ("chessboard", "charuco") and min(self.squares) < 2:
            raise ValueError("a board needs at least 2 × 2 squares")
        if self.target == "charuco" and self.marker_size >= self.square_size:
            raise ValueError("marker_size must be smaller than square_size")
        if self.target == "aruco" and min(self.markers) > 0 and self.marker_size <= 0:
            raise ValueError("an ArUco grid board needs marker_size (> 0)")

    @property
    def has_geometry(self) -> bool:
        """True when object coordinates of the points are known (always, except single ArUco markers)."""
        return self.target != "circles" and not (self.target == "aruco" and min(self.markers) <= 0)

    @property
    def inner_corners(self) -> tuple[int, int]:
        return (self.squares[0] - 1, self.squares[1] - 1)


def object_points(geom: BoardGeometry) -> tuple[list[str], np.ndarray]:
    """``(ids, XYZ (n, 3))`` of every point of the board in baarda's board frame."""
    if geom.target in ("chessboard", "charuco"):
        nx, ny = geom.inner_corners
        row, col = np.divmod(np.arange(nx * ny), nx)
        off = geom.square_size if geom.target == "charuco" else 0.0
        cv = np.column_stack([col * geom.square_size + off, row * geom.square_size + off, np.zeros(nx * ny)])
        ids = [str(i) for i in range(nx * ny)]
    elif geom.target == "aruco" and geom.has_geometry:
        mx, my = geom.markers
        step = geom.marker_size + geom.marker_separation
        corner = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float) * geom.marker_size
        cv, ids = [], []
        for m in range(mx * my):
            r, c = divmod(m, mx)
            for k in range(4):
                cv.append([c * step + corner[k, 0], r * step + corner[k, 1], 0.0])
                ids.append(str(4 * m + k))
        cv = np.array(cv, float)
    elif geom.target == "circles-grid":
        cols, rows = geom.circles
        row, col = np.divmod(np.arange(cols * rows), cols)
        s = geom.square_size
        if geom.asymmetric:   # OpenCV's sample layout: x = (2 col + row % 2) s, y = row s
            cv = np.column_stack([(2 * col + row % 2) * s, row * s, np.zeros(row.size)])
        else:
            cv = np.column_stack([col * s, row * s, np.zeros(row.size)])
        ids = [str(i) for i in range(cols * rows)]
    else:
        return [], np.zeros((0, 3))
    return ids, cv @ F_BOARD


def aruco_dictionary(name: str):
    """The predefined ArUco dictionary ``name`` (``ValueError`` listing the valid names)."""
    import cv2

    key = name.strip().upper()
    if not key.startswith("DICT_"):
        key = "DICT_" + key
    value = getattr(cv2.aruco, key, None)
    if not isinstance(value, int):
        names = sorted({n.upper() for n in dir(cv2.aruco) if n.startswith("DICT_")})
        raise ValueError(f"unknown ArUco dictionary {name!r}; known: {', '.join(names)}")
    return cv2.aruco.getPredefinedDictionary(value)


def opencv_board(geom: BoardGeometry):
    """The OpenCV board object (CharucoBoard or GridBoard) of a geometry, or None."""
    import cv2

    if geom.target == "charuco":
        board = cv2.aruco.CharucoBoard(tuple(int(v) for v in geom.squares), float(geom.square_size),
                                       float(geom.marker_size), aruco_dictionary(geom.dictionary))
        board.setLegacyPattern(bool(geom.legacy_pattern))
        return board
    if geom.target == "aruco" and geom.has_geometry:
        return cv2.aruco.GridBoard(tuple(int(v) for v in geom.markers), float(geom.marker_size),
                                   float(geom.marker_separation), aruco_dictionary(geom.dictionary))
    return None
