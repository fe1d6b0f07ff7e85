"""Compound CRS with heights above a geoid: a synthetic GTX grid (written here, nothing downloaded)
with a known undulation N, found by PROJ through baarda's grid folders; h = H + N into the local
frame, H back out; a missing grid is a clear error, not PROJ's silent ballpark (h = H)."""

from __future__ import annotations

import struct
import subprocess
import sys

import numpy as np
import pyproj
import pytest

from baarda.pipeline.crs import local_frame, use_grid_directories
from baarda.pipeline.errors import InputError

# the grid: a plane in longitude and latitude over 52°W … 48°W, 27°S … 23°S (UTM 22S), so that
# bilinear interpolation reproduces it exactly
LON0, LAT0, STEP, SIZE = -52.0, -27.0, 0.25, 17


def undulation(lon, lat):
    return 20.0 + 2.0 * (np.asarray(lon) - LON0) + 1.5 * (np.asarray(lat) - LAT0)


def write_gtx(path, N: np.ndarray) -> None:
    """NOAA's GTX: big-endian header (south latitude, west longitude, Δlat, Δlon as doubles; rows,
    columns as int32), then float32 rows from south to north, each from west to east."""
    rows, cols = N.shape
    with open(path, "wb") as f:
        f.write(struct.pack(">4d2i", LAT0, LON0, STEP, STEP, rows, cols))
        f.write(np.asarray(N, ">f4").tobytes())


@pytest.fixture(scope="module")
def grids(tmp_path_factory):
    d = tmp_path_factory.mktemp("grids")
    lat = LAT0 + STEP * np.arange(SIZE)
    lon = LON0 + STEP * np.arange(SIZE)
    N = undulation(lon[None, :], lat[:, None])
    write_gtx(d / "baarda_test_geoid.gtx", N)
    # the same plane under the name PROJ looks for when a CRS uses EGM96 heights (EPSG:5773):
    # us_nga_egm96_15.tif, or its former name egm96_15.gtx
    write_gtx(d / "egm96_15.gtx", N)
    before = pyproj.datadir.get_data_dir()
    assert use_grid_directories(d) == [str(d)]
    yield d
    # the rest of the session must not see the synthetic "EGM96"
    from baarda.pipeline import crs

    pyproj.datadir.set_data_dir(before)
    crs._ADDED_GRID_DIRS.discard(str(d))


# three targets of the odm-br-gcp set (UTM 22S) with heights above the geoid
ENH = np.array([[658528.361, 7167002.098, 865.636], [658610.20, 7166950.55, 861.2], [658480.0, 7167120.0, 870.9]])


def _lonlat(enh):
    t = pyproj.Transformer.from_crs("EPSG:32722", "EPSG:4326", always_xy=True)
    lon, lat = t.transform(enh[:, 0], enh[:, 1])
    return np.asarray(lon), np.asarray(lat)


@pytest.mark.parametrize("crs", ["+proj=utm +zone=22 +south +datum=WGS84 +units=m +geoidgrids=baarda_test_geoid.gtx",
                                 "EPSG:32722+5773"])
def test_heights_above_the_geoid_become_ellipsoidal_and_come_back(grids, crs):
    lon, lat = _lonlat(ENH)
    N = undulation(lon, lat)
    assert 27 < N.min() and N.max() < 27.5                   # the plane's value here
    frame = local_frame(crs, ENH)
    # reference: the same points with ellipsoidal heights h = H + N in plain UTM 22S (no geoid),
    # in a frame with the same origin
    ell = local_frame("EPSG:32722", ENH + np.c_[0 * N, 0 * N, N])
    assert frame.origin[2] == pytest.approx(ell.origin[2], abs=1e-9)
    assert frame.origin[2] == pytest.approx(np.mean(ENH[:, 2] + N), abs=1e-9)
    enu = frame.to_local(ENH)
    assert np.abs(enu - ell.to_local(ENH + np.c_[0 * N, 0 * N, N])).max() < 1e-6
    # reported back in the user's CRS (heights above the geoid) to far better than 1 mm
    back = frame.from_local(enu)
    assert np.abs(back - ENH).max() < 1e-6
    # and a point moved 1 m up in the local frame is 1 m higher above the geoid
    up = frame.from_local(enu + [0, 0, 1.0])
    assert np.allclose(up[:, 2] - ENH[:, 2], 1.0, atol=1e-4)


