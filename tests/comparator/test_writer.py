"""comparator-export: comparator files (photo mode) written from blocks and read back by the
comparator reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.testing import check_stage, make_block, run_stage
from baarda.plugins.comparator.block import build_block, interior_orientation
from baarda.plugins.comparator.parser import parse_comparator
from baarda.plugins.comparator.writer import ComparatorExport, comparator_text, write_comparator

FIXTURES = Path(__file__).resolve().parents[2] / "fixtures" / "paper000"


def read(path):
    parsed = parse_comparator(path)
    return build_block(parsed, interior_orientation(parsed))


def same(a, b, *, xy_tol=0.0):
    assert b.photos.ids.tolist() == a.photos.ids.tolist()
    assert b.cameras.ids.tolist() == a.cameras.ids.tolist()
    for f in ("c", "xp", "yp"):
        assert np.array_equal(getattr(b.cameras, f), getattr(a.cameras, f), equal_nan=True), f
    assert np.array_equal(b.cameras.format_mm, a.cameras.format_mm, equal_nan=True)
    ka = {i: k for k, i in enumerate(a.points.ids.tolist())}
    assert sorted(b.points.ids.tolist()) == sorted(ka)
    for k, q in enumerate(b.points.ids.tolist()):
        j = ka[q]
        assert b.points.role[k] == a.points.role[j]
        assert np.array_equal(b.points.XYZ[k], a.points.XYZ[j], equal_nan=True)
        assert np.array_equal(b.points.sigma[k], a.points.sigma[j])
    oa = {(a.photos.ids[p], a.points.ids[q]): r for r, (p, q) in enumerate(zip(a.observations.photo,
                                                                                a.observations.point))}
    assert len(b.observations) == len(oa)
    for r, (p, q) in enumerate(zip(b.observations.photo, b.observations.point)):
        ra = oa[(b.photos.ids[p], b.points.ids[q])]
        assert np.abs(b.observations.xy[r] - a.observations.xy[ra]).max() <= xy_tol
        assert np.allclose(np.diagonal(b.observations.cov[r]), np.diagonal(a.observations.cov[ra]), rtol=1e-15)
    assert b.pairs.left.tolist() == a.pairs.left.tolist() and b.pairs.right.tolist() == a.pairs.right.tolist()


@pytest.mark.parametrize("name", ["data1.cmp", "printed.cmp"])
def test_photo_mode_fixtures_round_trip(tmp_path, name):
    src = read(FIXTURES / name)
    write_comparator(src, tmp_path / "again.cmp")
    same(src, read(tmp_path / "again.cmp"), xy_tol=1e-12)      # unit mm: the numbers themselves


def test_synthetic_block_with_cameras_weighted_and_check_points(tmp_path):
    block = make_block(model="none")
    s = block.points.sigma.copy()
    s[0] = [0.002, 0.002, 0.004]                                 # a weighted control point
    role = block.points.role.astype(object)
    role[1] = "check"
    s[1] = np.inf
    role[2], s[2] = "xy", [0, 0, np.inf]
    pts = block.points.replace(role=role.astype(str), sigma=s)
    act = block.observations.active.copy()
    act[5] = False
    b = block.replace(points=pts, observations=block.observations.replace(active=act))
    info = write_comparator(b, tmp_path / "s.cmp")
    assert info["inactive_left_out"] == 1 and info["cameras"] == 1
    back = read(tmp_path / "s.cmp")
    keep = np.flatnonzero(act)
    expected = b.replace(observations=b.observations.take(keep))
    same(expected, back)
    assert back.object_unit == b.object_unit


def test_fiducial_mode_is_written_as_photo_mode_only_without_correlation(tmp_path):
    src = read(FIXTURES / "fiducial.cmp")
    assert (src.observations.cov[:, 0, 1] != 0).any()
    with pytest.raises(InputError, match="correlated x, y") as e:
        comparator_text(src)
    assert e.value.field == "on_correlated"
    out = run_stage(ComparatorExport, {"block": src}, {"path": "f.cmp", "on_correlated": "drop"}, tmp_path=tmp_path)
    assert out.summary["correlation_dropped"] == len(src.observations) and out.warnings
    assert out.summary["headline"] == (f"comparator file f.cmp (photo mode, mm): {out.summary['photos']} photos, "
                                       f"{len(src.observations)} measurements, {out.summary['points_declared']} "
                                       f"object points, {out.summary['pairs']} pair(s)")
    back = read(tmp_path / "f.cmp")
    assert np.abs(back.observations.xy - src.observations.xy).max() == 0.0
    assert np.allclose(np.diagonal(back.observations.cov, axis1=1, axis2=2),
                       np.diagonal(src.observations.cov, axis1=1, axis2=2), rtol=1e-15)


def test_refusals(tmp_path):
    block = make_block(model="brown")
    with pytest.raises(InputError, match=r"camera 'cam' \(brown model\) has additional parameter 1"):
        comparator_text(block)
    block = make_block(model="none")
    ids = block.photos.ids.copy().astype(object)
    ids[0] = "P 1"
    with pytest.raises(InputError, match="photo id 'P 1'"):
        comparator_text(block.replace(photos=block.photos.replace(ids=ids.astype(str))))
    with pytest.raises(InputError, match="object unit 'ft'"):
        comparator_text(block.replace(object_unit="ft"))
    with pytest.raises(InputError, match="cannot write a comparator file: camera 'cam'") as e:
        run_stage(ComparatorExport, {"block": make_block(model="brown")}, {}, tmp_path=tmp_path)
    assert e.value.field == "path"


def test_stage_protocol():
    check_stage(ComparatorExport, "comparator-export")
