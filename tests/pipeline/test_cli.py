"""The command line: help, exit codes, --quiet/--verbose, stages NAME, --set, did-you-mean, review;
and the progress display (plain lines and tqdm bars, the bundle's iteration hook)."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import numpy as np
import pytest

from baarda.pipeline.cli import EXIT_STATUS, build_parser, main
from baarda.pipeline.stage import Progress, set_verbose

ROOT = Path(__file__).resolve().parents[2]
BLOCK = ROOT / "fixtures" / "testfield" / "block.toml"
DEMO = ROOT / "fixtures" / "paper000" / "data1.toml"


def test_baarda_alone_prints_help(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    assert "usage: baarda" in out and "run" in out and "review" in out
    assert "exit status:" in out and "130" in out      # the exit codes are in the help


@pytest.mark.parametrize("command", ["run", "validate", "stages"])   # review, view: test_cli_view.py
def test_exit_codes_in_every_command_help(capsys, command):
    with pytest.raises(SystemExit) as e:
        main([command, "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    for code in ("0", "1", "2", "3", "130"):
        assert re.search(rf"^\s+{code}\s", out, re.M), (command, code)


def test_stages_name_describes_one_stage(capsys):
    assert main(["stages", "bundle"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("bundle")
    assert "reads: block" in out
    # a nested table is listed as its options, each under its dotted name, after a line naming the table
    assert "    solver.*  (a [stage.options.solver] table): the iteration and the linear algebra\n" \
           "    solver.max_iter (int, default 30, ≥ 1)\n        maximum number of iterations\n" in out
    assert "    robust.method ('none' | 'huber' | 'danish' | 'l1', default 'none')\n" in out
    assert "(table (" not in out and "Config(" not in out         # no group shown as a dataclass repr


def test_stages_verbose_lists_the_options_of_nested_tables(capsys):
    assert main(["stages", "-v"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"^ +tests\.alpha0 \(float, default 0\.001, in \(0, 1\)\): significance level of the w-test",
                     out, re.M)
    assert re.search(r"^ +output\.\*  \(a \[stage\.options\.output\] table\): ", out, re.M)
    assert "Config(" not in out


def test_unknown_stage_name_says_did_you_mean(capsys):
    assert main(["stages", "bundel"]) == EXIT_STATUS["input"]
    err = capsys.readouterr().err
    assert "did you mean 'bundle'" in err and len(err.strip().splitlines()) == 1


def test_set_overrides_an_option(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["-q", "run", str(BLOCK), "--out", str(out), "--set", "bundle.solver.max_iter=2",
                 "--set", "bundle.solver.tol_rel=1e-3"]) in (0, 1)
    resolved = (out / "project.resolved.toml").read_text()
    assert re.search(r"max_iter = 2\b", resolved) and "tol_rel = 0.001" in resolved
    results = json.loads((out / "results.json").read_text())
    bundle = next(s for s in results["stages"] if s["id"] == "bundle")
    assert bundle["status"] != "ok" or bundle["summary"]["iterations"] <= 2
    # the project file itself is untouched and its input paths still resolve
    assert "max_iter = 2" not in BLOCK.read_text()


@pytest.mark.parametrize("arg, expect", [
    ("bundle.solver.max_iterr=5", "did you mean 'bundle.solver.max_iter'"),
    ("bundel.max_iter=5", "did you mean 'bundle'"),
    ("bundle.solver.max_iter=-5", "must be at least 1"),
    ("max_iter=5", "expected STAGE.OPTION=VALUE"),
    ("bundle.tests.alpha_global=1.5", "must be greater than 0 and less than 1, got 1.5"),
    ("bundle.tests.alpha_global='Baarda'", "expected float | 'B-method'"),
])
def test_set_mistakes_are_one_line_errors(capsys, arg, expect):
    assert main(["validate", str(BLOCK), "--set", arg]) == EXIT_STATUS["input"]
    err = capsys.readouterr().err.strip()
    assert expect in err and len(err.splitlines()) == 1, err


@pytest.mark.parametrize("value", ["0.01", "'B-method'"])
def test_alpha_global_values_validate(capsys, value):
    assert main(["validate", str(BLOCK), "--set", f"bundle.tests.alpha_global={value}"]) == 0


def test_quiet_and_verbose_before_or_after_the_command():
    p = build_parser()
    a = p.parse_args(["-v", "run", "x.toml"])
    assert a.top_verbose and not a.verbose
    a = p.parse_args(["run", "x.toml", "--quiet"])
    assert a.quiet
    with pytest.raises(SystemExit):
        p.parse_args(["run", "x.toml", "--quiet", "--verbose"])


def test_quiet_run_prints_no_progress(tmp_path, capfd):
    assert main(["run", str(BLOCK), "--out", str(tmp_path / "r"), "--quiet"]) == 0
    err = capfd.readouterr().err
    assert "[1/2]" not in err and "[bundle]" not in err


def test_review_summarises_flags_and_where_to_look(tmp_path, capsys):
    run = tmp_path / "demo"
    assert main(["-q", "run", str(DEMO), "--out", str(run)]) == 0
    capsys.readouterr()
    assert main(["review", str(run)]) == 0
    out = capsys.readouterr().out
    # the screening table marks X9 (the +4 mm gross error of Park & Yeu's Data 1)
    assert re.search(r"screening_observations\.csv, column decision: 1 of 18 rows .*X9", out), out
    # blunder-rejection flags X9, Y5, X5 (RRR decides, action = flag): the review names them and the
    # stage's global test
    assert re.search(r"blunders: global test rejected \(σ̂0 too large\), p = ", out), out
    assert re.search(r"blunders_observations\.csv, column decision: 3 of 18 rows \(3 flagged\): .*X5.*Y5.*X9", out), out
    assert "the 2-D views photos/" in out and "report.md, section 'screening'" in out
    assert "every stage ok" in out
    assert "/screening/photos/L/points" not in out        # entities only on request
    assert main(["review", str(run), "--entities"]) == 0
    assert "/screening/photos/L/points" in capsys.readouterr().out


def test_review_counts_against_the_tables(tmp_path):
    """The review's counts are the CSV's, recounted here independently."""
    import csv

    from baarda.pipeline.review import flagged_rows

    t = tmp_path / "x_obs.csv"
    rows = [{"photo": f"P{i}", "point": str(i), "decision": d}
            for i, d in enumerate(["ok", "flagged", "rejected", "ok", "flagged", "inactive"])]
    with t.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["photo", "point", "decision"])
        w.writeheader()
        w.writerows(rows)
    (f,) = flagged_rows(t)
    assert (f.rows, f.total, f.by_value) == (3, 6, {"flagged": 2, "rejected": 1})
    assert f.examples == ["1/P1", "2/P2", "4/P4"]


def test_review_reads_flags_from_results_when_no_table_says_so(tmp_path):
    """A stage whose protocol counts flags but whose tables were not written still appears."""
    import io as _io
    from baarda.pipeline.review import print_review

    results = {"project": {"name": "p"}, "stages": [
        {"id": "bundle", "status": "ok", "summary": {"protocol": {
            "tests": {"n_flagged": 15, "n_rejected": 2},
            "global_test": {"verdict": "rejected (σ̂0 too large)", "rejected": True, "p_value": 1e-5}}}}]}
    out = _io.StringIO()
    print_review(tmp_path, results, {}, out=out)
    assert "bundle: 15 flagged, 2 rejected (results.json; no table with a decision column was written)" in out.getvalue()


# ------------------------------------------------------------------------------------ progress
def test_plain_progress_lines_with_eta():
    s = io.StringIO()
    p = Progress("st", stream=s, enabled=True, live=False, interval=0.0)
    for _ in p.track(range(4), what="images"):
        pass
    lines = s.getvalue().splitlines()
    assert lines[0].startswith("  [st] images 1/4 (25 %)") and "ETA" in lines[0]
    assert "\r" not in s.getvalue()                              # readable in a log file
    assert lines[-1].startswith("  [st] images 4/4 (100 %)") and "ETA" not in lines[-1]


def test_live_progress_is_a_tqdm_bar():
    s = io.StringIO()
    p = Progress("st", stream=s, enabled=True, live=True)
    with p.bar(3, "realisation") as b:
        for _ in range(3):
            b.update()
        p.message("a line above the bar")
    text = s.getvalue()
    assert "realisation" in text and "3/3" in text and "\r" in text
    assert "a line above the bar" in text


def test_disabled_progress_prints_nothing():
    s = io.StringIO()
    p = Progress("st", stream=s, enabled=False)
    assert list(p.track(range(3))) == [0, 1, 2]
    p.message("x")
    assert s.getvalue() == ""


def test_iteration_callback_reports_every_iteration_of_the_adjustment():
    from baarda.pipeline.adjustment import ITERATION_CALLBACK, BundleSettings, adjust
    from baarda.pipeline.synthetic.closerange import make_block, perturb

    rng = np.random.default_rng(1)
    block = perturb(make_block(noise_mm=1e-3, rng=rng)[0], rng)
    seen = []
    token = ITERATION_CALLBACK.set(seen.append)
    try:
        res = adjust(block, BundleSettings())
    finally:
        ITERATION_CALLBACK.reset(token)
    assert len(seen) >= 2
    assert [e.step for e in seen] == list(res.history[1:])      # the observer sees each step as recorded
    assert all(e.max_iter == BundleSettings().max_iter for e in seen)
    assert all(b.seconds >= a.seconds for a, b in zip(seen, seen[1:]))
    # without the observer the numbers are the same
    res2 = adjust(block, BundleSettings())
    np.testing.assert_array_equal(res2.state.XYZ, res.state.XYZ)


def test_bundle_stage_prints_ceres_lines_with_verbose_and_times_all_its_work(tmp_path):
    from baarda.pipeline.runner import run_project

    s = io.StringIO()
    set_verbose(True)
    try:
        out = run_project(BLOCK, tmp_path / "r", verbose=True, stream=s)
    finally:
        set_verbose(False)
    assert out.ok
    text = s.getvalue()
    lines = [ln for ln in text.splitlines() if re.match(r"\s+\[bundle\]\s+\d+\s+\d+\s", ln)]
    adjustments = {int(ln.split()[1]) for ln in lines}
    report = (tmp_path / "r" / "report.md").read_text()
    m = re.search(r"stage time: ([\d.]+) s for (\d+) adjustments \((\d+) iterations", report)
    assert m, report
    assert int(m.group(2)) == len(adjustments) and int(m.group(3)) == len(lines)
    last = float(re.search(r"- time: ([\d.]+) s \(initial", report).group(1))
    assert float(m.group(1)) >= last
    results = json.loads((tmp_path / "r" / "results.json").read_text())
    runner_seconds = next(st["seconds"] for st in results["stages"] if st["id"] == "bundle")
    assert float(m.group(1)) <= runner_seconds + 1e-3


def test_view_opens_the_recordings_in_run_order(tmp_path, capsys):
    run = tmp_path / "demo"
    assert main(["-q", "run", str(DEMO), "--out", str(run)]) == 0
    capsys.readouterr()
    assert main(["view", str(run), "--print"]) == 0
    cmd = capsys.readouterr().out.split()
    assert Path(cmd[0]).name == "rerun"
    assert [Path(c).name for c in cmd[1:]] == ["source.rrd", "screening.rrd", "blunders.rrd"]
    assert main(["view", str(tmp_path / "nowhere")]) == EXIT_STATUS["input"]


def test_rrr_monte_carlo_progress_changes_nothing(tmp_path):
    """A bar over RRR's Monte Carlo tasks (Progress.mapper) gives the very critical value."""
    from baarda.pipeline.runner import run_project
    from baarda.plugins.blunder_rejection.decide import BlunderOptions, run_rrr

    out = run_project(DEMO, tmp_path / "r", verbose=False)
    art = next(a for a in [out.artefacts.get("adjustment")] if a is not None)
    s = BlunderOptions(n_sim=2000)
    plain = run_rrr(art, s, np.random.default_rng(5))
    stream = io.StringIO()
    shown = run_rrr(art, s, np.random.default_rng(5),
                    progress=Progress("blunders", stream=stream, enabled=True, live=False, interval=0.0))
    assert shown.summary["H"] == plain.summary["H"] and shown.rejected == plain.rejected
    last = stream.getvalue().splitlines()[-1]
    m = re.search(r"RRR Monte Carlo task (\d+)/(\d+) \(100 %\)", last)
    assert m and m.group(1) == m.group(2), stream.getvalue()
