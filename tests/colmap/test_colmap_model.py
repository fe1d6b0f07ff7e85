"""COLMAP models in and out: the real binary model, text models, many cameras, broken input, stages."""

from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.model import Block, Cameras, Observations, Photos, Points
from baarda.pipeline.stage import Context
from baarda.pipeline.geometry.image import pixels_from_mm
from baarda.pipeline.adjustment import project_block
from baarda.pipeline.colmap.reader import block_from_reconstruction, read_colmap, read_reconstruction
from baarda.pipeline.adjustment import reprojection_px
from baarda.plugins.colmap.stage import ColmapExport, ColmapExportOptions, ColmapSource, ColmapSourceOptions
from baarda.pipeline.colmap.writer import reconstruction_from_block, write_colmap


@pytest.fixture(scope="module")
def model_dir(shared_data) -> Path:
    p = shared_data / "colmap-model"
    if not p.is_dir():
        pytest.skip(f"{p} not present")
    return p


def _projections(rec) -> dict:
    """{(image_id, point3D_id): pixel projection} of every track element, by pycolmap."""
    out = {}
    for pid, p in rec.points3D.items():
        for el in p.track.elements:
            out[(el.image_id, pid)] = np.asarray(rec.images[el.image_id].project_point(p.xyz))
    return out


def test_real_model_reads_and_projects_like_pycolmap(model_dir):
    block, info = read_colmap(model_dir)
    rec = read_reconstruction(model_dir)
    assert info["format"] == "binary"
    s = block.summary()
    assert (s["cameras"], s["photos"], s["points"], s["observations"]) == (23, 23, 1443, 5931)
    # 7 points are in a track twice with the same image: one measurement each is switched off
    assert info["duplicate_observations"] == 7 and s["active_observations"] == 5924
    assert set(block.meta["colmap"]["camera_models"]) == {"SIMPLE_RADIAL"}
    assert len(set(block.photos.camera.tolist())) == 23            # one camera per image
    # baarda's projection (bundle collinearity + brown) reproduces pycolmap's projection
    obs = block.observations
    xy = project_block(block, obs.photo, obs.point)
    cam = block.photos.camera[obs.photo]
    uv = pixels_from_mm(xy, block.cameras.resolution[cam], block.cameras.pixel_mm[cam], "colmap")
    img_ids = np.array(block.meta["colmap"]["image_ids"])[obs.photo]
    pt_ids = np.array(block.meta["colmap"]["point3D_ids"])[obs.point]
    ref = _projections(rec)
    diff = max(np.abs(uv[i] - ref[(img_ids[i], pt_ids[i])]).max() for i in range(len(obs)))
    print(f"\nmax |baarda − pycolmap| projection on the real model: {diff:.2e} px")
    assert diff < 1e-9
    # residuals reproduce COLMAP's own mean reprojection error (mean over points of the per-point mean)
    e = np.linalg.norm(reprojection_px(block), axis=1)       # all observations, inactive ones too
    per_point = np.bincount(obs.point, e) / np.bincount(obs.point)
    rec.update_point_3d_errors()
    print(f"mean reprojection error: per observation {e.mean():.6f} px, per point {per_point.mean():.6f} px, "
          f"pycolmap {rec.compute_mean_reprojection_error():.6f} px")
    assert per_point.mean() == pytest.approx(rec.compute_mean_reprojection_error(), rel=1e-9)
    # conventions: c > 0 mm, principal point at the format centre, y up
    assert (block.cameras.c > 0).all()
    np.testing.assert_allclose(block.cameras.xp, 0.0, atol=1e-15)   # cx = W/2 in COLMAP's corner convention
    assert (block.cameras.sigma_iop[:, 0] == np.inf).all() and (block.cameras.sigma_iop[:, 1:] == 0).all()
    assert (block.cameras.sigma_ap[:, 0] == np.inf).all() and (block.cameras.sigma_ap[:, 1:] == 0).all()


