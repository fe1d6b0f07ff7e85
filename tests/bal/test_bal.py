"""BAL and libmv problems → blocks: counts, conventions, reprojection numbers, broken files."""

from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.geometry import rotation_from_opk
from baarda.pipeline.stage import Context
from baarda.plugins.bal.bal import bal_reprojection, block_from_bal, read_bal
from baarda.pipeline.geometry import nearest_rotation
from baarda.plugins.bal.libmv import block_from_libmv, libmv_reprojection, read_libmv
from baarda.plugins.bal.stage import BalOptions, BalSource, LibmvOptions, LibmvSource
from baarda.pipeline.adjustment import reprojection_px, reprojection_summary

BAL = "problem-49-7776-pre.txt"
BAL_SMALL = "bal-ladybug-problem-49-7776-pre-shrink-1800.txt"


@pytest.fixture(scope="module")
def bal_dir(shared_data) -> Path:
    return shared_data / "bal"


@pytest.fixture(scope="module")
def libmv_dir(shared_data) -> Path:
    return shared_data / "libmv-ba"


def _bal_independent(path):
    """BAL's camera model written out from the format description, with cv2.Rodrigues."""
    import cv2

    tok = Path(path).read_text().split()
    nc, npt, no = (int(t) for t in tok[:3])
    o = np.array(tok[3:3 + 4 * no], float).reshape(no, 4)
    rest = np.array(tok[3 + 4 * no:], float)
    cams, pts = rest[:9 * nc].reshape(nc, 9), rest[9 * nc:].reshape(npt, 3)
    R = np.array([cv2.Rodrigues(cam[:3])[0] for cam in cams])
    ci, pj = o[:, 0].astype(int), o[:, 1].astype(int)
    P = np.einsum("kij,kj->ki", R[ci], pts[pj]) + cams[ci, 3:6]
    p = -P[:, :2] / P[:, 2:]
    r2 = (p * p).sum(axis=1)
    f, k1, k2 = cams[ci, 6], cams[ci, 7], cams[ci, 8]
    return o[:, 2:] - (f * (1 + k1 * r2 + k2 * r2 * r2))[:, None] * p


@pytest.mark.parametrize("name,counts,mean_px,rms_px", [
    (BAL, (49, 7776, 31843), 4.208563, 7.310557),
    (BAL_SMALL, (49, 1800, 10863), 4.189091, 6.570976),
])
def test_bal_reads_and_reprojects(bal_dir, name, counts, mean_px, rms_px):
    prob = read_bal(bal_dir / name)
    block = block_from_bal(prob)
    s = block.summary()
    assert (s["cameras"], s["points"], s["observations"]) == counts and s["photos"] == counts[0]
    v_ref = _bal_independent(bal_dir / name)
    v = reprojection_px(block)
    diff = np.abs(v - v_ref).max()
    e = np.linalg.norm(v_ref, axis=1)
    print(f"\n{name}: initial reprojection error mean {e.mean():.6f} px, RMS {np.sqrt((e**2).mean()):.6f} px, "
          f"median {np.median(e):.4f} px, max {e.max():.3f} px; |baarda − BAL model| max {diff:.1e} px")
    assert diff < 1e-9                 # brown K1 = k1/c², K2 = k2/c⁴ at the ideal point is BAL's model exactly
    np.testing.assert_allclose(bal_reprojection(prob), v_ref, atol=1e-9)
    rep = reprojection_summary(block)
    assert rep["mean_px"] == pytest.approx(mean_px, abs=1e-5)
    assert rep["rms_px"] == pytest.approx(rms_px, abs=1e-5)


def test_bal_convention_is_baardas(bal_dir):
    """BAL's camera frame is baarda's image-space frame: observed points have W < 0 (in front),
    and R_cam_from_world is the Rodrigues matrix itself."""
    import cv2

    prob = read_bal(bal_dir / BAL_SMALL)
    block = block_from_bal(prob, pixel_mm=0.005)
    ph, obs = block.photos, block.observations
    for k in (0, 17, 48):
        np.testing.assert_allclose(rotation_from_opk(*ph.opk[k]), cv2.Rodrigues(prob.cameras[k, :3])[0], atol=1e-12)
    W = np.array([(rotation_from_opk(*ph.opk[p]) @ (block.points.XYZ[j] - ph.X0[p]))[2]
                  for p, j in zip(obs.photo[:500], obs.point[:500])])
    assert (W < 0).all()
    np.testing.assert_allclose(block.cameras.c, prob.cameras[:, 6] * 0.005)
    np.testing.assert_allclose(block.cameras.ap[:, 0], prob.cameras[:, 7] / block.cameras.c**2)
    np.testing.assert_allclose(block.cameras.ap[:, 1], prob.cameras[:, 8] / block.cameras.c**4)
    np.testing.assert_allclose(obs.xy, prob.xy * 0.005)           # origin at the centre, y up: only scaled
    np.testing.assert_allclose(obs.cov[:, 0, 0], 0.005**2)
    assert (block.cameras.sigma_iop[:, 0] == np.inf).all() and (block.cameras.sigma_ap[:, :2] == np.inf).all()
    assert (block.cameras.sigma_ap[:, 2:] == 0).all()


