"""The real AICON close-range network (../shared/data/aicon-closerange): self-calibrating free
network from initial values perturbed well away from the exported ones."""

import numpy as np
import pytest

from plugins.bundle import BundleSettings, adjust


@pytest.fixture(scope="module")
def aicon(shared_data):
    from plugins.aicon.reader import aicon_block, read_aicon

    return aicon_block(read_aicon(shared_data / "aicon-closerange" / "example"), image_sigma_um=0.5)


def test_aicon_converges_from_perturbed_start(aicon):
    from plugins.aicon.reader import perturb_initial_values

    ref = adjust(aicon, BundleSettings(datum="free"))
    start = perturb_initial_values(aicon, np.random.default_rng(1), position_sigma=50.0, angle_sigma_deg=1.0,
                                   c_sigma=0.2, zero_distortion=True)
    res = adjust(start, BundleSettings(datum="free"))
    assert res.iterations <= 10
    # same minimum as from the exported values (the datum differs only by the inner constraints'
    # reference, so compare datum-invariant quantities)
    assert res.vtpv == pytest.approx(ref.vtpv, rel=1e-8)
    assert np.allclose(res.state.cam_params, ref.state.cam_params, rtol=1e-6, atol=1e-12)
    # AICON's own estimate of c is −28.78507 mm; ours agrees to a few σ-equivalents of a µm
    assert res.state.cam_params[0, 0] == pytest.approx(28.78507, abs=0.005)
    # the scale bar 506–507 is held to its σ (0.01 mm)
    i, j = aicon.points.index_of(["506", "507"])
    assert np.linalg.norm(res.state.XYZ[i] - res.state.XYZ[j]) == pytest.approx(1389.688, abs=0.01)
    # sub-µm image residuals: σ̂0 × 0.5 µm
    assert 0.2 < res.sigma0_hat * 0.5 < 0.6
    # image rows carry all the redundancy but the scale bar's share (0 ≤ r_distance ≤ 1; here the bar
    # alone fixes the free network's scale, so its share is 0 up to rounding)
    assert res.dof - 1 <= res.redundancy.sum() <= res.dof + 1e-6
