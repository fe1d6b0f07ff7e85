"""GNSS antenna positions with a lever arm as observations of the bundle (``Block.gnss``):
``X_antenna + v = X0 + R_cam_from_worldᵀ · e`` on the photo's six orientation unknowns.

References: central finite differences (the Jacobian), the simulated truth (``simulate_aerial``:
centres within their σ, σ̂0 and the GNSS group's Ω/r near 1 over a Monte Carlo), the identity
Σ r_i = dof, a 1 m blunder found by data snooping, the dense against the sparse route, the
datum diagnosis for antennas on a line, the linearised model's own least squares.
"""

from __future__ import annotations

import numpy as np
import pytest

from baarda.pipeline import stats
from baarda.pipeline.adjustment import BundleSettings, adjust, estimate_components, global_rows, linearised_model
from baarda.pipeline.adjustment.problem import BundleProblem
from baarda.pipeline.errors import AdjustmentError, InputError
from baarda.pipeline.geometry import rotation_from_opk_many
from baarda.pipeline.model import Gnss
from baarda.pipeline.synthetic.aerial import simulate_aerial

ARM = np.array([0.1, -0.05, 0.3])          # antenna in the camera frame (m): x right, y up, z back


def _block(rng, *, n_strips=3, per_strip=8, sigma=0.05, sigma_model=None, arm=ARM, blunder=None, photos=None):
    """A simulated aerial block without control: tie points unknown, photos started from the noisy
    antennas reduced with a nadir attitude; antenna = true centre + Rᵀ·arm + N(0, σ²)."""
    noisy, exact = simulate_aerial(rng, n_strips=n_strips, photos_per_strip=per_strip, height=100.0,
                                   points_per_photo=60, control_spacing=100, noise_px=0.5)
    pts = noisy.points
    R = rotation_from_opk_many(exact.photos.opk)
    antenna = exact.photos.X0 + np.einsum("kji,j->ki", R, ARM) + rng.normal(0.0, sigma, exact.photos.X0.shape)
    if blunder is not None:
        antenna[blunder[0], blunder[1]] += blunder[2]
    sel = np.arange(len(antenna)) if photos is None else np.asarray(photos)
    gn = Gnss.make(sel, antenna[sel], sigma=sigma if sigma_model is None else sigma_model, lever_arm=arm)
    blk = noisy.replace(points=pts.replace(role=np.full(len(pts), "tie"), sigma=np.full((len(pts), 3), np.inf),
                                           XYZ=np.full_like(pts.XYZ, np.nan)),
                        photos=noisy.photos.replace(X0=antenna, opk=np.zeros_like(antenna)), gnss=gn)
    return blk, exact


def test_antenna_jacobian_against_central_differences():
    rng = np.random.default_rng(5)
    blk, exact = _block(rng, n_strips=2, per_strip=4)
    prob = BundleProblem(blk, BundleSettings())
    st = prob.initial_state(exact)
    st.opk[:] = rng.normal(0.0, 0.4, st.opk.shape)          # away from nadir: every derivative non-zero
    (k,) = [g for g in prob.grows if g.kind == "gnss"]
    f, J = prob.global_rows_eval(k, st)
    # the observation itself: X0 + R_cam_from_worldᵀ e, R from the conventions' formula
    R = rotation_from_opk_many(st.opk)
    assert np.allclose(f, st.X0 + np.einsum("kji,j->ki", R, ARM), atol=1e-12)
    h = 1e-6
    for a in range(6):
        sp, sm = st.copy(), st.copy()
        (sp.X0 if a < 3 else sp.opk)[:, a % 3] += h
        (sm.X0 if a < 3 else sm.opk)[:, a % 3] -= h
        num = (prob.global_rows_eval(k, sp, False)[0] - prob.global_rows_eval(k, sm, False)[0]) / (2 * h)
        assert np.allclose(J[:, :, a], num, atol=1e-9), a
    # the whitened, flat rows the normal equations use: ẽ = L (l − f), J̃ = L J = −∂ẽ/∂x
    Jw, cols, e = prob.global_rows_linear(st)
    zero_p = np.zeros((prob.n_e, 3))
    for j in range(6):
        col = int(cols[0, j])
        dx = np.zeros(prob.n_g)
        dx[col] = h
        ep = prob.global_rows_linear(prob.apply(st, dx, zero_p), False)[2]
        em = prob.global_rows_linear(prob.apply(st, -dx, zero_p), False)[2]
        assert np.allclose(-(ep - em) / (2 * h), Jw[:, j] * (cols[:, j] == col), atol=1e-6)