def test_export_reports_heights_above_the_geoid(grids, tmp_path):
    """The whole path: a gcp_list in UTM + EGM96 heights → block in the local frame → export CSV."""
    import csv

    from baarda.pipeline.testing import run_stage
    from baarda.plugins.export.stage import PointExport
    from baarda.plugins.gcp.block import CameraSpec, gcp_block
    from baarda.plugins.gcp.reader import read_gcp_list

    text = "EPSG:32722+5773\n" + "".join(f"{e} {n} {h} {100 + 10 * k} {200 + 5 * k} IMG_1.JPG T{k}\n"
                                         for k, (e, n, h) in enumerate(ENH))
    (tmp_path / "gcp_list.txt").write_text(text)
    gcp = read_gcp_list(tmp_path / "gcp_list.txt")
    frame = local_frame(gcp.crs, gcp.geo)
    block, _ = gcp_block(gcp, CameraSpec("c", 4000, 3000, 2904.0, 0.00155), frame, min_points=1)
    lon, lat = _lonlat(ENH)
    ref = local_frame("EPSG:32722", ENH)                     # same horizontal frame, h read as H
    h = block.points.XYZ[:, 2] + frame.origin[2]            # ellipsoidal heights in the block
    H = ref.to_local(ENH)[:, 2] + ref.origin[2]
    assert np.allclose(h - H, undulation(lon, lat), atol=1e-6)
    run_stage(PointExport, {"block": block}, {"path": "pts", "formats": ["csv"]}, tmp_path=tmp_path)
    rows = list(csv.DictReader(l for l in (tmp_path / "pts.csv").read_text().splitlines() if not l.startswith("#")))
    got = np.array([[float(r["E"]), float(r["N"]), float(r["h"])] for r in rows])
    assert np.abs(got - ENH).max() < 1e-3                    # the CSV's rounding; heights above the geoid
    assert (tmp_path / "pts.csv").read_text().splitlines()[0] == "# crs: EPSG:32722+5773"
    # and a gcp_list.txt written from the block reads back in the compound CRS, heights above the geoid
    from baarda.plugins.gcp.writer import write_gcp_list

    meta = {**block.meta, "gcp": {k: v for k, v in block.meta["gcp"].items() if k != "crs"}}
    write_gcp_list(block.replace(meta=meta), tmp_path / "again.txt")
    again = read_gcp_list(tmp_path / "again.txt")
    assert again.crs == "EPSG:32722+5773" and np.abs(again.geo - ENH).max() < 1e-6


def test_missing_grid_is_a_clear_error(tmp_path):
    """In a fresh process (no grid folder added): the EGM96 grid is not installed here, so PROJ's
    best transformation is unavailable and its fallback would ignore the geoid."""
    code = f"""
import pyproj, sys
from baarda.pipeline.crs import local_frame
from baarda.pipeline.errors import InputError
try:
    local_frame("EPSG:32722+5773", [[658528.361, 7167002.098, 865.6]], path="gcp_list.txt", line=1)
except InputError as e:
    print(str(e)); sys.exit(0)
print("no error"); sys.exit(1)
"""
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "PROJ_USER_WRITABLE_DIRECTORY": str(tmp_path),
           "PROJ_NETWORK": "OFF"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    msg = out.stdout.strip()
    assert msg.startswith("gcp_list.txt:1, field 'crs': CRS 'EPSG:32722+5773'"), msg
    assert "us_nga_egm96_15.tif" in msg and "PROJ_DATA" in msg
    # a PROJ string naming a grid file that is not there
    with pytest.raises(InputError, match=r"need the grid no_such_geoid\.gtx.*PROJ_DATA"):
        local_frame("+proj=utm +zone=22 +south +datum=WGS84 +geoidgrids=no_such_geoid.gtx", ENH)


def test_proj_data_names_a_grid_folder(grids, tmp_path):
    """PROJ_DATA is honoured (pyproj's wheels would use only their own data directory)."""
    code = """
import numpy as np
from baarda.pipeline.crs import local_frame
f = local_frame("EPSG:32722+5773", [[658528.361, 7167002.098, 865.636]])
print(repr(f.origin[2]))
"""
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "PROJ_USER_WRITABLE_DIRECTORY": str(tmp_path),
           "PROJ_NETWORK": "OFF", "PROJ_DATA": str(grids)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60)
    assert out.returncode == 0, out.stderr
    lon, lat = _lonlat(ENH[:1])
    assert float(out.stdout) == pytest.approx(865.636 + undulation(lon, lat)[0], abs=1e-6)
