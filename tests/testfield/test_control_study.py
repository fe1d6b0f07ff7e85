"""The control study: AP selection by the paper's rule, the study's tables and claims, the stage."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("baarda.pipeline.adjustment.adjust")

from baarda.pipeline.errors import InputError  # noqa: E402
from baarda.pipeline.testing import check_stage, log_stage, run_stage  # noqa: E402
from baarda.pipeline.synthetic.testfield import TestFieldConfig, simulate_testfield  # noqa: E402
from baarda.pipeline.adjustment.apselect import select_aps_weak_priors  # noqa: E402
from baarda.plugins.testfield.control_study import ControlStudy, _claim, control_study
from baarda.plugins.testfield.study_config import ControlStudyConfig  # noqa: E402


def test_selection_removes_correlated_parameters():
    """Case 5 with Ebner's set and c, xp, yp: c is ≈ 1-correlated with the Z0 of the photos in a
    normal-case block and must go; every kept parameter has |ρ| ≤ 0.75 with all other unknowns."""
    block, _ = simulate_testfield(TestFieldConfig(case=5, sigma_image_um=40.0, ap_model="ebner12",
                                                  calibrate_iop=True), np.random.default_rng(0))
    sel = select_aps_weak_priors(block, rho_max=0.75, alpha=0.0)
    removed = {n for n, _, _ in sel.removed}
    assert "c" in removed and all(r > 0.75 for _, r, _ in sel.removed)
    assert set(sel.kept) | removed == {"c", "xp", "yp"} | {f"b{i}" for i in range(1, 13)}
    res = sel.result
    prob = res.problem
    Q = res.Qx[:prob.n_g, :prob.n_g]
    d = np.sqrt(np.diag(Q))
    R = np.abs(Q / np.outer(d, d))
    names = ["c", "xp", "yp"] + [f"b{i}" for i in range(1, 13)]
    for n in sel.kept:
        g = prob.g_cam[0, names.index(n)]
        assert g >= 0 and np.isinf(res.problem.cam_sigma[0, names.index(n)])
        row = R[g].copy()
        row[g] = 0
        assert row.max() <= 0.75 + 0.05      # checked on the final, unconstrained adjustment
    assert res.dof == 66 - len(sel.kept)
    # with the t-test every kept parameter is significant at 5 %
    from scipy.stats import t as student
    sig = select_aps_weak_priors(block, rho_max=0.75, alpha=0.05)
    assert set(sig.kept) <= set(sel.kept)
    r2 = sig.result
    for n in sig.kept:
        j = names.index(n)
        sd = np.sqrt(r2.cov_cameras[0][j, j])
        assert abs(r2.state.cam_params[0, j]) / sd >= student.ppf(0.975, r2.dof)


def test_study_small_run_and_claim_arithmetic():
    st = control_study(ControlStudyConfig(repetitions=1, cases=(1, 2, 3), single_model=False), seed=3)
    t2, t3 = st["tables"]["table2"], st["tables"]["table3"]
    assert [r["case"] for r in t2] == [1, 2, 3] and [r["dof"] for r in t2] == [40, 52, 52]
    # the bundle's selection runs where the block is regular with every AP free; case 1 is not
    assert [r["selection"] for r in t3] == ["study(1)", "bundle(1)", "bundle(1)"]
    t2, t3 = t2[1:], t3[1:]
    assert all(r["dof"] <= 52 for r in t3)
    for r in t2 + t3:
        assert 0 < r["Sxy"] < 1 and 0 < r["Sz"] < 2 and 20 < r["sigma0_um"] < 60
        assert r["Sxy"] == pytest.approx(np.sqrt((r["Sx"] ** 2 + r["Sy"] ** 2) / 2))
    # the claim arithmetic on hand-made rows: a 10 % smaller RMSE in both realisations
    rows = [{"repetition": i, "block": "block", "case": c, "aps": False, "error": "", "Sx": s, "Sy": s, "Sz": 2 * s}
            for i in range(2) for c, s in ((2, 0.9 * (i + 1)), (3, 1.0 * (i + 1)))]
    c = _claim(rows, "x", {"case": 2}, {"case": 3})
    assert c["holds"] and c["keys"]["Sxy"]["change_pct"] == pytest.approx(-10.0)
    assert c["keys"]["Sz"]["share"] == 1.0


def test_stage(tmp_path):
    check_stage(ControlStudy)
    r = run_stage(ControlStudy, {}, {"repetitions": 1, "cases": [1, 5], "seed": 2}, tmp_path=tmp_path)
    study = r.artefacts["study"]
    assert [row["case"] for row in study["tables"]["table2"]] == [1, 5]
    assert study["tables"]["single"][0]["case"] == 5
    assert "Table 2" in r.report and "Table 4" in r.report and "holds" in r.report
    held = sum(c["holds"] for c in study["conclusions"])
    assert r.summary["headline"] == (f"1 realisations, σ 40 µm, systematics ×1: 5 configurations (2 cases "
                                     f"with/without APs, single model), 5 adjustments; "
                                     f"{held}/{len(study['conclusions'])} paper claims hold")
    assert {"table2", "table3", "single", "realisations", "conclusions"} <= set(r.tables)
    log_stage(ControlStudy, r, tmp_path / "study.rrd")
    with pytest.raises(InputError):
        run_stage(ControlStudy, {}, {"cases": [7]}, tmp_path=tmp_path)
