"""COLMAP models with fisheye / omnidirectional / division cameras: read, project like pycolmap, write,
read again (pycolmap's synthetic datasets with each camera model)."""

import numpy as np
import pytest

from baarda.pipeline.adjustment import project_block
from baarda.pipeline.colmap.reader import block_from_reconstruction, read_colmap
from baarda.pipeline.colmap.writer import reconstruction_from_block, write_colmap
from baarda.pipeline.geometry.image import pixels_from_mm

pycolmap = pytest.importorskip("pycolmap")

W, H = 1024, 768
PARAMS = {
    "SIMPLE_FISHEYE": [380.0, 515.0, 380.0],
    "FISHEYE": [382.0, 377.0, 510.0, 386.0],
    "SIMPLE_RADIAL_FISHEYE": [380.0, 512.0, 384.0, 0.03],
    "RADIAL_FISHEYE": [380.0, 512.0, 384.0, 0.03, -0.005],
    "OPENCV_FISHEYE": [381.0, 379.0, 514.0, 382.0, 0.02, -0.01, 0.004, -0.0007],
    "THIN_PRISM_FISHEYE": [381.0, 379.0, 514.0, 382.0, 0.02, -0.006, 0.001, -0.0007, 0.001, -0.0002, 0.0009,
                           -0.0006],
    "RAD_TAN_THIN_PRISM_FISHEYE": [381.0, 379.0, 514.0, 382.0, 0.02, -0.008, 0.002, -0.0004, 0.0001, -0.00002,
                                   0.0008, -0.0005, 0.0006, -0.0001, -0.0004, 0.00007],
    "FOV": [400.0, 398.0, 511.0, 385.0, 0.9],
    "EUCM": [380.0, 378.0, 512.0, 384.0, 0.6, 1.05],
    "DIVISION": [420.0, 418.0, 512.0, 384.0, -0.15],
    "SIMPLE_DIVISION": [420.0, 512.0, 384.0, -0.1],
    "EQUIRECTANGULAR": [float(W), float(H)],
}


def _synthetic(model):
    opt = pycolmap.SyntheticDatasetOptions()
    opt.num_rigs, opt.num_cameras_per_rig, opt.num_frames_per_rig = 2, 1, 3
    opt.num_points3D = 60
    opt.camera_width, opt.camera_height = W, H
    opt.camera_model_id = getattr(pycolmap.CameraModelId, model)
    opt.camera_params = PARAMS[model]
    return pycolmap.synthesize_dataset(opt)


def _pixels(block):
    obs = block.observations
    xy = project_block(block, obs.photo, obs.point)
    cams = block.cameras
    k = block.photos.camera[obs.photo]
    return pixels_from_mm(xy, cams.resolution[k], cams.pixel_mm[k], "colmap")


