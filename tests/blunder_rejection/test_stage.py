"""The blunder-rejection stage: actions, artefact contract, method availability, recording."""

import numpy as np
import pytest

from baarda.pipeline.errors import InputError
from baarda.pipeline.recording import read_recording, read_series
from baarda.pipeline.stats import LinearModel
from baarda.pipeline.testing import check_stage, log_stage, run_stage
from baarda.pipeline.contracts import AdjustmentArtefact
from baarda.plugins.blunder_rejection.decide import auto_rho
from baarda.plugins.blunder_rejection.stage import BlunderRejection

from .test_table4 import adjust


def test_stage_protocol():
    check_stage(BlunderRejection)


def test_all_methods_side_by_side_flag_only(tmp_path):
    inputs = adjust("data1", tmp_path)
    res = run_stage(BlunderRejection, inputs, {"rho": 4}, tmp_path=tmp_path)
    rep = res.artefacts["blunders"]
    assert set(rep.methods) == {"data-snooping", "ids", "pope", "rrr"}
    # IDS with σ0 = 0.2 mm: X9, then X5, Y5, then the global test (B-method α′) accepts
    assert rep.methods["ids"].rejected_labels == ["X9", "X5", "Y5"]
    assert res.artefacts["block"] is inputs["block"]  # action = flag leaves the block alone
    ids = inputs["block"].observation_ids()
    assert [ids[i] for i in rep.acted_observations] == [("R", "5"), ("R", "9")]
    cols = res.tables["observations"].columns
    i = cols["label"].index("X9")
    assert cols["rrr"][i] == "reject" and cols["rrr_statistic"][i].startswith("H_exp=0.995")
    assert cols["ids"][cols["label"].index("X3")] == "accept"
    assert cols["observation"][i] == "R/9 x"
    assert "| rrr | X9, Y5, X5 |" in res.report


@pytest.mark.parametrize("method,removed", [("ids", {("R", "5"), ("R", "9")}),
                                            ("pope", {("R", "9")})])
def test_remove_marks_the_observations_inactive(tmp_path, method, removed):
    inputs = adjust("data1", tmp_path)
    res = run_stage(BlunderRejection, inputs, {"method": method, "action": "remove"}, tmp_path=tmp_path)
    block = res.artefacts["block"]
    ids = block.observation_ids()
    assert {ids[i] for i in np.flatnonzero(~block.observations.active)} == removed
    assert inputs["block"].observations.active.all()  # the input is not modified


def test_decide_by(tmp_path):
    inputs = adjust("data4", tmp_path)
    res = run_stage(BlunderRejection, inputs, {"decide_by": "pope", "action": "remove", "n_sim": 2000},
                    tmp_path=tmp_path)
    block = res.artefacts["block"]
    ids = block.observation_ids()
    assert {ids[i] for i in np.flatnonzero(~block.observations.active)} == {("R", "7"), ("R", "3")}


class NonLinear:
    """A Refittable that is not a LinearModel (as a bundle linearisation might be)."""

    def __init__(self, model):
        self._m = model

    def refit(self, active):
        return self._m.refit(active)


def test_rrr_needs_a_linear_model(tmp_path):
    inputs = adjust("data1", tmp_path)
    art = inputs["adjustment"]
    other = AdjustmentArtefact("bundle", art.snapshot, NonLinear(art.model), art.obs_rows)
    assert not other.supports_rrr
    res = run_stage(BlunderRejection, {**inputs, "adjustment": other}, {}, tmp_path=tmp_path)
    assert res.artefacts["blunders"].methods["rrr"].skipped
    assert res.artefacts["blunders"].methods["pope"].rejected_labels == ["X9"]
    assert any("rrr skipped" in w for w in res.warnings)
    with pytest.raises(InputError, match="method 'rrr' needs a linear model"):
        run_stage(BlunderRejection, {**inputs, "adjustment": other}, {"method": "rrr"}, tmp_path=tmp_path)


