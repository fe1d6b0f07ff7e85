"""The checks every source's block gets (pipeline/plausibility.py)."""

from __future__ import annotations

import numpy as np

from baarda.pipeline.model import SourceInfo
import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.model import Block, Cameras, Observations, Pairs, Photos, Points
from baarda.pipeline.plausibility import check_block


def block(xy=((1.0, 1.0), (2.0, 2.0), (3.0, 3.0)), photo=(0, 0, 1), point=(0, 1, 0), active=True, c=100.0,
          pixel_mm=np.nan, pairs=None, point_ids=("a", "b"), sigma=0.01, source=None):
    cams = Cameras.make(["cam"], c, format_mm=[[20.0, 20.0]], pixel_mm=pixel_mm)
    obs = Observations.make(list(photo), list(point), np.array(xy, float), sigma=sigma, active=active)
    p = Pairs(left=np.array([a for a, _ in pairs or []], int), right=np.array([b for _, b in pairs or []], int))
    return Block(cams, Photos.make(["L", "R"], camera=0), Points.make(list(point_ids)), obs, pairs=p,
                 source=source or SourceInfo(path="obs.txt"))


def test_a_good_block_passes_and_a_film_camera_has_no_pixels():
    assert check_block(block()) == []


@pytest.mark.parametrize("kw, words", [
    ({"xy": ((1.0, np.nan), (2.0, 2.0), (3.0, 3.0))}, "not finite"),
    ({"xy": ((1e300, 1.0), (2.0, 2.0), (3.0, 3.0))}, "10 format sizes"),
    ({"point": (0, 0, 0)}, "measured twice"),
    ({"c": 0.0}, "c = 0 must be a positive"),
    ({"c": np.inf}, "c = inf must be a positive"),
    ({"pixel_mm": -0.005}, "pixel_mm = -0.005"),
    ({"point_ids": ("a", "a")}, "point id 'a' occurs twice"),
    ({"pairs": [(0, 1), (1, 0)]}, "listed twice"),
    ({"pairs": [(0, 0)]}, "names photo 'L' twice"),
    ({"sigma": 0.0}, "not positive definite"),
])
def test_what_no_adjustment_can_use_is_an_error_naming_the_source(kw, words):
    with pytest.raises(InputError) as e:
        check_block(block(**kw))
    assert words in str(e.value) and str(e.value).startswith("obs.txt")


def test_a_switched_off_copy_is_no_duplicate_and_an_idle_photo_is_a_warning():
    w = check_block(block(point=(0, 0, 0), active=[True, False, False]))
    assert len(w) == 1 and "without an active measurement" in w[0] and "R" in w[0]


def test_the_reader_line_is_named_where_the_reader_knows_it():
    source = SourceInfo(path="x.phc", lines={(0, 1): ("x.phc", 17)})
    with pytest.raises(InputError) as e:
        check_block(block(xy=((1.0, 1.0), (1e9, 2.0), (3.0, 3.0)), source=source))
    assert (e.value.path, e.value.line) == ("x.phc", 17)
