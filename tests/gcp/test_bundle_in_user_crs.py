"""The bundle reports its points in the user's CRS too: the odm-br-gcp project (UTM 22S, adjusted in
a local east-north-up frame) — bundle_points.csv's *_crs columns against the export stage's CSV
(another code path), and their σ against the local ones (UTM's grid scale factor)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.runner import run_project

from conftest import SHARED_BESIDE, needs_shared_beside

ROOT = Path(__file__).resolve().parents[2]
PROJECT = ROOT / "fixtures" / "odm" / "odm-br-gcp.toml"


def _rows(path: Path) -> list[dict]:
    lines = [ln for ln in path.read_text(encoding="utf-8").splitlines() if not ln.startswith("#")]
    return list(csv.DictReader(lines))


def test_bundle_points_in_the_users_crs(tmp_path):
    if needs_shared_beside(PROJECT):
        pytest.skip(f"reads ../shared/data beside the repository ({SHARED_BESIDE}), absent here")
    out = run_project(PROJECT, tmp_path / "run", verbose=False)
    assert out.ok, out.message
    pts = {r["point"]: r for r in _rows(tmp_path / "run" / "bundle_points.csv")}
    exp = {r["point"]: r for r in _rows(tmp_path / "run" / "odm_points.csv")}
    assert set(exp) <= set(pts)
    for pid, e in exp.items():
        p = pts[pid]
        assert [float(p[k + "_crs_m"]) for k in "ENh"] == pytest.approx([float(e[k]) for k in "ENh"], abs=2e-6)
        assert [float(p["s" + k + "_crs_m"]) for k in "ENh"] == pytest.approx([float(e["s" + k]) for k in "ENh"],
                                                                          rel=1e-5)
        # UTM: horizontal σ scaled by the grid scale factor (≈ 0.9996 near the central meridian), height unchanged
        sl = np.array([float(p[k]) for k in ("sX_m", "sY_m", "sZ_m")])
        su = np.array([float(p["s" + k + "_crs_m"]) for k in "ENh"])
        assert np.hypot(*su[:2]) / np.hypot(*sl[:2]) == pytest.approx(1.0, abs=2e-3)
        assert su[2] == pytest.approx(sl[2], rel=1e-6)
