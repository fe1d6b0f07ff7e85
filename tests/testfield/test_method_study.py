"""The method study's numerics: the paper's percentages, paired comparisons, and the mechanisms
behind the numbers (B/H and image scale, least squares against a two-step estimate, APs against
systematic errors) checked against closed forms and Monte Carlo — not against hoped-for outcomes."""

from __future__ import annotations

import numpy as np
import pytest

from baarda.pipeline.synthetic.testfield import FOCAL_MM, TABLE1, simulate_testfield
from baarda.plugins.testfield.method_study import (BUNDLE, BUNDLE_AP, IM, PAPER_PERCENT, SINGLE, SINGLE_AP, VARIANTS,
                                           MethodStudyConfig, compare, method_study, run_realisation)


def test_paper_percentages_are_those_printed_in_the_paper():
    # paper 001, §3.2.3: the block improves Sxy by 64 µm = 10.72 % and Sz by 243 µm = 10.13 %
    p = PAPER_PERCENT["block vs single model"]
    assert p["Sxy"] == pytest.approx(-10.72, abs=0.005)
    assert p["Sz"] == pytest.approx(-10.13, abs=0.005)
    # Table 5: independent models 0.0416 / 0.3832 cm against the bundle's 0.0533 / 0.2155 cm
    q = PAPER_PERCENT["independent models vs bundle"]
    assert q["Sxy"] == pytest.approx(100 * (0.0416 - 0.0533) / 0.0533)
    assert q["Sz"] == pytest.approx(100 * (0.3832 - 0.2155) / 0.2155)


def _rows(a, b, name_a="A", name_b="B"):
    rows = []
    for i, (x, y) in enumerate(zip(a, b)):
        for name, v in ((name_a, x), (name_b, y)):
            rows.append({"variant": name, "repetition": i, "Sx": v, "Sy": v, "Sz": v, "error": ""})
    return rows


def test_compare_on_known_values():
    b = np.array([1.0, 2.0, 3.0, 4.0])
    c = compare(_rows(0.5 * b, b), "A", "B", ("Sx", "Sxy", "Sz"))
    for k in ("Sx", "Sxy", "Sz"):
        assert c[k]["change_pct"] == pytest.approx(-50.0)
        assert c[k]["ratio"] == pytest.approx(0.5)
        assert c[k]["share"] == 1.0 and c[k]["n"] == 4
    # a/b alternating 1.01, 1/1.01: geometric mean 1, interval covers 1 → not significant
    a = b * np.array([1.01, 1 / 1.01, 1.01, 1 / 1.01])
    c = compare(_rows(a, b), "A", "B", ("Sz",))["Sz"]
    assert c["ratio"] == pytest.approx(1.0) and not c["significant"] and c["share"] == 0.5
    # only paired realisations count: a failed realisation of B drops that pair
    rows = _rows(0.5 * b, b)
    rows[-1]["error"] = "singular"
    assert compare(rows, "A", "B", ("Sz",))["Sz"]["n"] == 3


def test_every_method_sees_the_same_draws_and_the_same_check_points():
    cfg = MethodStudyConfig(case=5, sigma_image_um=40.0)
    a, _ = simulate_testfield(cfg.testfield("block", "none"), np.random.default_rng([7, 0]))
    b, _ = simulate_testfield(cfg.testfield("block", "ebner12"), np.random.default_rng([7, 0]))
    np.testing.assert_array_equal(a.observations.xy, b.observations.xy)
    np.testing.assert_array_equal(a.points.XYZ, b.points.XYZ)
    rows = run_realisation(MethodStudyConfig(methods=(BUNDLE, IM, SINGLE)), 7, 0)
    ids = {r["variant"]: sorted(r["ids"]) for r in rows}
    assert not any(r["error"] for r in rows)
    assert ids[BUNDLE] == ids[IM] == ids[SINGLE] == sorted(a.points.ids[a.points.role == "check"].tolist())


