"""Wolf & DeWitt's sample problems (../shared/data/textbook) through baarda, checked by independent means."""

import numpy as np
import pytest

from pipeline.errors import InputError
from plugins.indmodel.textbook import (conf3d_example, format_examples, read_3dconf, read_relor,
                                       relor_example, resection_example)


@pytest.fixture(scope="module")
def textbook(shared_data):
    return shared_data / "textbook"


def test_relative_orientation_sample(textbook):
    ex = relor_example(textbook / "dewitt_relor_sample.dat")
    # four formulations of one least-squares problem agree
    for k, a in ex["agreement"].items():
        assert a["max_dv_mm"] < 1e-9 and a["d_sigma0_hat"] < 1e-10, k
        assert a["max_dR_right_from_left"] < 1e-10 and a["max_dbase_direction"] < 1e-10, k
    ro = ex["runs"][("coplanarity", "dependent")]
    assert ro.dof == 1 and abs(ro.snapshot.r.sum() - 1) < 1e-12
    # DeWitt's model scale: XL of the right photo = mean x-parallax of the six points (by hand: 91.9825)
    assert abs(ex["dewitt_right_photo"]["XL"] - 551.895 / 6) < 1e-12
    # DeWitt's frame is baarda's dependent frame moved by (0, 0, f)
    dep = ex["runs"][("collinearity", "dependent")]
    assert np.allclose(ex["dewitt_frame_XYZ"] - dep.XYZ, [0, 0, 152.113])
    assert np.isclose(ex["dewitt_right_photo"]["ZL"], 152.113 + dep.p[1])
    # rays meet at the adjusted image coordinates: re-intersect and re-project them
    lhat = ro.xy - ro.v
    from plugins.indmodel.relor import coplanarity_condition

    F = coplanarity_condition(lhat, ro.p, "dependent", ro.bx, (152.113, 0, 0))[0]
    assert np.abs(F).max() < 1e-9 * np.abs(ro.bx * 152.113 * 100)
    # the residuals are small against the 1 µm-level measurement: σ̂0 in mm (unit weights)
    assert 0.001 < ro.sigma0_hat < 0.01


def test_conformal_sample(textbook):
    ex = conf3d_example(textbook / "dewitt_3DCONF_sample.dat")
    ls = ex["lsq"]
    assert ls.converged and ls.iterations >= 3  # really iterated from scale 1, zero angles
    assert ex["max_d_params"].max() < 1e-9  # = Horn/Umeyama closed form
    assert ls.dof == 6 * 3 - 7
    assert np.isclose(ls.sigma0_hat, np.sqrt(np.nansum(ls.residuals ** 2) / 11), rtol=1e-12)
    # transformed points: X = s Mᵀ x + T by hand, for point 1
    M = ls.R_src_from_dst
    x1 = np.array([611.37, 498.98, 470.45])
    assert np.allclose(ex["transformed"][0], ls.params[0] * M.T @ x1 + ls.params[4:], atol=1e-9)
    assert np.all(ex["transformed_std"] > 0)


def test_resection_sample(textbook):
    ex = resection_example(textbook / "dewitt_resect_sample.dat")
    assert ex["opencv"]["ok"]
    assert ex["max_dX0"] < 1e-3 and ex["max_dangle_deg"] < 1e-4  # two implementations agree
    r = ex["result"]
    assert np.abs(r.residuals).max() < 0.005  # mm


def test_format_examples_runs(textbook):
    text = format_examples(textbook)
    assert "relative orientation" in text and "3-D conformal" in text and "space resection" in text


def test_reader_errors(tmp_path):
    p = tmp_path / "bad.dat"
    p.write_text("152.1\na 1 2 3 4\nb 1 x2 3 4\n")
    with pytest.raises(InputError) as e:
        read_relor(p)
    assert e.value.line == 3 and e.value.field == "yl" and "x2" in str(e.value)
    p.write_text("152.1 7\n")
    with pytest.raises(InputError, match="focal length only"):
        read_relor(p)
    q = tmp_path / "conf.dat"
    q.write_text("a 1 2 3 4 5 6\nb 1 2 3\n#\n")
    with pytest.raises(InputError) as e:
        read_3dconf(q)
    assert e.value.line == 2
    q.write_text("a 1 2 3 4 5 6\n")
    with pytest.raises(InputError, match="missing '#'"):
        read_3dconf(q)
