"""Datum definition, rank-defect diagnosis and broken inputs give clear messages."""

import numpy as np
import pytest

from baarda.pipeline.errors import AdjustmentError, InputError
from baarda.pipeline.model import FIXED, FREE, Block, Cameras, Observations, Photos, Points
from baarda.pipeline.adjustment import BundleSettings, Distance, adjust
from baarda.pipeline.camera import LinearAPModel, register_ap_model

from baarda.pipeline.synthetic.closerange import make_block, perturb


def _free(blk):
    pts = blk.points
    return blk.replace(points=pts.replace(role=np.array(["tie"] * len(pts)), sigma=np.full((len(pts), 3), FREE)))


def test_no_datum_is_reported():
    blk, _ = make_block(model="none", n_photos=6, n_points=30)
    with pytest.raises(AdjustmentError) as e:
        adjust(_free(blk))
    assert "no datum: 7 degrees of freedom undetermined (3 translations, 3 rotations, scale)" in str(e.value)
    assert "datum = 'free'" in str(e.value)


def test_incomplete_datum_names_the_missing_motions():
    """Two control points fix translation, scale and two rotations; the rotation about the line
    through them stays free."""
    blk, _ = make_block(model="none", n_photos=6, n_points=30, n_control=0)
    pts = blk.points
    sigma = np.full((len(pts), 3), FREE)
    sigma[0] = sigma[1] = 0.0
    with pytest.raises(AdjustmentError) as e:
        adjust(blk.replace(points=pts.replace(sigma=sigma)))
    msg = str(e.value)
    assert "incomplete datum: 1 degree(s) of freedom undetermined (rotation about the axis (" in msg
    # … and the axis is the line through the two points
    axis = np.array([float(t) for t in msg.split("rotation about the axis (")[1].split(")")[0].split(",")])
    line = pts.XYZ[1] - pts.XYZ[0]
    line = line / np.linalg.norm(line) * np.sign(line[np.argmax(np.abs(line))])
    assert np.allclose(axis, line, atol=0.006)          # printed to 2 decimals
    assert "cannot be determined" not in msg


def _rotate_world(blk, angle_deg, axis=1):
    """The same block in a world rotated about a coordinate axis (images unchanged)."""
    from baarda.pipeline.geometry import opk_from_rotation, rotation_from_opk_many

    a = np.radians(angle_deg)
    c, s = np.cos(a), np.sin(a)
    i, j = [k for k in range(3) if k != axis]
    Rw = np.eye(3)
    Rw[i, i], Rw[i, j], Rw[j, i], Rw[j, j] = c, -s, s, c
    ph, pts = blk.photos, blk.points
    R = rotation_from_opk_many(ph.opk) @ Rw.T
    return blk.replace(photos=ph.replace(X0=ph.X0 @ Rw.T, opk=np.array([opk_from_rotation(r) for r in R])),
                       points=pts.replace(XYZ=pts.XYZ @ Rw.T))


@pytest.mark.parametrize("angle", [0.0, 86.0])
def test_scale_bar_without_control_names_all_six_motions(angle):
    """A scale bar and no control: 3 translations and 3 rotations are missing — each named, also
    when the photos are near φ = ±90° (ω, κ change fast there; the datum motions must not wrap)."""
    blk, truth = make_block(model="none", n_photos=6, n_points=30, n_control=0)
    blk = _rotate_world(_free(blk), angle)
    if angle:
        assert np.abs(np.degrees(blk.photos.opk[:, 1])).max() > 75     # 1/cos φ > π
    d = float(np.linalg.norm(truth["XYZ"][0] - truth["XYZ"][5]))
    with pytest.raises(AdjustmentError) as e:
        adjust(blk, BundleSettings(distances=(Distance("100", "105", d, 1e-5),)))
    assert str(e.value) == ("incomplete datum: 6 degree(s) of freedom undetermined (translation X, translation Y, "
                            "translation Z, rotation about X, rotation about Y, rotation about Z) — add or spread "
                            "control points, or set datum = 'free'")


def test_height_control_only_leaves_plane_motions():
    """Heights of 3 points (not on a line) fix Z, the tilts — and with them nothing in the plane:
    translation X, Y and rotation about Z remain, plus the scale (which 3 heights cannot fix
    without a tilt that compensates it)."""
    blk, _ = make_block(model="none", n_photos=6, n_points=30, n_control=0)
    pts = blk.points
    sigma = np.full((len(pts), 3), FREE)
    sigma[[0, 1, 2], 2] = 0.0
    with pytest.raises(AdjustmentError) as e:
        adjust(blk.replace(points=pts.replace(sigma=sigma)))
    msg = str(e.value)
    assert msg.startswith("incomplete datum: 4 degree(s) of freedom undetermined (translation X, translation Y, "
                          "rotation about Z, rotation about the axis (")
    assert "with scale)" in msg


def test_free_network_inner_constraints_keep_the_shape():
    blk, truth = make_block(model="brown", n_photos=8, n_points=40)
    start = perturb(_free(blk), np.random.default_rng(2), dXYZ=0.01, dX0=0.01, dang=0.005)
    res = adjust(start, BundleSettings(datum="free"))
    assert res.vtpv < 1e-12
    X = res.state.XYZ
    # the shape is the truth's (distances between points), the datum that of the approximations
    d = np.linalg.norm(X[:, None] - X[None], axis=2)
    dt = np.linalg.norm(truth["XYZ"][:, None] - truth["XYZ"][None], axis=2)
    ratio = d[np.triu_indices(len(X), 1)] / dt[np.triu_indices(len(X), 1)]
    assert np.allclose(ratio, ratio.mean(), rtol=1e-9)        # a similarity of the truth
    # inner constraints: the centroid of the datum points did not move (linearised, at convergence)
    assert np.allclose(X.mean(axis=0), start.points.XYZ.mean(axis=0), atol=1e-3)
    assert res.problem.n_c == 7 and res.dof == res.problem.n_obs_rows + 7 - res.problem.n_unknowns