def test_height_precision_follows_base_to_distance_ratio():
    """Single model (A, B at 4.0 m) against the block (1.4 m): the geometry is the paper's Table 1,
    the bundle's covariance agrees with the normal-case formula σ_Z = √2 (H/B)(H/c) σ, Monte Carlo
    agrees with the covariance, and height loses more than planimetry because B/H is smaller."""
    cfg = MethodStudyConfig(repetitions=30, with_ap_errors=False, sigma_image_um=40.0, methods=(BUNDLE, SINGLE))
    st = method_study(cfg, seed=11)
    geo = st["geometry"]
    # the bases of Table 1 (approximate EO) against the simulated true ones (σ 5 mm deviations)
    t1 = np.mean([TABLE1[b][0] - TABLE1[a][0] for s in ("1", "2") for a, b in
                  zip([s + str(i) for i in range(1, 5)], [s + str(i) for i in range(2, 6)])])
    assert geo["block"]["B_m"] == pytest.approx(t1, abs=0.01)
    assert geo["single model"]["B_m"] == pytest.approx(TABLE1["B"][0] - TABLE1["A"][0], abs=0.01)
    assert geo["block"]["H_m"] == pytest.approx(1.4, abs=0.02)
    assert geo["single model"]["H_m"] == pytest.approx(4.0, abs=0.05)
    gs = geo["single model"]
    sz = np.sqrt(2) * (gs["H_m"] / gs["B_m"]) * (gs["H_m"] / (FOCAL_MM * 1e-3)) * 40e-6 * 100   # cm
    var = st["variants"]
    assert var[SINGLE]["pred_Sz"] == pytest.approx(sz, rel=0.15)
    # Monte Carlo against the covariance (no systematic errors: the functional model is right)
    for v in (BUNDLE, SINGLE):
        for k in ("Sxy", "Sz"):
            assert 0.75 < var[v][k] / var[v][f"pred_{k}"] < 1.3, (v, k)
    rz = var[SINGLE]["Sz"] / var[BUNDLE]["Sz"]
    rxy = var[SINGLE]["Sxy"] / var[BUNDLE]["Sxy"]
    assert rz > rxy > geo["single model"]["H_m"] / geo["block"]["H_m"] > 1
    # the covariance says the same without noise
    assert var[SINGLE]["pred_Sz"] / var[BUNDLE]["pred_Sz"] > var[SINGLE]["pred_Sxy"] / var[BUNDLE]["pred_Sxy"]


def test_independent_models_cannot_beat_least_squares_on_the_same_observations():
    """Gauss–Markov: the bundle (no APs) is the best linear unbiased estimate from the image
    coordinates and control; the independent-model block is another (linearised) unbiased estimate
    from the same observations, so its error is the bundle's error plus a part uncorrelated with it —
    checked on the realisations, without systematic errors (a correct functional model)."""
    cfg = MethodStudyConfig(with_ap_errors=False, sigma_image_um=40.0, methods=(BUNDLE, IM))
    eb, d = [], []
    for rep in range(20):
        rows = {r["variant"]: r for r in run_realisation(cfg, 5, rep)}
        b, m = rows[BUNDLE], rows[IM]
        pos = {p: i for i, p in enumerate(m["ids"])}
        em = m["errors"][[pos[p] for p in b["ids"]]]
        eb.append(b["errors"])
        d.append(em - b["errors"])
    eb, d = np.vstack(eb), np.vstack(d)
    for k in range(3):
        rho = np.corrcoef(eb[:, k], d[:, k])[0, 1]
        assert abs(rho) < 0.35, (k, rho)      # 120 samples: the standard error of ρ is ≈ 0.09
        assert np.mean((eb[:, k] + d[:, k]) ** 2) > np.mean(eb[:, k] ** 2)


def test_additional_parameters_pay_when_systematic_errors_dominate():
    """With a comparator's noise (4 µm) and four times the systematic errors (≈ 80 µm RMS), the
    bundle without APs cannot fit (σ̂0 ≫ 1), the selected APs take up the pattern (σ̂0 falls) and the
    check points improve; without systematic errors σ̂0 ≈ 1 and the APs change the check points by
    no more than the noise."""
    strong = method_study(MethodStudyConfig(repetitions=4, sigma_image_um=4.0, systematic_scale=4.0,
                                            methods=(BUNDLE, BUNDLE_AP)), seed=3)
    v = strong["variants"]
    assert v[BUNDLE]["sigma0_hat"] > 1.5 and v[BUNDLE_AP]["sigma0_hat"] < 0.8 * v[BUNDLE]["sigma0_hat"]
    c = strong["comparisons"]["APs vs no APs"]
    assert c["Sxy"]["change_pct"] < 0 and c["Sz"]["change_pct"] < 0
    none = method_study(MethodStudyConfig(repetitions=4, sigma_image_um=4.0, with_ap_errors=False,
                                          methods=(BUNDLE, BUNDLE_AP)), seed=3)
    v = none["variants"]
    assert v[BUNDLE]["sigma0_hat"] == pytest.approx(1.0, abs=0.25)
    assert abs(none["comparisons"]["APs vs no APs"]["Sz"]["change_pct"]) < 10


def test_config_rejects_unknown_methods():
    with pytest.raises(ValueError, match="methods: expected a non-empty list"):
        MethodStudyConfig(methods=("bundle",))
    assert set(VARIANTS) == {BUNDLE, BUNDLE_AP, IM, SINGLE, SINGLE_AP}
    assert not MethodStudyConfig(single_model=False).runs(SINGLE_AP)
