"""baarda.pipeline.units: one way to print a value with its unit."""

import math

import pytest

from baarda.pipeline.units import best_length_unit, fmt_num, fmt_q


@pytest.mark.parametrize("value, unit, text", [
    (3.98e-5, "m", "39.80 µm"),
    (2.545e-5, "m", "25.45 µm"),
    (0.0464, "m", "46.40 mm"),
    (0.186, "px", "0.1860 px"),
    (321.6, "px", "321.6 px"),
    (2.98, "", "2.980"),
    (0.0, "m", "0 m"),
    (12.5, "um", "12.50 µm"),
])
def test_fmt_q(value, unit, text):
    assert fmt_q(value, unit) == text


def test_map_coordinates_keep_their_unit():
    assert fmt_q(5421034.25, "m", sig=10, rescale=False) == "5421034.250 m"


def test_fmt_num_edge_cases():
    assert fmt_num(None) == "–" and fmt_num(math.nan) == "–" and fmt_num(7) == "7"
    assert fmt_num(8.61e-315) == "8.610e-315"


def test_best_length_unit():
    assert [best_length_unit(v) for v in (2e3, 2.0, 2e-3, 2e-6)] == ["km", "m", "mm", "µm"]
    assert best_length_unit(2e-6, allowed=("m", "mm")) == "mm"


# -- image units of a block, column names ------------------------------------------------------------

import numpy as np  # noqa: E402

from baarda.pipeline.geometry.image import mm_from_pixels  # noqa: E402
from baarda.pipeline.model import SourceInfo  # noqa: E402
from baarda.pipeline.synthetic.closerange import make_block  # noqa: E402
from baarda.pipeline.units import (MODEL_UNITS, ImageUnits, column_unit, fmt_obj, image_units,  # noqa: E402
                                   object_unit_text, unit_mismatches)


def _block(fmt=None, pitch=0.005, size=(800, 600)):
    blk, _ = make_block(model="brown", n_photos=6, n_points=20, noise_mm=0.001, rng=np.random.default_rng(1))
    cams = blk.cameras
    blk = blk.replace(cameras=cams.replace(pixel_mm=np.full(len(cams), pitch),
                                           resolution=np.tile(size, (len(cams), 1))))
    return blk if fmt is None else blk.replace(source=SourceInfo(path="x", format=fmt, pixel_format=fmt))


@pytest.mark.parametrize("fmt, convention", [("COLMAP", "colmap"), ("OpenCV", "opencv")])
def test_pixel_source_coordinates_and_differences_in_px(fmt, convention):
    blk = _block(fmt)
    iu = image_units(blk)
    assert iu.is_pixels and iu.unit == "px" and iu.suffix == "_px" and iu.scale == pytest.approx(200.0)
    uv = np.array([[0.0, 0.0], [799.0, 599.0], [400.0, 300.0]])
    xy = mm_from_pixels(uv, (800, 600), 0.005, convention)
    np.testing.assert_allclose(iu.coordinates(blk, xy, np.zeros(3, int)), uv, atol=1e-9)
    # a residual (mm, y up) in px along the pixel axes: y changes sign; an MDB (a length) does not
    np.testing.assert_allclose(iu.diff([[0.001, 0.002]], flip_y=True), [[0.2, -0.4]])
    np.testing.assert_allclose(iu.diff([[0.001, 0.002]]), [[0.2, 0.4]])


def test_bal_and_metric_sources():
    bal = image_units(_block("BAL"))
    assert bal.convention == "bal"
    np.testing.assert_allclose(bal.diff([[0.001, 0.002]], flip_y=True), [[0.2, 0.4]])     # BAL: y up
    mm = ImageUnits.of(_block())
    assert not mm.is_pixels and mm.unit == "µm" and mm.suffix == "_um"
    np.testing.assert_allclose(mm.diff([[0.001, -0.002]], flip_y=True), [[1.0, -2.0]])
    xy = np.array([[1.5, -2.0]])
    assert mm.coordinates(_block(), xy, [0]) is not None and (mm.coordinates(_block(), xy, [0]) == xy).all()


def test_model_units_without_datum():
    blk = _block("COLMAP")
    assert object_unit_text(blk) == blk.object_unit                 # the synthetic block has control points
    tie = blk.replace(points=blk.points.replace(role=np.full(len(blk.points), "tie")))
    assert object_unit_text(tie) == MODEL_UNITS
    assert object_unit_text(_block().replace(points=tie.points)) == blk.object_unit     # a metric source


def test_column_unit_and_object_lengths():
    assert [column_unit(c) for c in ("vx_um", "x_px", "X_m", "sX_mm", "omega_deg", "X_mu", "w", "cov_xx_mm2",
                                     "decision", "_m")] == ["µm", "px", "m", "mm", "deg", MODEL_UNITS, "", "mm²", "",
                                                            ""]
    assert fmt_obj(3.98e-5, "m") == "0.03980 mm" and fmt_obj(12.0, MODEL_UNITS) == "12.00 model units"
    from baarda.pipeline.stage import TableData
    assert TableData({"v_px": [1.0]}).units == {"v_px": "px"} and not unit_mismatches(TableData({"v_px": [1.0]}))


def test_camera_parameter_units_agree_with_the_bundle():
    """pipeline/units.py's AP unit powers (design, testfield-render tables) are the bundle's
    AP_PIXEL_POWER (plugins/bundle/protocol.py): one table of units for camera parameters."""
    from baarda.pipeline.units import AP_UNIT_POWER, camera_parameter_units
    from baarda.plugins.bundle.protocol import AP_PIXEL_POWER

    assert AP_UNIT_POWER == AP_PIXEL_POWER
    assert camera_parameter_units("brown", 7) == ["mm", "mm", "mm", "mm⁻²", "mm⁻⁴", "mm⁻⁶", "mm⁻¹", "mm⁻¹", "1", "1"]
    assert camera_parameter_units("ebner12", 12, "px")[3:6] == ["1", "1", "px⁻¹"]
    assert camera_parameter_units("someone-elses", 2) == ["mm"] * 3 + ["model units (mm)"] * 2
