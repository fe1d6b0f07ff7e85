"""The comparator reader: fixtures, interior orientation check, and every broken input."""

from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.testing import check_stage, log_stage, run_stage
from baarda.plugins.comparator.stage import ComparatorSource

FIX = Path(__file__).resolve().parents[2] / "fixtures" / "paper000"

from tests.screening.test_paper000 import PRINTED

# Table 3 of paper 000 with the left x of point 9 corrected (docs/screening.md)
TABLE3 = PRINTED.copy()
TABLE3[8, 0] = 155.576

GOOD = """\
unit um
mode fiducial
transform similarity
camera C c 152.0 format 230 230
fiducial A -110 -110
fiducial B  110 -110
fiducial C  110  110
fiducial D -110  110
photo 1
fid A  40000  40000
fid B 260000  40000
fid C 260000 260000
fid D  40000 260000
pt 10 150000 150000
pt 11 170000 120000
photo 2
fid A  41000  40000
fid B 261000  40000
fid C 261000 260000
fid D  41000 260000
pt 10 140000 150000
pt 11 160000 120000
pair 1 2
point 10 full 1.0 2.0 3.0
"""


def run_text(tmp_path, text, **opts):
    (tmp_path / "m.cmp").write_text(text, encoding="utf-8")
    return run_stage(ComparatorSource, {}, {"path": "m.cmp", **opts}, tmp_path=tmp_path)


def error_of(tmp_path, text, **opts) -> InputError:
    with pytest.raises(InputError) as info:
        run_text(tmp_path, text, **opts)
    e = info.value
    s = str(e)
    assert "\n" not in s, s
    assert s.startswith(str(tmp_path / "m.cmp")), s
    return e


def test_stage_protocol():
    check_stage(ComparatorSource)


def test_good_file_builds_the_block(tmp_path):
    res = run_text(tmp_path, GOOD)
    b = res.artefacts["block"]
    assert b.summary()["observations"] == 4 and len(b.pairs) == 1
    # machine (150000, 150000) µm is the centre of fiducials A..D -> image origin (0, 0)
    assert np.allclose(b.observations.xy[0], [0.0, 0.0], atol=1e-9)
    # 20 mm right, 30 mm down in machine units
    assert np.allclose(b.observations.xy[1], [20.0, -30.0], atol=1e-9)
    assert b.points.role.tolist() == ["full", "tie"]
    assert b.cameras.format_mm[0].tolist() == [230.0, 230.0]
    # default sigma 5 µm, propagated through the (unit-scale) similarity
    assert np.sqrt(b.observations.cov[0, 0, 0]) == pytest.approx(0.005)
    assert b.source.lines[(0, 0)][1] == 14


def test_fiducial_fixture_reproduces_table3(tmp_path):
    # fiducial.cmp holds the base of Table 3 as µm machine coordinates; after the affine interior
    # orientation the image coordinates are the paper's, shifted by (125, 160) / (100, 60) mm
    res = run_stage(ComparatorSource, {}, {"path": str(FIX / "fiducial.cmp")}, tmp_path=tmp_path)
    b = res.artefacts["block"]
    o = b.observations
    left, right = o.xy[o.photo == 0], o.xy[o.photo == 1]
    assert np.abs(left - (TABLE3[:, :2] - [125, 160])).max() < 1e-4
    assert np.abs(right - (TABLE3[:, 2:] - [100, 60])).max() < 1e-4
    io = res.summary["interior_orientation"]
    for pid in ("L", "R"):
        assert io[pid]["dof"] == 10
        assert 0.5 < io[pid]["sigma0_hat_um"] < 2.0


def test_photo_fixture_is_table3(tmp_path):
    res = run_stage(ComparatorSource, {}, {"path": str(FIX / "base.cmp")}, tmp_path=tmp_path)
    o = res.artefacts["block"].observations
    assert np.array_equal(o.xy[o.photo == 0], TABLE3[:, :2])
    assert np.array_equal(o.xy[o.photo == 1], TABLE3[:, 2:])


def test_tolerance_fails_naming_photo_and_fiducial(tmp_path):
    bad = GOOD.replace("fid C 261000 260000", "fid C 261060 260000")  # 60 µm off
    e = error_of(tmp_path, bad)
    assert e.line == 19 and e.field == "fid C"
    assert "photo 2" in e.message and "fiducial C" in e.message and "tolerance of 20.0 µm" in e.message


def test_tolerance_warns_when_asked(tmp_path):
    bad = GOOD.replace("fid C 261000 260000", "fid C 261060 260000")
    res = run_text(tmp_path, bad, on_tolerance="warn")
    assert len(res.summary["io_violations"]) >= 1
    assert res.summary["io_violations"][0]["photo"] == "2"
    assert any("fiducial C" in w for w in res.warnings)
    # a looser tolerance accepts it
    res = run_text(tmp_path, bad, tol_io_um=100.0)
    assert res.summary["io_violations"] == []


def test_affine_override_and_no_redundancy_warning(tmp_path):
    three = "\n".join(ln for ln in GOOD.splitlines() if not ln.startswith("fid D")) + "\n"
    res = run_text(tmp_path, three, transform="affine")
    assert res.summary["interior_orientation"]["1"]["dof"] == 0
    assert any("no redundancy" in w for w in res.warnings)


