"""Test-field simulator: geometry against the paper, projection against OpenCV, seeding, noise."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from baarda.pipeline.synthetic.testfield import (BLOCK_PHOTOS, Blunder, CASES, FOCAL_MM, FORMAT_MM, SYSTEMATIC_ERRORS, TABLE1,
                                        TestFieldConfig, constraint_count, control_configuration,
                                        degrees_of_freedom, inside_format, physical_distortion, project_truth,
                                        simulate_testfield, single_model, target_field)


@pytest.fixture(scope="module")
def sim():
    return simulate_testfield(TestFieldConfig(), np.random.default_rng(11))


def test_format_orientation_from_the_papers_coverage():
    """The paper: 1.64 m × 1.18 m at 1.4 m.  Long side horizontal gives 1.61 × 1.14 (ratio 1.41
    against the paper's 1.39); portrait would give 1.14 × 1.61 (ratio 0.71)."""
    w, h = (np.array(FORMAT_MM) * 1.4 / FOCAL_MM)
    assert w == pytest.approx(1.61, abs=0.01) and h == pytest.approx(1.14, abs=0.01)
    assert abs(w / h - 1.64 / 1.18) < 0.05 and abs(h / w - 1.64 / 1.18) > 0.5


def test_block_geometry(sim):
    block, truth = sim
    geo = block.meta["testfield"]["geometry"]
    assert len(block.photos) == 10 and len(block.points) == 21 and len(block.observations) == 78
    assert geo["min_rays"] >= 2                                  # every target in ≥ 2 photos
    assert geo["distance_m"] == pytest.approx(1.4, abs=0.03)     # 1.4 m object distance
    fwd = [f for *_, f in geo["forward_overlap"]]
    assert len(fwd) == 8 and all(0.58 < f < 0.67 for f in fwd)   # ≈ 60 % (63 % with Table 1's bases)
    side = [f for *_, f in geo["side_overlap"]]
    assert len(side) == 5 and all(0.70 < f < 0.77 for f in side)  # Table 1's 0.30 m strip spacing
    for fp in (d["footprint_m"] for d in geo["photos"].values()):
        assert fp[0] == pytest.approx(1.62, abs=0.04) and fp[1] == pytest.approx(1.15, abs=0.03)
    # every observation is inside the format, every target outside a photo is really outside it
    xy, depth = project_truth(truth.XYZ, truth.X0, truth.opk, truth.c, truth.xp, truth.yp, truth.distortion)
    seen = np.zeros(xy.shape[:2], bool)
    seen[block.observations.photo, block.observations.point] = True
    assert inside_format(xy[seen], 2.0).all() and not inside_format(xy[~seen], 2.0).any()
    assert (depth > 0).all()
    # the object: 260 × 120 cm with relief of tens of cm toward the cameras
    ext = np.ptp(truth.XYZ, axis=0)
    assert 2.3 < ext[0] < 2.6 and 1.0 < ext[1] < 1.2 and 0.15 < ext[2] < 0.3
    # approximate EO are the paper's Table 1 with angles 0; truth differs by mm and tenths of a degree
    np.testing.assert_array_equal(block.photos.X0, [TABLE1[p] for p in BLOCK_PHOTOS])
    assert np.all(block.photos.opk == 0)
    d = np.abs(truth.X0 - block.photos.X0)
    assert 0 < d.max() < 0.02 and 0 < np.rad2deg(np.abs(truth.opk)).max() < 0.6
    assert len(block.pairs) == 8


def test_single_model_geometry():
    block, truth = single_model(rng=np.random.default_rng(0))
    geo = block.meta["testfield"]["geometry"]
    assert list(block.photos.ids) == ["A", "B"]
    assert geo["photos"]["A"]["n"] == geo["photos"]["B"]["n"] == 21   # the whole object in the model
    assert geo["distance_m"] == pytest.approx(4.0, abs=0.05)
    assert np.linalg.norm(truth.X0[1] - truth.X0[0]) == pytest.approx(1.0, abs=0.02)
    np.testing.assert_allclose(block.photos.X0[:, :2], [TABLE1["A"][:2], TABLE1["B"][:2]])


def test_control_cases_and_degrees_of_freedom():
    """dof without APs: 40 52 52 71 66 76 (paper 34 46 46 87 82 92, see docs/testfield.md): the
    paper's steps 1→2 (+12), 2 = 3, 5→4 (+5), 4→6 (+5) are kept."""
    dofs = []
    for case in CASES:
        block, _ = simulate_testfield(TestFieldConfig(case=case), np.random.default_rng(0))
        dofs.append(degrees_of_freedom(block))
        roles = control_configuration(case)
        assert len(roles) == 21 and set(roles.values()) <= {"full", "xy", "z", "check"}
        assert list(block.points.role) == [roles[p] for p in block.points.ids]
    assert dofs == [40, 52, 52, 71, 66, 76]
    assert constraint_count(control_configuration(1)) == 7            # exactly the datum
    c2, c3 = control_configuration(2), control_configuration(3)
    assert sorted(c2.values()) == sorted(c3.values()) and c2 != c3     # same count and kinds
    assert {p for p, r in c2.items() if r != "check"} == {p for p, r in c3.items() if r != "check"}
    # same places, other types: case 2 has its XY control inside the block, case 3 on the outline
    _, XYZ = target_field()
    lo, hi = XYZ[:, :2].min(0), XYZ[:, :2].max(0)
    margin = lambda p: np.min(np.r_[XYZ[int(p) - 1, :2] - lo, hi - XYZ[int(p) - 1, :2]])
    xy2 = [p for p, r in c2.items() if r == "xy"]
    xy3 = [p for p, r in c3.items() if r == "xy"]
    assert min(map(margin, xy2)) > 0.25 > max(map(margin, xy3))


def test_projection_against_opencv(sim):
    """project_truth with radial + decentring errors equals cv2.projectPoints (an independent
    implementation) after mapping baarda's mm model to OpenCV's normalised one."""
    cv2 = pytest.importorskip("cv2")
    _, truth = sim
    d = {k: SYSTEMATIC_ERRORS[k] for k in ("K1", "K2", "P1", "P2")}
    c = truth.c
    xy, _ = project_truth(truth.XYZ, truth.X0[:1], truth.opk[:1], c, 0.0, 0.0, d)
    # OpenCV camera: x right, y down, looks down +z  →  flip y and z of baarda's camera frame
    from baarda.pipeline.geometry import rotation_from_opk
    R = np.diag([1.0, -1.0, -1.0]) @ rotation_from_opk(*truth.opk[0])
    rvec, _ = cv2.Rodrigues(R)
    tvec = -R @ truth.X0[0]
    # Δx = x̄(K1 r² + K2 r⁴) + P1 (r² + 2x̄²) + 2 P2 x̄ȳ in mm; with x̄ = c·xn, ȳ = −c·yn (yn down)
    dist = np.array([d["K1"] * c**2, d["K2"] * c**4, -d["P2"] * c, d["P1"] * c, 0.0])
    K = np.array([[c, 0, 0], [0, c, 0], [0, 0, 1.0]])
    uv, _ = cv2.projectPoints(truth.XYZ.reshape(-1, 1, 3), rvec, tvec, K, dist)
    ref = np.column_stack([uv[:, 0, 0], -uv[:, 0, 1]])
    np.testing.assert_allclose(xy[0], ref, atol=1e-9)


def test_systematic_error_size():
    """Corner of the format: radial 37 − 9 µm, decentring ≈ 12 µm: tens of µm."""
    hw, hh = np.array(FORMAT_MM) / 2
    dx, dy = physical_distortion(np.array([hw]), np.array([hh]), SYSTEMATIC_ERRORS)
    assert 0.02 < np.hypot(dx, dy)[0] < 0.06


def test_same_seed_same_block_and_noise_shared_across_cases():
    a, ta = simulate_testfield(TestFieldConfig(case=2), np.random.default_rng(3))
    b, tb = simulate_testfield(TestFieldConfig(case=2), np.random.default_rng(3))
    c, tc = simulate_testfield(TestFieldConfig(case=5), np.random.default_rng(3))
    d, _ = simulate_testfield(TestFieldConfig(case=2), np.random.default_rng(4))
    np.testing.assert_array_equal(a.observations.xy, b.observations.xy)
    np.testing.assert_array_equal(a.points.XYZ, b.points.XYZ)
    np.testing.assert_array_equal(a.observations.xy, c.observations.xy)   # noise independent of case
    np.testing.assert_array_equal(a.points.XYZ, c.points.XYZ)
    assert not np.array_equal(a.observations.xy, d.observations.xy)
    np.testing.assert_array_equal(ta.X0, tc.X0)                          # the field is fixed


def test_noise_and_components():
    cfg = TestFieldConfig(sigma_image_um=40.0, sigma_control_mm=0.5)
    rng = np.random.default_rng(8)
    noise, survey = [], []
    for _ in range(30):
        block, truth = simulate_testfield(cfg, rng)
        np.testing.assert_allclose(block.observations.xy, truth.xy_true + truth.noise, atol=1e-12)
        noise.append(truth.noise)
        survey.append(block.points.XYZ - truth.XYZ)
    noise, survey = np.concatenate(noise), np.concatenate(survey)
    assert np.std(noise) * 1e3 == pytest.approx(40.0, rel=0.05)     # 4680 draws: 1 % standard error
    assert np.std(survey) * 1e3 == pytest.approx(0.5, rel=0.06)     # 1890 draws
    assert np.allclose(block.observations.cov[:, 0, 0], 0.04**2)
    assert np.allclose(block.points.sigma[block.points.role == "full"], 0.5e-3)


def test_systematic_errors_off_and_on():
    on, t_on = simulate_testfield(TestFieldConfig(), np.random.default_rng(0))
    off, t_off = simulate_testfield(TestFieldConfig(with_ap_errors=False), np.random.default_rng(0))
    assert np.all(t_off.systematic == 0) and t_off.c == FOCAL_MM
    rms = np.sqrt(np.mean(t_on.systematic**2)) * 1e3
    assert 10 < rms < 40
    np.testing.assert_allclose(on.observations.xy - off.observations.xy, t_on.systematic, atol=1e-12)


def test_blunders():
    cfg = TestFieldConfig(blunders=(Blunder(photo="12", point="8", dx=0.1, dy=-0.05),))
    block, truth = simulate_testfield(cfg, np.random.default_rng(1))
    clean, _ = simulate_testfield(TestFieldConfig(), np.random.default_rng(1))
    diff = block.observations.xy - clean.observations.xy
    k = [i for i, (p, q) in enumerate(block.observation_ids()) if (p, q) == ("12", "8")]
    np.testing.assert_allclose(diff[k[0]], [0.1, -0.05])
    assert np.count_nonzero(diff) == 2
    with pytest.raises(ValueError, match="does not observe"):
        simulate_testfield(dataclasses.replace(cfg, blunders=(Blunder(photo="11", point="1", dx=1),)),
                           np.random.default_rng(1))
    with pytest.raises(ValueError, match="a blunder is a Blunder"):          # no dict records
        simulate_testfield(dataclasses.replace(cfg, blunders=({"photo": "12", "point": "8"},)),
                           np.random.default_rng(1))


def test_ap_model_columns_and_ebner_base():
    block, _ = simulate_testfield(TestFieldConfig(ap_model="ebner12", calibrate_iop=True), np.random.default_rng(0))
    assert block.cameras.ap.shape == (1, 12) and np.isinf(block.cameras.sigma_ap).all()
    assert np.isinf(block.cameras.sigma_iop).all()
    assert block.ap_meta["P31"]["b"] == pytest.approx(0.6 * FOCAL_MM / 1.4, rel=0.03)


def test_bad_config():
    with pytest.raises(ValueError):
        TestFieldConfig(case=7)
    # the option table's bounds hold for a config built in Python too (one mechanism)
    with pytest.raises(ValueError, match="sigma_image_um: must be greater than 0"):
        TestFieldConfig(sigma_image_um=0.0)
    with pytest.raises(ValueError, match="margin_mm: must be greater than 0"):
        TestFieldConfig(margin_mm=-1.0)
    assert TestFieldConfig().sigma_image_mm == pytest.approx(0.040)
    with pytest.raises(ValueError):
        simulate_testfield(TestFieldConfig(ap_model="nonsense"), np.random.default_rng(0))


def test_bundle_recovers_the_truth_without_noise():
    """The simulator and the bundle are independent implementations of the same model: with
    (practically) no noise, a self-calibrating bundle with the 'brown' model returns the true
    orientations, points, c, xp, yp and systematic-error parameters of the simulation."""
    bundle = pytest.importorskip("baarda.pipeline.adjustment")
    cfg = TestFieldConfig(case=6, sigma_image_um=1e-6, sigma_control_mm=1e-9, ap_model="brown", calibrate_iop=True)
    block, truth = simulate_testfield(cfg, np.random.default_rng(0))
    res = bundle.adjust(block, bundle.BundleSettings(tol_obs=1e-8, max_iter=50))
    np.testing.assert_allclose(res.state.X0, truth.X0, atol=1e-8)          # measured 2.5e-10 m
    np.testing.assert_allclose(res.state.opk, truth.opk, atol=1e-8)
    np.testing.assert_allclose(res.state.XYZ, truth.XYZ, atol=1e-8)
    c, xp, yp, K1, K2, K3, P1, P2, B1, B2 = res.state.cam_params[0]
    np.testing.assert_allclose([c, xp, yp], [truth.c, truth.xp, truth.yp], atol=1e-6)
    d = truth.distortion
    np.testing.assert_allclose([K1, K2, P1, P2, B1, B2], [d["K1"], d["K2"], d["P1"], d["P2"], d["B1"], d["B2"]],
                               rtol=1e-4)
    assert abs(K3) < 1e-15