def test_bal_broken_files(bal_dir, tmp_path):
    lines = (bal_dir / BAL_SMALL).read_text().splitlines()
    with pytest.raises(InputError, match="not found"):
        read_bal(tmp_path / "missing.txt")
    # truncated inside the observations
    cut = tmp_path / "cut_obs.txt"
    cut.write_text("\n".join(lines[:101]) + "\n")
    with pytest.raises(InputError) as e:
        read_bal(cut)
    assert e.value.line == 102 and e.value.field == "observation" and "after 100 of 10863" in str(e.value)
    # truncated inside the camera parameters: the message names the camera and parameter
    n_obs = 10863
    cut.write_text("\n".join(lines[:1 + n_obs + 9 * 3 + 4]) + "\n")
    with pytest.raises(InputError) as e:
        read_bal(cut)
    assert e.value.line == 1 + n_obs + 9 * 3 + 4 + 1
    assert "camera 3 parameter 5 of 9" in str(e.value) and e.value.field == "camera"
    # truncated inside the points
    cut.write_text("\n".join(lines[:-2]) + "\n")
    with pytest.raises(InputError, match="point 1799 coordinate 2 of 3") as e:
        read_bal(cut)
    assert e.value.line == len(lines) - 1
    # a bad number names line and field
    bad = list(lines)
    bad[5] = "3 0 -2.5e+02 2,02e+02"
    cut.write_text("\n".join(bad))
    with pytest.raises(InputError) as e:
        read_bal(cut)
    assert (e.value.line, e.value.field) == (6, "y")
    bad = list(lines)
    bad[0] = "49 1800"
    cut.write_text("\n".join(bad))
    with pytest.raises(InputError, match="header") as e:
        read_bal(cut)
    assert e.value.line == 1
    bad = list(lines)
    bad[2] = "55 0 1.0 2.0"
    cut.write_text("\n".join(bad))
    with pytest.raises(InputError, match="camera index 55 out of range") as e:
        read_bal(cut)
    assert e.value.line == 3
    cut.write_text("\n".join(lines) + "\n1.0\n")
    with pytest.raises(InputError, match="more values"):
        read_bal(cut)
    # several parameters per line are accepted
    one_line = "\n".join(lines[:1 + n_obs]) + "\n" + " ".join(lines[1 + n_obs:]) + "\n"
    cut.write_text(one_line)
    p = read_bal(cut)
    np.testing.assert_array_equal(p.cameras, read_bal(bal_dir / BAL_SMALL).cameras)


@pytest.mark.parametrize("k,counts", [(1, (333, 26, 5421)), (2, (440, 71, 16718)), (3, (500, 37, 6184))])
def test_libmv_reads_and_reprojects(libmv_dir, k, counts):
    prob = read_libmv(libmv_dir / f"problem_0{k}.bin")
    block, info = block_from_libmv(prob)
    s = block.summary()
    assert (s["photos"], s["points"], s["observations"]) == counts and s["cameras"] == 1
    assert info["dropped_markers"] == 0
    v, used = libmv_reprojection(prob)                                  # libmv's model, R as stored
    e = np.linalg.norm(v, axis=1)
    v_o, _ = libmv_reprojection(prob, orthonormalize=True)
    vb = reprojection_px(block) * [1, -1]                                # baarda y up → pixel y down
    diff = np.abs(vb - v_o).max()
    print(f"\nlibmv problem_0{k}: f {prob.intrinsics[0]:.2f} px, image {info['resolution']}, reprojection of the "
          f"given solution: RMS {np.sqrt((e**2).mean()):.6f} px (per coordinate {np.sqrt((v**2).mean()):.6f} px), "
          f"mean {e.mean():.6f} px, max {e.max():.3f} px; |baarda − libmv model| max {diff:.1e} px")
    assert diff < 1e-9
    assert np.abs(v - v_o).max() < 1e-3              # float32 rotations: orthonormalizing moves < 0.001 px
    np.testing.assert_allclose(block.cameras.xp, 0.0, atol=1e-15)   # principal point at W/2, H/2
    assert e.mean() < 1.1


