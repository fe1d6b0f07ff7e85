"""dbat-export: DBAT script projects written from blocks and read back by baarda's dbat reader."""

from __future__ import annotations

import re
import time

import numpy as np
import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.geometry import rotation_from_opk_many
from baarda.pipeline.model import FIXED, FREE
from baarda.pipeline.synthetic.aerial import simulate_convergent
from baarda.pipeline.testing import check_stage, run_stage
from baarda.plugins.dbat.reader import DBAT_SIGN, dbat_block, read_dbat
from baarda.plugins.dbat.writer import DbatExport, dbat_files, write_dbat

AP = np.array([-2.0e-4, 3.0e-7, -1.0e-10, 2.0e-5, -1.5e-5, 1.0e-4, -5.0e-5])    # K1 K2 K3 P1 P2 aspect−1 skew


def synthetic(weighted=True, exact=False):
    """A convergent block in pixels with a brown-backward camera (every parameter non-zero),
    weighted or fixed control, two check points."""
    noisy, error_free = simulate_convergent(np.random.default_rng(3), n_photos=6, n_points=30, model="none",
                                            xp=0.06, yp=-0.04, pixel_mm=0.004, resolution=(6000, 4000))
    block = error_free if exact else noisy
    cams = block.cameras
    sig_ap = np.array([[FREE, FREE, FIXED, FREE, FREE, FIXED, FIXED]])
    cams = cams.replace(ap_model=np.array(["brown-backward"]), ap=AP[None], sigma_ap=sig_ap,
                        sigma_iop=np.array([[FREE, FREE, FREE]]))
    pts = block.points
    ids = np.array([str(100 + k) for k in range(len(pts))])
    role = pts.role.astype(object)
    tie = np.flatnonzero(role == "tie")
    role[tie[:2]] = "check"
    sigma = pts.sigma.copy()
    sigma[role == "full"] = [0.002, 0.002, 0.003] if weighted else 0.0
    sigma[role == "check"] = FREE
    pts = pts.replace(ids=ids, role=role.astype(str), sigma=sigma)
    obs = block.observations
    cov = obs.cov.copy()
    cov[::3] *= 4.0                                       # two σ, as sxb's marks
    photos = block.photos.replace(ids=np.array([f"IMG_{k + 1:04d}" for k in range(len(block.photos))]))
    return block.replace(cameras=cams, points=pts, photos=photos, observations=obs.replace(cov=cov))


def compare(a, b, *, xy_tol=1e-9):
    """Blocks a (written) and b (read back) hold the same camera, flags, points and marks."""
    ca, cb = a.cameras, b.cameras
    assert cb.ap_model.tolist() == ["brown-backward"]
    assert np.allclose([cb.c[0], cb.xp[0], cb.yp[0]], [ca.c[0], ca.xp[0], ca.yp[0]], rtol=0, atol=1e-12)
    assert np.allclose(cb.ap[0], ca.ap[0], rtol=1e-12, atol=1e-18)
    assert np.array_equal(np.isinf(cb.sigma_iop), np.isinf(ca.sigma_iop))
    assert np.array_equal(np.isinf(cb.sigma_ap), np.isinf(ca.sigma_ap[:, :7]))
    assert cb.pixel_mm[0] == pytest.approx(ca.pixel_mm[0], rel=1e-15)
    assert cb.resolution.tolist() == ca.resolution.tolist()
    assert b.photos.ids.tolist() == a.photos.ids.tolist()
    if a.photos.has_orientation.all():
        assert np.abs(b.photos.X0 - a.photos.X0).max() < 1e-12
        assert np.abs(rotation_from_opk_many(b.photos.opk) - rotation_from_opk_many(a.photos.opk)).max() < 1e-13
    else:
        assert not b.photos.has_orientation.any()
    ka = {i: k for k, i in enumerate(a.points.ids.tolist())}
    for k, pid in enumerate(b.points.ids.tolist()):
        j = ka[pid]
        assert b.points.role[k] == a.points.role[j], pid
        if a.points.role[j] != "tie":
            assert np.array_equal(b.points.XYZ[k], a.points.XYZ[j]), pid
        if a.points.role[j] == "full":
            assert np.array_equal(b.points.sigma[k], a.points.sigma[j]), pid
    assert len(b.points) == len(a.points)
    oa = {(a.photos.ids[p], a.points.ids[q]): r for r, (p, q) in enumerate(zip(a.observations.photo, a.observations.point))
          if a.observations.active[r]}
    ob = b.observations
    assert len(ob) == len(oa)
    for r, (p, q) in enumerate(zip(ob.photo, ob.point)):
        ra = oa[(b.photos.ids[p], b.points.ids[q])]
        assert np.abs(ob.xy[r] - a.observations.xy[ra]).max() < xy_tol
        sa = np.sqrt(0.5 * (a.observations.cov[ra, 0, 0] + a.observations.cov[ra, 1, 1]))
        assert np.sqrt(ob.cov[r, 0, 0]) == pytest.approx(sa, rel=1e-12)


