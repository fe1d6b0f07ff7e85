"""export stage (PLY, CSV in the user's CRS) and the AICON writer's round trip."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from plyfile import PlyData

from baarda.pipeline.adjustment import BundleSettings, adjust
from baarda.pipeline.crs import local_frame
from baarda.pipeline.errors import InputError
from baarda.pipeline.synthetic.aerial import simulate_aerial
from baarda.pipeline.testing import run_stage
from baarda.plugins.aicon.reader import aicon_block, read_aicon
from baarda.plugins.aicon.writer import write_aicon
from baarda.plugins.export.stage import PointExport


@pytest.fixture(scope="module")
def adjusted():
    rng = np.random.default_rng(5)
    noisy, _ = simulate_aerial(rng, n_strips=2, photos_per_strip=5, points_per_photo=40)
    frame = local_frame("EPSG:32722", [[658550.0, 7166980.0, 890.0]])
    block = noisy.replace(crs=frame.info())
    res = adjust(block, BundleSettings())
    return res.block, res, frame


def _read_csv(path):
    lines = path.read_text().splitlines()
    assert lines[0] == "# crs: EPSG:32722"
    return list(csv.DictReader(lines[1:]))


def test_csv_and_ply_in_the_users_crs(adjusted, tmp_path):
    block, res, frame = adjusted
    out = run_stage(PointExport, {"block": block, "bundle": res}, {"path": "pts", "ply": "binary"}, tmp_path=tmp_path)
    assert out.summary["points"] == len(block.points) and out.summary["with_sigma"] == len(block.points)
    n = len(block.points)
    assert out.summary["headline"].startswith(f"{n} points ({n} with σ, median ")
    assert out.summary["headline"].endswith(" mm) → pts.ply, pts.csv, EPSG:32722 (E N h)")
    rows = _read_csv(tmp_path / "pts.csv")
    utm = np.array([[float(r["E"]), float(r["N"]), float(r["h"])] for r in rows])
    # back to the local frame: the adjusted coordinates (to the CSV's 1 µm rounding)
    assert np.abs(frame.to_local(utm) - block.points.XYZ).max() < 2e-6
    # σ in UTM: J C Jᵀ, J = k·rotation(γ) on E, N: horizontal σ² summed scales with k², height unchanged
    s = np.array([[float(r["sE"]), float(r["sN"]), float(r["sh"])] for r in rows])
    C = res.cov_points
    k2 = np.linalg.det(frame.jacobian(np.zeros((1, 3)))[0][:2, :2])
    assert np.allclose(s[:, 0] ** 2 + s[:, 1] ** 2, k2 * (C[:, 0, 0] + C[:, 1, 1]), rtol=1e-4)
    assert np.allclose(s[:, 2], np.sqrt(C[:, 2, 2]), rtol=1e-4)
    # PLY read by plyfile: same numbers as the CSV, doubles for the coordinates
    ply = PlyData.read(str(tmp_path / "pts.ply"))
    v = ply["vertex"]
    assert ply.byte_order == "<" and not ply.text
    assert v["x"].dtype == np.float64
    assert np.allclose(np.column_stack([v["x"], v["y"], v["z"]]), utm, atol=2e-6, rtol=0)
    assert np.allclose(np.column_stack([v["sx"], v["sy"], v["sz"]]), s, rtol=1e-5)
    assert any(c.startswith("crs ") for c in ply.comments)


def test_ply_ascii_equals_binary_and_header_by_hand(adjusted, tmp_path):
    block, res, _ = adjusted
    run_stage(PointExport, {"block": block, "bundle": res}, {"path": "a", "ply": "ascii", "formats": ["ply"]},
              tmp_path=tmp_path)
    run_stage(PointExport, {"block": block, "bundle": res}, {"path": "b", "formats": ["ply"]}, tmp_path=tmp_path)
    raw = (tmp_path / "b.ply").read_bytes()
    head, _, body = raw.partition(b"end_header\n")
    assert head.startswith(b"ply\nformat binary_little_endian 1.0\n")
    assert f"element vertex {len(block.points)}".encode() in head
    props = [ln.split()[1:] for ln in head.decode().splitlines() if ln.startswith("property")]
    assert props == [["double", "x"], ["double", "y"], ["double", "z"], ["float", "sx"], ["float", "sy"],
                     ["float", "sz"], ["int", "rays"]]
    dt = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("sx", "<f4"), ("sy", "<f4"), ("sz", "<f4"),
                   ("rays", "<i4")])
    by_hand = np.frombuffer(body, dtype=dt)
    asc = PlyData.read(str(tmp_path / "a.ply"))["vertex"]
    for name in ("x", "y", "z"):
        assert np.allclose(by_hand[name], asc[name], atol=1e-6, rtol=0)


def test_export_without_crs_and_without_bundle(tmp_path):
    rng = np.random.default_rng(2)
    noisy, _ = simulate_aerial(rng, n_strips=2, photos_per_strip=4, points_per_photo=20)
    out = run_stage(PointExport, {"block": noisy}, {"path": "p", "formats": ["csv"], "roles": ["full"]},
                    tmp_path=tmp_path)
    lines = (tmp_path / "p.csv").read_text().splitlines()
    assert lines[0].startswith("point,role,X,Y,Z,sX,sY,sZ,rays")
    assert len(lines) - 1 == int((noisy.points.role == "full").sum()) == out.summary["points"]
    assert "nan" in lines[1]
    assert any("σ columns are nan" in w for w in out.warnings)
    assert out.summary["headline"] == (f"{out.summary['points']} points (no σ: no bundle for them) → p.csv, "
                                       "the block's local system")


def test_aicon_round_trip(shared_data, tmp_path):
    export = read_aicon(shared_data / "aicon-closerange" / "example")
    block = aicon_block(export)
    info = write_aicon(block, tmp_path / "copy")
    again = aicon_block(read_aicon(tmp_path / "copy"))
    assert info["measurements"] == len(block.observations)
    for a, b in ((block.cameras, again.cameras), (block.photos, again.photos), (block.points, again.points),
                 (block.observations, again.observations)):
        for name in a._columns:
            x, y = getattr(a, name), getattr(b, name)
            assert np.array_equal(x, y) or np.allclose(x, y, rtol=0, atol=0, equal_nan=True), name
    assert np.array_equal(block.cameras.ap, again.cameras.ap)
    assert block.scale_bars.rows() == again.scale_bars.rows()
    assert dict(block.ap_meta) == dict(again.ap_meta)


def test_aicon_writer_refuses_what_aicon_cannot_hold(tmp_path):
    rng = np.random.default_rng(2)
    noisy, _ = simulate_aerial(rng, n_strips=2, photos_per_strip=4, points_per_photo=20)
    noisy = noisy.replace(cameras=noisy.cameras.replace(ids=np.array(["1"])))
    # simulated ids are whole numbers ("001", "00001"): a block in metres is written in mm and read back
    write_aicon(noisy, tmp_path / "sim")
    back = aicon_block(read_aicon(tmp_path / "sim"), keep_unused=True)
    assert np.allclose(back.photos.X0, noisy.photos.X0 * 1000)
    bad = noisy.replace(points=noisy.points.replace(ids=np.array(["P" + i for i in noisy.points.ids])))
    with pytest.raises(InputError, match="whole-number point ids"):
        write_aicon(bad, tmp_path / "bad")


def test_aicon_export_stage_writes_the_bundles_residuals(shared_data, tmp_path):
    from baarda.plugins.aicon.writer import AiconExportStage

    block = aicon_block(read_aicon(shared_data / "aicon-closerange" / "example"), sigma_image_um=0.5)
    res = adjust(block, BundleSettings(datum="free"))
    out = run_stage(AiconExportStage, {"block": res.block, "bundle": res}, {"path": "out/adj"}, tmp_path=tmp_path)
    assert out.summary["measurements"] == len(block.observations)
    assert out.summary["headline"].endswith(f"{len(block.observations)} measurements, with the bundle's "
                                            "residuals and σ")
    back = read_aicon(tmp_path / "out" / "adj")
    # AICON's residual sign: computed − observed = −v
    assert np.allclose(back.measurements["vxy"], -res.residuals, rtol=0, atol=1e-15)
    sig = np.sqrt(np.einsum("kii->ki", res.cov_points))
    assert np.allclose(back.points["sigma"], sig, rtol=1e-15)
    assert np.allclose(back.images["X0"], res.block.photos.X0, rtol=0, atol=0)
