"""AICON reader: the conventions reproduce the exported image coordinates; broken inputs fail clearly."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from baarda.pipeline.errors import InputError
from baarda.plugins.aicon.reader import aicon_block, perturb_initial_values, read_aicon, resolve_prefix


@pytest.fixture(scope="module")
def export_dir(shared_data):
    d = shared_data / "aicon-closerange"
    if not (d / "example.ior").exists():
        pytest.skip(f"AICON export not found in {d}")
    return d


@pytest.fixture(scope="module")
def block(export_dir):
    return aicon_block(read_aicon(export_dir / "example"))


def _project_aicon(X, X0, omega, phi, kappa, c_aicon, x0, y0, A, r0, B, C):
    """Independent AICON projection written from data/README.md, with AICON's own numbers (c < 0).

    Rotation written out element by element (not baarda.pipeline.geometry): M = R3(κ) R2(φ) R1(ω);
    x = x0 + c_AICON · U/W + Δx, distortion at the projected reduced coordinates.
    """
    so, co = np.sin(omega), np.cos(omega)
    sp, cp = np.sin(phi), np.cos(phi)
    sk, ck = np.sin(kappa), np.cos(kappa)
    m = np.array([
        [cp * ck, co * sk + so * sp * ck, so * sk - co * sp * ck],
        [-cp * sk, co * ck - so * sp * sk, so * ck + co * sp * sk],
        [sp, -so * cp, co * cp],
    ])
    d = (X - X0) @ m.T
    xb = c_aicon * d[:, 0] / d[:, 2]
    yb = c_aicon * d[:, 1] / d[:, 2]
    r2 = xb**2 + yb**2
    dr = sum(a * (r2 ** (i + 1) - r0 ** (2 * (i + 1))) for i, a in enumerate(A))
    dx = xb * dr + B[0] * (r2 + 2 * xb**2) + 2 * B[1] * xb * yb + C[0] * xb + C[1] * yb
    dy = yb * dr + B[1] * (r2 + 2 * yb**2) + 2 * B[0] * xb * yb
    return np.column_stack([x0 + xb + dx, y0 + yb + dy])


def _raw(export_dir):
    ior = (export_dir / "example.ior").read_text().split()
    c, x0, y0, a1, a2, r0, a3, b1, b2, c1, c2 = map(float, ior[2:13])
    eor = {int(r[0]): r for r in np.loadtxt(export_dir / "example.eor")}
    obc = {int(r[0]): r for r in np.loadtxt(export_dir / "example.obc")}
    phc = np.loadtxt(export_dir / "example.phc")
    return (c, x0, y0, (a1, a2, a3), r0, (b1, b2), (c1, c2)), eor, obc, phc


def test_independent_projection_reproduces_phc(export_dir):
    """Project .obc through .eor/.ior with the file's own numbers: the active measurements are
    reproduced to their adjustment residuals (≈ 0.4 µm RMS), and the difference equals AICON's
    own residual columns (sign: AICON prints computed − observed)."""
    cam, eor, obc, phc = _raw(export_dir)
    c, x0, y0, A, r0, B, C = cam
    rows = [r for r in phc if int(r[1]) in obc and r[9] == 1]
    assert len(rows) == 9972
    xy = np.empty((len(rows), 2))
    for img in sorted({int(r[0]) for r in rows}):
        sel = [k for k, r in enumerate(rows) if int(r[0]) == img]
        X = np.array([obc[int(rows[k][1])][1:4] for k in sel])
        e = eor[img]
        xy[sel] = _project_aicon(X, e[2:5], e[5], e[6], e[7], c, x0, y0, A, r0, B, C)
    obs = np.array([r[2:4] for r in rows])
    v = obs - xy
    rms_um = np.sqrt(np.mean(v**2, axis=0)) * 1e3
    assert np.all(rms_um < 0.5), rms_um              # measured: 0.418 / 0.369 µm
    assert np.abs(v).max() < 3e-3                     # a few µm at most
    v_file = -np.array([r[6:8] for r in rows])
    assert np.sqrt(np.mean((v - v_file) ** 2)) < 1e-5  # 0.002 µm: AICON's residuals themselves


def test_block_conventions_reproduce_phc(block):
    """The block's numbers (c > 0, baarda's ω φ κ, the bundle's 'aicon' AP order) projected with
    baarda.pipeline.geometry give the same coordinates as the file: baarda's conventions are AICON's."""
    from baarda.pipeline.geometry import rotation_from_opk_many

    cam = block.cameras
    assert cam.ap_model[0] == "aicon" and cam.c[0] == pytest.approx(28.78507)
    A1, A2, A3, B1, B2, C1, C2 = cam.ap[0]
    r0 = block.ap_meta[cam.ids[0]]["r0"]
    assert r0 == block.meta["aicon"].r0[cam.ids[0]] == 13.488
    obs = block.observations
    act = obs.active
    ph, pt = block.photos, block.points
    R = rotation_from_opk_many(ph.opk)[obs.photo[act]]
    d = np.einsum("nij,nj->ni", R, pt.XYZ[obs.point[act]] - ph.X0[obs.photo[act]])
    xb, yb = -cam.c[0] * d[:, 0] / d[:, 2], -cam.c[0] * d[:, 1] / d[:, 2]
    r2 = xb**2 + yb**2
    dr = A1 * (r2 - r0**2) + A2 * (r2**2 - r0**4) + A3 * (r2**3 - r0**6)
    x = cam.xp[0] + xb + xb * dr + B1 * (r2 + 2 * xb**2) + 2 * B2 * xb * yb + C1 * xb + C2 * yb
    y = cam.yp[0] + yb + yb * dr + B2 * (r2 + 2 * yb**2) + 2 * B1 * xb * yb
    v = obs.xy[act] - np.column_stack([x, y])
    assert np.sqrt(np.mean(v**2)) * 1e3 < 0.5
    np.testing.assert_allclose(v, block.meta["aicon"].residuals_file[act], atol=2e-5)


def test_bundle_aicon_model_agrees(block):
    """The bundle's 'aicon' AP model gives the same distortion as the formula above."""
    apmodels = pytest.importorskip("baarda.pipeline.camera")
    model = apmodels.get_ap_model("aicon")
    assert tuple(model.params) == ("A1", "A2", "A3", "B1", "B2", "C1", "C2")
    xb = np.array([-15.0, 3.0, 12.0])
    yb = np.array([9.0, -11.0, 0.5])
    p = np.broadcast_to(block.cameras.ap[0], (3, 7))
    dx, dy = model.distortion(xb, yb, p, np.full(3, block.cameras.c[0]), block.ap_meta["1"])
    A1, A2, A3, B1, B2, C1, C2 = block.cameras.ap[0]
    r2, r0 = xb**2 + yb**2, 13.488
    dr = A1 * (r2 - r0**2) + A2 * (r2**2 - r0**4)
    np.testing.assert_allclose(dx, xb * dr + B1 * (r2 + 2 * xb**2) + 2 * B2 * xb * yb + C1 * xb + C2 * yb, atol=1e-12)
    np.testing.assert_allclose(dy, yb * dr + B2 * (r2 + 2 * yb**2) + 2 * B1 * xb * yb, atol=1e-12)


