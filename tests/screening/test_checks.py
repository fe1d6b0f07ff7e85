"""Swapped point numbers, out-of-format coordinates, too few points, deactivation, recording."""

from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.recording import read_recording
from baarda.pipeline.testing import check_stage, log_stage, run_stage
from baarda.plugins.comparator.stage import ComparatorSource
from baarda.plugins.screening.helmert import outside_format
from baarda.plugins.screening.stage import HelmertScreening

from .test_paper000 import PRINTED

BASE = PRINTED.copy()
BASE[8, 0] = 155.576
SHIFT_L, SHIFT_R = np.array([125.0, 160.0]), np.array([100.0, 60.0])


def cmp_text(left, right, ids=None, right_ids=None, camera="camera K c 152 format 230 230", extra=""):
    ids = ids or [str(i + 1) for i in range(len(left))]
    right_ids = right_ids or ids
    lines = ["unit mm", "mode photo", camera, "photo L"]
    lines += [f"pt {p} {x:.3f} {y:.3f}" for p, (x, y) in zip(ids, left)]
    lines += ["photo R"]
    lines += [f"pt {p} {x:.3f} {y:.3f}" for p, (x, y) in zip(right_ids, right)]
    lines += ["pair L R", extra]
    return "\n".join(lines) + "\n"


def screen_text(tmp_path, text, **opts):
    (tmp_path / "s.cmp").write_text(text, encoding="utf-8")
    src = run_stage(ComparatorSource, {}, {"path": "s.cmp"}, tmp_path=tmp_path)
    return run_stage(HelmertScreening, {"block": src.artefacts["block"]}, opts, tmp_path=tmp_path)


def centred():
    return BASE[:, :2] - SHIFT_L, BASE[:, 2:] - SHIFT_R


def test_stage_protocol():
    check_stage(HelmertScreening)


@pytest.mark.parametrize("a,b", [("2", "6"), ("4", "8"), ("1", "9")])
def test_swapped_point_numbers_are_found(tmp_path, a, b):
    left, right = centred()
    ids = [str(i + 1) for i in range(9)]
    rid = ids.copy()
    ia, ib = ids.index(a), ids.index(b)
    rid[ia], rid[ib] = b, a  # the operator wrote the two numbers the wrong way round in photo R
    res = screen_text(tmp_path, cmp_text(left, right, ids, rid))
    pair = res.summary["pairs"][0]
    assert [sorted(s) for s in pair["swaps"]] == [sorted([a, b])]
    assert sorted(pair["flagged"]["swap"]) == sorted([f"X{a}", f"Y{a}", f"X{b}", f"Y{b}"])
    cols = res.tables["observations"].columns
    assert cols["swap_with"][cols["label"].index(f"X{a}")] == b
    assert "Swapped point numbers?" in res.report


@pytest.mark.parametrize("a,b", [("2", "6"), ("4", "8"), ("1", "9")])
def test_a_swap_narrows_the_flags_to_what_the_correct_data_flag(tmp_path, a, b):
    """The swap smears over every residual (2↔6: threshold flags R/1–R/9 except 5); once it is undone
    the flags are the swapped points plus those of the correctly numbered data screened on its own."""
    left, right = centred()
    ids = [str(i + 1) for i in range(9)]
    rid = ids.copy()
    rid[ids.index(a)], rid[ids.index(b)] = b, a
    swapped_text = cmp_text(left, right, ids, rid)

    def flagged(res):
        return {pt for _, pt in res.summary["flagged_observations"]}

    for flag_by in (["pope", "threshold", "format", "swap"], ["threshold", "swap"]):
        truth = screen_text(tmp_path, cmp_text(left, right), flag_by=flag_by)
        res = screen_text(tmp_path, swapped_text, flag_by=flag_by)
        pair = res.summary["pairs"][0]
        assert len(pair["flagged"]["threshold"]) >= 7  # the smear the checks see
        assert flagged(res) == {a, b} | flagged(truth)
        truth_s = truth.artefacts["screening"].pairs[0].screening
        assert pair["after_swaps"]["still_flagged"] == [str(x) for x in truth_s.labels[truth_s.flagged]]
        assert pair["after_swaps"]["sigma0_hat"] == pytest.approx(truth.summary["pairs"][0]["sigma0_hat"])
        cleared = set(pair["after_swaps"]["cleared"])
        assert cleared and not cleared & {f"X{a}", f"Y{a}", f"X{b}", f"Y{b}"}
        assert f"swapped point numbers {a}↔{b} in R" in res.summary["headline"]
    # with flag_by threshold + swap the correct data flag nothing: the swap is the whole finding
    assert flagged(truth) == set() and pair["after_swaps"]["explains"]
    assert f"**Finding: point numbers {a}↔{b} swapped in photo R.**" in res.report
    assert "(explains every flag)" in res.summary["headline"]
    assert len(res.summary["flagged_observations"]) == 2


def test_swap_not_in_flag_by_keeps_every_flag(tmp_path):
    left, right = centred()
    ids = [str(i + 1) for i in range(9)]
    rid = ids.copy()
    rid[1], rid[5] = "6", "2"
    res = screen_text(tmp_path, cmp_text(left, right, ids, rid), flag_by=["threshold"])
    pair = res.summary["pairs"][0]
    assert [sorted(x) for x in pair["swaps"]] == [["2", "6"]] and pair["after_swaps"] is None
    assert {pt for _, pt in res.summary["flagged_observations"]} == \
        {lab[1:] for lab in pair["flagged"]["threshold"]}