def test_artefact_contract():
    m = LinearModel(np.ones((4, 1)), [1.0, 2.0, 3.0, 10.0])
    snap = m.adjust().snapshot
    with pytest.raises(ValueError, match="obs_rows has 3 rows, the snapshot 4"):
        AdjustmentArtefact("x", snap, m, np.zeros((3, 2), int))
    art = AdjustmentArtefact("x", snap, m, [[0, 0], [0, 1], [-1, -1], [5, 1]])
    assert art.observations_of(np.array([True, True, True, False])).tolist() == [0]
    assert art.observations_of([3, 2]).tolist() == [5]
    assert art.refit(np.array([1, 1, 1, 0], bool)).dof == 2


def test_auto_rho():
    assert auto_rho(14) == 3 and auto_rho(10) == 2 and auto_rho(1) == 1 and auto_rho(15) == 3


def test_recording_has_iteration_history(tmp_path):
    res = run_stage(BlunderRejection, adjust("data1", tmp_path), {"rho": 4, "n_sim": 2000}, tmp_path=tmp_path)
    path = log_stage(BlunderRejection, res, tmp_path / "b.rrd")
    summary = read_recording(path)
    series = read_series(path)
    by_path = {e.path: e for e in summary.entities}
    assert "iteration" in by_path["/b/blunders/ids/global_test/T"].timelines
    assert len(series["/b/blunders/ids/global_test/T"]) == 4    # 3 removals + the accepting step
    assert len(series["/b/blunders/rrr/H/H_exp"]) == 4         # ρ = 4 suspects
    assert len(series["/b/blunders/pope/tau/tau_max"]) == 2
    # the critical values beside their statistic: F and τ change with the dof
    ids = res.artefacts["blunders"].methods["ids"]
    np.testing.assert_allclose(sorted(series["/b/blunders/ids/global_test/F_critical"]),
                               sorted(h["F_critical"] for h in ids.history))
    assert len(set(series["/b/blunders/pope/tau/tau_critical"])) == 2
    # IDS's K and RRR's H stay the same for the whole run: static values, not flat lines
    assert "/b/blunders/ids/w/K" not in series and "/b/blunders/rrr/H/H" not in series
    assert "K" in by_path["/b/blunders/ids/w/constants"].columns
    assert "/b/summary" in by_path


def test_default_rho_that_rejects_nothing_says_a_larger_rho_may_be_needed(tmp_path):
    """Data 1 has three gross errors plus the relief point: ⌈0.20 · 14⌉ = 3 suspects mask each other
    (docs/screening.md), ρ = 4 finds them."""
    inputs = adjust("data1", tmp_path)
    res = run_stage(BlunderRejection, inputs, {"n_sim": 2000}, tmp_path=tmp_path)
    assert res.artefacts["blunders"].methods["rrr"].rejected == []
    note = ("RRR rejected nothing with the default ρ = 3 suspects (⌈0.20 (n − u)⌉, n − u = 14) while other "
            "methods rejected rows (data-snooping 7, ids 3, pope 1). A gross error left among the "
            "non-suspects masks the others, so a larger ρ may be needed: try rho = 4.")
    assert f"- **{note}**" in res.report and res.summary["rrr_note"] == note
    # the user's own ρ = 3 is not second-guessed; ρ = 4 rejects, so there is nothing to say
    for rho in (3, 4):
        res = run_stage(BlunderRejection, inputs, {"n_sim": 2000, "rho": rho}, tmp_path=tmp_path)
        assert res.summary["rrr_note"] is None and "larger ρ" not in res.report
    # clean data (a straight line, 20 points, σ = 1, no method rejects): a softer note
    rng = np.random.default_rng(5)
    t = np.linspace(0, 1, 20)
    A = np.column_stack([np.ones(20), t])
    model = LinearModel(A, A @ [1.0, 2.0] + rng.normal(0, 1, 20))
    art = AdjustmentArtefact("line", model.adjust().snapshot, model, -np.ones((20, 2), int))
    res = run_stage(BlunderRejection, {"adjustment": art, "block": inputs["block"]}, {"n_sim": 2000},
                    tmp_path=tmp_path)
    assert not any(m.rejected for m in res.artefacts["blunders"].methods.values())
    assert res.summary["rrr_note"] == ("RRR rejected nothing with the default ρ = 4 suspects (⌈0.20 (n − u)⌉, "
                                       "n − u = 18). A gross error left among the non-suspects masks the "
                                       "others, so a larger ρ may be needed: try rho = 5 if gross errors "
                                       "are expected.")