def test_counts_flags_and_scale(block, export_dir):
    s = block.summary()
    assert (s["photos"], s["points"]) == (115, 150)
    assert s["observations"] == 10030 and s["active_observations"] == 9972
    assert block.meta["aicon"].disabled_measurements == 58
    assert block.scale_bars.rows() == [("506", "507", 1389.688, 0.01)]
    assert block.object_unit == "mm"
    # as AICON ran it: A1 A2 B1 B2 free, A3 (= 0), C1, C2 fixed at the file's values; IOP free
    assert list(np.isinf(block.cameras.sigma_ap[0])) == [True, True, False, True, True, False, False]
    assert (block.cameras.sigma_ap[0, [2, 5, 6]] == 0).all()
    every = aicon_block(read_aicon(export_dir), free_ap=None)       # every non-zero parameter free
    assert list(np.isinf(every.cameras.sigma_ap[0])) == [True, True, False, True, True, True, True]
    with pytest.raises(ValueError, match="free_ap: 'K1'"):
        aicon_block(read_aicon(export_dir), free_ap=("A1", "K1"))
    assert np.isinf(block.cameras.sigma_iop).all()
    assert block.cameras.pixel_mm[0] == pytest.approx(35.968 / 8688)
    # every point left has at least two active rays
    act = block.observations.active
    assert np.bincount(block.observations.point[act], minlength=150).min() >= 2
    full = aicon_block(read_aicon(export_dir), keep_unused=True)
    assert full.summary()["observations"] == 10366 and full.summary()["points"] == 195
    assert np.isnan(full.points.XYZ[full.points.index_of(["1087"])]).all()


def test_export_info_is_typed_frozen_and_pickles(block):
    """What the source keeps of the export (``meta["aicon"]``) is a frozen :class:`AiconInfo`:
    arrays read-only (also after pickling: blocks go to worker processes), mappings read-only."""
    import dataclasses
    import pickle

    from baarda.plugins.aicon.reader import AiconExported, AiconInfo

    a = block.meta["aicon"]
    assert isinstance(a, AiconInfo) and a.perturbation is None and a.exported is None
    assert a.dropped_points == len(a.dropped_without_coordinates) + len(a.dropped_few_rays) == 45
    assert a.residuals_file.shape == (len(block.observations), 2)
    assert a.point_sigma_file.shape == (len(block.points), 3)
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.prefix = "x"
    with pytest.raises(TypeError):
        a.r0["1"] = 0.0
    p = dataclasses.replace(a, exported=AiconExported(X0=block.photos.X0, opk=block.photos.opk, c=block.cameras.c,
                                                      ap=block.cameras.ap, XYZ=block.points.XYZ))
    again = pickle.loads(pickle.dumps(block.replace(meta={"aicon": p}))).meta["aicon"]
    for arr in (again.residuals_file, again.point_sigma_file, again.exported.X0, again.exported.XYZ):
        with pytest.raises(ValueError):
            arr[0] = 0.0
    np.testing.assert_array_equal(again.residuals_file, a.residuals_file)
    np.testing.assert_array_equal(again.exported.ap, block.cameras.ap)
    assert dict(again.r0) == dict(a.r0) and again.dropped_few_rays == a.dropped_few_rays


