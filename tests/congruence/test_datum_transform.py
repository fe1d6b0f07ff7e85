"""datum-transform (S-transformation without re-adjusting) against re-adjusting with that datum."""

import csv
from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.runner import run_project

ROOT = Path(__file__).resolve().parents[2]
DATUM = ["T01", "T06", "T25", "T30", "T15"]


def _project(tmp_path, datum_points=None, transform=False):
    text = (ROOT / "fixtures" / "monitoring" / "panel-epochs.toml").read_text()
    head = text.split('[[stage]]\nuse = "epoch"\nid = "epoch-1"')[0]
    head = head.replace('"../design/', f'"{ROOT}/fixtures/design/').replace(
        '"panel-targets-1.csv"', f'"{ROOT}/fixtures/monitoring/panel-targets-1.csv"')
    if datum_points:
        head = head.replace('datum = "free"\n', f'datum = "free"\ndatum_points = {DATUM!r}\n'.replace("'", '"'))
    if transform:
        head += '[[stage]]\nuse = "datum-transform"\n[stage.options]\npoints = ' + str(DATUM).replace("'", '"') + "\n"
    name = "t.toml" if transform else "d.toml"
    (tmp_path / name).write_text(head)
    out = run_project(tmp_path / name, tmp_path / ("run-" + name), verbose=False)
    assert out.ok, out.message
    return out.run_dir


def _read(path):
    with open(path, encoding="utf-8") as fh:
        return {r["point"]: r for r in csv.DictReader(fh)}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """(the free network + datum-transform, the network adjusted in the datum points' datum)."""
    tmp = tmp_path_factory.mktemp("dt")
    return _project(tmp, transform=True), _project(tmp, datum_points=True)


def test_s_transformation_equals_adjusting_in_that_datum(runs):
    a = _read(runs[0] / "datum-transform_points.csv")
    b = _read(runs[1] / "bundle-1_points.csv")
    col = lambda r, names: np.array([float(r[n]) for n in names])  # noqa: E731
    for p in a:
        xa, xb = col(a[p], ("X_m", "Y_m", "Z_m")), col(b[p], [k for k in ("X_m", "Y_m", "Z_m", "X", "Y", "Z") if k in b[p]][:3])
        sa = col(a[p], ("sigma_X_m", "sigma_Y_m", "sigma_Z_m"))
        sb = col(b[p], [k for k in ("sigma_X_m", "sigma_Y_m", "sigma_Z_m", "sX_m", "sY_m", "sZ_m", "sX", "sY", "sZ") if k in b[p]][:3])
        assert np.abs(xa - xb).max() < 1e-7, p          # σ of a coordinate ≈ 40 µm
        assert np.abs(sa / sb - 1).max() < 1e-3, p      # first order: datum directions at the approximations


def _rows(path):
    with open(path, encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def test_external_reliability_in_the_new_datum_equals_adjusting_in_it(runs):
    """The effect of each MDB on its own point after the S-transformation equals the bundle's own
    figure when the bundle holds that datum itself (and differs from the free network's)."""
    ta = runs[0]
    a = _rows(ta / "datum-transform_reliability.csv")
    b = _rows(runs[1] / "bundle-1_observations.csv")
    free = _rows(ta / "bundle-1_observations.csv")
    assert len(a) == len(b) == len(free) > 100
    f = lambda rows, k: np.array([float(r[k]) if r[k] not in ("", "nan") else np.nan for r in rows])  # noqa: E731
    moved = 0.0
    for c in "xy":
        unit = next(k for k in a[0] if k.startswith(f"ext_point_{c}_"))
        ea, eb, ef = f(a, unit), f(b, unit), f(free, unit)
        sa, sb = f(a, f"ext_point_in_sigma_{c}"), f(b, f"ext_point_in_sigma_{c}")
        ok = np.isfinite(sa) & np.isfinite(sb)
        assert ok.sum() > 100
        assert [r[f"ext_point_coord_{c}"] for r in a] == [r[f"ext_point_coord_{c}"] for r in b]
        assert np.allclose(sa[ok], sb[ok], rtol=2e-3), np.abs(sa[ok] / sb[ok] - 1).max()
        assert np.allclose(ea[ok], eb[ok], rtol=2e-3, atol=1e-12)
        moved = max(moved, float(np.nanmax(np.abs(ef[ok] - eb[ok]) / np.abs(eb[ok]))))
    assert moved > 0.05        # the free network's own effects are not those of the datum points
