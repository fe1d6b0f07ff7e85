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
