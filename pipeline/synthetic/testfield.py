"""Simulator of the test field of Yeu, Kwon, Lee & Jeong (seed 001, SPEC §2) — pure numerics.

The field
---------
* Camera: Wild P31, c = 101.75 mm, format 117 × 83 mm with the **long side horizontal**
  (x along the object).  The paper states a coverage of 1.64 m × 1.18 m at 1.4 m: the ratio
  1.64 / 1.18 = 1.39 is that of 117 / 83 = 1.41 (portrait would give 0.71), and the scale
  1.4 m / 101.75 mm = 13.8 turns 117 × 83 mm into 1.61 m × 1.14 m.
* Object: 260 cm × 120 cm model object, X ∈ [1.46, 4.06] m, Y ∈ [−0.245, 0.955] m, a base plane
  at Z = 2.95 m with a relief (a broad hill and a ridge) that puts the 21 targets between
  Z = 2.95 m and 3.20 m: 1.20–1.48 m from the cameras (Z0 ≈ 4.40–4.43 m), hence relief
  displacements of several mm in the image.
* Targets: 21 in four evenly spaced rows of 5, 6, 5, 5 (jittered), ids ``"1"`` … ``"21"`` row
  by row from the bottom left (:func:`target_field`).
* Block: photos 11–15 (strip 1, Y0 ≈ 0.506 m) and 21–25 (strip 2, Y0 ≈ 0.206 m) at the
  positions of the paper's Table 1 with ω = φ = κ = 0 as approximate values; the true exterior
  orientation differs by fixed small deviations (σ 5 mm, 0.15°) drawn once with
  :data:`FIELD_SEED` — they are part of the field, not of the noise.
* Single model: photos A and B at 4.0 m (Table 1, Z0 read from the base plane, see
  :data:`SINGLE_MODEL_Z_OFFSET`), base 1.0 m.

The errors
----------
* Systematic image errors (``with_ap_errors``): a physical Brown-type pattern evaluated at the
  ideal projected reduced coordinates, see :data:`SYSTEMATIC_ERRORS` and
  :func:`physical_distortion`, plus a small error of the calibrated c, xp, yp.  Up to ≈ 45 µm in
  the corners, ≈ 17 µm RMS over the format.
* Image measurement noise: white, ``sigma_image_um`` per coordinate (default 40 µm: the paper's
  σ̂0 level of 40–50 µm, which includes unmodelled effects — film unflatness, target
  identification, the systematic errors themselves).  A Kern MK-2 mono-comparator on
  well-defined targets measures to about 4 µm: set ``sigma_image_um = 4`` for a clean comparator.
* Control survey noise: ``sigma_control_mm`` per coordinate (theodolite intersection with a
  1" Wild T2 from 5.8 m over a 5 m base: 1" is 0.03 mm at 5.8 m, so with centring and pointing
  ≈ 0.05 mm per coordinate).

Randomness comes only through the ``rng`` argument; the draws do not depend on the control
case, so the same ``rng`` seed gives the same noise for every case (a fair comparison).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from baarda.pipeline.geometry import rotation_from_opk_many
from baarda.pipeline.options import REQUIRED, check_bounds, option
from baarda.pipeline.model import FIXED, FREE, Block, Cameras, Observations, Pairs, Photos, Points

FOCAL_MM = 101.75
"""Calibrated principal distance of the Wild P31 (mm)."""

FORMAT_MM = (117.0, 83.0)
"""Width (x, horizontal) and height (y) of the format, mm."""

CAMERA_ID = "P31"

TABLE1: dict[str, tuple[float, float, float]] = {
    "11": (1.5606, 0.5056, 4.4280), "12": (2.1620, 0.5051, 4.4299), "13": (2.7618, 0.5052, 4.4189),
    "14": (3.3687, 0.5095, 4.3989), "15": (3.9600, 0.5060, 4.4103),
    "21": (1.5606, 0.2056, 4.4280), "22": (2.1620, 0.2051, 4.4299), "23": (2.7618, 0.2052, 4.4189),
    "24": (3.3687, 0.2095, 4.3989), "25": (3.9600, 0.2060, 4.4103),
    "A": (1.9383, 0.0376, 4.0844), "B": (2.9370, 0.0369, 4.0933),
}
"""Initial exterior orientation of the paper's Table 1 (m; all angles 0)."""