def test_simulated_block_recovers_truth_and_redundancy_sums_to_dof():
    rng = np.random.default_rng(1)
    blk, exact = _block(rng)
    res = adjust(blk, BundleSettings())
    gs = global_rows(res)["gnss"]
    # the datum comes from the antennas alone (no control point): every centre within 4 σ of truth
    err = np.concatenate([res.state.X0 - exact.photos.X0, res.state.opk - exact.photos.opk], axis=1)
    q = np.abs(err / res.eo_sigmas())
    print(f"centres and attitudes against truth: max |error| / σ {q.max():.2f}, RMS {np.sqrt(np.mean(q ** 2)):.2f}")
    assert q.max() < 4.0
    # degrees of freedom include the 3 rows of each antenna; Σ r (image + antennas) = dof
    n_unk = 6 * len(blk.photos) + 3 * int(res.point_used.sum())
    assert res.dof == res.n_observation_rows + 3 * len(blk.gnss) - n_unk
    assert res.redundancy.sum() + gs.r.sum() == pytest.approx(res.dof, rel=1e-9)
    assert ((gs.r > 0) & (gs.r < 1)).all()
    # vᵀPv includes the antennas' residuals (observed − computed, whitened by σ)
    v_img = res.snapshot.Pv @ res.snapshot.v
    assert res.vtpv == pytest.approx(v_img + np.sum((gs.v / 0.05) ** 2), rel=1e-9)
    # without the lever arm in the model the centres are off by |e| ≈ 0.32 m: far outside their σ
    bad = adjust(blk.replace(gnss=blk.gnss.replace(lever_arm=np.zeros((len(blk.gnss), 3)))), BundleSettings())
    assert np.abs((bad.state.X0 - exact.photos.X0) / bad.eo_sigmas()[:, :3]).max() > 10


def test_sigma0_and_gnss_variance_factor_monte_carlo():
    """Over 6 blocks: σ̂0² and the GNSS group's Ω_g / r_g (its own variance factor, E = 1 when the
    antennas' σ is right) average to 1; the antenna σ given twice too large shows as f ≈ 0.5."""
    rng = np.random.default_rng(11)
    s2, gnss_f = [], []
    for _ in range(6):
        blk, _ = _block(rng)
        res = adjust(blk, BundleSettings())
        s2.append(res.sigma0_hat ** 2)
        gs = global_rows(res)["gnss"]
        gnss_f.append(np.sum((gs.v / 0.05) ** 2) / gs.r.sum())
    print(f"σ̂0² mean {np.mean(s2):.3f}, GNSS Ω/r mean {np.mean(gnss_f):.3f} (both 1 expected)")
    assert abs(np.mean(s2) - 1.0) < 0.05
    assert 0.65 < np.mean(gnss_f) < 1.35
    blk, _ = _block(rng, sigma=0.05, sigma_model=0.10)
    vc = estimate_components(blk, BundleSettings(), image_groups="all")
    g = {x.name: x for x in vc.groups}
    assert g["GNSS"].kind == "gnss" and g["GNSS"].n == 3 * len(blk.gnss)
    assert 0.3 < g["GNSS"].factor < 0.75 and 0.8 < g["image"].factor < 1.2
    assert sum(x.redundancy for x in vc.groups) == pytest.approx(vc.result.dof, rel=1e-6)


def test_one_metre_blunder_on_an_antenna_is_found_by_data_snooping():
    rng = np.random.default_rng(2)
    blk, _ = _block(rng, blunder=(10, 2, 1.0))
    res = adjust(blk, BundleSettings())
    gs = global_rows(res)["gnss"]
    ds = stats.data_snooping(gs.snapshot)
    row = 3 * int(np.flatnonzero(gs.index == 10)[0]) + 2
    assert ds.largest == row and ds.flagged[row]
    assert str(gs.snapshot.labels[row]) == f"antenna photo {blk.photos.ids[10]} Z"
    assert ds.flagged.sum() <= 3                        # only the blundered antenna's rows
    # the estimated error ∇̂ = v / r is the blunder (σ ≈ 0.05 / √r)
    assert ds.nabla_hat[row] == pytest.approx(1.0, abs=0.25)
    assert np.isfinite(ds.mdb[row]) and ds.mdb[row] < 1.0
    # the global test sees it too
    assert stats.global_test(res.snapshot).rejected