@pytest.mark.parametrize("model", sorted(PARAMS))
def test_read_project_write_read(model, tmp_path):
    rec = _synthetic(model)
    block, info = block_from_reconstruction(rec, pixel_mm=0.005)
    cams = block.cameras
    assert set(cams.ap_model.tolist()) == {get_name(model)}
    # baarda's projection of every observation equals pycolmap's (the synthetic keypoints are exact)
    uv = _pixels(block)
    obs = block.observations
    ref = np.array([rec.images[block.meta["colmap"]["image_ids"][p]].project_point(block.points.XYZ[q])
                    for p, q in zip(obs.photo, obs.point)])
    np.testing.assert_allclose(uv, ref, rtol=0, atol=1e-7)
    np.testing.assert_allclose(uv, pixels_from_mm(obs.xy, cams.resolution[block.photos.camera[obs.photo]],
                                                  cams.pixel_mm[block.photos.camera[obs.photo]], "colmap"),
                               atol=1e-6)
    # write (binary and text); pycolmap reads what baarda writes; baarda reads it back unchanged
    for fmt in ("binary", "text"):
        out = tmp_path / fmt
        write_colmap(block, out, fmt=fmt)
        rec2 = pycolmap.Reconstruction(str(out))
        for cid, cam in rec.cameras.items():
            assert rec2.cameras[cid].model.name == model
            np.testing.assert_allclose(rec2.cameras[cid].params, cam.params, rtol=1e-12, atol=1e-9)
        block2, _ = read_colmap(out, pixel_mm=0.005)
        np.testing.assert_allclose(block2.cameras.ap, cams.ap, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(block2.cameras.c, cams.c, rtol=1e-14)
        assert (block2.cameras.ap_model == cams.ap_model).all()
        assert (block2.cameras.sigma_ap == cams.sigma_ap).all()


def get_name(model):
    from baarda.pipeline.camera.convert import colmap_ray_model_names
    return colmap_ray_model_names()[model]


def test_intrinsics_options_for_ray_models():
    rec = _synthetic("OPENCV_FISHEYE")
    b, _ = block_from_reconstruction(rec, intrinsics="colmap")
    assert np.isinf(b.cameras.sigma_ap[:, :5]).all() and np.isinf(b.cameras.sigma_iop[:, 0]).all()
    assert (b.cameras.sigma_iop[:, 1:] == 0).all()
    b, _ = block_from_reconstruction(rec, intrinsics="fixed")
    assert (b.cameras.sigma_ap == 0).all() and (b.cameras.sigma_iop == 0).all()
    b, _ = block_from_reconstruction(_synthetic("EQUIRECTANGULAR"), intrinsics="free")
    assert (b.cameras.sigma_ap == 0).all() and (b.cameras.sigma_iop == 0).all()


def test_equirectangular_that_colmap_cannot_hold_is_refused():
    from baarda.pipeline.errors import InputError

    block, _ = block_from_reconstruction(_synthetic("EQUIRECTANGULAR"), pixel_mm=0.005)
    cams = block.cameras.replace(c=block.cameras.c * 1.01)
    with pytest.raises(InputError, match="EQUIRECTANGULAR camera is fixed by its image size"):
        reconstruction_from_block(block.replace(cameras=cams))


def test_precheck_knows_every_pycolmap_model():
    from baarda.pipeline.colmap.precheck import MODEL_NAMES, MODEL_PARAMS

    for name, mid in pycolmap.CameraModelId.__members__.items():
        if name == "INVALID":
            continue
        n = len(pycolmap.Camera.create_from_model_name(1, name, 1.0, 10, 10).params)
        assert MODEL_PARAMS[int(mid)] == n and MODEL_NAMES[name] == n


def test_fisheye_and_pinhole_cameras_in_one_model(tmp_path):
    rec = _synthetic("RAD_TAN_THIN_PRISM_FISHEYE")
    ids = sorted(rec.cameras)
    assert len(ids) == 2
    cam = rec.cameras[ids[1]]
    cam.model = pycolmap.CameraModelId.SIMPLE_RADIAL
    cam.params = [500.0, 512.0, 384.0, -0.02]
    block, _ = block_from_reconstruction(rec, pixel_mm=0.005)
    cams = block.cameras
    assert cams.ap_model.tolist() == ["rad-tan-thin-prism-fisheye", "brown"] and cams.ap.shape == (2, 13)
    assert (cams.sigma_ap[1, 7:] == 0).all()
    write_colmap(block, tmp_path / "m", fmt="text")
    rec2 = pycolmap.Reconstruction(str(tmp_path / "m"))
    for cid in ids:
        assert rec2.cameras[cid].model == rec.cameras[cid].model
        np.testing.assert_allclose(rec2.cameras[cid].params, rec.cameras[cid].params, rtol=1e-12)


def test_bundled_fisheye_model_recovers_its_truth():
    """fixtures/fisheye: the model made by make.py (131 rays beyond 90°) adjusted as the project does;
    the true camera (truth.json) within 3 σ (the README says 2 σ for the values it quotes)."""
    import json
    from pathlib import Path

    from baarda.pipeline.adjustment import BundleSettings, adjust
    from baarda.pipeline.camera.convert import colmap_from_ray
    from baarda.pipeline.camera.ray_models import field_angle
    from baarda.pipeline.geometry import rotation_from_opk_many

    here = Path(__file__).resolve().parents[2] / "fixtures" / "fisheye"
    truth = json.loads((here / "truth.json").read_text())
    block, _ = read_colmap(here / "model", pixel_mm=0.003, sigma_px=0.4, intrinsics="free")
    ph, obs = block.photos, block.observations
    d = np.einsum("kij,kj->ki", rotation_from_opk_many(ph.opk)[obs.photo], block.points.XYZ[obs.point] - ph.X0[obs.photo])
    assert abs(int((field_angle(d) > 90).sum()) - truth["beyond_90_deg"]) <= 3     # the start geometry is disturbed
    res = adjust(block, BundleSettings(datum="free"))
    assert 0.9 < res.sigma0 < 1.1
    cams = res.block.cameras
    name, params = colmap_from_ray("opencv-fisheye", cams.c[0], cams.xp[0], cams.yp[0], cams.ap[0], (1800, 1800), 0.003)
    assert name == "OPENCV_FISHEYE"
    true = np.array([truth["params_px"][k] for k in ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")])
    # σ of the COLMAP parameters from baarda's covariance of (c, xp, yp, B1, k1 … k4), linearised
    C = res.cov_cameras[0]
    c, B1 = cams.c[0], cams.ap[0, 0]
    J = np.zeros((8, 8))
    J[0, 0], J[0, 3] = (1 + B1) / 0.003, c / 0.003        # fx
    J[1, 0] = 1 / 0.003                                   # fy
    J[2, 1], J[3, 2] = 1 / 0.003, -1 / 0.003              # cx, cy (y down)
    J[4:, 4:] = np.eye(4)
    sig = np.sqrt(np.diag(J @ C[:8, :8] @ J.T))
    assert (np.abs(params - true) < 3 * sig).all(), (params - true) / sig
