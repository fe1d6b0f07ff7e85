"""gcp-list: the ODM/OpenSfM reader, cameras.json, and the odm-br-gcp fixture."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.errors import InputError
from baarda.plugins.gcp.reader import read_cameras_json, read_gcp_list, read_gnss_csv

GOOD = """+proj=utm +zone=22 +south +datum=WGS84 +units=m +no_defs
658528.361 7167002.098 890.636 2460.6 233.9 IMG_5349.JPG HV01

658528.361 7167002.098 890.636 1823.5 1087.9 IMG_5350.JPG HV01 extra
658586.168 7167009.487 890.139 1855.8 602.3 IMG_5352.JPG
"""


def _write(tmp_path, text, name="gcp_list.txt"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_reader(tmp_path):
    g = read_gcp_list(_write(tmp_path, GOOD))
    assert g.crs.startswith("+proj=utm") and g.crs_line == 1
    assert g.name == ["HV01", "HV01", "658586.168,7167009.487,890.139"]
    assert g.line.tolist() == [2, 4, 5]
    assert np.allclose(g.pixel[1], [1823.5, 1087.9])


@pytest.mark.parametrize("text, line, field, msg", [
    ("", None, None, "empty GCP list"),
    ("658528.361 7167002.098 890.636 2460.6 233.9 IMG.JPG A\n", 1, "crs", "must name the coordinate"),
    ("EPSG:32722\n1 2 3 4 IMG.JPG\n", 2, "image_name", "at least 6 fields"),
    ("EPSG:32722\n1 2 x 4 5 IMG.JPG A\n", 2, "geo_z", "expected a number"),
    ("EPSG:32722\n1 2 3 4 nan IMG.JPG A\n", 2, "im_y", "finite"),
    ("EPSG:32722\n1 2 3 4 5 IMG.JPG A\n1 2 3 6 7 IMG.JPG A\n", 3, "image_name", "measured twice"),
    ("EPSG:32722\n1 2 3 4 5 I1.JPG A\n1 2 3.5 6 7 I2.JPG A\n", 3, "geo_x", "other coordinates"),
    ("EPSG:32722\n", 1, "geo_x", "no measurement lines"),
])
def test_reader_errors(tmp_path, text, line, field, msg):
    with pytest.raises(InputError, match=msg) as e:
        read_gcp_list(_write(tmp_path, text))
    assert e.value.line == line and e.value.field == field and e.value.path.endswith("gcp_list.txt")


def test_cameras_json(tmp_path):
    p = _write(tmp_path, json.dumps({"v2 canon 4000 3000 perspective 0.7": {
        "projection_type": "perspective", "width": 4000, "height": 3000, "focal": 0.726, "k1": -0.1, "k2": 0.02}}),
        "cameras.json")
    (c,) = read_cameras_json(p)
    assert c.fx_px == pytest.approx(0.726 * 4000) and c.k1 == -0.1
    bad = _write(tmp_path, json.dumps({"x": {"projection_type": "fisheye", "width": 1, "height": 1}}), "bad.json")
    with pytest.raises(InputError, match="fisheye") as e:
        read_cameras_json(bad)
    assert e.value.field == "projection_type"


def test_gnss_csv(tmp_path):
    p = _write(tmp_path, "# crs: EPSG:32722\nphoto;E;N;h;sigma_h;sigma_v\nA;1;2;3;0.02;0.04\n", "g.csv")
    g = read_gnss_csv(p)
    assert g.crs == "EPSG:32722" and g.sigma.tolist() == [[0.02, 0.02, 0.04]]
    p = _write(tmp_path, "photo,lon,lat,h\nA,-49.4,-25.6,900\nA,-49.4,-25.6,900\n", "g2.csv")
    with pytest.raises(InputError, match="given twice") as e:
        read_gnss_csv(p)
    assert e.value.line == 3


def test_odm_fixture(repo_root, shared_beside, tmp_path):
    """fixtures/odm/odm-br-gcp.toml: 8 photos resected from the GNSS targets, 4 check points."""
    from baarda.pipeline.runner import run_project

    run_project(repo_root / "fixtures" / "odm" / "odm-br-gcp.toml", tmp_path / "run", verbose=False)
    res = json.loads((tmp_path / "run" / "results.json").read_text())
    text = json.dumps(res)
    assert "IMG_5349.JPG" in text and "IMG_5354.JPG" in text        # left out, named
    rows = (tmp_path / "run" / "bundle_check_points.csv").read_text().splitlines()[1:]
    d = np.array([[float(v) for v in r.split(",")[1:]] for r in rows])
    rmse = np.sqrt((d ** 2).mean(axis=0))
    print("odm check-point RMSE (m):", rmse)
    assert len(d) == 4 and rmse.max() < 0.2
    csv_lines = (tmp_path / "run" / "odm_points.csv").read_text().splitlines()
    assert csv_lines[0] == "# crs: EPSG:32722" and len(csv_lines) == 2 + 19
    # the control targets come back near their surveyed UTM coordinates (σ 2-3 cm, residuals ≤ 11 cm)
    hv01 = next(l for l in csv_lines if l.startswith("HV01,")).split(",")
    assert abs(float(hv01[2]) - 658528.361) < 0.1 and abs(float(hv01[3]) - 7167002.098) < 0.1


def test_gcp_stage_with_cameras_json(shared_data, tmp_path):
    """The camera from an OpenSfM cameras.json (brown, principal point off centre, k1): c, xp, yp, K1."""
    from baarda.pipeline.testing import run_stage
    from baarda.plugins.gcp.stage import GcpListSource

    cam = {"v2 canon": {"projection_type": "brown", "width": 4000, "height": 3000, "focal_x": 0.726,
                        "focal_y": 0.726, "c_x": 0.002, "c_y": -0.001, "k1": -0.05, "k2": 0.0}}
    (tmp_path / "cameras.json").write_text(json.dumps(cam))
    opts = {"path": str(shared_data / "odm-br-gcp" / "gcp_list_floatxy_raw.txt"), "cameras_json": "cameras.json",
            "camera": {"sensor_width_mm": 6.17}, "skip_lines": [19, 51, 52, 55, 70], "check": ["HV16"]}
    out = run_stage(GcpListSource, {}, opts, tmp_path=tmp_path)
    cams = out.artefacts["block"].cameras
    p = 6.17 / 4000
    c = 0.726 * 4000 * p
    assert cams.c[0] == pytest.approx(c)
    assert cams.xp[0] == pytest.approx(0.002 * 4000 * p) and cams.yp[0] == pytest.approx(0.001 * 4000 * p)
    assert cams.ap_model[0] == "brown" and cams.ap[0, 0] == pytest.approx(-0.05 / c ** 2)
    assert sorted(out.summary["dropped_photos"]) == ["IMG_5349.JPG", "IMG_5354.JPG"]
    assert out.summary["check"] == 1 and len(out.warnings) == 2


def test_stage_protocol():
    from baarda.pipeline.testing import check_stage
    from baarda.plugins.aicon.writer import AiconExportStage
    from baarda.plugins.export.stage import PointExport
    from baarda.plugins.gcp.stage import GcpListSource, GnssCentres

    for cls in (GcpListSource, GnssCentres, PointExport, AiconExportStage):
        check_stage(cls)


def test_no_resectable_photo_gives_the_real_reason(shared_data):
    """A list where no photo measures min_points control targets: the message says so (and only then
    that the check list names a target the list lacks) — was: "check point(s) … not in the GCP list"."""
    from baarda.pipeline.crs import local_frame
    from baarda.plugins.gcp.block import CameraSpec, gcp_block
    from baarda.plugins.gcp.reader import read_gcp_list

    gcp = read_gcp_list(shared_data / "odm-br-gcp" / "gcp_list_floatxy_raw.txt", skip_lines=[19, 51, 52, 55, 70])
    frame = local_frame(gcp.crs, gcp.geo)
    cam = CameraSpec("sx260", 4000, 3000, 2904.0, 6.17 / 4000)
    with pytest.raises(InputError, match="no photo can be resected.*min_points.*also names 'NOPE'") as e:
        gcp_block(gcp, cam, frame, check=("NOPE",), min_points=1000)
    assert e.value.field == "image_name" and "not in the GCP list" not in str(e.value)
    with pytest.raises(InputError, match="'NOPE' not in the GCP list") as e:    # resectable: the check list is wrong
        gcp_block(gcp, cam, frame, check=("NOPE",), min_points=4, check_where={"path": "p.toml", "line": 7})
    assert (str(e.value.path), e.value.line, e.value.field) == ("p.toml", 7, "check")
