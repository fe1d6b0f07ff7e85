"""Interior orientation numerics against closed forms."""

import numpy as np
import pytest

from baarda.plugins.comparator.interior import fit_interior

SQUARE = np.array([[-100.0, -100.0], [100.0, -100.0], [100.0, 100.0], [-100.0, 100.0]])


def _machine(xy, theta=0.3, s=(1.02, 0.97), t=(150.0, 140.0), shear=0.0):
    c, sn = np.cos(theta), np.sin(theta)
    M = np.array([[c * s[0], -sn * s[1] + shear], [sn * s[0], c * s[1]]])
    return xy @ M.T + np.array(t)


@pytest.mark.parametrize("kind", ["affine", "similarity"])
def test_exact_transformation_is_recovered(kind):
    # machine coordinates from a known transformation; the fit must invert it exactly
    s = (1.01, 1.01) if kind == "similarity" else (1.02, 0.97)
    XY = _machine(SQUARE, s=s, shear=0.0 if kind == "similarity" else 0.01)
    fit = fit_interior(XY, SQUARE, kind)
    assert np.abs(fit.residuals).max() < 1e-10
    pts = np.array([[12.5, -40.0], [88.0, 3.0]])
    assert np.allclose(fit.apply(_machine(pts, s=s, shear=0.0 if kind == "similarity" else 0.01)), pts, atol=1e-10)
    assert fit.dof == 8 - (6 if kind == "affine" else 4)


def test_affine_residuals_of_one_bad_fiducial_follow_the_hat_matrix():
    # Four fiducials on a square: per coordinate the affine hat matrix is h_jk = (1 + x_j x_k + y_j y_k)/4
    # (unit square coordinates), so an error d in calibrated fiducial 0 gives v_0 = d/4,
    # v_opposite = +d/4 and v_adjacent = −d/4.
    d = 0.008
    cal = SQUARE.copy()
    cal[0, 0] += d
    fit = fit_interior(_machine(SQUARE), cal, "affine")
    assert fit.residuals[:, 0] == pytest.approx([d / 4, -d / 4, d / 4, -d / 4], abs=1e-12)
    assert fit.residuals[:, 1] == pytest.approx([0, 0, 0, 0], abs=1e-12)
    assert fit.sigma0_hat == pytest.approx(np.sqrt(4 * (d / 4) ** 2 / 2))


def test_similarity_rejects_an_affinity():
    # a machine with different x and y scales cannot be fitted by a similarity without residuals
    XY = _machine(SQUARE, s=(1.0, 1.001))
    assert np.abs(fit_interior(XY, SQUARE, "affine").residuals).max() < 1e-10
    sim = fit_interior(XY, SQUARE, "similarity")
    assert np.abs(sim.residuals).max() > 0.02  # 0.1 % of 100 mm, shared over the fiducials


def test_too_few_and_degenerate_fiducials():
    with pytest.raises(ValueError, match="at least 3"):
        fit_interior(SQUARE[:2], SQUARE[:2], "affine")
    with pytest.raises(ValueError, match="degenerate"):
        line = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])
        fit_interior(line, line, "affine")
    fit = fit_interior(SQUARE[:2], SQUARE[:2], "similarity")
    assert fit.dof == 0 and np.isnan(fit.sigma0_hat)
