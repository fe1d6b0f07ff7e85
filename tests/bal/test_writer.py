"""bal-export: BAL files written from blocks — round trip through the reader, BAL's own projection
formula (written out here from the BAL documentation) against baarda's projection, refusals."""

from __future__ import annotations

import numpy as np
import pytest

from baarda.pipeline.adjustment import BundleSettings, adjust, project_block
from baarda.pipeline.errors import InputError
from baarda.pipeline.synthetic.aerial import simulate_convergent
from baarda.pipeline.testing import check_stage, run_stage
from baarda.plugins.bal.bal import block_from_bal, read_bal
from baarda.plugins.bal.writer import BalExport, bal_from_block, write_bal

FIXTURE = "bal-ladybug-problem-49-7776-pre-shrink-1800.txt"


def bal_projection(cameras: np.ndarray, points: np.ndarray, cam: np.ndarray, pt: np.ndarray) -> np.ndarray:
    """BAL's camera model as its documentation writes it (Agarwal et al.): P = R(r) X + t with R the
    Rodrigues rotation, p = −P / P_z, p' = f (1 + k1 ‖p‖² + k2 ‖p‖⁴) p.  Rodrigues by its formula."""
    out = np.empty((len(cam), 2))
    for k, (j, i) in enumerate(zip(cam, pt)):
        r, t, f, k1, k2 = cameras[j, :3], cameras[j, 3:6], *cameras[j, 6:9]
        th = np.linalg.norm(r)
        u = r / th
        X = points[i]
        # Rodrigues: R X = X cos θ + (u × X) sin θ + u (u·X)(1 − cos θ)
        P = X * np.cos(th) + np.cross(u, X) * np.sin(th) + u * (u @ X) * (1 - np.cos(th)) + t
        p = -P[:2] / P[2]
        n2 = p @ p
        out[k] = f * (1 + k1 * n2 + k2 * n2 * n2) * p
    return out


@pytest.fixture(scope="module")
def adjusted():
    rng = np.random.default_rng(11)
    ap = np.array([2e-4, -3e-7, 0, 0, 0, 0, 0])
    noisy, _ = simulate_convergent(rng, n_photos=6, n_points=40, model="brown", ap=ap, xp=0.0, yp=0.0,
                                   free_intrinsics=("c", "K1", "K2"))
    return adjust(noisy, BundleSettings(), covariance=False)


def test_fixture_round_trip_is_identical(shared_data, tmp_path):
    src = read_bal(shared_data / "bal" / FIXTURE)
    block = block_from_bal(src)
    problem, info = bal_from_block(block)
    out = write_bal(problem, tmp_path / "again.txt")
    back = read_bal(out)
    assert info["skipped_observations"] == 0 and info["skipped_points"] == 0
    assert np.array_equal(back.cam, src.cam) and np.array_equal(back.pt, src.pt)
    # observations: pixels → mm → pixels; the file's 7 digits come back, to a rounding of 1e-15
    assert [f"{v:.6e}" for v in back.xy.ravel()] == [f"{v:.6e}" for v in src.xy.ravel()]
    assert np.allclose(back.xy, src.xy, rtol=1e-15, atol=0)
    assert np.array_equal(back.points, src.points)
    # camera values: angle-axis → ω φ κ → angle-axis and f → c → f; the file carries 16 digits
    scale = np.abs(src.cameras).max(axis=0)
    assert np.abs(back.cameras - src.cameras).max(axis=0).tolist() <= (1e-13 * np.maximum(scale, 1)).tolist()
    # and the block read back is the block written
    again = block_from_bal(back)
    assert np.allclose(again.photos.X0, block.photos.X0, rtol=0, atol=1e-12)
    assert np.allclose(again.photos.opk, block.photos.opk, rtol=0, atol=1e-13)
    assert np.allclose(again.cameras.ap, block.cameras.ap, rtol=1e-12, atol=0)
    assert np.allclose(again.cameras.c, block.cameras.c, rtol=1e-15, atol=0)


def test_bundle_result_reprojects_as_baarda(adjusted, tmp_path):
    res = adjusted
    block = res.block
    assert abs(block.cameras.ap[0, 0]) > 0 and abs(block.cameras.ap[0, 1]) > 0
    out = run_stage(BalExport, {"block": block, "bundle": res}, {"path": "out/adjusted.txt"}, tmp_path=tmp_path)
    assert out.summary["block"] == "adjusted"
    s = out.summary
    assert s["headline"] == (f"BAL problem out/adjusted.txt (adjusted block): {s['cameras']} cameras, {s['points']} "
                             f"points, {s['observations']} observations")
    back = read_bal(tmp_path / "out" / "adjusted.txt")
    assert len(back.cameras) == len(block.photos) and len(back.cam) == int(block.observations.active.sum())
    # BAL's formula on the file against baarda's collinearity on the adjusted block, in pixels
    uv = bal_projection(back.cameras, back.points, back.cam, back.pt)
    p = block.cameras.pixel_mm[0]
    obs = block.observations
    rows = np.flatnonzero(obs.active)
    ref = project_block(block, obs.photo[rows], obs.point[rows]) / p
    assert np.abs(uv - ref).max() < 1e-9
    assert np.allclose(back.xy, obs.xy[rows] / p, rtol=0, atol=1e-9)
    # source = true after a bundle: the bundle's input block (the pipeline's 'block' is the adjusted one)
    out = run_stage(BalExport, {"block": block, "bundle": res}, {"path": "src.txt", "source": True}, tmp_path=tmp_path)
    src = read_bal(tmp_path / "src.txt")
    assert out.summary["block"] == "source"
    assert np.array_equal(src.points, res.block_in.points.XYZ) and not np.allclose(src.points, back.points)