def test_missing_file(tmp_path):
    with pytest.raises(InputError) as info:
        run_stage(ComparatorSource, {}, {"path": "nope.cmp"}, tmp_path=tmp_path)
    # a stage run on its own has no project file; in a project the error names the project
    # file and the line of 'path' (tests/pipeline/test_validate.py)
    assert str(info.value) == f"field 'path': comparator file not found: {tmp_path / 'nope.cmp'}"


@pytest.mark.parametrize("old,new,line,field,words", [
    ("pt 11 170000 120000", "pt 11 170000 l20000", 15, "y", "expected a number for y, got 'l20000'"),
    ("pt 11 170000 120000", "pt 10 170000 120000", 15, "pt",
     "point '10' measured twice in photo '1' (first at line 14)"),
    ("pair 1 2", "pair 1 3", 23, "pair", "right photo '3' is not in this file"),
    ("pt 11 170000 120000", "pt 11 nan 120000", 15, "x", "x must be a finite number, got 'nan'"),
    ("pt 11 170000 120000", "pt 11 170000 inf", 15, "y", "y must be a finite number, got 'inf'"),
    ("point 10 full 1.0 2.0 3.0", "point 10 full 1.0 NaN 3.0", 24, "Y", "must be a finite number"),
    ("pair 1 2", "stereo 1 2", 23, "keyword", "unknown keyword 'stereo'"),
    ("fid A  41000  40000", "fid E  41000  40000", 17, "fid", "fiducial 'E' of photo '2' is not calibrated"),
    ("photo 2", "photo 1", 16, "photo", "photo '1' declared twice (first at line 9)"),
    ("camera C c 152.0", "camera C c -152.0", 4, "c", "principal distance c must be positive"),
    ("point 10 full", "point 10 control", 24, "role", "role must be one of"),
    ("unit um", "unit inch", 1, "unit", "unit must be one of"),
    ("pt 10 140000 150000", "pt 10 140000", 21, "pt", "expected 'pt <id> <x> <y> [<sx> <sy>]'"),
])
def test_broken_inputs_name_file_and_line(tmp_path, old, new, line, field, words):
    text = GOOD.replace(old, new, 1) if old != "photo 2" else GOOD.replace("photo 2\n", "photo 1\n")
    assert text != GOOD
    e = error_of(tmp_path, text)
    assert (e.line, e.field) == (line, field), str(e)
    assert words in e.message, str(e)
    assert str(e).startswith(f"{tmp_path / 'm.cmp'}:{line}, field '{field}': ")


def test_too_few_fiducials_for_the_transformation(tmp_path):
    # photo 1 keeps only fiducials A and B: enough for the similarity (no redundancy), not the affine
    text = GOOD.replace("fid C 260000 260000\n", "").replace("fid D  40000 260000\n", "")
    e = error_of(tmp_path, text, transform="affine")
    assert (e.line, e.field) == (9, "fid")
    assert "photo '1' has 2 measured fiducial(s); the affine interior orientation needs at least 3" in e.message
    one = text.replace("fid B 260000  40000\n", "")
    e = error_of(tmp_path, one)
    assert "photo '1' has 1 measured fiducial(s); the similarity interior orientation needs at least 2" in e.message


def test_fid_lines_need_fiducial_mode(tmp_path):
    e = error_of(tmp_path, GOOD.replace("mode fiducial", "mode photo"))
    assert (e.line, e.field) == (10, "fid")


def test_nothing_outside_a_section(tmp_path):
    e = error_of(tmp_path, "unit mm\nmode photo\npt 1 2 3\n")
    assert (e.line, e.field) == (3, "pt") and "inside a photo section" in e.message
    e = error_of(tmp_path, "unit mm\nmode photo\n")
    assert "no 'photo' section" in e.message


def test_recording(tmp_path):
    from baarda.pipeline.recording import read_recording

    res = run_stage(ComparatorSource, {}, {"path": str(FIX / "fiducial.cmp")}, tmp_path=tmp_path)
    summary = read_recording(log_stage(ComparatorSource, res, tmp_path / "c.rrd"))
    paths = {e.path for e in summary.entities}
    assert {"/c/photos/L/points", "/c/photos/R/points", "/c/photos/L/fiducials", "/c/photos/L/format"} <= paths


def test_nearly_collinear_fiducials_are_refused_by_line(tmp_path):
    """Three of four fiducials on one line and the fourth 2 µm off it: the affine interior orientation
    is not determined across the line — an InputError naming the fiducial lines (was: a warning, then
    Pope flagged a point in error-free data)."""
    text = (GOOD.replace("transform similarity", "transform affine")
            .replace("fid B 260000  40000", "fid B 150000  40000")
            .replace("fid C 260000 260000", "fid C 260000  40000")
            .replace("fid D  40000 260000", "fid D 370000  40002"))
    e = error_of(tmp_path, text)
    assert e.field == "fid" and e.line == 10 and "lines 10, 11, 12, 13" in str(e) and "affine" in str(e)
    run_text(tmp_path, GOOD.replace("transform similarity", "transform affine"))      # a real layout passes


@pytest.mark.parametrize("old, new, line, field", [
    ("pt 10 140000 150000", "pt 10 1e200 150000", 21, "x"),
    ("fid B 261000  40000", "fid B 261000 -2e10", 18, "y"),
])
def test_coordinates_beyond_a_physical_bound_are_refused(tmp_path, old, new, line, field):
    """x = 1e200 µm on a right photo (or a fiducial 20 km off) is an InputError naming line and field
    (was: accepted)."""
    e = error_of(tmp_path, GOOD.replace(old, new))
    assert (e.line, e.field) == (line, field) and "mm" in str(e)