SINGLE_MODEL_Z_OFFSET = 2.95
"""Added to Table 1's Z0 of A and B (m).  Table 1 gives Z0 ≈ 4.09 m for the pair the paper says
was taken at 4.0 m, while the block photos (Z0 ≈ 4.42 m) are 1.4 m from the object: the two
cannot share one frame with the object in it.  We read the pair's Z0 as measured from the
object's base plane (Z = 2.95 m), which puts A and B 4.0 m from the targets."""

BLOCK_PHOTOS = ("11", "12", "13", "14", "15", "21", "22", "23", "24", "25")
SINGLE_MODEL_PHOTOS = ("A", "B")
STRIPS = (("11", "12", "13", "14", "15"), ("21", "22", "23", "24", "25"))

OBJECT_X = (1.46, 4.06)
OBJECT_Y = (-0.245, 0.955)
BASE_Z = 2.95
FIELD_SEED = 19900908
"""Seed of the fixed parts of the field (target jitter, true EO deviations); not the noise."""

SYSTEMATIC_ERRORS: dict[str, float] = {
    "K1": 1.0e-7,    # mm^-2: radial, 37 µm at the corner (r = 71.7 mm)
    "K2": -5.0e-12,  # mm^-4: −9 µm at the corner
    "P1": 1.0e-6,    # decentring, ≈ 12 µm at the corner
    "P2": -0.7e-6,
    "B1": 1.0e-4,    # affinity (film shrinkage difference), 6 µm at the format edge
    "B2": 5.0e-5,    # shear, 2 µm at the format edge
    "dc": 0.020,     # mm: true c = 101.77 against the calibrated 101.75
    "dxp": 0.010,    # mm: true principal point against the fiducial centre
    "dyp": -0.015,
}
"""The true systematic image errors used when ``with_ap_errors`` is on (see physical_distortion)."""

CASES = (1, 2, 3, 4, 5, 6)


# --------------------------------------------------------------------------------------------
# configuration and truth


@dataclass(frozen=True, kw_only=True)
class SimulatedErrors:
    """The errors a simulation of the test field adds: one declaration for the ``testfield`` stage
    (:class:`TestFieldConfig`) and the studies that simulate it (their configs derive from this).

    Checked on construction (:func:`~baarda.pipeline.options.check_bounds`: the sigmas and the
    scale positive), from a project file or from Python alike."""

    with_ap_errors: bool = option(True, "add the known systematic image errors (radial, decentring, affinity, "
                                        "c/xp/yp offsets; docs/testfield.md)")
    sigma_image_um: float = option(40.0, "image measurement noise per coordinate, µm (also the a-priori sigma); "
                                         "40 ≈ the paper's σ̂0 level, 4 a clean comparator")
    sigma_control_mm: float = option(0.05, "control survey noise per coordinate, mm (also the a-priori sigma of "
                                          "weighted control)")
    systematic_scale: float = option(1.0, "multiply the systematic image errors by this factor")

    def __post_init__(self):
        check_bounds(self)

    @property
    def sigma_image_mm(self) -> float:
        """``sigma_image_um`` in mm, the image unit of the block (the one conversion of it)."""
        return self.sigma_image_um * 1e-3


@dataclass(frozen=True)
class Blunder:
    """A gross error added to one simulated image observation (mm)."""

    photo: str | int = option(REQUIRED, "photo id")
    point: str | int = option(REQUIRED, "point id")
    dx: float = option(0.0, "error added to x (mm)")
    dy: float = option(0.0, "error added to y (mm)")


@dataclass(frozen=True)
class Displacement:
    """A known movement of one target between the surveyed field and this simulation (mm): the
    epoch-2 field of a monitoring simulation (``fixtures/monitoring/testfield-epochs.toml``)."""

    point: str | int = option(REQUIRED, "target id (1–21)")
    dX: float = option(0.0, "movement along X (mm)")
    dY: float = option(0.0, "movement along Y (mm)")
    dZ: float = option(0.0, "movement along Z (mm)")


