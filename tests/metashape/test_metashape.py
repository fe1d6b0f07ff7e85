"""Metashape camera XML: the camera model mapped exactly, round trip, chunk transform, broken input."""

import numpy as np
import pytest

from baarda.pipeline.adjustment import project_block
from baarda.pipeline.errors import InputError
from baarda.pipeline.metashape import brown_from_metashape, read_metashape, write_metashape
from baarda.pipeline.model import Block, Cameras, Observations, Photos, Points


def _block(rng, aps=None):
    aps = aps if aps is not None else [np.r_[-2e-3, 1e-5, 1e-8, 2e-4, -1e-4, 0, 0], np.r_[0, 0, 0, 0, 0, 1e-3, -4e-4]]
    cams = Cameras.make(["s0", "s1"], [8.0, 12.0], xp=[0.01, -0.03], yp=[-0.02, 0.015], ap_model="brown",
                        ap=np.array(aps), pixel_mm=0.004, resolution=(3000, 2000), format_mm=(12.0, 8.0))
    XYZ = np.column_stack([rng.uniform(-5, 5, 30), rng.uniform(-5, 5, 30), rng.uniform(-1, 1, 30)])
    X0 = np.column_stack([np.linspace(-3, 3, 5), np.zeros(5), np.full(5, 20.0)])
    photos = Photos.make([f"IMG_{i}.JPG" for i in range(5)], camera=np.arange(5) % 2, X0=X0,
                         opk=rng.normal(0, 0.05, (5, 3)))
    role = np.array(["full"] * 6 + ["check"] * 2 + ["tie"] * 22)
    pts = Points.make([f"m{i}" for i in range(30)], XYZ=XYZ, role=role)
    ph, pt = np.meshgrid(np.arange(5), np.arange(30), indexing="ij")
    blk = Block(cams, photos, pts, Observations.make(ph.ravel(), pt.ravel(), np.zeros((150, 2))))
    xy = project_block(blk, ph.ravel(), pt.ravel()) + rng.normal(0, 0.002, (150, 2))
    return blk.replace(observations=blk.observations.replace(xy=xy))


def _metashape_project(t, W, H, Xc):
    """Metashape's frame-camera projection as its manual states it (pixels, top-left corner origin)."""
    x, y = Xc[0] / Xc[2], Xc[1] / Xc[2]
    r2 = x * x + y * y
    g = t.get
    rad = 1 + g("k1", 0) * r2 + g("k2", 0) * r2**2 + g("k3", 0) * r2**3 + g("k4", 0) * r2**4
    tan = 1 + g("p3", 0) * r2 + g("p4", 0) * r2**2
    xd = x * rad + (g("p1", 0) * (r2 + 2 * x * x) + 2 * g("p2", 0) * x * y) * tan
    yd = y * rad + (g("p2", 0) * (r2 + 2 * y * y) + 2 * g("p1", 0) * x * y) * tan
    return np.array([W / 2 + t["cx"] + xd * t["f"] + xd * g("b1", 0) + yd * g("b2", 0), H / 2 + t["cy"] + yd * t["f"]])


@pytest.mark.parametrize("terms", [
    {"f": 2000.0, "cx": 12.5, "cy": -7.25, "k1": -0.12, "k2": 0.05, "k3": -0.01, "p1": 3e-4, "p2": -2e-4},
    {"f": 2000.0, "cx": -3.0, "cy": 4.0, "b1": 1.5, "b2": -0.75},
])
def test_camera_model_maps_exactly(terms):
    rng = np.random.default_rng(5)
    p, W, H = 0.0039, 3000, 2000
    b = brown_from_metashape(terms, p)
    cams = Cameras.make(["s"], b["c"], xp=b["xp"], yp=b["yp"], ap_model="brown", ap=b["ap"][None], pixel_mm=p,
                        resolution=(W, H), format_mm=(W * p, H * p))
    Xc = np.column_stack([rng.uniform(-0.6, 0.6, 20), rng.uniform(-0.4, 0.4, 20), np.ones(20)]) * 10.0
    blk = Block(cams, Photos.make(["a"], X0=[0, 0, 0], opk=[np.pi, 0, 0]),     # camera y down, z forward = world
                Points.make([str(i) for i in range(20)], XYZ=Xc), Observations.make(np.zeros(20), np.arange(20),
                                                                                      np.zeros((20, 2))))
    mine = project_block(blk, np.zeros(20, int), np.arange(20))
    for k in range(20):
        uv = _metashape_project(terms, W, H, Xc[k])
        np.testing.assert_allclose(mine[k], [(uv[0] - W / 2) * p, -(uv[1] - H / 2) * p], atol=1e-11)


