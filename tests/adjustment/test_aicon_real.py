"""The real AICON close-range network (../shared/data/aicon-closerange): self-calibrating free
network from initial values perturbed well away from the exported ones."""

import numpy as np
import pytest

from baarda.pipeline.adjustment import BundleSettings, adjust


@pytest.fixture(scope="module")
def aicon(shared_data):
    from baarda.plugins.aicon.reader import aicon_block, read_aicon

    return aicon_block(read_aicon(shared_data / "aicon-closerange" / "example"), sigma_image_um=0.5)


def test_aicon_converges_from_perturbed_start(aicon):
    from baarda.plugins.aicon.reader import perturb_initial_values

    ref = adjust(aicon, BundleSettings(datum="free"))
    start = perturb_initial_values(aicon, np.random.default_rng(1), sigma_position=50.0, sigma_angle_deg=1.0,
                                   sigma_c=0.2, zero_distortion=True)
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


def test_aicon_weights_explain_the_data_snooping_count(shared_data):
    """Why fixtures/aicon/aicon.toml scales the file's sx, sy instead of one uniform σ: with one σ
    for all coordinates the w are a mixture of normals of different widths — far more |w| > 3.29
    than the normal distribution's 0.1 % (and a large excess kurtosis); with the .phc's own sx, sy
    (scaled by their variance component σ̂0) the tails come close to normal."""
    from scipy import stats as sps

    from baarda.pipeline import stats
    from baarda.plugins.aicon.reader import aicon_block, read_aicon

    ex = read_aicon(shared_data / "aicon-closerange" / "example")
    out = {}
    for name, blk in (("uniform", aicon_block(ex, sigma_image_um=0.41)), ("file", aicon_block(ex))):
        res = adjust(blk, BundleSettings(datum="free"))
        if name == "file":      # the variance component of the file's σ, then adjust again
            s0 = res.sigma0_hat
            assert 3.5 < s0 < 3.9                                   # the file's σ are ≈ 3.7 × too small
            obs = blk.observations
            res = adjust(blk.replace(observations=obs.replace(cov=obs.cov * s0 ** 2)), BundleSettings(datum="free"))
            assert res.sigma0_hat == pytest.approx(1.0, abs=1e-3)
        w = stats.w_test(res.snapshot)[res.snapshot.active]
        out[name] = (np.mean(np.abs(w) > 3.29), sps.kurtosis(w))
    normal = 2 * sps.norm.sf(3.29)
    assert out["uniform"][0] > 8 * normal and out["uniform"][1] > 1.5     # 182 of 19 944: 0.91 %
    assert out["file"][0] < 4 * normal and out["file"][1] < 1.0           # 57 of 19 944: 0.29 %