@pytest.mark.parametrize("weighted", [True, False])
def test_synthetic_round_trip(tmp_path, weighted):
    block = synthetic(weighted)
    info = write_dbat(block, tmp_path / "p", name="synthetic")
    assert info["weighted_control"] == weighted and info["check"] == 2 and info["orientations"]
    back = dbat_block(read_dbat(tmp_path / "p" / "synthetic.xml"))
    compare(block, back)
    xml = (tmp_path / "p" / "synthetic.xml").read_text()
    # the estimate flags in DBAT's groups where they agree: K1 K2 free, K3 fixed → single tags
    assert "<pp>true</pp>" in xml and "<K1>true</K1>" in xml and "<K3>false</K3>" in xml and "<P>true</P>" in xml
    # DBAT's own conventions in the file: pp from the image corner with y down, the reader's signs
    p, (W, H) = block.cameras.pixel_mm[0], block.cameras.resolution[0]
    pp = re.search(r"<pp>(.*),(.*)</pp>", xml).groups()
    assert float(pp[0]) == pytest.approx(W * p / 2 + 0.06) and float(pp[1]) == pytest.approx(H * p / 2 + 0.04)
    P = re.search(r"<P>(.*),(.*)</P>", xml).groups()
    assert float(P[0]) == DBAT_SIGN[3] * AP[3] and float(P[1]) == DBAT_SIGN[4] * AP[4]
    assert float(re.search(r"<skew>(.*)</skew>", xml).group(1)) == DBAT_SIGN[6] * AP[6]
    assert float(re.search(r"<aspect>(.*)</aspect>", xml).group(1)) == pytest.approx(1 + AP[5], abs=1e-16)
    assert "<eo>loaded</eo>" in xml and "spatial_resection" not in xml and "<prior_eo>" in xml


def test_sxb_orientations_are_written_as_dbat_reports_them(shared_data, tmp_path):
    """sxb adjusted, exported: the prior_eo row of photo 1 (8811.jpg) holds the values DBAT's own
    report prints for it (niclasborlin/dbat data/script/sxb/result/report.txt, DBAT 0.9.1.2; the
    numbers of tests/dbat/test_projects.py) — DBAT's X0 and ω φ κ are baarda's."""
    from baarda.pipeline.adjustment import BundleSettings, adjust

    src = dbat_block(read_dbat(shared_data / "dbat-sxb" / "sxb.xml"))
    res = adjust(src, BundleSettings(datum="control"))
    run_stage(DbatExport, {"block": res.block, "bundle": res}, {"path": "sxb", "name": "sxb"}, tmp_path=tmp_path)
    images = dict(ln.replace(" ", "").split(",") for ln in (tmp_path / "sxb" / "images" / "images.txt")
                  .read_text().splitlines() if ln[0] != "#")
    rows = {r[0].strip(): np.array([float(v) for v in r[1:]]) for r in (
        ln.split(",") for ln in (tmp_path / "sxb" / "prior" / "eo.txt").read_text().splitlines() if ln[0] != "#")}
    n = next(k for k, v in images.items() if v.endswith("8811.jpg"))
    assert np.allclose(rows[n][:3], (999660.940086, 112368.368648, 1916.563176), atol=0.002)
    assert np.allclose(rows[n][3:], (0.829772, -0.417236, -89.914549), atol=2e-5)
    # read back: the orientations are the initial values, to the last digits written
    back = dbat_block(read_dbat(tmp_path / "sxb" / "sxb.xml"))
    assert back.meta["dbat"].eo_initial == "loaded"
    assert np.abs(back.photos.X0 - res.block.photos.X0).max() < 1e-9
    assert np.abs(back.photos.opk - res.block.photos.opk).max() < 1e-14
    assert "spatial_resection" not in back.meta["dbat"].operations


def test_camcal_source_round_trip(shared_data, tmp_path):
    t0 = time.perf_counter()
    src = dbat_block(read_dbat(shared_data / "dbat-camcal" / "camcaldemo.xml"))
    write_dbat(src, tmp_path / "camcal", name="camcal")
    back = dbat_block(read_dbat(tmp_path / "camcal" / "camcal.xml"))
    compare(src, back, xy_tol=1e-12)
    assert back.meta["dbat"].estimate_io == src.meta["dbat"].estimate_io
    assert back.meta["dbat"].image_numbers == src.meta["dbat"].image_numbers
    assert time.perf_counter() - t0 < 3.0


def test_sxb_keeps_weighted_control_check_points_and_two_sigmas(shared_data, tmp_path):
    src = dbat_block(read_dbat(shared_data / "dbat-sxb" / "sxb.xml"))
    write_dbat(src, tmp_path / "sxb", name="sxb")
    back = dbat_block(read_dbat(tmp_path / "sxb" / "sxb.xml"))
    compare(src, back, xy_tol=1e-9)
    assert sorted(back.points.ids[back.points.role == "check"].tolist()) == ["351", "410"]
    sig = {round(float(v), 9) for v in np.sqrt(back.observations.cov[:, 0, 0]) / back.cameras.pixel_mm[0]}
    assert sig == {0.5, 1.0}