@pytest.mark.parametrize("bad", ["k4", "p3", "p4"])
def test_terms_without_counterpart_refused_by_name(bad):
    with pytest.raises(ValueError, match=bad):
        brown_from_metashape({"f": 1000.0, bad: 1e-3}, 0.004)
    with pytest.raises(ValueError, match="b1"):
        brown_from_metashape({"f": 1000.0, "b1": 0.5, "k1": 0.1}, 0.004)


def test_round_trip(tmp_path):
    blk = _block(np.random.default_rng(4))
    info = write_metashape(blk, tmp_path / "cams.xml")
    assert info["cameras"] == 5 and info["observations"] == 150
    back, rinfo = read_metashape(tmp_path / "cams.xml")
    assert rinfo["local_crs"]
    for name in ("c", "xp", "yp", "ap", "pixel_mm"):
        np.testing.assert_allclose(getattr(back.cameras, name), getattr(blk.cameras, name), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(back.photos.X0, blk.photos.X0, atol=1e-11)
    np.testing.assert_allclose(back.photos.opk, blk.photos.opk, atol=1e-12)
    assert back.points.role.tolist() == blk.points.role.tolist()
    ctrl = blk.points.role != "tie"
    np.testing.assert_allclose(back.points.XYZ[ctrl], blk.points.XYZ[ctrl], atol=1e-12)
    assert np.isnan(back.points.XYZ[~ctrl]).all()
    a, b = back.observations, blk.observations
    ia, ib = np.lexsort((a.point, a.photo)), np.lexsort((b.point, b.photo))
    assert (a.photo[ia] == b.photo[ib]).all() and (a.point[ia] == b.point[ib]).all()
    np.testing.assert_allclose(a.xy[ia], b.xy[ib], atol=1e-12)


def test_chunk_transform_applied(tmp_path):
    blk = _block(np.random.default_rng(4))
    write_metashape(blk, tmp_path / "a.xml")
    text = (tmp_path / "a.xml").read_text()
    a = 0.3
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    t, s = np.array([100.0, -50.0, 7.0]), 2.5
    tr = (f"<transform><rotation>{' '.join(map(repr, R.ravel().tolist()))}</rotation>"
          f"<translation>{' '.join(map(repr, t.tolist()))}</translation><scale>{s!r}</scale></transform>")
    (tmp_path / "b.xml").write_text(text.replace("<sensors", tr + "<sensors", 1))
    back, _ = read_metashape(tmp_path / "b.xml")
    np.testing.assert_allclose(back.photos.X0, s * blk.photos.X0 @ R.T + t, atol=1e-9)
    # the same image rays: projections of the transformed points equal the original ones
    XYZ = s * blk.points.XYZ @ R.T + t
    moved = back.replace(points=back.points.replace(XYZ=XYZ))
    ob = blk.observations
    np.testing.assert_allclose(project_block(moved, ob.photo, ob.point), project_block(blk, ob.photo, ob.point),
                               atol=1e-10)


@pytest.mark.parametrize("old, new, field", [
    ('<f>', '<f>x', "calibration/f"),
    ('type="frame"', 'type="fisheye"', "@type"),
    ('<transform>', '<transform>1 2 ', "transform"),
    ('sensor_id="1"', 'sensor_id="9"', "@sensor_id"),
    ('marker_id="3"', 'marker_id="99"', "@marker_id"),
    ('</document>', '', "xml"),
])
def test_broken_xml_names_element_and_field(tmp_path, old, new, field):
    write_metashape(_block(np.random.default_rng(4)), tmp_path / "a.xml")
    p = tmp_path / "a.xml"
    p.write_text(p.read_text().replace(old, new, 1))
    with pytest.raises(InputError) as e:
        read_metashape(p)
    assert e.value.field.endswith(field) and e.value.path == str(p)


def test_georeferenced_chunk_goes_to_a_local_frame(tmp_path):
    """A chunk in WGS 84 (lon, lat, h): the chunk transform maps to ECEF; the block comes out in a local
    east-north-up frame with the same image geometry (residuals of the control markers unchanged)."""
    from xml.etree import ElementTree as ET

    from baarda.pipeline.adjustment import reprojection_px
    from baarda.pipeline.crs import R_enu_from_ecef, ecef_from_geodetic, geodetic_from_ecef

    blk = _block(np.random.default_rng(8))
    write_metashape(blk, tmp_path / "local.xml")
    lon, lat, h = 8.5, 47.4, 400.0
    Re, o = R_enu_from_ecef(lon, lat), ecef_from_geodetic(lon, lat, h)
    tree = ET.parse(tmp_path / "local.xml")
    chunk = tree.getroot().find("chunk")
    tr = ET.SubElement(chunk, "transform")
    ET.SubElement(tr, "rotation").text = " ".join(map(repr, Re.T.ravel().tolist()))
    ET.SubElement(tr, "translation").text = " ".join(map(repr, o.tolist()))
    ET.SubElement(tr, "scale").text = "1"
    chunk.find("reference").text = "EPSG:4979"
    for m in chunk.find("markers"):
        ref = m.find("reference")
        if ref is not None:
            X = blk.points.XYZ[int(m.get("id"))] @ Re + o
            g = geodetic_from_ecef(X)
            ref.set("x", repr(float(g[0]))), ref.set("y", repr(float(g[1]))), ref.set("z", repr(float(g[2])))
    tree.write(tmp_path / "geo.xml")
    back, info = read_metashape(tmp_path / "geo.xml")
    assert not info["local_crs"] and back.crs is not None
    ctrl = np.flatnonzero(blk.points.role != "tie")
    a, b = back.observations, blk.observations
    ia, ib = np.lexsort((a.point, a.photo)), np.lexsort((b.point, b.photo))
    va = reprojection_px(back)[ia][np.isin(a.point[ia], ctrl)]
    vb = reprojection_px(blk)[ib][np.isin(b.point[ib], ctrl)]
    np.testing.assert_allclose(va, vb, atol=1e-6)
    d = lambda X: np.linalg.norm(X[:, None] - X[None], axis=-1)
    np.testing.assert_allclose(d(back.photos.X0), d(blk.photos.X0), atol=1e-6)
    assert np.abs(back.photos.X0).max() < 100          # local, not geocentric


# The layout of a Metashape 2.0 camera export (component transform, cameras in a <group>, a camera
# <reference>, k4 and b1/b2 calibrated), as public tools' tests quote it; numbers made up here.
V2_XML = """<?xml version="1.0" encoding="UTF-8"?>
<document version="2.0.0">
  <chunk label="Chunk 1" enabled="true">
    <sensors next_id="1">
      <sensor id="0" label="M3M (12.29mm)" type="frame">
        <resolution width="5280" height="3956"/>
        <property name="pixel_width" value="0.0033582"/>
        <property name="focal_length" value="12.29"/>
        <calibration type="frame" class="adjusted">
          <resolution width="5280" height="3956"/>
          <f>3705.47</f><cx>11.67</cx><cy>-27.75</cy>{extra}
        </calibration>
        <covariance><params>f cx cy k1</params><coeffs>1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1</coeffs></covariance>
      </sensor>
    </sensors>
    <components next_id="1" active_id="0">
      <component id="0" label="Component 1">
        <transform>
          <rotation locked="true">0 -1 0 1 0 0 0 0 1</rotation>
          <translation locked="true">1000 2000 300</translation>
          <scale locked="true">2</scale>
        </transform>
      </component>
    </components>
    <cameras next_id="1" next_group_id="1">
      <group id="0" label="Group 1" type="folder">
        <camera id="0" sensor_id="0" component_id="0" label="a.JPG">
          <transform>1 0 0 7 0 -1 0 5 0 0 -1 0.5 0 0 0 1</transform>
          <orientation>1</orientation>
          <reference x="-120.4" y="39.4" z="2420.1" yaw="179.9" pitch="0.1" roll="-0" enabled="true"/>
        </camera>
      </group>
    </cameras>
  </chunk>
</document>
"""


def test_metashape2_layout(tmp_path):
    p = tmp_path / "v2.xml"
    p.write_text(V2_XML.format(extra="<b1>0.526</b1><b2>-0.306</b2><k1>-0.0919</k1><k4>-0.076</k4>"))
    with pytest.raises(InputError) as e:
        read_metashape(p)
    assert e.value.field == "sensor[@id='0']/calibration/k4"
    p.write_text(V2_XML.format(extra="<k1>-0.0919</k1><k2>0.05</k2>"))
    blk, _ = read_metashape(p)
    assert blk.photos.ids.tolist() == ["a.JPG"]
    np.testing.assert_allclose(blk.cameras.pixel_mm, [0.0033582])
    np.testing.assert_allclose(blk.cameras.c, [3705.47 * 0.0033582])
    # centre = s R tc + t with R a quarter turn about z
    np.testing.assert_allclose(blk.photos.X0[0], [1000 - 2 * 5, 2000 + 2 * 7, 300 + 2 * 0.5], atol=1e-9)


@pytest.mark.parametrize("terms", [
    {"f": 3705.47, "cx": 11.67, "cy": -27.75, "b1": 0.526, "b2": -0.306, "k1": -0.0919, "k2": -0.0763, "k3": 0.116,
     "k4": -0.0761, "p1": -3.1e-4, "p2": 1.2e-4, "p3": 0.5, "p4": -0.2},
])
def test_metashape_ap_model_maps_every_term_exactly(tmp_path, terms):
    from baarda.pipeline.metashape import metashape_ap_from_terms, terms_from_metashape_ap

    rng = np.random.default_rng(6)
    p, W, H = 0.0033582, 5280, 3956
    b = metashape_ap_from_terms(terms, p)
    back = terms_from_metashape_ap(b["c"], b["xp"], b["yp"], b["ap"], p)
    for k, v in terms.items():
        assert back[k] == pytest.approx(v, rel=1e-12)
    cams = Cameras.make(["s"], b["c"], xp=b["xp"], yp=b["yp"], ap_model="metashape", ap=b["ap"][None], pixel_mm=p,
                        resolution=(W, H), format_mm=(W * p, H * p))
    Xc = np.column_stack([rng.uniform(-0.6, 0.6, 20), rng.uniform(-0.4, 0.4, 20), np.ones(20)]) * 10.0
    blk = Block(cams, Photos.make(["a"], X0=[0, 0, 0], opk=[np.pi, 0, 0]),
                Points.make([str(i) for i in range(20)], XYZ=Xc), Observations.make(np.zeros(20), np.arange(20),
                                                                                      np.zeros((20, 2))))
    mine = project_block(blk, np.zeros(20, int), np.arange(20))
    for k in range(20):
        uv = _metashape_project(terms, W, H, Xc[k])
        np.testing.assert_allclose(mine[k], [(uv[0] - W / 2) * p, -(uv[1] - H / 2) * p], atol=1e-11)
    # the reader takes them with ap_model = "metashape", and the writer gives them back
    (tmp_path / "v2.xml").write_text(V2_XML.format(extra="".join(f"<{k}>{v!r}</{k}>" for k, v in terms.items()
                                                                  if k not in ("f", "cx", "cy"))))
    with pytest.raises(InputError):
        read_metashape(tmp_path / "v2.xml")
    rb, _ = read_metashape(tmp_path / "v2.xml", ap_model="metashape")
    np.testing.assert_allclose(rb.cameras.ap[0][:8], b["ap"][:8], rtol=1e-12)
    write_metashape(rb, tmp_path / "out.xml")
    again, _ = read_metashape(tmp_path / "out.xml", ap_model="metashape")
    np.testing.assert_allclose(again.cameras.ap, rb.cameras.ap, rtol=1e-12)