@pytest.mark.parametrize("fmt", ["binary", "text"])
def test_round_trip_colmap_block_colmap(model_dir, tmp_path, fmt):
    import pycolmap

    block, _ = read_colmap(model_dir)
    info = write_colmap(block, tmp_path / fmt, fmt=fmt)
    assert sorted(p.name for p in (tmp_path / fmt).iterdir()) == sorted(
        f"{n}.{'bin' if fmt == 'binary' else 'txt'}" for n in ("cameras", "images", "points3D", "rigs", "frames"))
    orig = read_reconstruction(model_dir)
    back = pycolmap.Reconstruction(str(tmp_path / fmt))
    assert (back.num_images(), back.num_points3D(), back.compute_num_observations()) == (23, 1443, 5931)
    assert info["camera_models"] == ["SIMPLE_RADIAL"] * 23
    a, b = _projections(orig), _projections(back)
    assert a.keys() == b.keys()
    diff = max(np.abs(a[k] - b[k]).max() for k in a)
    print(f"\n{fmt} round trip COLMAP → Block → COLMAP: max projection change {diff:.2e} px")
    assert diff < 1e-9
    for cid, cam in orig.cameras.items():
        np.testing.assert_allclose(back.cameras[cid].params, cam.params, rtol=1e-12)
    for iid, im in orig.images.items():
        assert back.images[iid].name == im.name
        assert back.images[iid].num_points2D() == im.num_points2D()     # every keypoint kept
    back.update_point_3d_errors()
    orig.update_point_3d_errors()
    assert back.compute_mean_reprojection_error() == pytest.approx(orig.compute_mean_reprojection_error(), rel=1e-9)
    # and our reader reads what we wrote: the same block
    again, info2 = read_colmap(tmp_path / fmt)
    assert info2["format"] == fmt
    np.testing.assert_allclose(again.points.XYZ, block.points.XYZ, atol=1e-12)
    np.testing.assert_allclose(again.photos.X0, block.photos.X0, atol=1e-12)
    np.testing.assert_allclose(again.observations.xy, block.observations.xy, atol=1e-15)


def _synthetic_block(rng, n_cams=3):
    """A pixel-camera block with different brown cameras (exactly representable in COLMAP)."""
    aps = [np.zeros(7), np.r_[-2e-3, 1e-5, 0, 0, 0, 0, 0], np.r_[-1e-3, 2e-6, 1e-8, 2e-4, -1e-4, 0, 0],
           np.r_[0, 0, 0, 0, 0, 1.5e-3, 0]][:n_cams]
    k = len(aps)
    cams = Cameras.make([f"c{i}" for i in range(k)], [8.0, 12.0, 16.0][:k] + [10.0] * (k - 3), xp=0.01, yp=-0.02,
                        ap_model="brown", ap=np.array(aps), pixel_mm=0.004, resolution=(3000, 2000),
                        format_mm=(12.0, 8.0))
    XYZ = np.column_stack([rng.uniform(-5, 5, 60), rng.uniform(-5, 5, 60), rng.uniform(-1, 1, 60)])
    X0 = np.column_stack([np.linspace(-3, 3, 6), np.zeros(6), np.full(6, 20.0)])
    opk = rng.normal(0, 0.05, (6, 3))
    photos = Photos.make([f"IMG_{i}.JPG" for i in range(6)], camera=np.arange(6) % k, X0=X0, opk=opk)
    pts = Points.make([str(i) for i in range(60)], XYZ=XYZ)
    ph, pt = np.meshgrid(np.arange(6), np.arange(60), indexing="ij")
    blk = Block(cams, photos, pts, Observations.make(ph.ravel(), pt.ravel(), np.zeros((360, 2))))
    xy = project_block(blk, ph.ravel(), pt.ravel()) + rng.normal(0, 0.002, (360, 2))
    return blk.replace(observations=blk.observations.replace(xy=xy))