@pytest.mark.parametrize("name", ["printed", "data1", "data2", "data3", "data4"])
def test_no_swap_is_claimed_for_gross_errors(tmp_path, name):
    fix = Path(__file__).resolve().parents[2] / "fixtures" / "paper000" / f"{name}.cmp"
    res = screen_text(tmp_path, fix.read_text())
    assert res.summary["pairs"][0]["swaps"] == []


def test_outside_format_is_flagged(tmp_path):
    left, right = centred()
    right = right.copy()
    right[3] = [121.0, -5.0]  # |x| > 115 mm in a 230 mm format
    left = left.copy()
    left[6] = [0.0, -116.5]
    res = screen_text(tmp_path, cmp_text(left, right))
    pair = res.summary["pairs"][0]
    assert pair["flagged"]["format"] == ["X4", "Y4", "X7", "Y7"]
    assert "Outside the camera format: L/7, R/4" in res.report
    flagged = res.artefacts["screening"].flagged_observations()
    ids = res.artefacts["block"].observation_ids()
    assert {ids[i] for i in flagged} >= {("L", "7"), ("R", "4")}
    # a margin of 2 mm accepts left point 7 (1.5 mm outside), not right point 4 (6 mm outside)
    res = screen_text(tmp_path, cmp_text(left, right), format_margin_mm=2.0)
    assert res.summary["pairs"][0]["flagged"]["format"] == ["X4", "Y4"]


def test_outside_format_pure():
    xy = np.array([[0, 0], [115.1, 0], [0, -115.0], [np.nan, 0]])
    assert outside_format(xy, (230, 230)).tolist() == [False, True, False, False]
    assert not outside_format(xy, (np.nan, np.nan)).any()


def test_unknown_format_is_said(tmp_path):
    left, right = centred()
    res = screen_text(tmp_path, cmp_text(left, right, camera=""))
    assert "camera format unknown" in res.report


@pytest.mark.parametrize("n,words", [(2, "only 2 common points: the 4-parameter transformation is determined "
                                         "exactly, with no redundancy"),
                                     (1, "only 1 common point(s)")])
def test_too_few_common_points(tmp_path, n, words):
    left, right = centred()
    text = cmp_text(left[:n], right[:n])
    with pytest.raises(InputError) as info:
        screen_text(tmp_path, text)
    e = info.value
    assert e.path == str(tmp_path / "s.cmp") and e.line == 6 + 2 * n and e.field == "pair"
    assert f"pair L R: {words}" in e.message and "at least 3 common points" in e.message
    assert "\n" not in str(e)


def test_skip_a_weak_pair(tmp_path):
    left, right = centred()
    text = cmp_text(left, right) + "photo Q\n" + "".join(
        f"pt {i + 1} {x:.3f} {y:.3f}\n" for i, (x, y) in enumerate(right[:2])) + "pair R Q\n"
    res = screen_text(tmp_path, text, on_too_few="skip")
    assert len(res.summary["pairs"]) == 1 and res.summary["skipped"][0][:2] == ["R", "Q"]
    assert any("pair R Q" in w for w in res.warnings)


def test_action_remove_and_adjustment_artefact(tmp_path):
    fix = Path(__file__).resolve().parents[2] / "fixtures" / "paper000" / "printed.cmp"
    flag = screen_text(tmp_path, fix.read_text())
    assert flag.artefacts["block"].observations.active.all()
    res = screen_text(tmp_path, fix.read_text(), action="remove")
    block = res.artefacts["block"]
    ids = block.observation_ids()
    assert [ids[i] for i in np.flatnonzero(~block.observations.active)] == [("R", "9")]
    adj = res.artefacts["adjustment"]
    assert adj.name == "helmert-screening" and adj.obs_rows.shape == (18, 2)
    assert adj.obs_rows[16].tolist() == [ids.index(("R", "9")), 0]
    # rows of the removed point are inactive in the artefact's snapshot; σ̂0 is that of 8 points
    assert not adj.snapshot.active[16] and not adj.snapshot.active[17]
    assert adj.snapshot.dof == 12
    assert adj.snapshot.sigma0_hat == pytest.approx(
        adj.model.refit(np.r_[np.ones(16, bool), False, False]).sigma0_hat)


def test_two_pairs_stack(tmp_path):
    left, right = centred()
    text = cmp_text(left, right) + "photo Q\n" + "".join(
        f"pt {i + 1} {x + 1:.3f} {y - 2:.3f}\n" for i, (x, y) in enumerate(right)) + "pair R Q\n"
    res = screen_text(tmp_path, text)
    assert [p["pair"] for p in res.summary["pairs"]] == [["L", "R"], ["R", "Q"]]
    adj = res.artefacts["adjustment"]
    assert adj.snapshot.n == 36 and adj.snapshot.dof == 28
    assert adj.snapshot.labels[0] == "L-R X1" and adj.snapshot.labels[18] == "R-Q X1"
    # the second pair is a pure shift: residuals vanish there
    assert np.abs(adj.snapshot.v[18:]).max() < 1e-9


def test_recording(tmp_path):
    fix = Path(__file__).resolve().parents[2] / "fixtures" / "paper000" / "printed.cmp"
    res = screen_text(tmp_path, fix.read_text())
    summary = read_recording(log_stage(HelmertScreening, res, tmp_path / "s.rrd"))
    paths = {e.path for e in summary.entities}
    assert {"/s/photos/L/points", "/s/photos/R/points", "/s/photos/R/residuals", "/s/photos/R/flagged",
            "/s/pairs/L-R/tests", "/s/summary"} <= paths
    assert "Arrows2D" in summary.archetypes
