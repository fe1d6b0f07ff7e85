"""pipeline/crs.py against PROJ's own transformations (EPSG:4979 → EPSG:4978) and the UTM grid
factors (pyproj.Proj.get_factors), and the geodesic (pyproj.Geod)."""

from __future__ import annotations

import numpy as np
import pyproj
import pytest

from baarda.pipeline.crs import (LocalFrame, R_enu_from_ecef, ecef_from_geodetic, geodetic_from_ecef, local_frame,
                                 parse_crs)
from baarda.pipeline.errors import InputError

UTM22S = "+proj=utm +zone=22 +south +datum=WGS84 +units=m +no_defs"


def test_ecef_against_proj_and_inverse():
    rng = np.random.default_rng(1)
    g = np.column_stack([rng.uniform(-180, 180, 200), rng.uniform(-89.9, 89.9, 200), rng.uniform(-500, 9000, 200)])
    t = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    ref = np.column_stack(t.transform(g[:, 0], g[:, 1], g[:, 2]))
    mine = ecef_from_geodetic(g[:, 0], g[:, 1], g[:, 2])
    assert np.abs(mine - ref).max() < 1e-6                 # metres
    back = geodetic_from_ecef(mine)
    assert np.abs(back[:, :2] - g[:, :2]).max() < 1e-10    # degrees
    assert np.abs(back[:, 2] - g[:, 2]).max() < 1e-6


def test_enu_rotation_is_orthonormal_and_up_is_the_normal():
    R = R_enu_from_ecef(-49.4, -25.6)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-15)
    n = ecef_from_geodetic(-49.4, -25.6, 1.0) - ecef_from_geodetic(-49.4, -25.6, 0.0)
    assert np.allclose(R @ n, [0, 0, 1], atol=1e-9)


def test_utm_round_trip_scale_factor_and_convergence():
    xyz = np.array([[658000.0, 7166000.0, 900.0], [659000.0, 7166000.0, 900.0], [658000.0, 7167000.0, 905.0]])
    fr = local_frame(UTM22S, xyz)
    enu = fr.to_local(xyz)
    assert np.abs(fr.from_local(enu) - xyz).max() < 1e-6
    # local distance = geodesic distance (+ the height above the ellipsoid): not the grid distance
    geod = pyproj.Geod(ellps="WGS84")
    g = fr.geodetic(xyz)
    _, _, s = geod.inv(g[0, 0], g[0, 1], g[1, 0], g[1, 1])
    d_local = np.linalg.norm(enu[1] - enu[0])
    R_mean = 6371000.0
    assert abs(d_local - s * (1 + 900.0 / R_mean)) < 2e-3
    f = pyproj.Proj(UTM22S).get_factors(g[0, 0], g[0, 1])
    k = f.meridional_scale
    assert abs(1000.0 / d_local - k * (1 - 900 / R_mean) / (1 + 0) ) < 5e-5
    assert abs(1000.0 - d_local) > 0.1                     # the scale factor matters: 0.24 m in 1 km here
    # Jacobian of local → UTM at the frame's origin: scale k (reduced to the ellipsoid) rotated by
    # the meridian convergence
    J = fr.jacobian(np.zeros((1, 3)))[0]
    lon0, lat0, h0 = fr.origin
    f0 = pyproj.Proj(UTM22S).get_factors(lon0, lat0)
    gam = np.radians(f0.meridian_convergence)
    scale = np.sqrt(abs(np.linalg.det(J[:2, :2])))
    assert abs(scale - f0.meridional_scale * (1 - h0 / R_mean)) < 2e-6
    assert abs(np.arctan2(J[1, 0], J[0, 0]) - gam) < 1e-7
    assert abs(J[2, 2] - 1) < 1e-6


def test_geographic_and_identity_frames():
    lonlat = np.array([[-49.42, -25.61, 890.0], [-49.419, -25.61, 890.0]])
    fr = local_frame("EPSG:4979", lonlat)
    enu = fr.to_local(lonlat)
    assert abs(enu[1, 0] - enu[0, 0] - 100.4) < 1.0          # 0.001° of longitude at 25.6° S ≈ 100.4 m east
    assert np.abs(fr.from_local(enu) - lonlat).max() < 1e-9
    assert fr.axis_names() == ("lon", "lat", "h")
    ident = local_frame(None, lonlat)
    assert ident.is_identity and np.array_equal(ident.to_local(lonlat), lonlat)
    again = LocalFrame.from_info(fr.info())
    assert np.allclose(again.to_local(lonlat), enu)


def test_parse_crs_forms_and_errors():
    assert parse_crs("WGS84 UTM 22S").to_epsg() == 32722
    assert parse_crs("WGS84 UTM 32N").to_epsg() == 32632
    assert parse_crs("EPSG:32722").is_projected
    with pytest.raises(InputError, match="unknown coordinate reference system") as e:
        parse_crs("EPSG:99999999", path="x.txt", line=1)
    assert "x.txt:1" in str(e.value)
    with pytest.raises(InputError, match="UTM zone"):
        parse_crs("WGS84 UTM 75S")
