"""Writes tests/corpus/opensfm/ and tests/corpus/metashape/ (run from the repository root):
.venv/bin/python tests/corpus/opensfm/make_corpus.py"""
import json, sys
from pathlib import Path
import numpy as np
sys.path.insert(0, "fixtures/opensfm")
from make_fixture import block
from baarda.pipeline.opensfm import write_opensfm
from baarda.pipeline.metashape import write_metashape

C = Path("tests/corpus")
b = block(np.random.default_rng(7), aps=[-1.5e-3, 8e-6, 0, 1.2e-5, -6e-6, 0, 0], n_pts=14)
b = b.replace(photos=b.photos.replace(ids=b.photos.ids), observations=b.observations)
keep = b.observations.photo < 3
from baarda.pipeline.model import Photos
ob = b.observations
b3 = b.replace(photos=Photos.make(b.photos.ids[:3], X0=b.photos.X0[:3], opk=b.photos.opk[:3]),
               observations=ob.replace(**{k: getattr(ob, k)[keep] for k in ("photo", "point", "xy", "cov", "active")}))
d = C / "opensfm"
write_opensfm(b3, d)
(d / "reconstruction.json").rename(d / "mini.json"); (d / "tracks.csv").rename(d / "mini.tracks.csv")
base = json.loads((d / "mini.json").read_text())
cam = next(iter(base[0]["cameras"]))
shot = next(iter(base[0]["shots"]))
pt = next(iter(base[0]["points"]))
cases = {}
def jcase(name, edit, field):
    doc = json.loads(json.dumps(base)); edit(doc[0]); (d / f"{name}.json").write_text(json.dumps(doc, indent=1))
    cases[name] = (f"{name}.json", None, field)
jcase("camera-fisheye", lambda r: r["cameras"][cam].update(projection_type="fisheye"), "projection_type")
jcase("camera-no-focal", lambda r: r["cameras"][cam].pop("focal_x"), "focal_x")
jcase("camera-width-text", lambda r: r["cameras"][cam].update(width="5472"), "width")
jcase("camera-focal-negative", lambda r: r["cameras"][cam].update(focal_y=-0.5), "focal_y")
jcase("camera-k1-nan", lambda r: r["cameras"][cam].update(k1=None), "k1")
jcase("shot-rotation-short", lambda r: r["shots"][shot].update(rotation=[0.1, 0.2]), "rotation")
jcase("shot-translation-text", lambda r: r["shots"][shot].update(translation=["1", 2, 3]), "translation")
jcase("shot-camera-unknown", lambda r: r["shots"][shot].update(camera="other"), "camera")
jcase("point-no-coordinates", lambda r: r["points"][pt].pop("coordinates"), "coordinates")
jcase("no-cameras", lambda r: r.pop("cameras"), "cameras")
jcase("shots-list", lambda r: r.update(shots=[]), "shots")
(d / "not-json.json").write_text((d / "mini.json").read_text().replace('"cameras": {', '"cameras" {', 1))
cases["not-json"] = ("not-json.json", 3, "json")
(d / "empty-list.json").write_text("[]\n"); cases["empty-list"] = ("empty-list.json", None, "reconstructions")
lines = (d / "mini.tracks.csv").read_text().splitlines()
def tcase(name, ln, col, value, field):
    L = list(lines); parts = L[ln - 1].split("\t")
    if value is None: parts = parts[:col]
    else: parts[col] = value
    L[ln - 1] = "\t".join(parts); (d / f"{name}.tracks.csv").write_text("\n".join(L) + "\n")
    cases[name] = (f"{name}.tracks.csv", ln, field)
tcase("tracks-x-text", 4, 3, "0.1o", "x")
tcase("tracks-y-nan", 6, 4, "nan", "y")
tcase("tracks-short", 3, 3, None, "columns")
(d / "cases.py").write_text('"""Broken OpenSfM inputs (generated from mini.json / mini.tracks.csv, 3 shots of the fixture\'s '
    'simulated block): case -> (file, line or None, the field the InputError must end with).  A *.tracks.csv is '
    'read with mini.json."""\n\nCASES = ' + repr(cases) + "\n")

d = C / "metashape"
write_metashape(b3, d / "mini.xml")
text = (d / "mini.xml").read_text()
mcases = {}
def mcase(name, old, new, field, count=1):
    import re
    assert re.search(old, text), old
    (d / f"{name}.xml").write_text(re.sub(old, new, text, count=count)); mcases[name] = (f"{name}.xml", field)
mcase("f-text", "<f>", "<f>x", "calibration/f")
mcase("f-missing", r"\s*<f>[^<]*</f>", "", "calibration/f")
mcase("cx-nan", "<cx>", "<cx>nan", "calibration/cx")
mcase("k4-set", "<k1>", "<k4>0.01</k4>\n        <k1>", "calibration/k4")
mcase("b1-with-distortion", "<k1>", "<b1>0.5</b1>\n        <k1>", "calibration/b1")
mcase("sensor-fisheye", 'type="frame"', 'type="fisheye"', "@type")
mcase("resolution-missing", r'\s*<resolution [^>]*/>', '', "resolution", count=0)
mcase("pixel-width-text", 'name="pixel_width" value="', 'name="pixel_width" value="a', "@value")
mcase("transform-short", "<transform>", "<transform>1 ", "transform")
mcase("transform-not-rigid", "<transform>", "<transform>2", "transform")
mcase("camera-sensor-unknown", 'sensor_id="0"', 'sensor_id="7"', "@sensor_id")
mcase("reference-text", '<reference x="', '<reference x="q', "reference/@x")
mcase("location-y-text", ' y="', ' y="?', "@y")
mcase("marker-id-unknown", 'marker_id="0"', 'marker_id="77"', "@marker_id")
mcase("not-xml", "</document>", "", "xml")
mcase("root-other", "document", "project", "document/chunk", count=0)
(d / "cases.py").write_text('"""Broken Metashape camera XMLs (generated from mini.xml, 3 cameras of the fixture\'s simulated '
    'block): case -> (file, the field the InputError must end with)."""\n\nCASES = ' + repr(mcases) + "\n")
print(len(cases), len(mcases))
