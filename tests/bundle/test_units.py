"""Units a user recognises: a camera from a pixel source in pixels, one from a mm source in mm.

The conversion of camera parameters (``plugins/bundle/protocol.py`` ``camera_rows``) is checked
against the AP models' own distortion formulas evaluated in pixels; the stage's report, CSV tables
and external-reliability lines against the adjustment's mm numbers divided by the pitch.
"""

from types import SimpleNamespace

import numpy as np

from baarda.pipeline.model import SourceInfo
import pytest

from baarda.pipeline.camera import get_ap_model
from baarda.pipeline.synthetic.closerange import META, TRUE_AP, make_block
from baarda.pipeline.testing import run_stage
from baarda.plugins.bundle.protocol import AP_PIXEL_POWER, camera_rows
from baarda.plugins.bundle.stage import BundleAdjustment

PITCH = 0.0045


def _fake_result(model: str, params, sigma, meta, pixel_source: bool):
    """What ``camera_rows`` reads of a BundleResult: the block's camera and ``camera_table``."""
    names = ["c", "xp", "yp"] + list(get_ap_model(model).params)
    rows = [{"camera": "cam", "parameter": n, "value": float(v), "sigma": float(s), "status": "free",
             "apriori_sigma": float("inf")} for n, v, s in zip(names, params, sigma)]
    cams = SimpleNamespace(ap_model=np.array([model]), pixel_mm=np.array([PITCH]))
    block = SimpleNamespace(cameras=cams, source=SourceInfo(pixel_format="COLMAP" if pixel_source else None))
    return SimpleNamespace(block_in=block, camera_table=lambda j: rows)


@pytest.mark.parametrize("model", ["brown", "aicon", "ebner12", "brown-backward"])
def test_pixel_scaled_parameters_give_the_distortion_in_pixels(model):
    """Δ in px from the model's own formula on px coordinates with the px-scaled parameters (and its
    meta — ebner12's image base, AICON's r0 — in px) equals the mm distortion divided by the pitch."""
    mdl = get_ap_model(model)
    ap = np.array(TRUE_AP.get(model, TRUE_AP["brown"]), float)
    if model == "brown-backward":
        ap = np.array([-1.2e-4, 2e-7, -1e-10, 3e-6, -4e-6, 2e-4, -1e-4])
    c, xp, yp = 25.0, 0.05, -0.03
    params = np.r_[c, xp, yp, ap]
    sigma = np.abs(params) * 0.01 + 1e-9
    res = _fake_result(model, params, sigma, META.get(model, {}), pixel_source=True)
    rows = camera_rows(res, 0)
    assert [r["parameter"] for r in rows] == ["c", "xp", "yp"] + list(mdl.params)
    assert [r["unit"] for r in rows[:3]] == ["px"] * 3
    np.testing.assert_allclose([r["value"] for r in rows[:3]], params[:3] / PITCH, rtol=1e-14)
    ap_px = np.array([r["value"] for r in rows[3:]])
    # σ scale with their value (same factor)
    factor = np.array([r["sigma"] / s for r, s in zip(rows, sigma)])
    np.testing.assert_allclose([r["value"] for r in rows], params * factor, rtol=1e-12)
    meta = dict(META.get(model, {}))
    meta_px = {k: v / PITCH for k, v in meta.items()}
    rng = np.random.default_rng(4)
    x, y = rng.uniform(-15, 15, 50), rng.uniform(-10, 10, 50)
    dx, dy = mdl.distortion(x, y, np.repeat(ap[None], 50, 0), np.full(50, c), meta)
    dxp, dyp = mdl.distortion(x / PITCH, y / PITCH, np.repeat(ap_px[None], 50, 0), np.full(50, c / PITCH), meta_px)
    scale = np.max(np.abs(np.r_[dx, dy])) / PITCH
    np.testing.assert_allclose(dxp, dx / PITCH, rtol=1e-8, atol=1e-10 * scale)
    np.testing.assert_allclose(dyp, dy / PITCH, rtol=1e-8, atol=1e-10 * scale)
    # the unit names follow the powers: K1 (or A1) px⁻², P1 px⁻¹, B1 / b1 dimensionless
    powers = AP_PIXEL_POWER[model]
    for r, k in zip(rows[3:], powers):
        assert r["unit"] == ("1" if k == 0 else "px⁻" + "⁰¹²³⁴⁵⁶⁷⁸⁹"[k])


