"""PhotoModeler text exports (``pmexport``) against DBAT's own reports on them.

The references are read from DBAT's report files beside the exports
(``../shared/data/dbat-pmexport/camcal-dbatreport*.txt``, DBAT 0.9.2.0, niclasborlin/dbat
``data/dbat/dbatexports/``): σ0, the redundancy, the camera with its σ, and, for the two variants on
which DBAT's bundle stops, the points DBAT names as undetermined.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from baarda.pipeline.adjustment import BundleSettings, adjust
from baarda.pipeline.api import InputError
from baarda.plugins.dbat import dbat_block
from baarda.plugins.dbat import parse_estimate, pm_script, read_control, read_pmexport

NAMES = {"Camera Constant": "cc", "px - principal point x": "px", "py - principal point y": "py",
         "K1 - radial distortion 1": "K1", "K2 - radial distortion 2": "K2", "K3 - radial distortion 3": "K3",
         "P1 - decentering distortion 1": "P1", "P2 - decentering distortion 2": "P2",
         "as - off-unit aspect parameter": "as"}


def dbat_report(path):
    """σ0, redundancy, camera {name: (value, σ)} and the undetermined point ids of a DBAT report."""
    text = path.read_text()
    out = {"sigma0": float(re.search(r"Sigma0:\s+(\S+)", text).group(1)),
           "redundancy": int(re.search(r"Redundancy\s+(\d+)", text).group(1)),
           "undetermined": sorted({m for m in re.findall(r"O[XYZ]-\d+/(\d+)", text)}, key=int), "camera": {}}
    lines = text.splitlines()
    for i, ln in enumerate(lines):
        key = NAMES.get(ln.strip().rstrip(":"))
        if key and "Value:" in lines[i + 1] and "Deviation:" in lines[i + 2]:
            out["camera"][key] = (float(lines[i + 1].split()[1]), float(lines[i + 2].split()[1]))
    return out


@pytest.fixture(scope="module")
def data(shared_data):
    return shared_data / "dbat-pmexport"


def setup(data, variant=""):
    pm = read_pmexport(data / f"camcal-pmexport{variant}.txt")
    return pm_script(pm, control=read_control(data / "camcal-fixed.txt"), focal=7.3)


def test_reader_reads_the_export(data):
    pm = read_pmexport(data / "camcal-pmexport.txt")
    assert pm.image_size == (2272, 1704) and len(pm.photos) == 21
    assert pm.photos[0].name == "data/dbat/images/cam/P8250021.JPG"
    assert pm.camera[:5] == pytest.approx([7.4653, 3.6173, 2.6128, 7.25319, 5.43764])
    assert pm.control.shape == (0, 7) and pm.objects.shape == (100, 7) and pm.marks.shape == (2074, 6)
    assert pm.marks[0].tolist() == [0, 2, 1429.1871, 1456.4278, 0.1, 0.1]


@pytest.mark.parametrize("variant", ["", "-1ray", "-missing-obs"])
def test_dbat_counts_and_undetermined_points(data, variant):
    """DBAT's redundancy as it counts it, and the points its rank test names on the variants."""
    ref = dbat_report(data / f"camcal-dbatreport{variant}.txt")
    _, info = setup(data, variant)
    assert info["redundancy"] == ref["redundancy"]
    assert info["undetermined"] == ref["undetermined"]


def test_camcal_reproduces_dbat(data):
    from baarda.plugins.dbat.stage import _quality

    ref = dbat_report(data / "camcal-dbatreport.txt")
    script, _ = setup(data)
    res = adjust(dbat_block(script), BundleSettings(datum="control"))
    assert res.dof == ref["redundancy"] == 3725
    q = _quality(res)
    assert f"{q['sigma0_corrected']:.4g}" == f"{ref['sigma0']:.4g}"       # DBAT's residual definition
    assert set(ref["camera"]) == set(NAMES.values())
    for k, (v, s) in ref["camera"].items():
        assert abs(q["camera"][k][0] - v) / s < 0.3, k
        assert q["camera"][k][1] == pytest.approx(s, rel=0.05), k


def test_variant_without_the_undetermined_points_adjusts(data):
    """baarda leaves the one-ray point out (min_rays 2) where DBAT's bundle stops; the rest matches
    the full project's camera within its σ."""
    script, info = setup(data, "-1ray")
    block = dbat_block(script)
    assert "88" not in set(block.points.ids.tolist())
    res = adjust(block, BundleSettings(datum="control"))
    assert res.dof == info["redundancy"] + 1          # 2 observations and 3 unknowns fewer


def test_estimate_words():
    e = parse_estimate(["all", "not", "sk"], None)
    assert e["skew"] is False and all(v for k, v in e.items() if k != "skew")
    with pytest.raises(InputError, match="unknown camera parameter 'kk'"):
        parse_estimate(["kk"], None)


def test_camcal_in_dbats_residual_definition(data):
    """With the bundle's residual = "corrected" the PhotoModeler export gives DBAT's σ0 and camera to
    its printed digits (c: 4 decimals, 0.05 σ; every other parameter within 0.01 σ)."""
    from baarda.plugins.dbat.stage import _quality

    ref = dbat_report(data / "camcal-dbatreport.txt")
    script, _ = setup(data)
    res = adjust(dbat_block(script), BundleSettings(datum="control", residual="corrected"))
    assert f"{res.sigma0_hat:.5g}" == f"{ref['sigma0']:.5g}"
    q = _quality(res)
    for k, (v, s) in ref["camera"].items():
        assert abs(q["camera"][k][0] - v) / s < (0.05 if k == "cc" else 0.01), k
        assert q["camera"][k][1] == pytest.approx(s, rel=0.01), k
