"""OpenSfM reconstruction.json + tracks.csv: exact camera mapping, round trip, broken input, stages."""

import json

import numpy as np
import pytest

from baarda.pipeline.adjustment import project_block
from baarda.pipeline.errors import InputError
from baarda.pipeline.model import Block, Cameras, Observations, Photos, Points
from baarda.pipeline.opensfm import _rotvec_to_matrix, read_opensfm, write_opensfm


def _block(rng):
    aps = [np.r_[-2e-3, 1e-5, 0, 0, 0, 0, 0], np.r_[-1e-3, 2e-6, 1e-8, 2e-4, -1e-4, 0, 0]]
    cams = Cameras.make(["c0", "c1"], [8.0, 12.0], xp=[0.01, -0.03], yp=[-0.02, 0.015], ap_model="brown",
                        ap=np.array(aps), pixel_mm=0.004, resolution=(3000, 2000), format_mm=(12.0, 8.0))
    XYZ = np.column_stack([rng.uniform(-5, 5, 40), rng.uniform(-5, 5, 40), rng.uniform(-1, 1, 40)])
    X0 = np.column_stack([np.linspace(-3, 3, 5), np.zeros(5), np.full(5, 20.0)])
    photos = Photos.make([f"IMG_{i}.JPG" for i in range(5)], camera=np.arange(5) % 2, X0=X0,
                         opk=rng.normal(0, 0.05, (5, 3)))
    pts = Points.make([f"t{i}" for i in range(40)], XYZ=XYZ)
    ph, pt = np.meshgrid(np.arange(5), np.arange(40), indexing="ij")
    blk = Block(cams, photos, pts, Observations.make(ph.ravel(), pt.ravel(), np.zeros((200, 2))))
    xy = project_block(blk, ph.ravel(), pt.ravel()) + rng.normal(0, 0.002, (200, 2))
    return blk.replace(observations=blk.observations.replace(xy=xy))


def _opensfm_project(cam, shot, X):
    """OpenSfM's own projection, written from its documentation (normalised image coordinates)."""
    R = _rotvec_to_matrix(shot["rotation"])
    p = R @ X + np.asarray(shot["translation"])
    x, y = p[0] / p[2], p[1] / p[2]
    r2 = x * x + y * y
    if cam["projection_type"] == "perspective":
        d = 1 + cam["k1"] * r2 + cam["k2"] * r2 * r2
        return np.array([cam["focal"] * d * x, cam["focal"] * d * y])
    d = 1 + cam["k1"] * r2 + cam["k2"] * r2 ** 2 + cam["k3"] * r2 ** 3
    xd = x * d + 2 * cam["p1"] * x * y + cam["p2"] * (r2 + 2 * x * x)
    yd = y * d + cam["p1"] * (r2 + 2 * y * y) + 2 * cam["p2"] * x * y
    return np.array([cam["focal_x"] * xd + cam["c_x"], cam["focal_y"] * yd + cam["c_y"]])


