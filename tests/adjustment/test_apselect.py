"""AP selection: the paper's |ρ| > 0.75 rule, then significance tests."""

import numpy as np

from baarda.pipeline.adjustment import adjust
from baarda.pipeline.adjustment.apselect import select_aps

from baarda.pipeline.synthetic.closerange import make_block


def test_selection_removes_correlated_and_insignificant_aps():
    # truth: radial K1 and affinity B1 only; every other AP is 0 in the simulated camera
    blk, truth = make_block(model="brown", n_photos=8, n_points=50, noise_mm=0.001, rng=np.random.default_rng(11))
    cams = blk.cameras
    ap = np.array(cams.ap)
    ap[0, 1:] = 0.0
    ap[0, 5] = 1e-4
    from baarda.pipeline.adjustment.collinearity import project_observations
    obs = blk.observations
    cam = np.r_[truth["cam"][:3], ap[0]]
    pr = project_observations(obs.photo, obs.point, truth["XYZ"], truth["X0"], truth["opk"], np.zeros(8, int),
                              cam[None], ["brown"], [{}], jacobians=False)
    noisy = blk.replace(observations=obs.replace(xy=pr.xy + 0.001 * np.random.default_rng(3).standard_normal(pr.xy.shape)),
                        cameras=cams.replace(ap=np.zeros_like(ap)))
    sel = select_aps(noisy, rho_max=0.75, alpha=0.05)
    res = sel.result
    R = np.abs(res.correlation_camera(0))
    free = [t for t in range(3, 10) if res.problem.g_cam[0, t] >= 0]
    sub = R[np.ix_(free, free)] - np.eye(len(free))
    assert sub.max() <= 0.75                                   # the rule holds at the end
    kept = {k.parameter for k in sel.kept}
    assert {"K1", "B1"} <= kept                                # the real ones stay
    assert not {"K2", "K3"} & kept
    assert abs(res.sigma0_hat - 1) < 0.1
    assert all(k.significant for k in sel.kept)
    for s in sel.steps:                                        # every removal says why
        assert s.rule in ("correlation", "significance") and s.reason
    md = sel.markdown()
    assert "| camera | kept |" in md


def test_report_mode_keeps_everything_uncorrelated():
    blk, _ = make_block(model="ebner12", n_photos=8, n_points=50, noise_mm=0.001, rng=np.random.default_rng(2))
    sel = select_aps(blk, significance="report", rho_max=0.99)
    assert all(s.rule == "correlation" for s in sel.steps)
    assert len(sel.kept) + len(sel.steps) == 12
