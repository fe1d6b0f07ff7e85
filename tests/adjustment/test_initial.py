"""Space resection and intersection (closed form + refinement) and the alternating initial values."""

import numpy as np
import pytest

from baarda.pipeline.errors import AdjustmentError
from baarda.pipeline.adjustment import adjust, initial_values, intersection, resection
from baarda.pipeline.adjustment.collinearity import project_observations

from baarda.pipeline.synthetic.closerange import META, TRUE_AP, make_block


def _photo(blk, truth, i, pts=None):
    obs = blk.observations
    sel = obs.photo == i
    if pts is not None:
        sel &= np.isin(obs.point, pts)
    return obs.xy[sel], truth["XYZ"][obs.point[sel]]


@pytest.mark.parametrize("model", ["none", "brown"])
def test_resection_dlt_returns_truth(model):
    blk, truth = make_block(model=model, n_photos=6, n_points=30)
    cam = truth["cam"]
    for i in range(6):
        xy, XYZ = _photo(blk, truth, i)
        r = resection(xy, XYZ, cam[0], cam[1], cam[2], ap_model=model, ap=cam[3:], meta=META[model])
        assert r.method == "dlt"
        assert np.allclose(r.X0, truth["X0"][i], atol=1e-9)
        assert np.allclose(r.opk, truth["opk"][i], atol=1e-10)
        assert r.rms < 1e-10


def test_resection_from_four_coplanar_points():
    blk, truth = make_block(model="none", n_photos=4, n_points=30)
    XYZ = truth["XYZ"].copy()
    XYZ[:, 2] = 0.0                                          # a flat target
    ph = np.repeat(np.arange(4), 4)
    pt = np.tile([0, 5, 9, 14], 4)
    pr = project_observations(ph, pt, XYZ, truth["X0"], truth["opk"], np.zeros(4, int), truth["cam"][None],
                              ["none"], [{}], jacobians=False)
    for i in range(4):
        s = ph == i
        r = resection(pr.xy[s], XYZ[pt[s]], truth["cam"][0], truth["cam"][1], truth["cam"][2])
        assert r.method == "plane"
        assert np.allclose(r.X0, truth["X0"][i], atol=1e-8)


def test_resection_needs_four_points():
    with pytest.raises(AdjustmentError, match="at least 4 points"):
        resection(np.zeros((3, 2)), np.eye(3), 25.0)


def test_intersection_vectorised():
    blk, truth = make_block(model="aicon", n_photos=6, n_points=30)
    obs = blk.observations
    cam = truth["cam"]
    XYZ = intersection(obs.xy, obs.photo, truth["X0"], truth["opk"], cam[0], cam[1], cam[2], point=obs.point,
                       ap_model="aicon", ap=cam[3:], meta=META["aicon"])
    assert np.allclose(XYZ, truth["XYZ"], atol=1e-10)


def test_initial_values_alternate_resection_and_intersection():
    """Photo P1 sees no control point: it is oriented only after tie points were intersected."""
    blk, truth = make_block(model="none", n_photos=6, n_points=40, n_control=8)
    obs = blk.observations
    keep = ~((obs.photo == 0) & (obs.point < 8))
    ph, pts = blk.photos, blk.points
    XYZ = pts.XYZ.copy()
    XYZ[8:] = np.nan
    start = blk.replace(observations=obs.take(keep),
                        photos=ph.replace(X0=np.full((6, 3), np.nan), opk=np.full((6, 3), np.nan)),
                        points=pts.replace(XYZ=XYZ))
    init = initial_values(start)
    assert np.allclose(init.photos.X0, truth["X0"], atol=1e-8)
    assert np.allclose(init.points.XYZ, truth["XYZ"], atol=1e-8)
    res = adjust(start)
    assert np.allclose(res.state.X0, truth["X0"], atol=1e-10)


def test_initial_values_report_what_is_missing():
    blk, truth = make_block(model="none", n_photos=4, n_points=20, n_control=3)
    pts = blk.points
    XYZ = pts.XYZ.copy()
    XYZ[3:] = np.nan
    start = blk.replace(photos=blk.photos.replace(X0=np.full((4, 3), np.nan), opk=np.full((4, 3), np.nan)),
                        points=pts.replace(XYZ=XYZ))
    with pytest.raises(AdjustmentError, match="no initial orientation for photo 'P1': it sees 3 point"):
        initial_values(start)