def test_a_mm_source_keeps_mm_and_an_unknown_model_its_own_units():
    params = np.r_[25.0, 0.05, -0.03, TRUE_AP["brown"]]
    rows = camera_rows(_fake_result("brown", params, params * 0 + 1e-6, {}, pixel_source=False), 0)
    np.testing.assert_array_equal([r["value"] for r in rows], params)
    assert [r["unit"] for r in rows] == ["mm"] * 3 + ["mm⁻²", "mm⁻⁴", "mm⁻⁶", "mm⁻¹", "mm⁻¹", "1", "1"]


def _pixel_block(model="brown"):
    blk, _ = make_block(model=model, n_photos=8, n_points=40, noise_mm=0.001, rng=np.random.default_rng(5))
    cams = blk.cameras
    return blk.replace(source=SourceInfo(path="x", format="COLMAP", pixel_format="COLMAP"),
                       cameras=cams.replace(pixel_mm=np.full(len(cams), PITCH),
                                            resolution=np.tile([8000, 5333], (len(cams), 1))))


def test_stage_report_and_tables_in_pixels_for_a_pixel_source(tmp_path):
    blk = _pixel_block()
    res = run_stage(BundleAdjustment, {"block": blk}, {"tests": {"blunders": "data-snooping"}}, tmp_path=tmp_path)
    b = res.artefacts["bundle"]
    text = res.report
    assert "µm" not in text, [line for line in text.splitlines() if "µm" in line][:5]
    # the camera table: c in px (the adjustment's mm / pitch), K1 in px⁻²
    cam = res.tables["cameras"].columns
    table = {p: (v, s, u) for p, v, s, u in zip(cam["parameter"], cam["value"], cam["sigma"], cam["unit"])}
    mm = {r["parameter"]: r for r in b.camera_table(0)}
    assert table["c"][0] == pytest.approx(mm["c"]["value"] / PITCH, rel=1e-14) and table["c"][2] == "px"
    assert table["K1"][0] == pytest.approx(mm["K1"]["value"] * PITCH ** 2, rel=1e-14) and table["K1"][2] == "px⁻²"
    assert table["B1"][0] == mm["B1"]["value"] and table["B1"][2] == "1"
    assert f"| cam | c | {table['c'][0]:.8g} |" in text
    assert "cameras" not in res.summary          # the rows are the cameras table's (results.json points to it)
    # the observations: coordinates in mm and in pixels (u, v: y down, COLMAP's centre at W/2, H/2),
    # residuals in px = mm / pitch with y down (sign of −v_y), MDB / pitch; units agree with the names
    t = res.tables["observations"]
    obs = t.columns
    xy = np.column_stack([obs["x_mm"], obs["y_mm"]])
    np.testing.assert_array_equal(xy, blk.observations.xy)
    np.testing.assert_allclose(obs["x_px"], xy[:, 0] / PITCH + 4000, rtol=1e-12)
    np.testing.assert_allclose(obs["y_px"], -xy[:, 1] / PITCH + 5333 / 2, rtol=1e-12)
    v = res.data["result"].residuals
    np.testing.assert_allclose(obs["vx_px"], v[:, 0] / PITCH, rtol=1e-12)
    np.testing.assert_allclose(obs["vy_px"], -v[:, 1] / PITCH, rtol=1e-12)
    assert (np.asarray(obs["mdb_x_px"]) > 0).all() and "vx" not in obs and "mdb_x" not in obs
    assert t.units["vy_px"] == "px" and t.units["x_mm"] == "mm" and t.units["wx"] == ""
    # external reliability: the MDB of the largest effect in px
    big = res.summary["external_reliability"]["largest_on_point"]
    assert big["mdb_unit"] == "px" and big["mdb"] == pytest.approx(big["mdb_mm"] / PITCH, rel=1e-12)
    assert f"MDB {big['mdb']:.4g} px) moves point" in text
    # the protocol's camera: the same rows, with their unit
    p = res.summary["protocol"]["cameras"][0]["parameters"]
    assert [q["unit"] for q in p][:4] == ["px", "px", "px", "px⁻²"]