def test_prefix_forms(export_dir):
    assert resolve_prefix(export_dir) == export_dir / "example"
    assert resolve_prefix(export_dir / "example.phc") == export_dir / "example"
    assert resolve_prefix(export_dir / "example") == export_dir / "example"


def test_perturbation_is_seeded_and_leaves_input(block):
    a = perturb_initial_values(block, np.random.default_rng(5), sigma_position=50.0, sigma_angle_deg=1.0,
                               sigma_c=0.2, zero_distortion=True)
    b = perturb_initial_values(block, np.random.default_rng(5), sigma_position=50.0, sigma_angle_deg=1.0,
                               sigma_c=0.2, zero_distortion=True)
    np.testing.assert_array_equal(a.photos.X0, b.photos.X0)
    # free parameters start at 0; fixed ones (C1, C2) keep the file's values, A3 stays 0
    free = block.cameras.sigma_ap[0] != 0
    assert np.all(a.cameras.ap[0, free] == 0) and np.any(block.cameras.ap[0, free] != 0)
    np.testing.assert_array_equal(a.cameras.ap[0, ~free], block.cameras.ap[0, ~free])
    d = a.photos.X0 - block.photos.X0
    assert 35 < np.std(d) < 65                      # σ 50 mm over 345 draws
    np.testing.assert_array_equal(a.cameras.sigma_ap, block.cameras.sigma_ap)
    np.testing.assert_array_equal(a.points.XYZ, block.points.XYZ)


# ---------------------------------------------------------------------------------------------
# broken inputs


@pytest.fixture
def copy(export_dir, tmp_path):
    for f in export_dir.glob("example.*"):
        shutil.copy(f, tmp_path / f.name)
    return tmp_path


def _edit(path, line_no, fn):
    lines = path.read_text().splitlines()
    lines[line_no - 1] = fn(lines[line_no - 1])
    path.write_text("\n".join(lines) + "\n")


def test_missing_file(copy):
    (copy / "example.eor").unlink()
    with pytest.raises(InputError) as e:
        read_aicon(copy / "example")
    assert e.value.path.endswith("example.eor") and "not found" in e.value.message


def test_missing_scale_is_optional(copy):
    (copy / "example.scale").unlink()
    assert read_aicon(copy / "example").scales == []


def test_bad_number_in_phc(copy):
    _edit(copy / "example.phc", 17, lambda s: s.replace(s.split()[2], "7.1x0", 1))
    with pytest.raises(InputError) as e:
        read_aicon(copy / "example")
    assert (e.value.line, e.value.field) == (17, "x") and e.value.path.endswith("example.phc")
    assert "7.1x0" in str(e.value)


def test_bad_number_in_ior(copy):
    _edit(copy / "example.ior", 3, lambda s: s.replace("5.79843e-006", "5.79843e-00x"))
    with pytest.raises(InputError) as e:
        read_aicon(copy)
    assert (e.value.line, e.value.field) == (3, "B1")


def test_unknown_image_in_phc(copy):
    _edit(copy / "example.phc", 5, lambda s: "     999" + s[8:])
    with pytest.raises(InputError) as e:
        read_aicon(copy / "example")
    assert (e.value.line, e.value.field) == (5, "image") and "unknown image 999" in e.value.message


def test_unknown_camera_in_eor(copy):
    _edit(copy / "example.eor", 2, lambda s: s.replace("      1   ", "      7   ", 1))
    with pytest.raises(InputError) as e:
        read_aicon(copy / "example")
    assert (e.value.line, e.value.field) == (2, "camera")


def test_short_line_and_duplicates(copy):
    _edit(copy / "example.obc", 3, lambda s: " ".join(s.split()[:2]))
    with pytest.raises(InputError) as e:
        read_aicon(copy / "example")
    assert e.value.line == 3 and e.value.path.endswith("example.obc")


def test_duplicate_active_measurement(copy):
    lines = (copy / "example.phc").read_text().splitlines()
    lines.insert(1, lines[0])
    (copy / "example.phc").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as e:
        read_aicon(copy / "example")
    assert (e.value.line, e.value.field) == (2, "point") and "twice" in e.value.message


def test_scale_bar_to_unknown_point(copy):
    (copy / "example.scale").write_text('         0 "Scalebar"        506        999   1389.6880      0.0100  1\n')
    with pytest.raises(InputError) as e:
        aicon_block(read_aicon(copy / "example"))
    assert (e.value.line, e.value.field) == (1, "point_b")