def test_the_rho_option_does_not_claim_benciolinis_range():
    from baarda.pipeline.options import describe

    doc = next(o["doc"] for o in describe(BlunderRejection.Options) if o["name"] == "rho")
    assert "can leave that range (3 for n − u = 14)" in doc and "Data 1 needs ρ = 4" in doc


def test_recording_names_rejected_labels(tmp_path):
    res = run_stage(BlunderRejection, adjust("data1", tmp_path), {"rho": 4, "n_sim": 2000}, tmp_path=tmp_path)
    summary = read_recording(log_stage(BlunderRejection, res, tmp_path / "b.rrd"))
    cols = {e.path: e.columns for e in summary.entities}
    assert any("labels" in c for c in cols["/b/blunders/rrr/rejected"])
    assert not any(c.split(":")[-1] == "rows" for c in cols["/b/blunders/rrr/rejected"])


def test_ids_stop_w_test_reaches_the_library(tmp_path):
    """``ids_stop = "w-test"``: IDS goes on past the global test's acceptance and stops only when
    no |w| exceeds K (paper 000 Data 1, σ0 = 0.2 mm); Kok's rule is the default."""
    inputs = adjust("data1", tmp_path)
    kok = run_stage(BlunderRejection, inputs, {"method": "ids"}, tmp_path=tmp_path).artefacts["blunders"].methods["ids"]
    wt = run_stage(BlunderRejection, inputs, {"method": "ids", "ids_stop": "w-test"},
                   tmp_path=tmp_path).artefacts["blunders"].methods["ids"]
    assert kok.raw.stop_reason.startswith("global test accepts")
    assert wt.raw.stop_reason.startswith("no |w| above K") and "stop = 'w-test'" in wt.raw.stop_reason
    assert wt.rejected_labels[:len(kok.rejected_labels)] == kok.rejected_labels
    with pytest.raises(InputError, match="ids_stop"):
        run_stage(BlunderRejection, inputs, {"method": "ids", "ids_stop": "never"}, tmp_path=tmp_path)


def test_validate_refuses_rho_beyond_the_blocks_redundancy(tmp_path):
    """``baarda validate`` bounds RRR's rho by n − u of the source's block (was: rho = n passed
    validate and failed the run); the paper's rho = 4 still passes."""
    import contextlib
    import io
    from pathlib import Path
    from types import SimpleNamespace

    from baarda.pipeline.cli import main
    from baarda.plugins.blunder_rejection.stage import redundancy_bound
    from baarda.plugins.comparator.block import build_block, interior_orientation
    from baarda.plugins.comparator.parser import parse_comparator

    toml = Path(__file__).resolve().parents[2] / "fixtures" / "paper000" / "data1.toml"

    def validate(rho):
        err = io.StringIO()
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
            code = main(["validate", str(toml), "--set", f"blunders.rho={rho}"])
        return code, err.getvalue()

    assert validate(4)[0] == 0
    code, err = validate(36)                                       # = n: no clean redundancy left
    assert code == 2 and "field 'rho'" in err and "n = 36" in err, err
    # a bundle: three unknowns per observed tie point, distances count as rows
    parsed = parse_comparator(toml.parent / "data1.cmp")
    block = build_block(parsed, interior_orientation(parsed))
    n0, u0 = redundancy_bound(block, None)
    assert (n0, u0) == (2 * len(block.observations), 0)          # no weighted priors in this file
    n, u = redundancy_bound(block, SimpleNamespace(use="bundle", options=SimpleNamespace(distances=[1, 2])))
    tie = (block.points.role == "tie") & (np.bincount(block.observations.point, minlength=len(block.points)) >= 2)
    assert (n, u) == (n0 + 2, 3 * int(tie.sum())) and u > 0