def test_stage_report_in_mm_and_um_for_a_mm_source(tmp_path):
    blk, _ = make_block(model="brown", n_photos=8, n_points=40, noise_mm=0.001, rng=np.random.default_rng(5))
    res = run_stage(BundleAdjustment, {"block": blk}, {}, tmp_path=tmp_path)
    b = res.artefacts["bundle"]
    cam = res.tables["cameras"].columns
    assert set(cam["unit"][:3]) == {"mm"}
    np.testing.assert_array_equal(cam["value"][:10], [r["value"] for r in b.camera_table(0)])
    assert not any(k.endswith("_px") for k in res.tables["observations"].columns)
    big = res.summary["external_reliability"]["largest_on_point"]
    assert big["mdb_unit"] == "µm" and big["mdb"] == pytest.approx(1000 * big["mdb_mm"], rel=1e-12)
    assert " px" not in res.report


def test_network_figure_has_a_marker_and_legend_entry_per_control_role(tmp_path):
    """Full, planimetric and height control, check and tie points: five legend entries, no two
    drawn alike (marker, fill, colour)."""
    import matplotlib

    matplotlib.use("Agg")
    from baarda.plugins.bundle.figures import network

    blk, _ = make_block(model="none", n_photos=8, n_points=40, noise_mm=0.001, n_control=0,
                        rng=np.random.default_rng(2))
    pts = blk.points
    role = np.array(pts.role, dtype=object)
    role[:4], role[4:7], role[7:10], role[10:13] = "full", "xy", "z", "check"
    sigma = np.array(pts.sigma, float)
    sigma[role == "full"] = 1e-4
    sigma[role == "xy"] = [1e-4, 1e-4, np.inf]
    sigma[role == "z"] = [np.inf, np.inf, 1e-4]
    blk = blk.replace(points=pts.replace(role=role.astype(str), sigma=sigma))
    res = run_stage(BundleAdjustment, {"block": blk}, {}, tmp_path=tmp_path)
    fig = network(res.artefacts["bundle"])
    handles, labels = fig.axes[0].get_legend_handles_labels()
    by = dict(zip(labels, handles))
    want = {"full control XYZ (4)", "planimetric control XY (3)", "height control Z (3)", "check points (3)",
            "tie points (27)", "projection centres (8)"}
    assert want <= set(by), labels
    looks = {(h.get_marker(), str(h.get_markerfacecolor()), str(h.get_color())) for lab, h in by.items()}
    assert len(looks) == len(by), looks
    import matplotlib.pyplot as plt

    plt.close(fig)
    # the check-point figure's arrow factor is finite when tie points have no given coordinates
    import dataclasses

    from baarda.plugins.bundle.figures import checkpoint_errors

    b = res.artefacts["bundle"]
    XYZ = np.array(b.block_in.points.XYZ, float)
    XYZ[np.asarray(b.block_in.points.role) == "tie"] = np.nan
    nan_ties = dataclasses.replace(b, block_in=b.block_in.replace(points=b.block_in.points.replace(XYZ=XYZ)))
    fig = checkpoint_errors(nan_ties)
    title = fig.axes[0].get_title()
    assert "nan" not in title and "×" in title, title
    plt.close(fig)