@pytest.mark.parametrize("fmt", ["binary", "text"])
def test_block_without_colmap_meta_round_trips(tmp_path, fmt):
    rng = np.random.default_rng(11)
    blk = _synthetic_block(rng, 4)
    info = write_colmap(blk, tmp_path, fmt=fmt)
    assert info["camera_models"] == ["SIMPLE_PINHOLE", "RADIAL", "FULL_OPENCV", "PINHOLE"]
    back, _ = read_colmap(tmp_path, pixel_mm=0.004)
    # same cameras (in mm), orientations, points and observations
    for name in ("c", "xp", "yp", "ap"):
        np.testing.assert_allclose(getattr(back.cameras, name), getattr(blk.cameras, name), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(back.photos.X0, blk.photos.X0, atol=1e-12)
    np.testing.assert_allclose(back.photos.opk, blk.photos.opk, atol=1e-12)
    assert back.photos.ids.tolist() == blk.photos.ids.tolist()
    np.testing.assert_allclose(back.points.XYZ, blk.points.XYZ, atol=1e-12)
    np.testing.assert_allclose(back.observations.xy, blk.observations.xy, atol=1e-13)
    # the residuals are the same through pycolmap's projection
    import pycolmap

    rec = pycolmap.Reconstruction(str(tmp_path))
    obs = blk.observations
    v_ref = []
    for k, j, xy in zip(obs.photo, obs.point, obs.xy):
        cam = blk.cameras.resolution[blk.photos.camera[k]]
        uv = rec.images[k + 1].project_point(blk.points.XYZ[j])
        v_ref.append(pixels_from_mm(xy, cam, 0.004, "colmap") - uv)
    v_ref = np.array(v_ref) * [1, -1]                  # pixels y down → mm y up
    np.testing.assert_allclose(reprojection_px(blk), v_ref, atol=1e-9)


def test_writer_skips_inactive_and_unoriented(tmp_path):
    rng = np.random.default_rng(2)
    blk = _synthetic_block(rng, 2)
    active = np.ones(len(blk.observations), bool)
    active[:10] = False
    X0 = blk.photos.X0.copy()
    X0[5] = np.nan
    blk = blk.replace(observations=blk.observations.replace(active=active), photos=blk.photos.replace(X0=X0))
    rec, info = reconstruction_from_block(blk)
    assert info["images"] == 5 and info["skipped_photos"] == ["IMG_5.JPG"]
    assert info["observations"] == 360 - 10 - 60 + 0     # photo 5's 60 observations and 10 inactive ones


def test_writer_refuses_models_without_colmap_equivalent():
    rng = np.random.default_rng(2)
    blk = _synthetic_block(rng, 1)
    cams = blk.cameras.replace(ap_model=np.array(["ebner12"]), ap=np.zeros((1, 12)), sigma_ap=np.zeros((1, 12)))
    with pytest.raises(InputError, match="ebner12"):
        reconstruction_from_block(blk.replace(cameras=cams))
    cams = blk.cameras.replace(ap=np.array([[0, 0, 0, 0, 0, 0, 1e-3]]))
    with pytest.raises(InputError, match="B2"):
        reconstruction_from_block(blk.replace(cameras=cams))
    cams = blk.cameras.replace(pixel_mm=np.array([np.nan]))
    with pytest.raises(InputError, match="pixel pitch"):
        reconstruction_from_block(blk.replace(cameras=cams))


def test_sensor_width_sets_pitch_and_intrinsics_options(model_dir):
    block, _ = read_colmap(model_dir, sensor_width_mm=23.5, intrinsics="fixed")
    np.testing.assert_allclose(block.cameras.pixel_mm, 23.5 / 3031)
    np.testing.assert_allclose(block.cameras.format_mm[:, 0], 23.5)
    rec = read_reconstruction(model_dir)
    f = np.array([rec.cameras[int(i)].params[0] for i in block.cameras.ids])
    np.testing.assert_allclose(block.cameras.c, f * 23.5 / 3031, rtol=1e-14)
    assert (block.cameras.sigma_iop == 0).all() and (block.cameras.sigma_ap == 0).all()
    free, _ = read_colmap(model_dir, intrinsics="free")
    assert (free.cameras.sigma_iop == np.inf).all()
    with pytest.raises(ValueError):
        block_from_reconstruction(rec, intrinsics="sometimes")


def test_broken_input(tmp_path, model_dir):
    with pytest.raises(InputError, match="not found"):
        read_colmap(tmp_path / "nowhere")
    (tmp_path / "half").mkdir()
    (tmp_path / "half" / "cameras.bin").write_bytes((model_dir / "cameras.bin").read_bytes())
    with pytest.raises(InputError, match="images.bin/.txt"):
        read_colmap(tmp_path / "half")
    bad = tmp_path / "cut"
    bad.mkdir()
    for name in ("cameras", "points3D"):
        (bad / f"{name}.bin").write_bytes((model_dir / f"{name}.bin").read_bytes())
    (bad / "images.bin").write_bytes((model_dir / "images.bin").read_bytes()[:5000])
    with pytest.raises(InputError) as e:
        read_colmap(bad)
    assert "images.bin" in str(e.value) and e.value.field == "points2D"      # the file and record, before pycolmap
    assert "image record 0 at byte offset 93 claims 678 entries" in str(e.value)
    # an unsupported camera model names the camera
    import pycolmap

    rec = pycolmap.Reconstruction()
    cam = pycolmap.Camera.create_from_model_name(7, "FULL_OPENCV", 500.0, 640, 480)
    cam.params = [500, 500, 320, 240, 0.1, 0, 0, 0, 0, 0.01, 0, 0]
    rec.add_camera_with_trivial_rig(cam)
    with pytest.raises(InputError, match="camera 7: FULL_OPENCV with k4, k5, k6"):
        block_from_reconstruction(rec)


def test_stages_colmap_and_export(model_dir, tmp_path):
    import pycolmap

    from baarda.pipeline.recording import open_recording, read_recording

    ctx = Context("colmap", project_dir=model_dir.parent, run_dir=tmp_path)
    res = ColmapSource().run({}, ColmapSourceOptions(path=Path(model_dir.name)), ctx)
    assert res.summary["photos"] == 23 and res.summary["format"] == "binary"
    assert res.summary["reprojection"]["rms_px"] == pytest.approx(1.11052, abs=1e-4)
    assert any("7 observation(s) of a point already measured" in w for w in ctx.warnings)
    rec = open_recording(tmp_path / "colmap.rrd", "test")
    ColmapSource().log(res, rec, ctx)
    rec.disconnect()
    paths = {e.path for e in read_recording(tmp_path / "colmap.rrd").entities}
    assert "/colmap/block/points" in paths and any(p.startswith("/colmap/block/photos/") for p in paths)

    ectx = Context("export", project_dir=model_dir.parent, run_dir=tmp_path)
    out = ColmapExport().run({"block": res.artefacts["block"]}, ColmapExportOptions(path=Path("model"), format="text"),
                             ectx)
    assert out.summary["points3D"] == 1443
    assert out.summary["headline"].startswith("text COLMAP model model/ (block as given): 23 camera(s) (")
    assert out.summary["headline"].endswith(f"23 images, 1443 points, {out.summary['observations']} observations")
    assert pycolmap.Reconstruction(str(tmp_path / "model")).num_images() == 23
    with pytest.raises(InputError, match="required"):
        ColmapSource().run({}, ColmapSourceOptions(path=Path("")), ctx)
    from baarda.pipeline.testing import check_stage

    check_stage(ColmapSource, "colmap")
    check_stage(ColmapExport, "colmap-export")
    with pytest.raises(ValueError):
        ColmapExportOptions(path=Path("x"), camera_model="KANNALA")


def test_bundle_on_colmap_model_and_export_adjusted(model_dir, tmp_path):
    """A COLMAP user gets baarda's adjustment (free network, c and K1 per camera as COLMAP) and
    writes the adjusted model back."""
    adjust_mod = pytest.importorskip("baarda.pipeline.adjustment.adjust")
    from baarda.pipeline.adjustment.settings import BundleSettings
    import pycolmap

    from baarda.pipeline.adjustment import reprojection_summary
    from baarda.plugins.colmap.stage import block_to_export

    block, _ = read_colmap(model_dir)
    result = adjust_mod.adjust(block, BundleSettings(datum="free", max_iter=50))
    before, after = reprojection_summary(block), reprojection_summary(result.block)
    print(f"\nbaarda bundle on the COLMAP model: σ̂0 = {result.sigma0_hat:.4f} (σ = 1 px a priori), "
          f"{result.iterations} iterations, dof {result.dof}; RMS {before['rms_px']:.4f} → {after['rms_px']:.4f} px")
    assert 0.8 < result.sigma0_hat < 1.2
    assert after["rms_px"] <= before["rms_px"]
    chosen, which = block_to_export(block, result)
    assert which == "adjusted"
    # the block a bundle hands on (its adjusted block) is written as it is, and named adjusted
    adjusted = result.block                     # (a property: a new Block each time)
    handed_on, which = block_to_export(adjusted, result)
    assert handed_on is adjusted and which == "adjusted"
    given, which = block_to_export(block, None)
    assert given is block and which == "as given"
    ctx = Context("export", project_dir=tmp_path, run_dir=tmp_path)
    ColmapExport().run({"block": block, "bundle": result}, ColmapExportOptions(path=Path("adj")), ctx)
    rec = pycolmap.Reconstruction(str(tmp_path / "adj"))
    rec.update_point_3d_errors()
    XYZ = np.array([rec.points3D[int(i)].xyz for i in result.block.points.ids])
    np.testing.assert_allclose(XYZ, result.block.points.XYZ, atol=1e-12)
    print(f"pycolmap mean reprojection error of the adjusted model: {rec.compute_mean_reprojection_error():.6f} px")


def test_project_colmap_to_export_through_the_runner(model_dir, tmp_path):
    """The two stages in a project file, run by the runner (entry points, options, recordings)."""
    import pycolmap

    from baarda.pipeline.testing import run_project_text

    out = run_project_text(f"""
[project]
name = "colmap round trip"

[[stage]]
use = "colmap"
[stage.options]
path = "{model_dir}"
sigma_px = 0.7

[[stage]]
use = "colmap-export"
[stage.options]
path = "model"
format = "text"
camera_model = "auto"
""", tmp_path)
    assert out.ok, out.message
    assert {p.name for p in out.run_dir.iterdir()} >= {"colmap.rrd", "colmap-export.rrd", "report.md", "model"}
    rec = pycolmap.Reconstruction(str(out.run_dir / "model"))
    assert rec.num_points3D() == 1443
    assert out.artefacts["block"].observations.cov[0, 0, 0] == pytest.approx((0.7 * 0.001) ** 2)


def test_legacy_text_model_without_rigs_and_frames(model_dir, tmp_path):
    """COLMAP < 3.12 text models have only cameras, images, points3D."""
    block, _ = read_colmap(model_dir)
    write_colmap(block, tmp_path, fmt="text")
    (tmp_path / "rigs.txt").unlink()
    (tmp_path / "frames.txt").unlink()
    legacy, info = read_colmap(tmp_path)
    assert info["format"] == "text" and len(legacy.photos) == 23
    np.testing.assert_allclose(legacy.photos.opk, block.photos.opk, atol=1e-12)
    np.testing.assert_allclose(legacy.observations.xy, block.observations.xy, atol=1e-15)
