"""DBAT scripts as DBAT runs them: a camera in its own file, no control points with set_datum depend
(DBAT's dependent relative orientation) or baarda's free network, unknown operations refused.

The project is camcal rewritten as such a script (in ``tmp_path``): its camera moved to
``cameras/c4040z.xml``, its control points dropped, the orientations of a first bundle given as
``<prior_eo>``, ``spatial_resection`` replaced by ``set_datum``."""

from __future__ import annotations

import re

import numpy as np
import pytest

from baarda.pipeline.adjustment import BundleSettings, adjust
from baarda.pipeline.api import InputError
from baarda.plugins.dbat import dbat_block, read_dbat
from baarda.plugins.dbat.reader import depend_datum

CAMERA = """<?xml version="1.0" encoding="utf-8"?>
<document dbat_camera_version="1.0">
  <cameras>
    <camera>
      <id>1</id><name>Olympus Camedia C4040Z</name><unit>mm</unit>
      <sensor>auto,5.43764</sensor><image>2272,1704</image><aspect>1</aspect>
      <focal>7.5</focal><model>3</model><nK>3</nK><nP>2</nP>
    </camera>
  </cameras>
</document>
"""


@pytest.fixture(scope="module")
def camcal(shared_data):
    block = dbat_block(read_dbat(shared_data / "dbat-camcal" / "camcaldemo.xml"))
    return block, adjust(block, BundleSettings(datum="control"))


def script(tmp_path, shared_data, camcal, datum='<set_datum ref_cam="1" ref_base="longest">depend</set_datum>',
           extra_op=""):
    src = (shared_data / "dbat-camcal" / "camcaldemo.xml").read_text()
    block, res = camcal
    (tmp_path / "cameras").mkdir(exist_ok=True)
    (tmp_path / "cameras" / "c4040z.xml").write_text(CAMERA)
    X0, opk = res.state.X0, np.degrees(res.state.opk)
    (tmp_path / "eo.txt").write_text("".join(f"{i + 1},{x[0]:.6f},{x[1]:.6f},{x[2]:.6f},{a[0]:.6f},{a[1]:.6f},"
                                             f"{a[2]:.6f}\n" for i, (x, a) in enumerate(zip(X0, opk))))
    here = shared_data / "dbat-camcal"
    x = src.replace('<input base_dir="$HERE">', f'<input base_dir="{here}">')
    x = re.sub(r"<ctrl_pts>.*?</ctrl_pts>", "", x, flags=re.S)
    x = re.sub(r"<cameras>.*?</cameras>", f"<cameras><file>{tmp_path}/cameras/c4040z.xml</file></cameras>"
               f'<prior_eo><file format="id,x,y,z,omega,phi,kappa" units="degrees">{tmp_path}/eo.txt</file>'
               "</prior_eo>", x, flags=re.S)
    x = x.replace("<operation>spatial_resection</operation>", f"<operation>{datum}</operation>{extra_op}" if datum
                  else extra_op)
    x = re.sub(r"(<set_initial_values>)", r"\1<eo>loaded</eo>", x)
    p = tmp_path / "p.xml"
    p.write_text(x)
    return p


def test_camera_file_and_dependent_relative_orientation(tmp_path, shared_data, camcal):
    s = read_dbat(script(tmp_path, shared_data, camcal))
    assert s.camera.name == "Olympus Camedia C4040Z" and s.camera.sensor == (None, 5.43764)
    assert s.control == [] and s.datum[:3] == ("depend", "1", "longest")
    block = dbat_block(s)
    fixed = block.photos.sigma_eo == 0
    assert fixed.sum() == 7 and fixed[0].all()
    j, axis = depend_datum(np.asarray(block.photos.X0), 0, "longest")
    assert fixed[j, axis]
    off = block.photos.X0 - block.photos.X0[0]
    assert off[j, axis] == off.max()                   # DBAT: the largest signed offset, not |offset|
    res = adjust(block, BundleSettings(datum="control"))
    # camcal's 4148 coordinates; 9 IO + 21·6 − 7 EO + 100 points · 3 unknowns
    assert res.dof == 4148 - (9 + 126 - 7 + 300)
    # the camera does not depend on a minimal datum: the free network gives the same
    free = adjust(dbat_block(s, datum="free"), BundleSettings(datum="free"))
    assert free.dof == res.dof
    np.testing.assert_allclose(free.state.cam_params, res.state.cam_params, rtol=1e-6, atol=1e-10)


def test_depend_on_one_axis():
    X0 = np.array([[0.0, 0, 0], [5, 1, 0], [2, 9, 0], [-20, 0, 0]])
    assert depend_datum(X0, 0, "longest") == (2, 1)
    assert depend_datum(X0, 0, "x") == (1, 0)
    assert depend_datum(X0, 3, "x") == (1, 0)


def test_no_datum_is_an_error(tmp_path, shared_data, camcal):
    s = read_dbat(script(tmp_path, shared_data, camcal, datum=""))
    with pytest.raises(InputError, match="neither control points nor a set_datum"):
        dbat_block(s)


def test_unknown_operation_is_refused_by_name(tmp_path, shared_data, camcal):
    p = script(tmp_path, shared_data, camcal, extra_op="<operation>loop_closure</operation>")
    with pytest.raises(InputError, match="'loop_closure' is not one baarda carries out") as e:
        read_dbat(p)
    assert e.value.path == str(p) and e.value.field == "loop_closure" and e.value.line


def test_set_datum_without_orientations_is_refused(tmp_path, shared_data, camcal):
    p = script(tmp_path, shared_data, camcal)
    p.write_text(p.read_text().replace("<eo>loaded</eo>", ""))
    with pytest.raises(InputError, match="set_datum depend fixes initial orientations") as e:
        dbat_block(read_dbat(p))
    assert e.value.field == "set_datum"
