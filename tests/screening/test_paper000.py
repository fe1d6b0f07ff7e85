"""Helmert screening against paper 000 Table 3 (residuals) and the mis-transcribed coordinate.

Reference values are the paper's printed residual columns (../shared/seeds/000_…txt, Table 3),
copied here; the fixtures are built from the printed coordinate columns.
"""

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from baarda.pipeline.testing import run_stage
from baarda.plugins.comparator.stage import ComparatorSource
from baarda.plugins.screening.helmert import helmert_design
from baarda.plugins.screening.stage import HelmertScreening

FIX = Path(__file__).resolve().parents[2] / "fixtures" / "paper000"

# Table 3 as printed: X_L, Y_L, X_R, Y_R (mm)
PRINTED = np.array([
    [97.673, 180.515, 75.083, 80.475], [128.692, 180.423, 105.792, 80.359],
    [158.014, 180.618, 134.627, 80.543], [93.523, 160.744, 70.903, 60.735],
    [124.946, 160.523, 102.244, 60.468], [156.755, 159.548, 133.771, 59.456],
    [93.115, 142.816, 70.361, 42.833], [124.410, 141.949, 101.549, 41.913],
    [151.576, 141.152, 132.787, 41.063]])
# Table 3 residual columns Vx, Vy for Data 1, 2, 3 (mm)
V_PAPER = {
    1: [[-0.053, -0.121], [-0.557, -0.453], [-1.324, -0.758], [-0.134, 0.142], [1.479, 1.785],
        [-1.119, -0.560], [-0.443, 0.345], [-0.860, -0.012], [2.904, -0.368]],
    2: [[-0.139, -0.343], [-0.854, -0.748], [-1.720, -1.122], [-0.359, -0.004], [3.148, 3.566],
        [-1.560, -0.850], [-0.708, 0.260], [-1.233, -0.167], [3.424, -0.593]],
    3: [[-0.256, -0.453], [-0.966, -0.855], [-1.827, -1.228], [-0.475, -0.117], [4.037, 4.455],
        [-1.666, -0.959], [-0.823, 0.144], [-1.343, -0.281], [3.319, -0.705]],
}
# SPEC §1: gross errors added to the right image (point index, coordinate, size mm)
GROSS = {1: [(4, 0, 2.0), (4, 1, 2.0), (8, 0, 4.0)], 2: [(4, 0, 4.0), (4, 1, 4.0), (8, 0, 5.0)],
         3: [(4, 0, 5.0), (4, 1, 5.0), (8, 0, 5.0)]}
HALF_UNIT = 0.0005 + 1e-9  # printed to 0.001 mm


def residuals(table):
    """Independent reference: plain numpy least squares, v = l − A x̂."""
    A = helmert_design(table[:, :2])
    l = table[:, 2:].reshape(-1)
    x, *_ = np.linalg.lstsq(A, l, rcond=None)
    return (l - A @ x).reshape(-1, 2)


def with_errors(table, k):
    t = table.copy()
    for i, c, d in GROSS[k]:
        t[i, 2 + c] += d
    return t


def screen(name, tmp_path, **opts):
    src = run_stage(ComparatorSource, {}, {"path": str(FIX / f"{name}.cmp")}, tmp_path=tmp_path)
    return run_stage(HelmertScreening, {"block": src.artefacts["block"]}, opts, tmp_path=tmp_path)


def test_the_misprint_is_left_x_of_point_9():
    # Search every one of the 36 printed coordinates for a single correction that makes the
    # Data 2 and Data 3 residual columns come out as printed.  Only x_L of point 9 works, +4.000 mm.
    fits = []
    for i in range(9):
        for c in range(4):
            def misfit(d):
                t = PRINTED.copy()
                t[i, c] += d
                return max(np.abs(residuals(with_errors(t, k)) - V_PAPER[k]).max() for k in (2, 3))
            best = min((minimize_scalar(misfit, bounds=(s - 1.5, s + 1.5), method="bounded")
                        for s in range(-9, 10, 3)), key=lambda r: r.fun)
            fits.append((best.fun, i, c, best.x))
    fits.sort()
    err, i, c, d = fits[0]
    assert (i, c) == (8, 0) and d == pytest.approx(4.0, abs=0.002) and err < HALF_UNIT
    assert fits[1][0] > 0.05  # no other single coordinate comes close


@pytest.mark.parametrize("k", [2, 3])
def test_data2_data3_residuals_match_table3(tmp_path, k):
    res = screen(f"data{k}", tmp_path)
    v = np.array(res.tables["observations"].columns["v_mm"]).reshape(-1, 2)
    diff = np.abs(v - np.array(V_PAPER[k]))
    print(f"Data {k}: max |v − Table 3| = {diff.max():.5f} mm")
    assert diff.max() < HALF_UNIT


def test_data1_residuals_match_table3_except_a_sign(tmp_path):
    # 17 of 18 match to 0.001 mm; Vx of point 1 is printed −0.053, the adjustment gives +0.053:
    # a sign lost in printing (no single coordinate change explains it, see docs/screening.md).
    res = screen("data1", tmp_path)
    v = np.array(res.tables["observations"].columns["v_mm"]).reshape(-1, 2)
    paper = np.array(V_PAPER[1])
    diff = np.abs(v - paper)
    diff[0, 0] = 0.0
    print(f"Data 1: max |v − Table 3| (without Vx1) = {diff.max():.5f} mm; Vx1 = {v[0, 0]:+.4f}")
    assert diff.max() < HALF_UNIT
    assert v[0, 0] == pytest.approx(-paper[0, 0], abs=HALF_UNIT)


def test_screening_points_at_the_misprint(tmp_path):
    res = screen("printed", tmp_path)
    pair = res.summary["pairs"][0]
    # the largest |w| (= largest |τ|) is at x of point 9, Pope flags it alone, |v| > 2 mm there only
    assert pair["most_suspicious"]["row"] == "X9"
    assert pair["flagged"]["pope"] == ["X9"]
    assert pair["flagged"]["threshold"] == ["X9"]
    assert pair["swaps"] == []
    # the estimated error is the misprint's size (4 mm in x_L ≈ 4.03 mm in x_R) give or take the smear
    assert 3.8 < pair["most_suspicious"]["nabla_hat"] < 4.4
    assert pair["global_test"]["rejected"]
    assert res.summary["flagged_observations"] == [["R", "9"]]
    # corrected table: σ̂0 drops from 0.99 to 0.143 mm
    base = screen("base", tmp_path)
    assert pair["sigma0_hat"] == pytest.approx(0.9905, abs=1e-4)
    assert base.summary["pairs"][0]["sigma0_hat"] == pytest.approx(0.1426, abs=1e-4)
    assert "X9" not in base.summary["pairs"][0]["flagged"]["pope"]
    print("printed:", pair["most_suspicious"], "; base σ̂0:", base.summary["pairs"][0]["sigma0_hat"])


def test_sign_of_estimated_error_is_the_added_error(tmp_path):
    # conventions: ∇̂ has the sign of the error added to the observation (+4 mm at X9 in Data 1)
    res = screen("data1", tmp_path)
    cols = res.tables["observations"].columns
    i = cols["label"].index("X9")
    assert cols["v_mm"][i] > 0 and 3.5 < cols["nabla_hat_mm"][i] < 4.5


def test_fiducial_mode_gives_the_same_residuals(tmp_path):
    a = np.array(screen("fiducial", tmp_path).tables["observations"].columns["v_mm"])
    b = np.array(screen("base", tmp_path).tables["observations"].columns["v_mm"])
    assert np.abs(a - b).max() < 2e-4  # 0.1 µm rounding of the machine coordinates
