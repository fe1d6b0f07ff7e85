"""libmv-export: libmv problems written from blocks and read back.

References: the shared libmv problems as stored (a read → block → write → read round trip gives the
same intrinsics, ids, translations, points and markers to float32, rotations to their
orthonormalisation), and libmv's own camera model written out in ``libmv_reprojection`` (the
written problem reprojects a block exactly as baarda's collinearity does)."""

from __future__ import annotations

import numpy as np
import pytest

from baarda.pipeline.adjustment import project_block
from baarda.pipeline.errors import InputError
from baarda.pipeline.geometry import nearest_rotation
from baarda.pipeline.geometry.image import pixels_from_mm
from baarda.pipeline.testing import run_stage
from baarda.plugins.bal.libmv import block_from_libmv, libmv_reprojection, read_libmv
from baarda.plugins.bal.libmv_writer import LibmvExport, libmv_bytes, libmv_from_block


@pytest.mark.parametrize("k", [1, 3])
def test_shared_problem_round_trips(shared_data, tmp_path, k):
    prob = read_libmv(shared_data / "libmv-ba" / f"problem_0{k}.bin")
    block, _ = block_from_libmv(prob)
    again, info = libmv_from_block(block)
    (tmp_path / "p.bin").write_bytes(libmv_bytes(again))
    back = read_libmv(tmp_path / "p.bin")
    used = np.isin(prob.track, back.track)
    assert info["points"] == used.sum() and info["markers"] == len(back.marker_xy)
    assert np.allclose(back.intrinsics, prob.intrinsics, rtol=1e-6, atol=1e-12)
    assert np.array_equal(back.image, prob.image) and np.array_equal(back.track, prob.track[used])
    assert np.allclose(back.X, prob.X[used], rtol=1e-6, atol=1e-6)
    R_o = np.array([nearest_rotation(M) for M in prob.R])             # the reader orthonormalises
    assert np.allclose(back.R, R_o, atol=2e-7)
    assert np.allclose(back.t, prob.t, rtol=1e-6, atol=1e-5)
    keep = np.isin(prob.marker_track, back.track)
    assert np.allclose(back.marker_xy, prob.marker_xy[keep], atol=1e-3)
    # the reprojection residuals of the written problem equal those of the original (orthonormalised)
    v0, used0 = libmv_reprojection(prob, orthonormalize=True)
    v1, _ = libmv_reprojection(back)
    written = np.isin(prob.marker_track[used0], back.track)         # markers of the tracks written
    assert np.abs(v1 - v0[written]).max() < 2e-3                     # float32 markers and poses


def test_written_problem_reprojects_as_baarda(shared_data):
    """A block with every libmv parameter non-zero: libmv's model on the written (float64) problem
    gives baarda's projection of the block to 1e-9 px."""
    prob = read_libmv(shared_data / "libmv-ba" / "problem_03.bin")
    block, _ = block_from_libmv(prob)
    cams = block.cameras
    ap = np.array(cams.ap, float)
    ap[0, :5] = [3e-4, -2e-6, 1e-9, 2e-5, -1e-5]                        # K1 K2 K3 P1 P2 (mm powers)
    block = block.replace(cameras=cams.replace(ap=ap, xp=cams.xp + 0.013, yp=cams.yp - 0.021))
    p, _ = libmv_from_block(block)
    obs = block.observations
    pred = pixels_from_mm(project_block(block, obs.photo, obs.point), tuple(cams.resolution[0]),
                          float(cams.pixel_mm[0]), "colmap")
    v, used = libmv_reprojection(p)
    assert used.all()
    assert np.abs((p.marker_xy - v) - pred).max() < 1e-9


def test_what_libmv_cannot_hold_is_refused(shared_data, tmp_path):
    prob = read_libmv(shared_data / "libmv-ba" / "problem_03.bin")
    block, _ = block_from_libmv(prob)
    cams = block.cameras
    ap = np.array(cams.ap, float)
    ap[0, 5] = 1e-4
    with pytest.raises(InputError, match="B1") as e:
        libmv_from_block(block.replace(cameras=cams.replace(ap=ap)))
    assert e.value.field == "B1"
    with pytest.raises(InputError, match="photo id 'a1'"):
        libmv_from_block(block.replace(photos=block.photos.replace(ids=np.array(["a1"] + block.photos.ids[1:].tolist()))))
    # through the stage: one line naming the option, the file written inside the run
    out = run_stage(LibmvExport, {"block": block}, {"path": "out/p.bin"}, tmp_path=tmp_path)
    assert (tmp_path / "out" / "p.bin").is_file() or any(tmp_path.rglob("p.bin"))
    assert out.summary["cameras"] == len(block.photos) and out.summary["float32_markers_px"] < 1e-3
    assert out.summary["headline"].startswith(f"libmv problem out/p.bin (source block): {len(block.photos)} cameras, ")
