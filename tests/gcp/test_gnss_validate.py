"""``validate`` reads the GNSS CSV and checks its CRS and the lever arms (issue 27: 18 cases passed
validate and failed the run on the CSV)."""

from __future__ import annotations

import contextlib
import io
import shutil
from pathlib import Path

import pytest

from baarda.pipeline.cli import main

FIX = Path(__file__).resolve().parents[2] / "fixtures" / "gnss"
SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"


@pytest.fixture
def project(tmp_path):
    shutil.copytree(FIX, tmp_path / "g")
    return tmp_path / "g"


def validate(p):
    o, e = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(o), contextlib.redirect_stderr(e):
        code = main(["validate", str(p / "gnss.toml")])
    return code, e.getvalue()


def edit_csv(p, fn):
    f = p / "gnss.csv"
    lines = f.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln and not ln.startswith("#") and not ln.lower().startswith("photo"))
    lines[k] = fn(lines[k])
    f.write_text("\n".join(lines) + "\n")
    return k + 1


@pytest.mark.parametrize("name,fn,field", [
    ("letter", lambda ln: ln.replace(",", ",x", 1), "e"),
    ("extra-field", lambda ln: ln + ",7", "field 7"),
    ("short", lambda ln: ",".join(ln.split(",")[:3]), "h"),
    ("zero-sigma", lambda ln: ",".join(ln.split(",")[:-1] + ["0"]), "sigma_v"),
])
def test_validate_reads_the_gnss_csv(project, name, fn, field):
    line = edit_csv(project, fn)
    code, err = validate(project)
    assert code == 2 and f"gnss.csv:{line}, field '{field}'" in err, err


def test_validate_checks_the_csv_crs(project):
    f = project / "gnss.csv"
    f.write_text(f.read_text().replace("EPSG:32632", "EPSG:0"))
    code, err = validate(project)
    assert code == 2 and "gnss.csv:1" in err, err


def test_a_lever_arm_in_mm_is_an_input_error(project):
    t = project / "gnss.toml"
    t.write_text(t.read_text().replace("[0.12, -0.05, 0.35]", "[120, -50, 350]"))
    code, err = validate(project)
    assert code == 2 and "field 'lever_arm'" in err and "given in mm" in err, err


def test_the_fixture_validates(project):
    code, err = validate(project)
    assert code == 0, err


def test_validate_checks_the_csv_photos_and_lever_arm_cameras_against_the_block(project):
    line = edit_csv(project, lambda ln: "IMG_NOPE" + ln[ln.index(","):])
    code, err = validate(project)
    assert code == 2 and f"gnss.csv:{line}, field 'photo'" in err and "IMG_NOPE" in err, err
    edit_csv(project, lambda ln: ln)
    t = project / "gnss.toml"
    shutil.copy(FIX / "gnss.csv", project / "gnss.csv")
    t.write_text(t.read_text().replace('lever_arm = { "1" =', 'lever_arm = { "nocam" ='))
    code, err = validate(project)
    assert code == 2 and "field 'lever_arm'" in err and "nocam" in err, err


def test_heights_in_mm_are_an_input_error_naming_the_row(project):
    """A GNSS height in mm under a projected CRS (h × 1000: thousands of km above the ellipsoid) is an
    InputError naming the CSV line and the height column, in validate (was: not caught)."""
    def mm(ln):
        c = ln.split(",")
        c[3] = f"{float(c[3]) * 1000:.1f}"
        return ",".join(c)
    line = edit_csv(project, mm)
    code, err = validate(project)
    assert code == 2 and f"gnss.csv:{line}, field 'h'" in err and "km from the ellipsoid" in err, err
