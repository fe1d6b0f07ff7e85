"""The eccentricity options of ``opencv-targets`` and ``bundle``: ``baarda validate`` names the file,
line and field of a wrong diameter or normal; the circle table the stage hands to the bundle."""

from __future__ import annotations

import numpy as np
import pytest

from baarda.pipeline.cli import main
from baarda.pipeline.model import Block, Cameras, CircleTargets, Observations, Photos, Points
from baarda.plugins.targets.stage import TargetOptions, circle_table

PROJECT = """[project]
name = "circles"
object_unit = "m"

[[stage]]
use = "opencv-targets"
[stage.options]
target = "circles"
{line}
"""


@pytest.mark.parametrize("line, at, field, message", [
    ("circle_diameter = -3.0", 9, "circle_diameter", "must be at least 0"),
    # the class's own check: a message that starts with the option's name points to that option's line
    ("circle_normal = [0.0, 0.0, 0.0]", 9, "circle_normal", "not all zero"),
    ("circle_normal = [0.0, 1.0]", 9, "circle_normal", "expected 3 finite numbers"),
])
def test_validate_names_the_wrong_option(tmp_path, capsys, line, at, field, message):
    (tmp_path / "p.toml").write_text(PROJECT.format(line=line), encoding="utf-8")
    assert main(["validate", str(tmp_path / "p.toml")]) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path / 'p.toml'}:{at}" in err and field in err and message in err, err


def test_validate_names_a_wrong_bundle_tolerance(tmp_path, capsys):
    text = PROJECT.format(line="circle_diameter = 10.0") + '\n[[stage]]\nuse = "bundle"\n[stage.options]\n' \
                                                          "eccentricity.tol = 0.0\n"
    (tmp_path / "p.toml").write_text(text, encoding="utf-8")
    assert main(["validate", str(tmp_path / "p.toml")]) == 2
    err = capsys.readouterr().err
    assert "eccentricity" in err and "tol" in err, err


def _layout(unit="m"):
    cams = Cameras.make(["cam"], 10.0)
    return Block(cams, Photos.make(["a"], 0, [0, 0, 1], [0, 0, 0]), Points.make(["1", "2", "3"], np.eye(3)),
                 Observations.make([0, 0], [0, 1], np.zeros((2, 2)), sigma=0.001), object_unit=unit)


def test_circle_table_converts_the_diameter_to_the_object_unit():
    block = _layout("m")
    t = circle_table(TargetOptions(target="circles", circle_diameter=31.7, unit="mm"), None, block)
    assert t.ids.tolist() == ["1", "2", "3"] and np.allclose(t.diameter, 0.0317) and np.isnan(t.normal).all()
    t = circle_table(TargetOptions(target="circles", circle_diameter=2.0, unit="cm", circle_normal=[0, 0, 2]),
                     None, _layout("mm"))
    assert np.allclose(t.diameter, 20.0) and np.allclose(t.normal, [0, 0, 2])
    # off, or no diameter and no table in the input block: no correction
    assert circle_table(TargetOptions(target="circles", circle_diameter=31.7, eccentricity=False), None, block) is None
    assert circle_table(TargetOptions(target="circles"), block, block) is None
    # no diameter: the input block's own table, its rows of the detected points
    layout = block.replace(circles=CircleTargets.make(["2", "3", "9"], [0.01, 0.02, 0.03]))
    t = circle_table(TargetOptions(target="circles"), layout, block)
    assert t.ids.tolist() == ["2", "3"] and np.allclose(t.diameter, [0.01, 0.02])


def test_single_targets_get_their_own_normal_and_diameter():
    block = _layout("m")
    opts = TargetOptions(target="circles", circle_diameter=10.0, unit="mm", circle_normal=[0, 0, 1],
                         circle_normals={"2": [1, 0, 0]}, circle_diameters={"3": 20.0})
    t = circle_table(opts, None, block)
    assert np.allclose(t.diameter, [0.01, 0.01, 0.02])
    assert np.allclose(t.normal, [[0, 0, 1], [1, 0, 0], [0, 0, 1]])
    only = circle_table(TargetOptions(target="circles", circle_diameters={"3": 20.0}), None, block)
    assert only.ids.tolist() == ["3"] and np.isnan(only.normal).all()
    from baarda.pipeline.errors import InputError
    with pytest.raises(InputError, match="circle_normals: no point '7'"):
        circle_table(TargetOptions(target="circles", circle_diameter=10.0, circle_normals={"7": [0, 0, 1]}), None,
                     block)
    with pytest.raises(ValueError, match=r"circle_normals.2: expected 3 finite numbers"):
        TargetOptions(target="circles", circle_normals={"2": [0, 0, 0]})
