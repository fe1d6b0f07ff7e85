"""gcp-export: ODM gcp_list.txt written from a block and read back by baarda's reader."""

from __future__ import annotations

import numpy as np
import pytest

from baarda.pipeline.crs import local_frame
from baarda.pipeline.errors import InputError
from baarda.pipeline.testing import check_stage, run_stage
from baarda.plugins.gcp.block import CameraSpec, gcp_block
from baarda.plugins.gcp.reader import read_gcp_list
from baarda.plugins.gcp.writer import GcpExport, gcp_lines, write_gcp_list

CAMERA = CameraSpec("sx260", 4000, 3000, 2904.0, 6.17 / 4000)


@pytest.fixture(scope="module")
def odm(shared_data):
    # the bundled project's list and lines (fixtures/odm/odm-br-gcp.toml): sub-pixel measurements
    gcp = read_gcp_list(shared_data / "odm-br-gcp" / "gcp_list_floatxy_raw.txt", skip_lines=[19, 51, 52, 55, 70])
    frame = local_frame(gcp.crs, gcp.geo)
    block, info = gcp_block(gcp, CAMERA, frame, check=("HV13",), min_points=1)
    return gcp, block


def test_round_trip_of_the_odm_list(odm, tmp_path):
    gcp, block = odm
    info = write_gcp_list(block, tmp_path / "gcp_list.txt")
    back = read_gcp_list(tmp_path / "gcp_list.txt")
    assert back.crs == "EPSG:32722"                       # the frame's CRS (WKT) by its code
    assert back.line[0] == 2 and len(back.line) == len(gcp.line)
    assert info["measurements"] == len(gcp.image) == len(back.image)
    key = {(i, n): k for k, (i, n) in enumerate(zip(gcp.image, gcp.name))}
    order = [key[(i, n)] for i, n in zip(back.image, back.name)]
    assert sorted(order) == list(range(len(gcp.image)))
    # coordinates: local frame → UTM to well under a millimetre; pixels to 1e-6 px
    assert np.abs(back.geo - gcp.geo[order]).max() < 1e-6
    assert np.abs(back.pixel - gcp.pixel[order]).max() < 1e-6


def test_crs_text_as_read_and_another_crs(odm, tmp_path):
    gcp, block = odm
    b = block.replace(meta={**block.meta, "gcp": {**block.meta["gcp"], "crs": gcp.crs}})
    out = run_stage(GcpExport, {"block": b}, {"path": "odm/gcp_list.txt"}, tmp_path=tmp_path)
    back = read_gcp_list(tmp_path / "odm" / "gcp_list.txt")
    assert back.crs == gcp.crs and out.summary["measurements"] == len(gcp.image)
    assert out.summary["headline"].startswith(f"odm/gcp_list.txt (surveyed coordinates, {gcp.crs}): "
                                              f"{len(gcp.image)} measurements of ")
    # geographic: lon, lat in degrees, heights unchanged (same datum)
    run_stage(GcpExport, {"block": b}, {"path": "geo.txt", "crs": "EPSG:4979", "roles": ["check"]}, tmp_path=tmp_path)
    geo = read_gcp_list(tmp_path / "geo.txt")
    assert geo.crs == "EPSG:4979" and set(geo.name) == {"HV13"}
    import pyproj

    t = pyproj.Transformer.from_crs("EPSG:32722", "EPSG:4979", always_xy=True)
    k = gcp.name.index("HV13")
    lon, lat, h = t.transform(*gcp.geo[k])
    assert np.allclose(geo.geo[0], [lon, lat, h], rtol=0, atol=[1e-9, 1e-9, 1e-6])


def test_adjusted_points_and_refusals(odm, tmp_path):
    gcp, block = odm

    class Bundle:                       # what gcp-export reads of a bundle result: its block
        pass

    moved = Bundle()
    XYZ = block.points.XYZ.copy()
    XYZ[:, 2] += 0.25
    moved.block = block.replace(points=block.points.replace(XYZ=XYZ))
    run_stage(GcpExport, {"block": block, "bundle": moved}, {"points": "adjusted"}, tmp_path=tmp_path)
    back = read_gcp_list(tmp_path / "gcp_list.txt")
    assert np.allclose(back.geo[:, 2] - gcp.geo[[gcp.name.index(n) for n in back.name], 2], 0.25, atol=1e-6)
    # after a bundle the pipeline's 'block' is the adjusted one: 'surveyed' takes the bundle's input
    moved.block_in = block
    run_stage(GcpExport, {"block": moved.block, "bundle": moved}, {"path": "s.txt"}, tmp_path=tmp_path)
    # (0.25 m along the origin's vertical is a few µm horizontal at the targets: compare to 10 µm)
    assert np.abs(read_gcp_list(tmp_path / "s.txt").geo - back.geo + [0, 0, 0.25]).max() < 1e-5
    with pytest.raises(InputError, match="needs a bundle") as e:
        run_stage(GcpExport, {"block": block}, {"points": "adjusted"}, tmp_path=tmp_path)
    assert e.value.field == "points"
    local = block.replace(crs=None)
    with pytest.raises(InputError, match="no coordinate reference system"):
        gcp_lines(local)
    # inactive measurements are left out and counted
    act = block.observations.active.copy()
    act[:3] = False
    lines, info = gcp_lines(block.replace(observations=block.observations.replace(active=act)))
    assert info["inactive_left_out"] == 3 and len(lines) == 1 + len(gcp.image) - 3


def test_stage_protocol():
    check_stage(GcpExport, "gcp-export")
