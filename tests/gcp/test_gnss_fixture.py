"""fixtures/gnss/gnss.toml against the truth its generator wrote (fixtures/gnss/truth.csv).

The project reads a DBAT script project in UTM 32N (``crs`` option of the ``dbat`` source), puts
the RTK antenna positions of gnss.csv into the bundle with the lever arm, adjusts with 2 GCPs and
exports the points in UTM.  The adjusted projection centres (local frame, ``bundle_eo.csv``) and
the check and tie points (UTM, ``bundle_points.csv`` and the export's CSV) must agree with the
true values within their reported σ: every |error|/σ < 4.5 and the RMS of the normalised errors
near 1 (an error only 1/3 of what σ says, or 1.6 × it, fails).  Also: the generator is
deterministic (the committed files are what ``make.py`` writes), and the bundle's GNSS section
lists every photo.
"""

from __future__ import annotations

import csv
import importlib.util
import json

import numpy as np
import pytest

from baarda.pipeline.crs import LocalFrame, parse_crs


def _rows(path):
    lines = [ln for ln in path.read_text().splitlines() if ln and not ln.startswith("#")]
    return list(csv.DictReader(lines))


@pytest.fixture(scope="module")
def gnss_run(repo_root, tmp_path_factory):
    from baarda.pipeline.runner import run_project

    out = tmp_path_factory.mktemp("gnss") / "run"
    res = run_project(repo_root / "fixtures" / "gnss" / "gnss.toml", out, verbose=False)
    assert res.ok, res.message
    return out


def _close(x: str, y: str) -> bool:
    try:
        return abs(float(x) - float(y)) <= 1e-6 * max(1.0, abs(float(y)))
    except ValueError:
        return False


def _truth(repo_root):
    t = _rows(repo_root / "fixtures" / "gnss" / "truth.csv")
    return {(r["kind"], r["id"]): np.array([float(r["E"]), float(r["N"]), float(r["h"])]) for r in t}