@dataclass(frozen=True)
class TestFieldConfig(SimulatedErrors):
    """What to simulate — also the option table of the ``testfield`` stage (one definition).

    Every field is documented in its ``option(...)`` (``baarda stages testfield`` prints them);
    the systematic errors and the noise come from :class:`SimulatedErrors`.
    """

    __test__ = False  # not a pytest class

    case: int = option(5, "control configuration 1–6 (docs/testfield.md): 1 minimal outline, 2 interior "
                          "stiffening, 3 the same count on the outline, 4–6 many points")
    block: Literal["block", "single-model"] = option(
        "block", "'block': 2 strips × 5 photos at 1.4 m; 'single-model': the pair A, B at 4.0 m")
    control_weighted: bool = option(True, "control points enter as weighted constraints (true) or fixed")
    ap_model: Literal["none", "ebner12", "brown"] = option(
        "none", "additional-parameter model the block's camera carries for the adjustment (free, from 0)")
    calibrate_iop: bool = option(False, "c, xp, yp free in the adjustment (true) or fixed at the "
                                        "calibrated values")
    seed: int | None = option(None, "seed of the noise; default: the project's seed for this stage (a Python "
                                    "caller passes the generator to simulate_testfield)")
    blunders: tuple[Blunder, ...] = option((), "gross errors added to image observations: a list of tables "
                                               "{photo, point, dx, dy} (mm)")
    margin_mm: float = option(2.0, "a target is measured when its true image lies this far inside the format")
    displacements: tuple[Displacement, ...] = option(
        (), "known target movements (an epoch of a monitoring simulation): a list of tables "
            "{point, dX, dY, dZ} (mm); the moved targets are imaged, surveyed and reported where they moved to")

    def __post_init__(self):
        super().__post_init__()
        if self.case not in CASES:
            raise ValueError(f"case must be one of {sorted(CASES)}, got {self.case}")
        if self.block not in ("block", "single-model"):
            raise ValueError(f"block must be 'block' or 'single-model', got {self.block!r}")
        n = sum(ROW_COUNTS)
        moved = [str(getattr(d, "point", "")) for d in self.displacements]
        bad = [p for p in moved if p not in {str(i + 1) for i in range(n)}]
        if bad:
            raise ValueError(f"displacements: the test field has no target {bad[0]!r} (targets 1–{n})")
        twice = sorted({p for p in moved if moved.count(p) > 1})
        if twice:
            raise ValueError(f"displacements: target {twice[0]} is moved twice")


@dataclass(frozen=True, eq=False)
class Truth:
    """The exact values behind a simulated block (object unit m, image mm, angles rad).

    photo_ids (m,), X0 (m, 3), opk (m, 3); point_ids (n,), XYZ (n, 3) true target positions,
    XYZ_surveyed (n, 3) with survey noise; c, xp, yp the true interior orientation;
    distortion: the systematic-error parameters (keys of :data:`SYSTEMATIC_ERRORS` without
    dc/dxp/dyp, which are folded into c, xp, yp); per observation row: xy_true (k, 2) without
    noise (systematic errors included), systematic (k, 2), noise (k, 2), blunder (k, 2).
    """

    photo_ids: np.ndarray
    X0: np.ndarray
    opk: np.ndarray
    point_ids: np.ndarray
    XYZ: np.ndarray
    XYZ_surveyed: np.ndarray
    c: float
    xp: float
    yp: float
    distortion: dict
    xy_true: np.ndarray
    systematic: np.ndarray
    noise: np.ndarray
    blunder: np.ndarray

    def as_dict(self) -> dict:
        """Plain dict (lists and floats) for ``Block.meta["truth"]`` and reports."""
        out = {}
        for k in self.__dataclass_fields__:
            v = getattr(self, k)
            out[k] = v.tolist() if isinstance(v, np.ndarray) else (dict(v) if isinstance(v, dict) else v)
        return out


# --------------------------------------------------------------------------------------------
# the field


def _field_rng() -> np.random.Generator:
    return np.random.default_rng(FIELD_SEED)