def test_refusals(tmp_path):
    block = synthetic()
    cams = block.cameras
    with pytest.raises(InputError, match=r"'brown' model; DBAT projects use PhotoModeler's backward Brown"):
        dbat_files(block.replace(cameras=cams.replace(ap_model=np.array(["brown"]))))
    ids = block.points.ids.copy()
    ids[4] = "A4"
    with pytest.raises(InputError, match="point id 'A4': DBAT's point ids are whole numbers"):
        dbat_files(block.replace(points=block.points.replace(ids=ids)))
    s = cams.sigma_ap.copy()
    s[0, 0] = 1e-5
    with pytest.raises(InputError, match="K1 has the a-priori σ 1e-05"):
        dbat_files(block.replace(cameras=cams.replace(sigma_ap=s)))
    role = block.points.role.astype(object)
    role[np.flatnonzero(role == "full")[0]] = "xy"
    with pytest.raises(InputError, match="'xy' control"):
        dbat_files(block.replace(points=block.points.replace(role=role.astype(str))))
    with pytest.raises(InputError, match="cannot write a DBAT project: camera .* 'brown' model") as e:
        run_stage(DbatExport, {"block": block.replace(cameras=cams.replace(ap_model=np.array(["brown"])))}, {},
                  tmp_path=tmp_path)
    assert e.value.field == "path"


def test_stage_after_a_bundle_takes_the_adjusted_camera_and_the_prior_control(tmp_path):
    block = synthetic()

    class Bundle:                                  # what dbat-export reads of a bundle result
        pass

    b = Bundle()
    b.block_in = block
    adj_pts = block.points.replace(XYZ=block.points.XYZ + 0.001)
    cov = block.observations.cov.copy()
    cov[0, 0, 0] *= 2.0                            # σx ≠ σy: DBAT has one sxy
    b.block = block.replace(cameras=block.cameras.replace(c=block.cameras.c + 0.01), points=adj_pts,
                            observations=block.observations.replace(cov=cov))
    out = run_stage(DbatExport, {"block": b.block, "bundle": b}, {"path": "out/dbat", "name": "adj"},
                    tmp_path=tmp_path)
    assert out.summary["camera"] == "adjusted" and "1 mark(s) with different σ" in out.warnings[0]
    s = out.summary
    assert s["headline"].startswith(f"DBAT project out/dbat/adj.xml (adjusted camera): {s['images']} images, "
                                    f"{s['control']} control (")
    assert f"{s['marks']} marks" in s["headline"]
    back = dbat_block(read_dbat(tmp_path / "out" / "dbat" / "adj.xml"))
    assert back.cameras.c[0] == pytest.approx(block.cameras.c[0] + 0.01, abs=1e-12)
    full = back.points.role == "full"
    k = block.points.index_of(back.points.ids[full].tolist())
    assert np.array_equal(back.points.XYZ[full], block.points.XYZ[k])       # the surveyed values
    src = run_stage(DbatExport, {"block": b.block, "bundle": b}, {"path": "src", "source": True}, tmp_path=tmp_path)
    assert src.summary["camera"] == "source"
    assert dbat_block(read_dbat(tmp_path / "src" / "baarda.xml")).cameras.c[0] == pytest.approx(block.cameras.c[0])


def test_stage_protocol():
    check_stage(DbatExport, "dbat-export")


def test_camcal_adjusted_exported_and_adjusted_again_gives_the_same_solution(shared_data, tmp_path):
    """camcal adjusted (resection, intersection, bundle), its camera written as a DBAT project's
    initial values, that project read and adjusted again: the same minimum (vᵀPv, camera)."""
    from baarda.pipeline.adjustment import BundleSettings, adjust

    src = dbat_block(read_dbat(shared_data / "dbat-camcal" / "camcaldemo.xml"))
    first = adjust(src, BundleSettings())
    run_stage(DbatExport, {"block": first.block, "bundle": first}, {"path": "camcal", "name": "camcal"},
              tmp_path=tmp_path)
    again = dbat_block(read_dbat(tmp_path / "camcal" / "camcal.xml"))
    assert again.cameras.c[0] == pytest.approx(first.block.cameras.c[0], abs=1e-12)
    second = adjust(again, BundleSettings())
    assert second.vtpv == pytest.approx(first.vtpv, rel=1e-9)
    assert abs(second.block.cameras.c[0] - first.block.cameras.c[0]) < 1e-8
    assert np.abs(second.block.cameras.ap[0] - first.block.cameras.ap[0]).max() < 1e-8
    assert second.iterations <= first.iterations
