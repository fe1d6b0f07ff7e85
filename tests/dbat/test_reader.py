"""The DBAT script reader: what it reads from the two shared projects, the conversion to baarda's
conventions, and a clear InputError (file, line, field) for every broken input."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.geometry import pixels_from_mm
from baarda.plugins.dbat import dbat_block, dbat_from_baarda, read_dbat
from baarda.plugins.dbat.reader import camera_values


def test_camcal_is_read(shared_data):
    s = read_dbat(shared_data / "dbat-camcal" / "camcaldemo.xml")
    b = dbat_block(s)
    assert (len(b.photos), len(b.points), len(b.observations)) == (21, 100, 2074)
    pts = b.points
    assert sorted(pts.ids[pts.role == "full"].tolist()) == ["1001", "1002", "1003", "1004"]
    assert np.all(pts.sigma[pts.role == "full"] == 0)               # fixed control
    assert (pts.role == "tie").sum() == 96
    p = 5.43764 / 1704                                                # sensor "auto,5.43764": square pixels
    assert b.cameras.pixel_mm[0] == pytest.approx(p, rel=1e-12)
    assert np.allclose(np.sqrt(b.observations.cov[:, 0, 0]), 0.1 * p)
    # io: everything estimated but the skew; initial values "default": c = focal, pp at the centre
    assert b.cameras.ap_model[0] == "brown-backward"
    assert np.all(np.isinf(b.cameras.sigma_iop[0]))
    assert np.isinf(b.cameras.sigma_ap[0, :6]).all() and b.cameras.sigma_ap[0, 6] == 0
    assert (b.cameras.c[0], b.cameras.xp[0], b.cameras.yp[0]) == (7.5, 0.0, 0.0)
    assert not b.photos.has_orientation.any()
    assert all(v is not None for v in b.meta["dbat"].images.values())   # found beside images.txt
    assert b.photos.ids[0] == "P8250021" and b.meta["dbat"].image_numbers["P8250021"] == "1"
    # a mark in pixels (origin at the image corner, y down) → mm (centre, y up) and back
    first = s.marks[0]
    k = next(i for i in range(len(b.observations)) if b.observations.photo[i] == int(first.image[0]) - 1
             and b.points.ids[b.observations.point[i]] == first.point[0])
    assert np.allclose(pixels_from_mm(b.observations.xy[k], (2272, 1704), p, convention="colmap"), first.uv[0])
    assert np.allclose(b.observations.xy[k], [(1429.1871 - 1136) * p, -(1456.4278 - 852) * p])


def test_sxb_is_read(shared_data):
    s = read_dbat(shared_data / "dbat-sxb" / "sxb.xml")
    b = dbat_block(s)
    pts = b.points
    ctrl, chk = pts.role == "full", pts.role == "check"
    assert ctrl.sum() == 14 and sorted(pts.ids[chk].tolist()) == ["351", "410"]
    assert np.allclose(pts.sigma[ctrl], [0.02, 0.02, 0.04])
    assert np.isinf(pts.sigma[chk]).all()
    assert len(b.observations) == 47 + 1149
    sig_px = np.sqrt(b.observations.cov[:, 0, 0]) / 0.006
    assert sorted(np.unique(np.round(sig_px, 9)).tolist()) == [0.5, 1.0]
    assert (np.abs(sig_px - 0.5) < 1e-9).sum() == 47
    # camera fixed, loaded: c = cc, pp (26.5770, 38.8110) mm from the corner, y down
    cam = b.cameras
    assert np.all(cam.sigma_iop[0] == 0) and np.all(cam.sigma_ap[0] == 0)
    assert cam.c[0] == 123.9392
    assert cam.xp[0] == pytest.approx(26.5770 - 8858 * 0.006 / 2, abs=1e-9)
    assert cam.yp[0] == pytest.approx(12996 * 0.006 / 2 - 38.8110, abs=1e-9)
    back = dbat_from_baarda(cam.c[0], cam.xp[0], cam.yp[0], cam.ap[0], s.camera)
    assert (back["px"], back["py"]) == (pytest.approx(26.577), pytest.approx(38.811))
    assert s.min_rays == 2


def test_camera_values_round_trip(shared_data):
    s = read_dbat(shared_data / "dbat-sxb" / "sxb.xml")
    iv = camera_values(s.camera, "loaded")
    back = dbat_from_baarda(iv["c"], iv["xp"], iv["yp"], iv["ap"], s.camera)
    assert back["cc"] == s.camera.cc and back["as"] == s.camera.aspect - 1


# -- broken inputs ---------------------------------------------------------------------------------

@pytest.fixture
def project(shared_data, tmp_path):
    src = shared_data / "dbat-camcal"
    dst = tmp_path / "camcal"
    dst.mkdir()
    shutil.copy(src / "camcaldemo.xml", dst)
    for sub, name in (("reference", "camcal-fixed.txt"), ("images", "images.txt"), ("measurements", "markpts.txt")):
        (dst / sub).mkdir()
        shutil.copy(src / sub / name, dst / sub / name)
    return dst


def _edit(path: Path, old: str, new: str, count: int = 1):
    text = path.read_text(encoding="utf-8")
    assert old in text, old
    path.write_text(text.replace(old, new, count), encoding="utf-8")


def _line_of(path: Path, needle: str) -> int:
    return next(i for i, ln in enumerate(path.read_text(encoding="utf-8").splitlines(), 1) if needle in ln)


def _read(project):
    s = read_dbat(project / "camcaldemo.xml")
    return dbat_block(s)


@pytest.mark.parametrize("where, old, new, file, field", [
    ("marks", " 1,    2, 1429.1871", " 1,    2, 14z9.1871", "markpts.txt", "x"),
    ("marks", " 1,    2, 1429.1871", " 1,    2, nan", "markpts.txt", "x"),
    ("marks", " 1,    2, 1429.1871, 1456.4278, 0.1", " 1,    2, 1429.1871, 1456.4278", "markpts.txt", "sxy"),
    ("marks", " 1,    2, 1429.1871, 1456.4278, 0.1", " 1,    2, 1429.1871, 1456.4278, 0", "markpts.txt", "sxy"),
    ("marks", " 1,    2, 1429.1871, 1456.4278, 0.1", " 99,    2, 1429.1871, 1456.4278, 0.1", "markpts.txt", "im"),
    ("marks", " 1,    3, 1217.8557, 1456.1798, 0.1", " 1,    2, 1217.8557, 1456.1798, 0.1", "markpts.txt", "id"),
    ("marks", " 1,    2, 1429.1871, 1456.4278, 0.1", " 1,    2, 91429.1871, 1456.4278, 0.1", "markpts.txt", "x"),
    ("ctrl", "1002,CP2,1,1,0", "1001,CP2,1,1,0", "camcal-fixed.txt", "id"),
    ("ctrl", "1002,CP2,1,1,0", "1002,CP2,1,one,0", "camcal-fixed.txt", "y"),
    ("xml", "<model>3</model>", "<model>1</model>", "camcaldemo.xml", "model"),
    ("xml", 'format="id,label,x,y,z"', 'format="id,label,x,y,q"', "camcaldemo.xml", "format"),
    ("xml", 'format="im,id,x,y,sxy"', 'format="im,id,x,y"', "camcaldemo.xml", "sxy"),
    ("xml", "<sensor>auto,5.43764</sensor>", "<sensor>auto,-5.4</sensor>", "camcaldemo.xml", "sensor"),
    ("xml", "<image>2272,1704</image>", "<image>2272</image>", "camcaldemo.xml", "image"),
    ("xml", "reference/camcal-fixed.txt", "reference/missing.txt", "camcaldemo.xml", "file"),
    ("xml", "<all>true</all>\n          <skew>false</skew>", "<all>maybe</all>", "camcaldemo.xml", "all"),
    ("xml", "<skew>false</skew>", "<lens>false</lens>", "camcaldemo.xml", "lens"),
    ("xml", "</ctrl_pts>", '<filter id="7777">keep</filter></ctrl_pts>', "camcaldemo.xml", "id"),
    ("xml", "<operation>spatial_resection</operation>", "<operation>spatial_resection</operation", "camcaldemo.xml", None),
])
def test_broken_inputs_name_file_line_field(project, where, old, new, file, field):
    target = {"marks": project / "measurements" / "markpts.txt", "ctrl": project / "reference" / "camcal-fixed.txt",
              "xml": project / "camcaldemo.xml"}[where]
    line = _line_of(target, old.splitlines()[0].strip())
    _edit(target, old, new)
    with pytest.raises(InputError) as e:
        _read(project)
    err = e.value
    assert err.path is not None and Path(err.path).name == file, str(err)
    if field is not None:
        assert err.field == field, str(err)
    if where != "xml" or field in ("model", "sensor", "image", "all", "lens"):
        assert err.line == line, str(err)
    else:
        assert err.line is not None, str(err)
    assert "\n" not in str(err)


def test_missing_dbat_dir_is_named(project):
    _edit(project / "camcaldemo.xml", '<input base_dir="$HERE">', '<input base_dir="$DBAT/data">')
    with pytest.raises(InputError, match="dbat_dir") as e:
        _read(project)
    assert e.value.field == "base_dir" and e.value.line == _line_of(project / "camcaldemo.xml", "<input ")


def test_filters_keep_and_remove(shared_data):
    s = read_dbat(shared_data / "dbat-sxb" / "sxb.xml")
    assert "351" not in s.control[0].ids and "410" not in s.control[0].ids and len(s.control[0].ids) == 14
    assert s.check[0].ids == ["410", "351"] or sorted(s.check[0].ids) == ["351", "410"]
    assert s.check[0].filters == [("keep", ["351", "410"])]


def test_script_info_is_typed_frozen_and_pickles(shared_data):
    """What the source keeps of the script (``meta["dbat"]``) is a frozen :class:`DbatInfo`: no
    dict read by key, nothing changeable in place, and it travels to worker processes."""
    import dataclasses
    import pickle

    from baarda.plugins.dbat.reader import DbatCamera, DbatInfo, DbatMarksInfo

    b = dbat_block(read_dbat(shared_data / "dbat-sxb" / "sxb.xml"))
    d = b.meta["dbat"]
    assert isinstance(d, DbatInfo) and isinstance(d.camera, DbatCamera)
    assert all(isinstance(m, DbatMarksInfo) for m in d.marks) and sum(m.count for m in d.marks) >= len(b.observations)
    assert isinstance(d.operations, tuple) and isinstance(d.dropped_points, tuple)
    with pytest.raises(dataclasses.FrozenInstanceError):
        d.min_rays = 3
    with pytest.raises(TypeError):
        d.estimate_io["cc"] = False
    with pytest.raises(TypeError):
        d.image_numbers[b.photos.ids[0]] = "99"
    again = pickle.loads(pickle.dumps(b)).meta["dbat"]
    assert again == d and again.images_found == d.images_found


def test_source_table_names_each_photos_image_file(shared_data):
    """The ``dbat`` source's photos table gives the file found for each photo (photo ids are file
    names, the script's image numbers are not: the table once looked files up by photo id and
    stayed empty)."""
    from baarda.plugins.dbat.report import source_tables

    b = dbat_block(read_dbat(shared_data / "dbat-camcal" / "camcaldemo.xml"))
    files = source_tables(b)["photos"].columns["file"]
    assert len(files) == 21 and all(Path(f).stem == pid for f, pid in zip(files, b.photos.ids))


def test_swapped_format_is_refused_by_name(project):
    """x and y swapped in the marks' format: most marks outside W × H but inside H × W — an InputError
    naming the script, the line of the format attribute and the field (was: a warning, then a result)."""
    xml = project / "camcaldemo.xml"
    line = _line_of(xml, 'format="im,id,x,y,sxy"')
    _edit(xml, 'format="im,id,x,y,sxy"', 'format="im,id,y,x,sxy"')
    with pytest.raises(InputError, match="swapped") as e:
        _read(project)
    assert Path(e.value.path).name == "camcaldemo.xml" and e.value.line == line and e.value.field == "format"


@pytest.mark.parametrize("u", ["-100.0", "2372.0"])
def test_marks_outside_the_image_count_on_either_side(project, u):
    """u = −100 px counts as outside as u = W + 100 does (was: only the right side warned)."""
    marks = project / "measurements" / "markpts.txt"
    assert _read(project).meta["dbat"].marks_outside == ()
    line = _line_of(marks, " 1,    2, 1429.1871")
    _edit(marks, " 1,    2, 1429.1871", f" 1,    2, {u}")
    out = _read(project).meta["dbat"].marks_outside
    assert out == (1, f"markpts.txt:{line}")


def test_the_stage_warns_of_a_mark_left_of_the_image(project, tmp_path):
    """u = −100 px is reported as u = W + 100 px is: a warning naming the file and line."""
    from baarda.pipeline.testing import run_stage
    from baarda.plugins.dbat.stage import DbatSource

    marks = project / "measurements" / "markpts.txt"
    line = _line_of(marks, " 1,    2, 1429.1871")
    _edit(marks, " 1,    2, 1429.1871", " 1,    2, -100.0")
    res = run_stage(DbatSource, {}, {"path": str(project / "camcaldemo.xml")}, tmp_path=tmp_path)
    assert any("1 mark(s) outside the 2272 × 1704 px image" in w and f"markpts.txt:{line}" in w for w in res.warnings), \
        res.warnings