def relief(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Height of the model object above the base plane (m, toward the cameras) at ``X, Y``.

    A broad hill (0.20 m) in the right half, a ridge (0.12 m) across the left half, a gentle
    tilt of 3 cm over the length; 0 … ≈ 0.25 m over the object.
    """
    X = np.asarray(X, float)
    Y = np.asarray(Y, float)
    hill = 0.20 * np.exp(-(((X - 3.25) / 0.45) ** 2 + ((Y - 0.40) / 0.45) ** 2))
    ridge = 0.12 * np.exp(-(((X - 2.05) / 0.25) ** 2)) * (0.6 + 0.4 * np.cos(np.pi * (Y - 0.355) / 1.2))
    tilt = 0.03 * (X - OBJECT_X[0]) / (OBJECT_X[1] - OBJECT_X[0])
    return hill + ridge + tilt


ROW_COUNTS = (5, 6, 5, 5)
"""Targets per row, bottom to top (21 in all)."""


def target_field() -> tuple[np.ndarray, np.ndarray]:
    """The 21 targets: ids ``"1"``…``"21"`` and true XYZ (21, 3) in m.

    Four evenly spaced rows (Y = −0.175, 0.178, 0.532, 0.885 m) of 5, 6, 5, 5 targets spread
    evenly over the length, jittered by up to ±3 cm (fixed, :data:`FIELD_SEED`), numbered row by
    row from the bottom left: row 0 = 1–5, row 1 = 6–11, row 2 = 12–16, row 3 = 17–21.
    Z = base plane + :func:`relief`.
    """
    rng = _field_rng()
    rows = np.linspace(OBJECT_Y[0] + 0.07, OBJECT_Y[1] - 0.07, len(ROW_COUNTS))
    XY = np.array([(x, y) for y, n in zip(rows, ROW_COUNTS)
                   for x in np.linspace(OBJECT_X[0] + 0.06, OBJECT_X[1] - 0.06, n)])
    XY = XY + rng.uniform(-0.03, 0.03, size=XY.shape)
    Z = BASE_Z + relief(XY[:, 0], XY[:, 1])
    ids = np.array([str(i + 1) for i in range(len(XY))])
    return ids, np.column_stack([XY, Z])


def true_orientation(photo_ids) -> tuple[np.ndarray, np.ndarray]:
    """True X0 (m, 3) and ω φ κ (m, 3) of the given photos: Table 1 plus the field's fixed
    deviations (σ 5 mm in position, 0.15° in each angle)."""
    rng = _field_rng()
    rng.uniform(size=(sum(ROW_COUNTS), 2))            # the target jitter comes first
    all_ids = list(TABLE1)
    dX = rng.normal(0.0, 0.005, size=(len(all_ids), 3))
    dA = np.deg2rad(rng.normal(0.0, 0.15, size=(len(all_ids), 3)))
    idx = [all_ids.index(str(p)) for p in photo_ids]
    return table1_positions(photo_ids) + dX[idx], dA[idx]


def table1_positions(photo_ids) -> np.ndarray:
    """Approximate projection centres (m, 3) of the paper's Table 1 in the field's frame
    (A and B raised by :data:`SINGLE_MODEL_Z_OFFSET`)."""
    X0 = np.array([TABLE1[str(p)] for p in photo_ids], dtype=float)
    X0[:, 2] += [SINGLE_MODEL_Z_OFFSET if str(p) in SINGLE_MODEL_PHOTOS else 0.0 for p in photo_ids]
    return X0


# --------------------------------------------------------------------------------------------
# projection with the simulator's own systematic-error model


def physical_distortion(xbar: np.ndarray, ybar: np.ndarray, params: dict) -> tuple[np.ndarray, np.ndarray]:
    """Brown-type image errors (mm) at reduced image coordinates ``xbar, ybar`` (mm).

    ``Δx = x̄ (K1 r² + K2 r⁴) + P1 (r² + 2x̄²) + 2 P2 x̄ȳ + B1 x̄ + B2 ȳ``,
    ``Δy = ȳ (K1 r² + K2 r⁴) + P2 (r² + 2ȳ²) + 2 P1 x̄ȳ``; missing keys count as 0.
    """
    g = lambda k: float(params.get(k, 0.0))
    xbar = np.asarray(xbar, float)
    ybar = np.asarray(ybar, float)
    r2 = xbar**2 + ybar**2
    radial = g("K1") * r2 + g("K2") * r2**2
    dx = xbar * radial + g("P1") * (r2 + 2 * xbar**2) + 2 * g("P2") * xbar * ybar + g("B1") * xbar + g("B2") * ybar
    dy = ybar * radial + g("P2") * (r2 + 2 * ybar**2) + 2 * g("P1") * xbar * ybar
    return dx, dy


def project_truth(XYZ: np.ndarray, X0: np.ndarray, opk: np.ndarray, c: float, xp: float, yp: float,
                  distortion: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Project points ``XYZ (n, 3)`` into photos ``X0 (m, 3), opk (m, 3)``.

    Returns ``xy (m, n, 2)`` image coordinates (mm, systematic errors applied at the ideal
    projected reduced coordinates) and ``depth (m, n)`` = −W (positive in front of the camera).
    """
    R = rotation_from_opk_many(opk)
    d = np.einsum("mij,mnj->mni", R, np.asarray(XYZ, float)[None, :, :] - np.asarray(X0, float)[:, None, :])
    W = d[..., 2]
    xbar = -c * d[..., 0] / W
    ybar = -c * d[..., 1] / W
    dx, dy = physical_distortion(xbar, ybar, distortion or {})
    return np.stack([xp + xbar + dx, yp + ybar + dy], axis=-1), -W


def inside_format(xy: np.ndarray, margin_mm: float = 0.0) -> np.ndarray:
    """(…) bool: image coordinates lie inside the 117 × 83 mm format shrunk by ``margin_mm``."""
    hw, hh = FORMAT_MM[0] / 2 - margin_mm, FORMAT_MM[1] / 2 - margin_mm
    return (np.abs(xy[..., 0]) <= hw) & (np.abs(xy[..., 1]) <= hh)


# --------------------------------------------------------------------------------------------
# control configurations

CONTROL_CASES: dict[int, dict[str, tuple[str, ...]]] = {
    1: {"full": ("1", "21"), "z": ("5",)},
    2: {"full": ("1", "21"), "z": ("5", "3", "19", "12", "11"), "xy": ("7", "10", "13", "15")},
    3: {"full": ("1", "21"), "z": ("5", "7", "10", "13", "15"), "xy": ("3", "19", "12", "11")},
    4: {"full": ("1", "5", "17", "21", "3", "19", "12", "11", "8", "14"), "xy": ("7", "10", "13", "15")},
    5: {"full": ("1", "5", "17", "21", "3", "19", "7", "10", "14"), "z": ("2", "4", "18", "20", "12", "11")},
    6: {"full": ("1", "5", "17", "21", "3", "19", "6", "11", "12", "16", "8", "14", "10"), "xy": ("2", "20")},
}
"""Control points of each case by role; every other target is a check point."""


def control_configuration(case: int) -> dict[str, str]:
    """Role of each of the 21 targets in control case 1–6 (``full``, ``xy``, ``z``, ``check``).

    Modelled on the paper's Figure 3 / Table 2 (the figure itself is not in the OCR text); the
    corners are 1, 5, 17, 21, the edge middles 3 (bottom), 19 (top), 12 (left), 11 (right), the
    interior points 7, 8, 9, 10, 13, 14, 15:

    1. minimal outline: corners 1 and 21 XYZ, corner 5 Z only — exactly the 7 datum constraints;
    2. case 1 + planimetric (XY) control inside the block (7, 10, 13, 15) and height (Z) control
       at the four edge middles (3, 19, 12, 11): +12 constraints, as the paper's 34 → 46;
    3. the same eight places with the types swapped: XY on the outline, Z inside.  The paper:
       "the same number of control points at the same places in a different form, same dof …
       planimetric control that stiffens the block's interior rather than planimetric and height
       control on the outline";
    4. many points, planimetry-heavy: ten XYZ + four XY (38 constraints);
    5. many points, height-heavy: nine XYZ + six Z (33 constraints);
    6. many well-distributed points: thirteen XYZ + two XY (43 constraints).

    Every target that is not control is a check point; XY-control points serve as Z check points
    and Z-control points as XY check points (the paper's n_x, n_y, n_z).
    """
    if case not in CASES:
        raise ValueError(f"control case must be one of {CASES}, got {case!r}")
    roles = {str(i + 1): "check" for i in range(sum(ROW_COUNTS))}
    for role, ids in CONTROL_CASES[case].items():
        for pid in ids:
            roles[pid] = role
    return roles


def constraint_count(roles: dict[str, str]) -> int:
    """Number of coordinate constraints a role assignment gives (full 3, xy 2, z 1)."""
    return sum({"full": 3, "xy": 2, "z": 1}.get(r, 0) for r in roles.values())


# --------------------------------------------------------------------------------------------
# the simulation


def _photo_ids(config: TestFieldConfig) -> tuple[str, ...]:
    return BLOCK_PHOTOS if config.block == "block" else SINGLE_MODEL_PHOTOS


def _pairs(photo_ids) -> tuple[np.ndarray, np.ndarray]:
    if tuple(photo_ids) == SINGLE_MODEL_PHOTOS:
        return np.array([0]), np.array([1])
    index = {p: i for i, p in enumerate(photo_ids)}
    left, right = [], []
    for strip in STRIPS:
        for a, b in zip(strip[:-1], strip[1:]):
            left.append(index[a])
            right.append(index[b])
    return np.array(left), np.array(right)


AP_PARAMETER_COUNT = {"none": 0, "ebner12": 12, "brown": 7}
"""Parameters of the AP models a simulated camera may carry (pipeline/camera/models.py)."""


def _ap_columns(ap_model: str) -> int:
    try:
        return AP_PARAMETER_COUNT[ap_model]
    except KeyError:
        raise ValueError(f"ap_model must be one of {sorted(AP_PARAMETER_COUNT)}, got {ap_model!r}") from None


def displaced(point_ids: np.ndarray, XYZ: np.ndarray, displacements) -> tuple[np.ndarray, np.ndarray]:
    """``XYZ`` (m) with each :class:`Displacement` (mm) added to its target (a new array).

    Raises ``ValueError`` for a target that does not exist or one named twice."""
    out = np.array(XYZ, float, copy=True)
    index = {str(p): k for k, p in enumerate(point_ids)}
    seen = set()
    for d in displacements:
        if not isinstance(d, Displacement):
            raise ValueError(f"a displacement is a Displacement(point, dX, dY, dZ) (mm); got {d!r}")
        p = str(d.point)
        if p not in index:
            raise ValueError(f"displacements: the test field has no target {p!r} (targets 1–{len(point_ids)})")
        if p in seen:
            raise ValueError(f"displacements: target {p} is moved twice")
        seen.add(p)
        out[index[p]] += np.array([d.dX, d.dY, d.dZ], float) * 1e-3
    return point_ids, out


def simulate_testfield(config: TestFieldConfig, rng: np.random.Generator) -> tuple[Block, Truth]:
    """Simulate the paper's test field: a :class:`~baarda.pipeline.model.Block` and its :class:`Truth`.

    The block holds one camera (c = 101.75 mm, xp = yp = 0 as calibrated; ``config.ap_model``
    with free parameters starting at 0), the photos with the paper's Table 1 as approximate
    exterior orientation (angles 0, all free), the 21 targets with their *surveyed* coordinates
    and roles of ``config.case``, and every image observation of a target whose true image lies
    inside the format, with covariance ``sigma_image² I``.  ``block.meta["truth"]`` holds
    ``truth.as_dict()``; ``block.meta["testfield"]`` the configuration and geometry summary.

    Raises ``ValueError`` for a blunder naming an observation that does not exist.
    """
    photo_ids = _photo_ids(config)
    point_ids, XYZ = displaced(*target_field(), config.displacements)
    X0, opk = true_orientation(photo_ids)
    sys_params = ({k: v * config.systematic_scale for k, v in SYSTEMATIC_ERRORS.items()}
                  if config.with_ap_errors else {})
    c = FOCAL_MM + sys_params.get("dc", 0.0)
    xp, yp = sys_params.get("dxp", 0.0), sys_params.get("dyp", 0.0)
    distortion = {k: v for k, v in sys_params.items() if k not in ("dc", "dxp", "dyp")}

    xy_all, depth = project_truth(XYZ, X0, opk, c, xp, yp, distortion)
    xy_ideal, _ = project_truth(XYZ, X0, opk, FOCAL_MM, 0.0, 0.0, None)
    seen = inside_format(xy_all, config.margin_mm) & (depth > 0)
    obs_photo, obs_point = np.nonzero(seen)
    xy_true = xy_all[obs_photo, obs_point]
    systematic = xy_true - xy_ideal[obs_photo, obs_point]

    # random draws: survey noise first, then image noise, independent of the control case
    sig_img = config.sigma_image_mm
    survey_noise = rng.normal(0.0, config.sigma_control_mm * 1e-3, size=XYZ.shape)
    noise = rng.normal(0.0, sig_img, size=xy_true.shape)

    blunder = np.zeros_like(xy_true)
    for b in config.blunders:
        if not isinstance(b, Blunder):
            raise ValueError(f"a blunder is a Blunder(photo, point, dx, dy) (mm); got {b!r}")
        p, q, dx, dy = str(b.photo), str(b.point), float(b.dx), float(b.dy)
        rows = np.nonzero((np.asarray(photo_ids)[obs_photo] == p) & (point_ids[obs_point] == q))[0]
        if rows.size == 0:
            raise ValueError(f"blunder: photo {p} does not observe point {q}")
        blunder[rows[0]] += (dx, dy)

    roles = control_configuration(config.case)
    role = np.array([roles[p] for p in point_ids])
    s = config.sigma_control_mm * 1e-3 if config.control_weighted else FIXED
    sigma = np.full((len(point_ids), 3), FREE)
    sigma[role == "full"] = s
    sigma[role == "xy", :2] = s
    sigma[role == "z", 2] = s
    XYZ_surveyed = XYZ + survey_noise

    nap = _ap_columns(config.ap_model)
    cameras = Cameras.make(
        [CAMERA_ID], FOCAL_MM, 0.0, 0.0, ap_model=config.ap_model,
        ap=np.zeros((1, nap)), sigma_ap=np.full((1, nap), FREE),
        sigma_iop=FREE if config.calibrate_iop else FIXED, format_mm=FORMAT_MM)
    approx_X0 = table1_positions(photo_ids)
    photos = Photos.make(photo_ids, 0, approx_X0, np.zeros((len(photo_ids), 3)), FREE)
    points = Points(ids=point_ids, XYZ=XYZ_surveyed, role=role, sigma=sigma)
    observations = Observations.make(obs_photo, obs_point, xy_true + noise + blunder, sigma=sig_img)
    left, right = _pairs(photo_ids)

    truth = Truth(photo_ids=np.array(photo_ids), X0=X0, opk=opk, point_ids=point_ids, XYZ=XYZ,
                  XYZ_surveyed=XYZ_surveyed, c=c, xp=xp, yp=yp, distortion=distortion,
                  xy_true=xy_true, systematic=systematic, noise=noise, blunder=blunder)
    block = Block(cameras=cameras, photos=photos, points=points, observations=observations,
                  pairs=Pairs(left=left, right=right), object_unit="m")
    geometry = geometry_summary(block, truth)
    meta = {
        "truth": truth.as_dict(),
        "testfield": {"config": _config_dict(config), "geometry": geometry,
                      "constraints": constraint_count(roles)},
    }
    return block.replace(meta=meta, ap_meta={CAMERA_ID: {"b": image_base_mm(truth, geometry["distance_m"])}}), truth


def _config_dict(config: TestFieldConfig) -> dict:
    """What was simulated, as plain values (the seed is the generator's business, not the field's)."""
    d = {f.name: getattr(config, f.name) for f in dataclasses.fields(config) if f.name != "seed"}
    d["blunders"] = [dataclasses.asdict(b) for b in config.blunders]
    d["displacements"] = [dataclasses.asdict(m) for m in config.displacements]
    return d


def single_model(config: TestFieldConfig | None = None, rng: np.random.Generator | None = None,
                 **changes) -> tuple[Block, Truth]:
    """The stereo pair A, B at 4.0 m (Table 1): ``simulate_testfield`` with ``block="single-model"``."""
    config = replace(config or TestFieldConfig(), block="single-model", **changes)
    return simulate_testfield(config, rng if rng is not None else np.random.default_rng(0))


# --------------------------------------------------------------------------------------------
# geometry checks


def footprint(X0: np.ndarray, opk: np.ndarray, c: float, plane_Z: float) -> np.ndarray:
    """Corners (4, 2) of the format projected onto the plane ``Z = plane_Z`` (object X, Y)."""
    R = rotation_from_opk_many(np.asarray(opk, float)[None])[0]
    hw, hh = FORMAT_MM[0] / 2, FORMAT_MM[1] / 2
    corners = np.array([[-hw, -hh, -c], [hw, -hh, -c], [hw, hh, -c], [-hw, hh, -c]])
    rays = corners @ R                       # R^T · (x, y, −c): world directions
    t = (plane_Z - X0[2]) / rays[:, 2]
    return X0[:2] + t[:, None] * rays[:, :2]


def _overlap(fa: np.ndarray, fb: np.ndarray, axis: int) -> float:
    lo = max(fa[:, axis].min(), fb[:, axis].min())
    hi = min(fa[:, axis].max(), fb[:, axis].max())
    length = 0.5 * (np.ptp(fa[:, axis]) + np.ptp(fb[:, axis]))
    return max(hi - lo, 0.0) / length


def geometry_summary(block: Block, truth: Truth) -> dict:
    """Coverage and overlaps of a simulated block (true orientation, mean target plane).

    Keys: ``photos`` {id: {"points": [...], "n": k, "footprint_m": [w, h]}}, ``rays_per_point``
    {id: k}, ``min_rays``, ``forward_overlap`` [(a, b, fraction)], ``side_overlap``
    [(a, b, fraction)], ``mean_target_Z``, ``distance_m`` (mean camera-to-target depth),
    ``observations``.
    """
    obs = block.observations
    plane = float(truth.XYZ[:, 2].mean())
    photos = {}
    fps = []
    for i, pid in enumerate(truth.photo_ids):
        pts = block.points.ids[obs.point[obs.photo == i]].tolist()
        fp = footprint(truth.X0[i], truth.opk[i], truth.c, plane)
        fps.append(fp)
        photos[str(pid)] = {"points": pts, "n": len(pts),
                            "footprint_m": [float(np.ptp(fp[:, 0])), float(np.ptp(fp[:, 1]))]}
    rays = {str(p): int((obs.point == k).sum()) for k, p in enumerate(block.points.ids)}
    forward, side = [], []
    ids = [str(p) for p in truth.photo_ids]
    if tuple(ids) == SINGLE_MODEL_PHOTOS:
        forward.append(("A", "B", _overlap(fps[0], fps[1], 0)))
    else:
        for strip in STRIPS:
            for a, b in zip(strip[:-1], strip[1:]):
                forward.append((a, b, _overlap(fps[ids.index(a)], fps[ids.index(b)], 0)))
        for a, b in zip(*STRIPS):
            side.append((a, b, _overlap(fps[ids.index(a)], fps[ids.index(b)], 1)))
    depth = truth.X0[obs.photo, 2] - truth.XYZ[obs.point, 2]
    return {
        "photos": photos, "rays_per_point": rays, "min_rays": min(rays.values()) if rays else 0,
        "forward_overlap": [(a, b, round(f, 4)) for a, b, f in forward],
        "side_overlap": [(a, b, round(f, 4)) for a, b, f in side],
        "mean_target_Z": plane, "distance_m": float(depth.mean()) if depth.size else float("nan"),
        "observations": int(len(obs)),
    }


def image_base_mm(truth: Truth, distance_m: float) -> float:
    """Ebner's image base b (mm): the mean base between neighbouring photos of a strip (or of
    the pair) at image scale, ``|ΔX0| · c / distance``."""
    ids = [str(p) for p in truth.photo_ids]
    strips = (SINGLE_MODEL_PHOTOS,) if tuple(ids) == SINGLE_MODEL_PHOTOS else STRIPS
    bases = [np.linalg.norm(truth.X0[ids.index(b)] - truth.X0[ids.index(a)])
             for strip in strips for a, b in zip(strip[:-1], strip[1:])]
    return float(np.mean(bases) * truth.c / distance_m)


def degrees_of_freedom(block: Block) -> int:
    """Redundancy of a bundle without additional parameters and with fixed IOP:
    2 × active observations + constraints − 6 × photos − 3 × points."""
    obs = block.observations
    n = 2 * int(obs.active.sum())
    constraints = int(np.isfinite(block.points.sigma).sum())
    return n + constraints - 6 * len(block.photos) - 3 * len(block.points)