def test_round_trip_and_projection_as_opensfm(tmp_path):
    blk = _block(np.random.default_rng(3))
    info = write_opensfm(blk, tmp_path)
    assert info == {"cameras": 2, "shots": 5, "points": 40, "observations": 200, "skipped_photos": []}
    back, rinfo = read_opensfm(tmp_path / "reconstruction.json", pixel_mm=0.004)
    assert rinfo["inexact_cameras"] == []
    for name in ("c", "xp", "yp", "ap"):
        np.testing.assert_allclose(getattr(back.cameras, name), getattr(blk.cameras, name), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(back.photos.X0, blk.photos.X0, atol=1e-11)
    np.testing.assert_allclose(back.photos.opk, blk.photos.opk, atol=1e-12)
    np.testing.assert_allclose(back.points.XYZ, blk.points.XYZ, atol=1e-12)
    assert back.photos.ids.tolist() == blk.photos.ids.tolist() and back.points.ids.tolist() == blk.points.ids.tolist()
    np.testing.assert_allclose(back.observations.xy, blk.observations.xy, atol=1e-12)
    # the file's numbers projected by OpenSfM's formulas give baarda's projection of the block
    rec = json.loads((tmp_path / "reconstruction.json").read_text())[0]
    ob = blk.observations
    mine = project_block(blk, ob.photo, ob.point)
    for k in range(0, len(ob), 17):
        sid, cid = blk.photos.ids[ob.photo[k]], blk.cameras.ids[blk.photos.camera[ob.photo[k]]]
        xn = _opensfm_project(rec["cameras"][cid], rec["shots"][sid], blk.points.XYZ[ob.point[k]])
        uv = xn * 3000 + np.array([1500, 1000]) - 0.5
        xy = np.array([uv[0] - 1499.5, -(uv[1] - 999.5)]) * 0.004
        np.testing.assert_allclose(xy, mine[k], atol=1e-10)


def test_perspective_camera_maps_exactly(tmp_path):
    cam = {"projection_type": "perspective", "width": 4000, "height": 3000, "focal": 0.85, "k1": -0.1, "k2": 0.02}
    shot = {"camera": "cam", "rotation": [0.1, -0.2, 0.05], "translation": [0.3, -0.1, 2.0]}
    X = np.array([0.4, 0.2, 1.5])
    (tmp_path / "reconstruction.json").write_text(json.dumps(
        [{"cameras": {"cam": cam}, "shots": {"a.jpg": shot}, "points": {"1": {"coordinates": X.tolist()}}}]))
    xn = _opensfm_project(cam, shot, X)
    (tmp_path / "tracks.csv").write_text(f"OPENSFM_TRACKS_VERSION_v2\na.jpg\t1\t0\t{float(xn[0])!r}\t{float(xn[1])!r}\t0\t1\t2\t3\t-1\t-1\n")
    blk, info = read_opensfm(tmp_path / "reconstruction.json", pixel_mm=0.002)
    assert len(blk.observations) == 1 and info["tracks"]
    np.testing.assert_allclose(project_block(blk, [0], [0])[0], blk.observations.xy[0], atol=1e-12)
    np.testing.assert_allclose(blk.cameras.c, [0.85 * 4000 * 0.002])


@pytest.mark.parametrize("edit, field", [
    (lambda r: r["cameras"]["c0"].update(projection_type="fisheye"), "projection_type"),
    (lambda r: r["cameras"]["c0"].pop("focal_x"), "focal_x"),
    (lambda r: r["cameras"]["c0"].update(width="3000"), "width"),
    (lambda r: r["shots"]["IMG_0.JPG"].update(rotation=[0, 1]), "rotation"),
    (lambda r: r["shots"]["IMG_0.JPG"].update(camera="nope"), "camera"),
    (lambda r: r["points"]["t3"].update(coordinates=[0, None, 1]), "coordinates"),
    (lambda r: r.pop("cameras"), "cameras"),
    (lambda r: r.update(shots=[1]), "shots"),
])
def test_broken_json_names_the_field(tmp_path, edit, field):
    write_opensfm(_block(np.random.default_rng(1)), tmp_path)
    p = tmp_path / "reconstruction.json"
    doc = json.loads(p.read_text())
    edit(doc[0])
    p.write_text(json.dumps(doc))
    with pytest.raises(InputError) as e:
        read_opensfm(p)
    assert e.value.field.endswith(field) and e.value.path == str(p)


def test_broken_tracks_names_the_line(tmp_path):
    write_opensfm(_block(np.random.default_rng(1)), tmp_path)
    t = tmp_path / "tracks.csv"
    lines = t.read_text().splitlines()
    lines[4] = lines[4].replace("\t0\t255", "\t0\t255").split("\t")
    lines[4][3] = "1.2.3"
    lines[4] = "\t".join(lines[4])
    t.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as e:
        read_opensfm(tmp_path / "reconstruction.json")
    assert e.value.line == 5 and e.value.field == "x"
    (tmp_path / "reconstruction.json").write_text("[{\"cameras\": {}\n")
    with pytest.raises(InputError) as e:
        read_opensfm(tmp_path / "reconstruction.json")
    assert e.value.line == 2


# OpenDroneMap/ODM tests/assets/reconstruction.json (AGPL-3.0), a real camera-only file, verbatim
ODM_ASSET = """[{"reference_lla": {"latitude": 46.84265666666667, "altitude": 0, "longitude": -91.99400802469134},
 "cameras": {"v2 dji fc300s 4000 2250 perspective 0.5555": {"focal_prior": 0.5555555555555556, "width": 4000,
  "k1": 0.0052219633739416784, "k2": 0.015202301516716735, "k1_prior": 0.0, "k2_prior": 0.0,
  "projection_type": "perspective", "focal": 0.5614307793062748, "height": 2250}}, "shots": {}}]"""


def test_real_odm_camera_file(tmp_path):
    p = tmp_path / "reconstruction.json"
    p.write_text(ODM_ASSET)
    blk, info = read_opensfm(p, pixel_mm=0.00156)
    assert info["tracks"] is None and len(blk.photos) == 0 and len(blk.points) == 0
    c = 0.5614307793062748 * 4000 * 0.00156
    np.testing.assert_allclose(blk.cameras.c, [c])
    np.testing.assert_allclose(blk.cameras.ap[0, :2], [0.0052219633739416784 / c**2, 0.015202301516716735 / c**4])
    np.testing.assert_allclose([blk.cameras.xp[0], blk.cameras.yp[0]], [0, 0], atol=1e-15)