def test_free_network_scale_from_a_distance():
    blk, truth = make_block(model="none", n_photos=8, n_points=40, noise_mm=0.001, rng=np.random.default_rng(3))
    d_true = float(np.linalg.norm(truth["XYZ"][10] - truth["XYZ"][20]))
    st = BundleSettings(datum="free", distances=(Distance("110", "120", d_true, 1e-5),))
    res = adjust(_free(perturb(blk, np.random.default_rng(4), dXYZ=0.01, dX0=0.01, dang=0.005)), st)
    assert res.problem.n_c == 6
    X = res.state.XYZ
    assert np.linalg.norm(X[10] - X[20]) == pytest.approx(d_true, abs=3e-5)
    dt = np.linalg.norm(truth["XYZ"][0] - truth["XYZ"][39])
    assert np.linalg.norm(X[0] - X[39]) == pytest.approx(dt, rel=1e-3)
    # the image rows carry the whole redundancy except the distance's own share (0 ≤ r_d ≤ 1; here
    # the one distance fixes the scale, so its share is 0 and the sum is dof up to rounding)
    assert res.dof - 1 <= res.redundancy.sum() <= res.dof * (1 + 1e-12)


class _Twin(LinearAPModel):
    """A deliberately broken model: a2 duplicates a1, a3 affects nothing."""

    name = "twin-test"
    params = ("a1", "a2", "a3")
    default_sigma = (np.inf,) * 3

    def basis(self, x, y, c, meta):
        B = np.zeros((len(x), 2, 3))
        r2 = x * x + y * y
        B[:, 0, 0] = B[:, 0, 1] = x * r2
        B[:, 1, 0] = B[:, 1, 1] = y * r2
        return B

    def basis_xy(self, x, y, c, meta):
        D = np.zeros((len(x), 2, 2, 3))
        for t in (0, 1):
            D[:, 0, 0, t] = 3 * x * x + y * y
            D[:, 0, 1, t] = 2 * x * y
            D[:, 1, 0, t] = 2 * x * y
            D[:, 1, 1, t] = x * x + 3 * y * y
        return D


def _with_model(blk, name, sigma_ap):
    cams = blk.cameras
    return blk.replace(cameras=cams.replace(ap_model=np.array([name]), ap=np.zeros((1, 3)),
                                            sigma_ap=np.array([sigma_ap], float)))


def test_undeterminable_ap_is_named():
    register_ap_model("twin-test", _Twin(), replace=True)
    blk, _ = make_block(model="none", n_photos=6, n_points=30)
    with pytest.raises(AdjustmentError) as e:
        adjust(_with_model(blk, "twin-test", [FREE, FREE, 0.0]))
    msg = str(e.value)
    assert "of camera 'cam' cannot be determined (correlation 1.000 with a" in msg
    assert "fix it or give it an a-priori sigma" in msg
    with pytest.raises(AdjustmentError) as e:
        adjust(_with_model(blk, "twin-test", [FREE, 0.0, FREE]))
    assert "parameter a3 of camera 'cam' cannot be determined: no observation depends on it" in str(e.value)
    # an a-priori sigma makes it determinable
    res = adjust(_with_model(blk, "twin-test", [FREE, 1e-6, 0.0]))
    assert res.camera_table(0)[4]["status"] == "weighted"


def test_photo_with_too_few_points():
    blk, _ = make_block(model="none", n_photos=6, n_points=30)
    obs = blk.observations
    keep = (obs.photo != 2) | (obs.point < 2)
    bad = blk.replace(observations=obs.take(keep))
    with pytest.raises(AdjustmentError, match=r"photo 'P3' has only 2 observed point\(s\)"):
        adjust(bad)
    res = adjust(bad, BundleSettings(on_weak="drop"))
    assert any("photo 'P3' dropped" in w for w in res.warnings)
    assert not res.problem.photo_used[2]


def test_point_seen_once():
    blk, _ = make_block(model="none", n_photos=6, n_points=30)
    obs = blk.observations
    keep = (obs.point != 20) | (obs.photo == 0)
    with pytest.raises(AdjustmentError, match=r"point '120' is observed in only one photo \('P1'\)"):
        adjust(blk.replace(observations=obs.take(keep)))


def test_duplicate_ids_and_measurements():
    blk, _ = make_block(model="none", n_photos=4, n_points=20)
    ph = blk.photos
    ids = ph.ids.copy()
    ids[3] = ids[1]
    with pytest.raises(InputError, match=r"duplicate photo id 'P2' \(rows 2, 4\)"):
        adjust(blk.replace(photos=ph.replace(ids=ids)))
    obs = blk.observations
    twice = Observations.make(np.r_[obs.photo, obs.photo[:1]], np.r_[obs.point, obs.point[:1]],
                              np.vstack([obs.xy, obs.xy[:1]]), sigma=0.001)
    with pytest.raises(InputError, match="measured twice in photo 'P1'"):
        adjust(blk.replace(observations=twice))


def test_non_convergence_keeps_the_last_state():
    blk, _ = make_block(model="none", n_photos=6, n_points=30, noise_mm=0.001)
    start = perturb(blk, np.random.default_rng(1))
    with pytest.raises(AdjustmentError) as e:
        adjust(start, BundleSettings(max_iter=1))
    assert "no convergence after 1 iterations" in str(e.value)
    assert e.value.state is not None and e.value.state.X0.shape == (6, 3)