def test_refusals_and_drop(adjusted, tmp_path):
    block = adjusted.block
    cams = block.cameras
    ap = cams.ap.copy()
    ap[0, 3] = 1e-5                                              # P1
    with pytest.raises(InputError, match=r"camera '.*': P1 = 1e-05 \(decentring") as e:
        bal_from_block(block.replace(cameras=cams.replace(ap=ap)))
    assert e.value.field == "P1"
    ap = cams.ap.copy()
    ap[0, 5] = 1e-4                                              # B1: fx ≠ fy
    with pytest.raises(InputError, match=r"B1 .*fx ≠ fy"):
        bal_from_block(block.replace(cameras=cams.replace(ap=ap)))
    with pytest.raises(InputError, match=r"principal point xp = 0.05 mm"):
        bal_from_block(block.replace(cameras=cams.replace(xp=np.full(len(cams), 0.05))))
    with pytest.raises(InputError, match=r"'ebner12' model"):
        bal_from_block(block.replace(cameras=cams.replace(ap_model=np.array(["ebner12"] * len(cams)))))
    film = cams.replace(pixel_mm=np.full(len(cams), np.nan))
    with pytest.raises(InputError, match="no pixel pitch") as e:
        bal_from_block(block.replace(cameras=film))
    assert e.value.field == "pixel_mm"
    # drop: the principal point goes into the observations, exactly; P1 is dropped with a warning
    shifted = cams.replace(xp=np.full(len(cams), 0.05), yp=np.full(len(cams), -0.02), ap=ap * 0 + cams.ap)
    b2 = block.replace(cameras=shifted)
    said = []
    problem, _ = bal_from_block(b2, drop=True, warn=said.append)
    assert len(said) == 2 and "xp = 0.05" in said[0]
    obs = b2.observations
    rows = np.flatnonzero(obs.active)
    p = cams.pixel_mm[0]
    ref = (project_block(b2, obs.photo[rows], obs.point[rows]) - [0.05, -0.02]) / p
    assert np.abs(bal_projection(problem.cameras, problem.points, problem.cam, problem.pt) - ref).max() < 1e-9
    # the stage names the option in its error
    ap = cams.ap.copy()
    ap[0, 2] = 1e-9
    with pytest.raises(InputError, match="cannot write a BAL file: camera .* K3") as e:
        run_stage(BalExport, {"block": block.replace(cameras=cams.replace(ap=ap))}, {}, tmp_path=tmp_path)
    assert e.value.field == "drop"
    out = run_stage(BalExport, {"block": block.replace(cameras=cams.replace(ap=ap))}, {"drop": True},
                    tmp_path=tmp_path)
    assert any("K3" in w for w in out.warnings)


def test_unoriented_photos_and_unknown_points_are_left_out(adjusted):
    block = adjusted.block
    X0 = block.photos.X0.copy()
    X0[2] = np.nan
    XYZ = block.points.XYZ.copy()
    XYZ[5] = np.nan
    b = block.replace(photos=block.photos.replace(X0=X0), points=block.points.replace(XYZ=XYZ))
    problem, info = bal_from_block(b)
    assert info["skipped_photos"] == [block.photos.ids[2]]
    assert block.points.ids[5] not in info["point_ids"]
    assert len(problem.cameras) == len(block.photos) - 1
    n = int((b.observations.active & (b.observations.photo != 2) & (b.observations.point != 5)).sum())
    assert len(problem.cam) == n == info["observations"]


def test_stage_protocol():
    check_stage(BalExport, "bal-export")


def test_in_a_project_the_file_lands_in_the_run_directory(adjusted, tmp_path):
    from baarda.pipeline.testing import run_project_text

    src_problem, _ = bal_from_block(adjusted.block)
    write_bal(src_problem, tmp_path / "small.txt")
    text = """
[project]
name = "bal in, bal out"
[[stage]]
use = "bal"
[stage.options]
path = "small.txt"
pixel_mm = 0.004
[[stage]]
use = "bal-export"
[stage.options]
path = "out/problem.txt"
"""
    outcome = run_project_text(text, tmp_path)
    assert outcome.ok, outcome.message
    back = read_bal(tmp_path / "run" / "out" / "problem.txt")
    src = read_bal(tmp_path / "small.txt")
    assert np.array_equal(back.points, src.points) and np.array_equal(back.xy, src.xy)
    assert np.allclose(back.cameras, src.cameras, rtol=1e-12, atol=1e-12)
