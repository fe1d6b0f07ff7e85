"""The method-study stage: protocol, configuration from the testfield block, the comparison
convention, the paper's tables in the report, the recording."""

from __future__ import annotations

import numpy as np
import pytest

from baarda.pipeline.units import unit_mismatches

from baarda.pipeline.errors import InputError
from baarda.pipeline.recording import read_recording
from baarda.pipeline.testing import check_stage, log_stage, run_stage
from baarda.pipeline.synthetic.testfield import TestFieldConfig, simulate_testfield
from baarda.plugins.testfield.method_study_stage import MethodStudy
from baarda.plugins.testfield.method_study import MethodStudyConfig, resolve, BUNDLE, BUNDLE_AP, IM, SINGLE_AP, VARIANTS


def test_protocol():
    check_stage(MethodStudy)
    assert MethodStudy.reads == ("block?",) and MethodStudy.writes == ("method-study",)


def test_configuration_comes_from_the_testfield_block_unless_an_option_says_otherwise():
    block, _ = simulate_testfield(TestFieldConfig(case=3, sigma_image_um=12.0, systematic_scale=2.0),
                                  np.random.default_rng(0))
    cfg, src = resolve(MethodStudyConfig(sigma_image_um=40.0), block)
    assert (cfg.case, cfg.sigma_image_um, cfg.systematic_scale) == (3, 40.0, 2.0)
    assert src["case"] == "testfield block" and src["sigma_image_um"] == "option"
    cfg, src = resolve(MethodStudyConfig(), None)
    assert (cfg.case, cfg.sigma_image_um) == (5, 40.0) and src["case"] == "default"
    assert resolve(cfg, block)[0] == cfg            # resolved once, nothing left to the block


def test_the_options_are_the_library_configuration():
    assert MethodStudy.Options is MethodStudyConfig
    for bad in ({"sigma_image_um": 0.0}, {"rho_max": 1.0}, {"case": 7}, {"methods": ()}):
        with pytest.raises(ValueError):
            MethodStudyConfig(**bad)
    assert MethodStudyConfig(methods=["bundle, no APs"]).methods == ("bundle, no APs",)


def test_bad_options_are_input_errors(tmp_path):
    for bad in ({"methods": ["bundle"]}, {"case": 7}, {"repetitions": 0}, {"rho_max": 1.5}):
        with pytest.raises(InputError):
            run_stage(MethodStudy, {}, bad, tmp_path=tmp_path)


def test_run_report_tables_and_comparison_convention(tmp_path):
    block, _ = simulate_testfield(TestFieldConfig(case=2, sigma_image_um=40.0), np.random.default_rng(1))
    res = run_stage(MethodStudy, {"block": block}, {"repetitions": 2, "seed": 4}, tmp_path=tmp_path)
    s = res.summary
    assert s["case"] == 2 and s["repetitions"] == 2 and s["headline"].startswith("2 realisations, case 2")
    n_check = int((block.points.role == "check").sum())
    cp = s["check_points"]
    assert set(cp) == set(VARIANTS)
    for v, d in cp.items():
        assert d["unit"] == "m" and d["n"] == n_check and d["realisations"] == 2
        assert d["Sxy"] == pytest.approx(np.sqrt((d["Sx"] ** 2 + d["Sy"] ** 2) / 2))
    # the check_points table holds every error; the summary's RMSE is recomputed from it
    tab = res.tables["check_points"]
    assert list(tab.columns)[:4] == ["point", "dX_m", "dY_m", "dZ_m"]
    for v in (BUNDLE, IM, SINGLE_AP):
        m = np.array(tab.columns["method"]) == v
        reps = np.array(tab.columns["repetition"])[m]
        dz = np.asarray(tab.columns["dZ_m"], float)[m]
        per_rep = [np.sqrt(np.mean(dz[reps == r] ** 2)) for r in (0, 1)]
        assert cp[v]["Sz"] == pytest.approx(np.sqrt(np.mean(np.square(per_rep))), rel=1e-12)
    # Tables 4 and 5: one row per method, every column in one unit (cm, %), the paper's numbers beside ours
    t4 = res.tables["table4"].columns
    assert t4["method"] == ["single model", "block"] and t4["paper_Sxy_cm"][0] == 0.0597
    assert t4["Sxy_cm"][0] == pytest.approx(100 * cp[SINGLE_AP]["Sxy"])
    assert t4["Sxy_vs_paper_pct"][0] == pytest.approx(100 * (100 * cp[SINGLE_AP]["Sxy"] - 0.0597) / 0.0597)
    assert t4["paper_distance_cm"] == [400.0, 140.0]
    t5 = res.tables["table5"].columns
    assert t5["method"] == ["independent models", "bundle"] and t5["paper_Sx_cm"][0] == 0.0432
    assert t5["paper_Sz_cm"][1] == 0.2155 and t5["Sz_cm"][1] == pytest.approx(100 * cp[BUNDLE_AP]["Sz"])
    # the comparison of the two methods (the paper's last rows) is the comparisons table's
    cmp = res.tables["comparisons"].columns
    row = {(c, k): i for i, (c, k) in enumerate(zip(cmp["comparison"], cmp["key"]))}
    i = row[("block vs single model", "Sz")]
    assert cmp["paper_pct"][i] == pytest.approx(-10.13, abs=0.005)
    assert cmp["change_pct"][i] == pytest.approx(100 * (cp[BUNDLE_AP]["Sz"] / cp[SINGLE_AP]["Sz"] - 1))
    i = row[("independent models vs bundle", "Sz")]
    assert cmp["change_pct"][i] == pytest.approx(100 * (cp[IM]["Sz"] / cp[BUNDLE_AP]["Sz"] - 1))
    for t in ("table4", "table5"):
        assert not unit_mismatches(res.tables[t]) and all(res.tables[t].units[c] == "" for c in res.tables[t].columns
                                                          if c.endswith("_pct"))
    for text in ("**Table 4**", "**Table 5**", "**Why**", "B/H", "10.72", "(Sxy, Sz)"):
        assert text in res.report, text
    rec = read_recording(log_stage(MethodStudy, res, tmp_path / "ms.rrd"))
    paths = {e.path for e in rec.entities}
    assert {"/ms/Sz_cm/single_model_4_0_m", "/ms/pooled/Sz_cm"} <= paths


def test_without_single_model_and_kept_out_of_the_comparison(tmp_path):
    res = run_stage(MethodStudy, {}, {"repetitions": 1, "single_model": False, "in_comparison": False,
                                      "methods": [BUNDLE, IM]}, tmp_path=tmp_path)
    assert "check_points" not in res.summary and "table4" not in res.tables
    assert set(res.summary["variants"]) == {BUNDLE, IM}
    assert "**Table 5**" in res.report
