"""Camera models are found through the entry-point group ``baarda.camera_models``.

The third-party case builds a distribution on a temporary sys.path entry (a ``*.dist-info`` folder
with ``entry_points.txt``): importlib.metadata finds it exactly as it finds an installed package,
and nothing is installed.
"""

from __future__ import annotations

import textwrap
import tomllib
from importlib.metadata import entry_points
from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.camera import REGISTRY, APModel, CameraModelRegistry, get_ap_model
from baarda.pipeline.camera.registry import GROUP

ROOT = Path(__file__).resolve().parents[2]


def test_builtin_models_come_from_the_entry_point_group():
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"][GROUP]
    ray = {"simple-fisheye", "fisheye", "simple-radial-fisheye", "radial-fisheye", "opencv-fisheye",
           "thin-prism-fisheye", "rad-tan-thin-prism-fisheye", "fov", "eucm", "division", "simple-division",
           "equirectangular", "fisheye-equidistant", "fisheye-equisolid", "fisheye-stereographic",
           "fisheye-orthographic"}
    assert set(declared) == {"none", "ebner12", "brown", "aicon", "brown-backward", "metashape"} | ray
    installed = {ep.name: ep.value for ep in entry_points(group=GROUP) if ep.value.startswith("baarda.")}
    assert installed == declared, "reinstall (pip install -e .) after changing entry points"
    reg = CameraModelRegistry()
    assert reg.names() == sorted(declared)
    for name in declared:
        m = reg.get(name)
        assert isinstance(m, APModel) and m.name == name
    assert get_ap_model("brown").params == ("K1", "K2", "K3", "P1", "P2", "B1", "B2")


def test_nothing_is_registered_until_asked():
    reg = CameraModelRegistry()
    assert reg._models == {} and not reg._discovered
    assert "ebner12" in reg
    assert reg._discovered


def test_unknown_model_names_the_known_ones_and_the_closest():
    with pytest.raises(KeyError) as e:
        CameraModelRegistry().get("ebner")
    assert "did you mean 'ebner12'" in str(e.value) and "aicon" in str(e.value)


def _third_party(tmp_path, body: str, target: str, package: str = "thirdcam") -> Path:
    site = tmp_path / "site"
    (site / package).mkdir(parents=True)
    (site / package / "__init__.py").write_text(textwrap.dedent(body))
    info = site / f"{package}-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {package}\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(f"[{GROUP}]\nradial3 = {target}\n")
    return site


def test_a_third_party_model_is_found_through_its_entry_point(tmp_path, monkeypatch):
    site = _third_party(tmp_path, """
        import numpy as np

        class Radial3:                               # duck-typed: no baarda base class
            name = "radial3"
            params = ("k1",)
            def distortion(self, xbar, ybar, params, c, meta):
                r2 = xbar ** 2 + ybar ** 2
                return xbar * params[:, 0] * r2, ybar * params[:, 0] * r2
    """, "thirdcam:Radial3")
    monkeypatch.syspath_prepend(str(site))
    reg = CameraModelRegistry()
    m = reg.get("radial3")
    assert isinstance(m, APModel) and m.params == ("k1",) and m.default_sigma == (np.inf,)
    x, y = np.array([1.0, -2.0]), np.array([0.5, 3.0])
    p = np.array([[1e-3], [1e-3]])
    dx, dy = m.distortion(x, y, p, np.full(2, 50.0), {})
    np.testing.assert_allclose(dx, x * 1e-3 * (x**2 + y**2))
    # the fallback Jacobian (central differences) agrees with the closed form
    J = m.jacobian_params(x, y, p, np.full(2, 50.0), {})
    np.testing.assert_allclose(J[:, 0, 0], x * (x**2 + y**2), rtol=1e-6)
    assert "radial3" not in REGISTRY._models or REGISTRY is not reg


def test_a_broken_third_party_model_is_reported_when_asked_for(tmp_path, monkeypatch):
    site = _third_party(tmp_path, "raise ImportError('no such thing')\n", "brokencam:Radial3", package="brokencam")
    monkeypatch.syspath_prepend(str(site))
    reg = CameraModelRegistry()
    assert "brown" in reg                                  # the others still load
    with pytest.raises(KeyError, match="radial3.*failed to load.*ImportError"):
        reg.get("radial3")
