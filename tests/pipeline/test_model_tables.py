"""The block's tables: taking rows keeps every column, the per-camera AP arrays too."""

import numpy as np
import pytest

from baarda.pipeline.model import Cameras


def _cameras():
    return Cameras.make(["a", "b", "c"], [24.0, 35.0, 50.0], ap_model=["brown"] * 3,
                        ap=np.arange(21.0).reshape(3, 7), sigma_ap=np.full((3, 7), 0.5) * [[1], [2], [3]])


@pytest.mark.parametrize("index", [np.array([True, False, True]), np.array([2, 0]), np.array([1])])
def test_take_cuts_ap_and_sigma_ap_with_the_other_columns(index):
    cams = _cameras()
    out = cams.take(index)
    rows = np.arange(3)[index]
    assert list(out.ids) == [cams.ids[i] for i in rows]
    np.testing.assert_array_equal(out.c, cams.c[rows])
    np.testing.assert_array_equal(out.ap, cams.ap[rows])
    np.testing.assert_array_equal(out.sigma_ap, cams.sigma_ap[rows])
    assert out.ap.shape == (len(rows), 7)


def test_take_of_cameras_without_aps():
    out = Cameras.make(["a", "b"], [24.0, 35.0]).take(np.array([1]))
    assert out.ap.shape == (1, 0) and list(out.ids) == ["b"]