def test_dense_and_sparse_routes_agree_with_antennas():
    rng = np.random.default_rng(4)
    blk, _ = _block(rng, n_strips=2, per_strip=6)
    cov = np.array(blk.gnss.cov)
    cov[:, 0, 1] = cov[:, 1, 0] = 0.5 * 0.05 ** 2          # correlated E/N
    blk = blk.replace(gnss=blk.gnss.replace(cov=cov))
    dense = adjust(blk, BundleSettings(solver="dense"))
    sparse = adjust(blk, BundleSettings(solver="sparse"))
    assert dense.solver_route == "dense" and sparse.solver_route == "sparse"
    assert np.allclose(sparse.state.X0, dense.state.X0, atol=1e-8)
    assert np.allclose(sparse.state.opk, dense.state.opk, atol=1e-10)
    assert np.allclose(sparse.redundancy, dense.redundancy, atol=1e-8)
    gd, gs = global_rows(dense)["gnss"], global_rows(sparse)["gnss"]
    assert np.allclose(gs.r, gd.r, atol=1e-8) and np.allclose(gs.PQvvP, gd.PQvvP, rtol=1e-8, atol=1e-8)
    assert np.allclose(sparse.cov_eo, dense.cov_eo, rtol=1e-7, atol=1e-12)
    assert dense.redundancy.sum() + gd.r.sum() == pytest.approx(dense.dof, rel=1e-9)


def test_linearised_model_holds_the_antenna_rows():
    """RRR's dense linearisation carries the antennas (full 3×3 weight): its own least squares
    reproduces the bundle's vᵀPv, dof and the antennas' redundancy numbers."""
    rng = np.random.default_rng(6)
    blk, _ = _block(rng, n_strips=2, per_strip=4)
    cov = np.array(blk.gnss.cov)
    cov[:, 0, 2] = cov[:, 2, 0] = -0.3 * 0.05 ** 2
    blk = blk.replace(gnss=blk.gnss.replace(cov=cov))
    res = adjust(blk, BundleSettings())
    model, n_img = linearised_model(res)
    A, l, P = model.A, model.l, model.P
    N = A.T @ P @ A
    x = np.linalg.solve(N, A.T @ P @ l)
    v = l - A @ x
    assert np.abs(x).max() < 1e-6
    assert v @ P @ v == pytest.approx(res.vtpv, rel=1e-6)
    assert A.shape[0] - A.shape[1] == res.dof
    r = np.diag(np.eye(len(l)) - A @ np.linalg.solve(N, A.T @ P))
    gs = global_rows(res)["gnss"]
    assert np.allclose(r[-3 * len(blk.gnss):], gs.r.reshape(-1), atol=1e-8)
    assert model.labels[-1] == f"antenna photo {blk.photos.ids[-1]} Z"


def test_datum_from_antennas_and_its_diagnosis():
    rng = np.random.default_rng(3)
    # three antennas, not on a line, fix the whole datum
    blk, exact = _block(rng, photos=[0, 5, 20])
    res = adjust(blk, BundleSettings())
    assert np.abs(res.state.X0 - exact.photos.X0).max() < 0.5
    # two antennas: the rotation about the line through them is missing, and the diagnosis says so
    blk, _ = _block(rng, photos=[0, 7])                  # both in the first strip, along Y
    with pytest.raises(AdjustmentError, match=r"incomplete datum: 1 degree\(s\).*rotation about Y"):
        adjust(blk, BundleSettings())
    # no antenna, no control: the full datum is missing
    with pytest.raises(AdjustmentError, match="no datum: 7 degrees"):
        adjust(blk.replace(gnss=Gnss.empty()), BundleSettings())
    # antennas and a free network's inner constraints contradict each other: refused, naming the option
    with pytest.raises(InputError, match='use datum = "control"') as e:
        adjust(blk, BundleSettings(datum="free"))
    assert e.value.field == "datum"


def test_antenna_covariance_must_be_positive_definite():
    rng = np.random.default_rng(3)
    blk, _ = _block(rng, n_strips=2, per_strip=4)
    cov = np.array(blk.gnss.cov)
    cov[2, 0, 0] = -1.0
    with pytest.raises(InputError, match=f"photo '{blk.photos.ids[blk.gnss.photo[2]]}'"):
        adjust(blk.replace(gnss=blk.gnss.replace(cov=cov)), BundleSettings())
    with pytest.raises(ValueError, match="two antenna observations"):
        blk.replace(gnss=Gnss.make([0, 0], np.zeros((2, 3)), sigma=0.1))