def test_libmv_big_endian_and_broken(libmv_dir, tmp_path):
    import struct

    data = (libmv_dir / "problem_03.bin").read_bytes()
    little = read_libmv(libmv_dir / "problem_03.bin")
    # rewrite the file big-endian: every 4-byte word after the two flag bytes is swapped
    words = np.frombuffer(data[2:], "<u4").astype(">u4").tobytes()
    (tmp_path / "big.bin").write_bytes(b"V" + data[1:2] + words)
    big = read_libmv(tmp_path / "big.bin")
    np.testing.assert_array_equal(big.R, little.R)
    np.testing.assert_array_equal(big.marker_xy, little.marker_xy)
    (tmp_path / "cut.bin").write_bytes(data[:-10])
    with pytest.raises(InputError, match="ends after 6183 of 6184 markers") as e:
        read_libmv(tmp_path / "cut.bin")
    assert e.value.field == "markers"
    (tmp_path / "cut.bin").write_bytes(data[:30])
    with pytest.raises(InputError, match="intrinsics"):
        read_libmv(tmp_path / "cut.bin")
    (tmp_path / "bad.bin").write_bytes(b"xP" + data[2:])
    with pytest.raises(InputError, match="endianness"):
        read_libmv(tmp_path / "bad.bin")
    (tmp_path / "norm.bin").write_bytes(b"vN" + data[2:])
    with pytest.raises(InputError, match="normalized"):
        block_from_libmv(read_libmv(tmp_path / "norm.bin"))
    with pytest.raises(InputError, match="not found"):
        read_libmv(tmp_path / "none.bin")
    # a marker of an image without a camera is dropped and counted
    n_cam = struct.unpack("<i", data[34:38])[0]
    assert n_cam == 500
    p = read_libmv(libmv_dir / "problem_03.bin")
    p2 = type(p)(**{**p.__dict__, "marker_image": np.r_[p.marker_image[:-1], 99999]})
    _, info = block_from_libmv(p2)
    assert info["dropped_markers"] == 1


def test_nearest_rotation():
    rng = np.random.default_rng(0)
    R = rotation_from_opk(0.3, -0.2, 1.0)
    M = R + rng.normal(0, 1e-7, (3, 3))
    Q = nearest_rotation(M)
    np.testing.assert_allclose(Q @ Q.T, np.eye(3), atol=1e-14)
    assert np.linalg.det(Q) == pytest.approx(1.0)
    assert np.abs(Q - R).max() < 1e-6


def test_stages(bal_dir, libmv_dir, tmp_path):
    from baarda.pipeline.recording import open_recording

    ctx = Context("bal", project_dir=bal_dir)
    res = BalSource().run({}, BalOptions(path=Path(BAL_SMALL)), ctx)
    assert res.summary["observations"] == 10863
    assert "mean 4.1891 px" in res.report
    rec = open_recording(tmp_path / "bal.rrd", "t")
    BalSource().log(res, rec, ctx)
    rec.disconnect()
    ctx = Context("libmv", project_dir=libmv_dir)
    res = LibmvSource().run({}, LibmvOptions(path=Path("problem_01.bin"), resolution=[2048, 1080]), ctx)
    assert res.summary["photos"] == 333 and res.summary["resolution"] == (2048, 1080)
    from baarda.pipeline.options import parse_options
    from baarda.pipeline.testing import check_stage

    with pytest.raises(InputError, match="required option 'path'"):
        parse_options(BalOptions, {})
    with pytest.raises(InputError, match="required"):
        BalSource().run({}, BalOptions(path=Path("")), ctx)
    check_stage(BalSource, "bal")
    check_stage(LibmvSource, "libmv")
    with pytest.raises(ValueError):
        LibmvOptions(path=Path("x"), resolution=[1])


def test_points_behind_their_camera(bal_dir, tmp_path):
    """on_behind: the observations whose point is behind the camera (by BAL's projection written
    out independently: p = R X + t, in front when p_z < 0) are kept with a warning, or switched off."""
    import cv2

    from baarda.plugins.bal.bal import behind_camera

    problem = read_bal(bal_dir / BAL_SMALL)
    behind = behind_camera(problem)
    cams, pts = problem.cameras, problem.points
    pz = np.array([(cv2.Rodrigues(cams[c, :3])[0] @ pts[p] + cams[c, 3:6])[2] for c, p in zip(problem.cam, problem.pt)])
    assert np.array_equal(behind, pz >= 0) and behind.sum() == 31
    for mode in ("warn", "skip"):
        ctx = Context(stage_id="source", project_dir=bal_dir, run_dir=tmp_path)
        res = BalSource().run({}, BalOptions(path=bal_dir / BAL_SMALL, on_behind=mode), ctx)
        active = res.artefacts["block"].observations.active
        assert res.summary["behind_camera"] == 31
        if mode == "skip":
            assert np.array_equal(active, ~behind) and not ctx.warnings
        else:
            assert active.all() and "31 observation(s) of points behind their camera" in ctx.warnings[0]


def test_libmv_rotation_not_orthonormal_is_refused(libmv_dir, tmp_path):
    """A camera rotation with a zero diagonal is an InputError naming the record, its byte offset and
    the field (was: silently replaced by the nearest rotation)."""
    data = bytearray((libmv_dir / "problem_03.bin").read_bytes())
    rec = 38 + 2 * 52                                    # camera record 2: image i4, R 9 × f4, t 3 × f4
    for d in (0, 4, 8):
        data[rec + 4 + 4 * d:rec + 8 + 4 * d] = np.float32(0).tobytes()
    (tmp_path / "zero.bin").write_bytes(bytes(data))
    with pytest.raises(InputError, match="record 2 .*not orthonormal") as e:
        read_libmv(tmp_path / "zero.bin")
    assert e.value.field == "cameras.R" and f"byte offset {rec}" in str(e.value)
