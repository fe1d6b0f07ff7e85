"""Stage ``testfield-render``: files, artefacts, the truth it keeps, options and errors."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.model import Block, Pairs
from baarda.pipeline.recording import read_recording
from baarda.pipeline.testing import check_stage, log_stage, run_stage
from baarda.pipeline.geometry.image import pixels_from_mm
from baarda.pipeline.adjustment import project_block
from baarda.plugins.testfield.photos import image_size, partial_targets, true_targets, truth_from_meta
from baarda.plugins.testfield.render import RenderedImages, TestFieldRender
from baarda.pipeline.synthetic.testfield import TestFieldConfig, simulate_testfield
from baarda.plugins.targets.blocks import pairs_of_layout
from baarda.plugins.testfield.source import TestFieldSource

COARSE = {"pixel_mm": 0.1, "supersample": 2}     # 1170 × 830 pixels: fast


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("render")
    return run_stage(TestFieldRender, options=COARSE, tmp_path=tmp, seed=3), tmp


def test_protocol():
    check_stage(TestFieldRender)


def test_files_and_artefacts(rendered):
    res, tmp = rendered
    images, block = res.artefacts["images"], res.artefacts["block"]
    assert isinstance(images, RenderedImages) and isinstance(block, Block)
    assert images.photo_ids == tuple(str(p) for p in block.photos.ids) and len(images) == 10
    assert images.size == (1170, 830) and images.pixel_mm == 0.1 and images.camera_ids == ("P31",) * 10
    for pid, path in zip(images.photo_ids, images.paths):
        img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        assert path.endswith(f"images/{pid}.png") and str(tmp) in path
        assert img.dtype == np.uint8 and img.shape == (830, 1170)
        # a bright target at every true centre that lies well inside the image, dark ground elsewhere
        for q, (u, v) in images.targets[pid].items():
            if q not in images.partial[pid]:
                assert img[int(round(v)), int(round(u))] > 150, (pid, q)
        assert np.median(img) < 30
    # the block: no observations, the camera of the images, the simulator's layout and truth
    assert len(block.observations) == 0
    cam = block.cameras
    assert cam.pixel_mm[0] == 0.1 and tuple(cam.resolution[0]) == (1170, 830)
    np.testing.assert_allclose(cam.format_mm[0], [117.0, 83.0])
    assert cam.ap_model[0] == "brown" and np.isinf(cam.sigma_iop[0]).all() and np.isinf(cam.sigma_ap[0]).all()
    assert block.photos.has_orientation.all() and len(block.pairs) == 8
    assert "truth" in block.meta and block.meta["render"]["targets"] == images.targets
    assert res.summary["targets"] == sum(len(t) for t in images.targets.values())
    assert set(res.tables) == {"targets", "camera_truth", "points"} and "photos" in res.figures


def test_true_targets_match_the_bundle_projection(rendered):
    """The ground truth of detection, checked with an independent projection: the bundle's
    collinearity (baarda.pipeline.adjustment) with the true camera written as brown parameters and the true
    orientations — the simulator has its own projection code."""
    res, _ = rendered
    block = res.artefacts["block"]
    truth = truth_from_meta(block.meta)
    names = ("K1", "K2", "K3", "P1", "P2", "B1", "B2")
    cams = block.cameras.replace(c=[truth.c], xp=[truth.xp], yp=[truth.yp],
                                 ap=[[truth.distortion.get(n, 0.0) for n in names]])
    pts = block.points.replace(XYZ=truth.XYZ)
    ph = block.photos.replace(X0=truth.X0, opk=truth.opk)
    true_block = block.replace(cameras=cams, points=pts, photos=ph)
    images = res.artefacts["images"]
    n = 0
    for i, pid in enumerate(images.photo_ids):
        for q, uv in images.targets[pid].items():
            k = int(block.points.index_of([q])[0])
            xy = project_block(true_block, [i], [k])
            np.testing.assert_allclose(pixels_from_mm(xy, images.size, images.pixel_mm)[0], uv, atol=1e-6)
            n += 1
    assert n == res.summary["targets"] >= 78


def test_partial_targets_are_the_ones_at_the_border():
    _, truth = simulate_testfield(TestFieldConfig(), np.random.default_rng(0))
    size = image_size((117.0, 83.0), 0.05)
    assert size == (2340, 1660)
    targets = true_targets(truth, 0.05, size)
    partial = partial_targets(truth, targets, 0.005, 0.05, size)
    # photo 13 sees target 10 6 px from the right border with a 7.5 px radius
    assert partial["13"] == ["10"]
    u, v = targets["13"]["10"]
    assert 2339 - u < 7.5
    # a larger target is cut more often, a tiny one never
    assert sum(map(len, partial_targets(truth, targets, 0.05, 0.05, size).values())) > 1
    assert sum(map(len, partial_targets(truth, targets, 1e-6, 0.05, size, margin_px=0).values())) == 0


def test_input_block_from_the_testfield_stage(tmp_path):
    field = run_stage(TestFieldSource, options={"case": 2, "ap_model": "ebner12"}, tmp_path=tmp_path)
    res = run_stage(TestFieldRender, options={**COARSE, "testfield": {"case": 6}}, inputs={"block": field.artefacts["block"]},
                    tmp_path=tmp_path)
    block = res.artefacts["block"]
    assert block.meta["testfield"]["config"]["case"] == 2          # the input block, not the option
    assert block.cameras.ap_model[0] == "ebner12"
    assert any("dropped" in w for w in res.warnings)
    with pytest.raises(InputError, match="not a simulated test field"):
        run_stage(TestFieldRender, options=COARSE, inputs={"block": block.replace(meta={})}, tmp_path=tmp_path)


def test_same_seed_same_images_other_seed_other_noise(tmp_path):
    a = run_stage(TestFieldRender, options={**COARSE, "folder": "a"}, tmp_path=tmp_path, seed=1)
    b = run_stage(TestFieldRender, options={**COARSE, "folder": "b"}, tmp_path=tmp_path, seed=1)
    c = run_stage(TestFieldRender, options={**COARSE, "folder": "c"}, tmp_path=tmp_path, seed=2)
    img = lambda r: cv2.imread(r.artefacts["images"].paths[0], cv2.IMREAD_UNCHANGED).astype(int)
    assert (img(a) == img(b)).all() and (img(a) != img(c)).any()
    assert (tmp_path / "a" / "11.png").is_file()
    np.testing.assert_array_equal(a.artefacts["block"].points.XYZ, b.artefacts["block"].points.XYZ)


def test_other_files_in_the_folder_are_kept_and_named(tmp_path):
    (tmp_path / "images").mkdir()
    (tmp_path / "images" / "99.png").write_bytes(b"x")
    res = run_stage(TestFieldRender, options=COARSE, tmp_path=tmp_path)
    assert (tmp_path / "images" / "99.png").read_bytes() == b"x" and any("99.png" in w for w in res.warnings)
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "99.png").write_bytes(b"x")
    res = run_stage(TestFieldRender, options={**COARSE, "folder": "mine"}, tmp_path=tmp_path)
    assert (tmp_path / "mine" / "99.png").exists() and any("99.png" in w for w in res.warnings)


@pytest.mark.parametrize("opts, match", [
    ({"testfield": {"sigma_image_um": 4.0}}, "testfield.sigma_image_um does not apply"),
    ({"testfield": {"blunders": []}}, "testfield.blunders does not apply"),
    ({"testfield": {"cases": 5}}, "unknown option 'testfield.cases'"),
    ({"testfield": {"case": "five"}}, "testfield.case"),
    ({"testfield": {"case": 9}}, "case must be one of"),
    ({"pixel_mm": 0.0}, "pixel_mm.: must be greater than 0"),
    ({"supersample": 0}, "field .supersample.: must be at least 1, got 0"),
    ({"folder": "../../x"}, "climbs out of it"),
    ({"folder": "/tmp/x"}, "must be relative to the run directory"),
    ({"sigma_noise": -1.0}, "sigma_noise.: must be at least 0"),
])
def test_bad_options(opts, match, tmp_path):
    with pytest.raises(InputError, match=match):
        run_stage(TestFieldRender, options=opts, tmp_path=tmp_path)


def test_recording(rendered, tmp_path):
    res, _ = rendered
    rec = read_recording(log_stage(TestFieldRender, res, tmp_path / "render.rrd"))
    cols = {e.path: e.columns for e in rec.entities}
    assert any("Image:" in c for c in cols["/render/world/cameras/13/image"])
    assert any("Points2D:positions" in c for c in cols["/render/world/cameras/13/image/true_targets"])
    assert any("Points3D:positions" in c for c in cols["/render/world/targets"])


def test_pairs_of_layout():
    block, _ = simulate_testfield(TestFieldConfig(), np.random.default_rng(0))
    kept = block.replace(photos=block.photos.take([9, 0, 1, 2, 7, 8]), observations=block.observations.take([]),
                         pairs=Pairs(left=[], right=[]))
    pairs = pairs_of_layout(block, kept)
    got = {(str(kept.photos.ids[a]), str(kept.photos.ids[b])) for a, b in zip(pairs.left, pairs.right)}
    assert got == {("11", "12"), ("12", "13"), ("23", "24"), ("24", "25")}


def test_detection_reads_the_images_artefact(rendered, tmp_path):
    """``opencv-targets`` without an ``images`` option takes the render stage's files, photo ids and
    pixel pitch, and keeps the layout's stereo pairs among the photos it uses; without either
    it stops with a message naming the option."""
    from baarda.pipeline.options import parse_options
    from baarda.pipeline.stage import Context
    from baarda.plugins.testfield.truth import detection_errors
    from baarda.plugins.targets.stage import TargetDetection, TargetOptions

    res, _ = rendered
    images, layout = res.artefacts["images"], res.artefacts["block"]
    opts = parse_options(TargetOptions, {"target": "circles", "polarity": "light", "match_radius_px": 25.0})
    assert opts.images == [] and opts.pixel_mm == 0.001                # the default pitch …
    det = TargetDetection().run({"images": images, "block": layout}, opts, Context("targets", project_dir=tmp_path))
    block = det.artefacts["block"]
    assert block.photos.ids.tolist() == list(images.photo_ids)
    assert len(block.pairs) == len(layout.pairs) == 8
    assert [(str(block.photos.ids[a]), str(block.photos.ids[b])) for a, b in zip(block.pairs.left, block.pairs.right)] \
        == [(str(layout.photos.ids[a]), str(layout.photos.ids[b])) for a, b in zip(layout.pairs.left, layout.pairs.right)]
    # … is replaced by the artefact's 0.1 mm: detections land on the true targets (1170 × 830 px images)
    check = detection_errors(block)
    assert len(check.duv) >= 70 and check.extra == [] and np.abs(check.duv).max() < 0.2, check.summary()
    with pytest.raises(InputError, match="option 'images' is empty and no earlier stage wrote an 'images' artefact"):
        TargetDetection().run({"block": layout}, opts, Context("targets", project_dir=tmp_path))