def test_generator_is_deterministic(repo_root, tmp_path):
    """make.py writes the committed files (a second run in a temporary folder; numbers to 1e-6)."""
    spec = importlib.util.spec_from_file_location("gnss_make", repo_root / "fixtures" / "gnss" / "make.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    info = mod.generate(tmp_path)
    here = repo_root / "fixtures" / "gnss"
    files = ["gnss.csv", "truth.csv"] + [f"dbat/{f}" for f in info["files"]]
    for f in files:
        a, b = (tmp_path / f).read_text().splitlines(), (here / f).read_text().splitlines()
        assert len(a) == len(b), f
        for la, lb in zip(a, b):      # numbers to 1e-6 (another BLAS or PROJ may change the last digits)
            ta, tb = la.replace(",", " ").split(), lb.replace(",", " ").split()
            assert len(ta) == len(tb) and all(x == y or _close(x, y) for x, y in zip(ta, tb)), (f, la, lb)
    assert info["photos"] == 24 and info["control"] == 2 and info["check"] == 6 and info["tie"] >= 250


def test_gnss_fixture_against_truth(repo_root, gnss_run):
    run = gnss_run
    truth = _truth(repo_root)
    res = json.loads((run / "results.json").read_text())
    st = {s["id"]: s for s in res["stages"]}
    assert all(s["status"] == "ok" for s in res["stages"])
    # the frame the source placed: convert the true centres (UTM) into it
    src = st["source"]["summary"]
    assert src["crs"] == "EPSG:32632" and src["control"] == 2 and src["check"] == 6
    frame = LocalFrame(parse_crs("EPSG:32632").to_wkt(), tuple(src["origin_lon_lat_h"]))
    eo = _rows(run / "bundle_eo.csv")
    ids = [r["photo"] for r in eo]
    X0 = np.array([[float(r[k]) for k in ("X0_m", "Y0_m", "Z0_m")] for r in eo])
    sX0 = np.array([[float(r[k]) for k in ("sX0_m", "sY0_m", "sZ0_m")] for r in eo])
    true_c = frame.to_local(np.array([truth[("photo", p)] for p in ids]))
    zc = (X0 - true_c) / sX0
    # the points in UTM with their σ (J C Jᵀ) from the bundle's table
    pts = _rows(run / "bundle_points.csv")
    kinds = {"check": "check", "tie": "tie", "full": "control"}
    P = np.array([[float(r[k]) for k in ("E_crs_m", "N_crs_m", "h_crs_m")] for r in pts])
    sP = np.array([[float(r[k]) for k in ("sE_crs_m", "sN_crs_m", "sh_crs_m")] for r in pts])
    true_p = np.array([truth[(kinds[r["role"]], r["point"].zfill(5))] for r in pts])
    zp = (P - true_p) / sP
    check = np.array([r["role"] == "check" for r in pts])
    err_c = np.linalg.norm(X0 - true_c, axis=1)
    print(f"gnss fixture: centres RMS error {np.sqrt(np.mean(err_c ** 2)) * 1000:.1f} mm, "
          f"|z| max {np.abs(zc).max():.2f}"
          f", RMS z {np.sqrt(np.mean(zc ** 2)):.2f}; points |z| max {np.abs(zp).max():.2f}, RMS z "
          f"{np.sqrt(np.mean(zp ** 2)):.2f}; check points RMS z {np.sqrt(np.mean(zp[check] ** 2)):.2f}, errors (mm) "
          f"{np.round((P - true_p)[check] * 1000, 1).tolist()}")
    assert len(ids) == 24 and check.sum() == 6 and len(pts) == 302
    # every centre and point within 4.5 σ (302 × 3 + 72 normal variates: P(|z| > 4.5) ≈ 7e-6 each)
    assert np.abs(zc).max() < 4.5 and np.abs(zp).max() < 4.5
    assert np.abs(zp[check]).max() < 4.0
    for z in (zc, zp, zp[check]):
        assert 0.5 < np.sqrt(np.mean(z ** 2)) < 1.6
    # the centres are within centimetres (the GNSS σ 1.5–5 cm and 0.5 px rays; the 0.37 m lever arm applied)
    assert np.sqrt(np.mean(err_c ** 2)) < 0.05
    # the export writes the same UTM coordinates
    ex = {r["point"]: r for r in _rows(run / "gnss_points.csv")}
    assert (run / "gnss_points.csv").read_text().splitlines()[0] == "# crs: EPSG:32632"
    for r, p in zip(pts, P):
        e = ex[r["point"]]
        assert np.allclose([float(e["E"]), float(e["N"]), float(e["h"])], p, atol=2e-6)


def test_gnss_section_lists_every_photo(repo_root, gnss_run):
    run = gnss_run
    res = json.loads((run / "results.json").read_text())
    bundle = next(s for s in res["stages"] if s["id"] == "bundle")
    g = bundle["summary"]["gnss"]
    assert g["antennas"] == 24 and g["flagged"] == 0
    tab = _rows(run / "bundle_gnss.csv")
    assert sorted(r["photo"] for r in tab) == [f"{k:03d}" for k in range(1, 25)]
    # the receiver's σ from gnss.csv (sigma_h for E and N, sigma_v for U)
    sig = {r["photo"]: (float(r["sigma_h"]), float(r["sigma_v"]))
           for r in _rows(repo_root / "fixtures" / "gnss" / "gnss.csv")}
    for r in tab:
        assert np.allclose([float(r["sE_m"]), float(r["sN_m"]), float(r["sU_m"])], np.array(sig[r["photo"]])[[0, 0, 1]])
    report = (run / "report.md").read_text()
    assert "### GNSS antennas" in report and "24 antenna positions observed" in report
    # the antennas' share of vᵀPv over their redundancy is near 1 (simulated with the σ they carry)
    assert 0.5 < g["omega"] / g["redundancy"] < 1.6


def test_dbat_source_in_a_crs(tmp_path):
    """The ``dbat`` source's ``crs`` option: control, check and prior-EO coordinates in UTM 32N far
    from the central meridian (meridian convergence 1.9°) land in the local east-north-up frame.
    The truth is a block in a local frame; its prior attitudes in UTM are fitted independently
    (orthogonal Procrustes of the camera-frame vectors to the points against their UTM
    differences; that reference is good to ~2e-5 rad, the curvature over 200 m), so the stage's rotation of the attitudes is checked against geometry, not
    against its own formula."""
    from baarda.pipeline.crs import local_frame
    from baarda.pipeline.geometry import opk_from_rotation_many, rotation_from_opk_many
    from baarda.pipeline.model import FIXED, Cameras
    from baarda.pipeline.synthetic.aerial import simulate_aerial
    from baarda.pipeline.testing import run_stage
    from baarda.plugins.dbat.stage import DbatSource
    from baarda.plugins.dbat.writer import write_dbat

    rng = np.random.default_rng(4)
    _, exact = simulate_aerial(rng, n_strips=2, photos_per_strip=3, points_per_photo=30, control_spacing=1)
    mine = local_frame("EPSG:32632", [[680_000.0, 5_300_000.0, 420.0]])
    pts, ph = exact.points, exact.photos
    utm_pts, utm_X0 = mine.from_local(pts.XYZ), mine.from_local(ph.X0)
    R_local = rotation_from_opk_many(ph.opk)
    R_utm = []
    for k in range(len(ph)):
        v = (pts.XYZ - ph.X0[k]) @ R_local[k].T               # camera-frame vectors (truth)
        u = utm_pts - utm_X0[k]                                # the same in UTM
        U, _, Vt = np.linalg.svd(v.T @ u)
        R_utm.append(U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt)
    opk_utm = opk_from_rotation_many(np.array(R_utm))
    control = pts.role == "full"
    role = np.where(control, "full", np.where(np.arange(len(pts)) % 7 == 0, "check", "tie"))
    cams = exact.cameras
    camera = Cameras.make(["1"], cams.c[0], 0.0, 0.0, ap_model="brown-backward", ap=np.zeros((1, 7)),
                          sigma_iop=[[FIXED] * 3], sigma_ap=[[FIXED] * 7], format_mm=cams.format_mm,
                          pixel_mm=cams.pixel_mm[0], resolution=cams.resolution)
    block = exact.replace(cameras=camera, photos=ph.replace(X0=utm_X0, opk=opk_utm),
                          points=pts.replace(XYZ=np.where((role != "tie")[:, None], utm_pts, np.nan), role=role,
                                             sigma=np.where(control[:, None], np.full((len(pts), 3), 0.02), np.inf)))
    write_dbat(block, tmp_path / "p", name="utm")
    plain = run_stage(DbatSource, {}, {"path": str(tmp_path / "p" / "utm.xml")}, tmp_path=tmp_path)
    assert plain.artefacts["block"].crs is None
    out = run_stage(DbatSource, {}, {"path": str(tmp_path / "p" / "utm.xml"), "crs": "EPSG:32632"}, tmp_path=tmp_path)
    blk = out.artefacts["block"]
    frame = LocalFrame.from_info(blk.crs)
    assert out.summary["crs"] == "EPSG:32632"
    k = blk.points.index_of([str(int(i)) for i in pts.ids[role != "tie"]])   # DBAT ids read as numbers
    assert np.allclose(blk.points.XYZ[k], frame.to_local(utm_pts[role != "tie"]), atol=1e-6)
    assert np.isnan(blk.points.XYZ[blk.points.role == "tie"]).all()
    assert np.allclose(blk.photos.X0, frame.to_local(utm_X0), atol=1e-6)
    # the truth in the stage's frame: the same points, so the rotation from mine to it is the
    # Procrustes fit of the two point sets (a few 1e-6 rad: the origins are ~100 m apart)
    a, b = pts.XYZ - pts.XYZ.mean(0), frame.to_local(utm_pts)
    b = b - b.mean(0)
    U, _, Vt = np.linalg.svd(b.T @ a)
    R_frame = U @ Vt                                           # stage frame ← my frame
    R_true = R_local @ R_frame.T                               # cam ← stage frame
    got = rotation_from_opk_many(blk.photos.opk)
    ang = np.array([np.arccos(np.clip((np.trace(g @ t.T) - 1) / 2, -1, 1)) for g, t in zip(got, R_true)])
    raw = rotation_from_opk_many(opk_utm)                       # UTM attitudes taken as they are
    ang_raw = np.array([np.arccos(np.clip((np.trace(g @ t.T) - 1) / 2, -1, 1)) for g, t in zip(raw, R_true)])
    print(f"dbat crs: attitude error {ang.max():.2e} rad, without the rotation {ang_raw.min():.2e} rad")
    assert ang.max() < 1e-4 and ang_raw.min() > 0.025      # the reference fit itself: ~2e-5 (curvature)
    # dbat-export of the block in its local frame writes the user's CRS again: the control and centres
    # as they were in UTM, and reading that back with the same crs gives the same local block
    info = write_dbat(blk, tmp_path / "back", name="again")
    assert info["crs"] == "EPSG:32632"
    assert "Coordinates in EPSG:32632" in (tmp_path / "back" / "again.xml").read_text()
    back = run_stage(DbatSource, {}, {"path": str(tmp_path / "back" / "again.xml"), "crs": "EPSG:32632"},
                     tmp_path=tmp_path).artefacts["block"]
    assert np.allclose(LocalFrame.from_info(back.crs).from_local(back.points.XYZ[k]), utm_pts[role != "tie"],
                       atol=1e-6)
    assert np.allclose(back.points.XYZ[k], blk.points.XYZ[k], atol=1e-6)
    assert np.allclose(back.photos.X0, blk.photos.X0, atol=1e-6)
    # the CRS rotation comes from a central-difference Jacobian (0.01 m steps on UTM coordinates of
    # ~1e6 m): ~1e-8 rad of rounding each way
    assert np.abs(back.photos.opk - blk.photos.opk).max() < 1e-7


def test_dbat_crs_errors(tmp_path, repo_root):
    from baarda.pipeline.errors import InputError
    from baarda.pipeline.testing import run_stage
    from baarda.plugins.dbat.stage import DbatSource

    xml = repo_root / "fixtures" / "gnss" / "dbat" / "gnss-block.xml"
    with pytest.raises(InputError) as e:
        run_stage(DbatSource, {}, {"path": str(xml), "crs": "EPSG:99999999"}, tmp_path=tmp_path)
    assert e.value.field == "crs"
