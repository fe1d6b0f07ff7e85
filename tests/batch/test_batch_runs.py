"""`baarda batch` end to end on real Dask clusters: three projects with one broken, a sweep."""

import csv
import tomllib
from pathlib import Path

import pytest

from baarda.pipeline import montecarlo as mc
from baarda.pipeline.batch import plan_batch, run_batch, summary_rows
from baarda.pipeline.cli import main

ROOT = Path(__file__).resolve().parents[2]
FIX = ROOT / "fixtures" / "paper000"


@pytest.fixture(scope="module")
def client():
    """A real Dask cluster (2 worker processes on 127.0.0.1), stopped here."""
    from distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address="127.0.0.1:0")
    c = Client(cluster)
    try:
        c.wait_for_workers(2, timeout=60)
        yield c
    finally:
        c.close()
        cluster.close()


def _broken(tmp_path) -> Path:
    p = tmp_path / "broken" / "bad.toml"
    p.parent.mkdir()
    p.write_text('[project]\nname = "broken"\n\n[[stage]]\nuse = "comparator"\n[stage.options]\n'
                 'path = "missing.cmp"\n', encoding="utf-8")
    return p


def test_cli_batch_of_three_projects_one_broken(tmp_path, capsys):
    """Default scheduler: baarda starts (and stops) a local cluster of 2 worker processes."""
    out = tmp_path / "batch"
    code = main(["batch", str(FIX / "data1.toml"), str(FIX / "data2.toml"), str(_broken(tmp_path)),
                 "--out", str(out), "--workers", "2"])
    cap = capsys.readouterr()
    assert code == 1                                    # one run failed
    assert "local Dask cluster, 2 worker process(es) on 127.0.0.1" in cap.err
    assert sorted(ln.split("]")[0] for ln in cap.err.splitlines() if ln.startswith("[")) == ["[1/3", "[2/3", "[3/3"]
    assert "runs: 2/3 ok" in cap.out
    rows = summary_rows(out)
    assert [r["name"] for r in rows] == ["data1", "data2", "bad"]          # job order
    ok = {r["name"]: r for r in rows}
    assert ok["data1"]["status"] == ok["data2"]["status"] == "ok"
    assert ok["data1"]["stages_ok"] == ok["data1"]["stages"] == 3
    assert ok["bad"]["status"] == "failed" and ok["bad"]["failure"] == "input"
    assert "bad.toml" in ok["bad"]["message"] and "missing.cmp" in ok["bad"]["message"]
    for name in ("data1", "data2"):
        assert (out / "runs" / name / "results.json").is_file()
    import json

    assert json.loads((out / "runs" / "bad" / "results.json").read_text())["ok"] is False   # the failed run's own record
    with open(out / "summary.csv", newline="", encoding="utf-8") as f:
        table = list(csv.DictReader(f))
    assert [t["status"] for t in table] == ["ok", "ok", "failed"]
    assert table[0]["source.observations"] == "18"          # a stage's summary figure as a column
    # the runs compared: each run's σ̂0, global test and counts are its own results.json's and its tables'
    for t in table[:2]:
        res = json.loads((out / "runs" / t["name"] / "results.json").read_text())
        p = next(s for s in res["stages"] if s["id"] == "blunders")["summary"]["protocol"]
        assert t["adjustment"] == "blunders" and float(t["sigma0_hat"]) == p["sigma0_hat"]
        assert t["global_test"] == p["global_test"]["verdict"] and float(t["global_test_p"]) == p["global_test"]["p_value"]
        with open(out / "runs" / t["name"] / "blunders_observations.csv", newline="", encoding="utf-8") as f:
            decision = [r["decision"] for r in csv.DictReader(f)]
        assert int(t["n_flagged"]) == decision.count("flagged") == p["tests"]["n_decided"]
        assert int(t["n_rejected"]) == decision.count("rejected") == 0
    assert table[2]["sigma0_hat"] == ""                     # the failed run has none
    md = (out / "summary.md").read_text(encoding="utf-8")
    assert "3 of 3 run(s) done, 2 ok, 1 failed" in md and "| bad | failed (input) |" in md
    assert "## Runs compared" in md and "![σ̂0, global test, flagged and rejected per run](summary.png)" in md
    assert (out / "summary.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the same summary as a self-contained page, each complete run linked to its own report.html
    from html.parser import HTMLParser

    from baarda.pipeline.html import external_references

    page = (out / "summary.html").read_text(encoding="utf-8")
    links: list[str] = []

    class _Links(HTMLParser):
        def handle_starttag(self, tag, attrs):
            links.extend(v for k, v in attrs if tag == "a" and k == "href")

    _Links().feed(page)
    # each complete run linked from the runs table and from "Runs compared"
    assert links == ["runs/data1/report.html", "runs/data2/report.html"] * 2 and not external_references(page)
    assert all((out / link).is_file() for link in links)
    assert "3 of 3 run(s) done, 2 ok, 1 failed" in page and "failed (input)" in page
    assert "<figure><svg" in page and "Runs compared" in page
    # a second batch into the same directory replaces the complete runs
    assert main(["batch", str(FIX / "data1.toml"), "--out", str(out), "--scheduler", "sync", "--quiet"]) == 0
    assert [r["name"] for r in summary_rows(out)] == ["data1"]


def test_quality_columns_of_a_bundle_run():
    """The quality columns come from the run's bundle protocol (not the last adjustment), camera
    parameters with their unit in the column name."""
    from baarda.pipeline.batch import quality

    prot = {"kind": "bundle", "sigma0_hat": 1.2, "dof": 40,
            "global_test": {"verdict": "rejected (σ̂0 too large)", "rejected": True, "p_value": 1e-3},
            "tests": {"n_flagged": 4, "n_rejected": 2},
            "check": {"n": 3, "Sx": 0.01, "Sy": 0.02, "Sz": 0.03, "unit": "m"},
            "cameras": [{"camera": "A", "parameters": [{"name": "c", "value": 24.1, "unit": "mm"},
                                                       {"name": "K1", "value": 1e-4, "unit": "mm⁻²"},
                                                       {"name": "skew", "value": 0.0, "unit": "1"}]}]}
    other = {"kind": "adjustment", "sigma0_hat": 9.0, "dof": 3, "global_test": {}, "tests": {}}
    q = quality([{"id": "bundle", "summary": {"protocol": prot}}, {"id": "b2", "summary": {"protocol": other}}])
    assert q["adjustment"] == "bundle" and q["sigma0_hat"] == 1.2 and q["global_test_p"] == 1e-3
    assert (q["n_flagged"], q["n_rejected"], q["check_rmse_z"], q["check_unit"]) == (4, 2, 0.03, "m")
    assert q["camera.c_mm"] == 24.1 and q["camera.K1_per_mm2"] == 1e-4 and "camera.skew" not in q
    assert quality([{"id": "source", "summary": {"photos": 2}}]) == {}


def test_sweep_on_a_given_cluster(tmp_path, client):
    sweep = tmp_path / "sweep.csv"
    sweep.write_text("name,screening.threshold_mm,blunders.alpha_rrr,blunders.method\n"
                     "strict,1.5,0.01,rrr\n"
                     ",3.0,0.001,ids\n"
                     "loose,5,0.001,\n", encoding="utf-8")
    out = tmp_path / "sweep-batch"
    jobs = plan_batch([FIX / "data1.toml"], out, sweep=sweep)
    assert [j.name for j in jobs] == ["strict", "data1-002", "loose"]
    assert jobs[1].source == f"{sweep}:3"
    seen = []
    with mc.Engine(client=client) as eng:
        rows = run_batch(jobs, out, eng, progress=seen.append)
        assert eng.tasks_sent == 3
    assert len(seen) == 3 and all(r["status"] == "ok" for r in rows), [r["message"] for r in rows]
    for row, (thr, alpha, method) in zip(rows, [(1.5, 0.01, "rrr"), (3.0, 0.001, "ids"), (5.0, 0.001, "all")]):
        resolved = tomllib.loads((Path(row["run_dir"]) / "project.resolved.toml").read_text(encoding="utf-8"))
        opts = {s["id"]: s["options"] for s in resolved["stage"]}
        assert opts["screening"]["threshold_mm"] == thr
        assert opts["blunders"]["alpha_rrr"] == alpha and opts["blunders"]["method"] == method
        assert row["overrides"]["screening.threshold_mm"] == thr
    # the sweep's project files live in the batch directory and run again on their own
    variant = out / "projects" / "strict.toml"
    assert "[strict]" in tomllib.loads(variant.read_text(encoding="utf-8"))["project"]["name"]
    assert main(["run", str(variant), "--out", str(tmp_path / "again"), "--quiet", "--scheduler", "sync"]) == 0
    md = (out / "summary.md").read_text(encoding="utf-8")
    assert "screening.threshold_mm" in md.splitlines()[4]


def test_batch_refuses_a_foreign_directory_and_a_bad_scheduler(tmp_path, capsys):
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    assert main(["batch", str(FIX / "data1.toml"), "--out", str(foreign)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "not a baarda batch directory" in err and "Traceback" not in err
    assert main(["batch", str(FIX / "data1.toml"), "--out", str(tmp_path / "b"), "--scheduler", "nowhere"]) == 2
    assert "field '--scheduler'" in capsys.readouterr().err
    assert main(["batch", str(tmp_path / "nope-*.toml"), "--out", str(tmp_path / "c")]) == 2
    assert "no project file matches" in capsys.readouterr().err


def test_run_takes_the_scheduler_options(tmp_path, capsys):
    assert main(["run", str(FIX / "data1.toml"), "--out", str(tmp_path / "r"), "--scheduler", "10.0.0.1"]) == 2
    assert "field '--scheduler': expected local, processes, sync or a Dask scheduler address" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["run", str(FIX / "data1.toml"), "--workers", "0"])


def test_a_run_whose_task_never_returns_is_a_failed_row(tmp_path):
    """The engine hands back the exception of a lost task (a dead worker); the batch records it
    and keeps the other rows."""
    jobs = plan_batch([FIX / "data1.toml", FIX / "data2.toml"], tmp_path / "b")

    class Lossy(mc.Engine):
        def as_completed(self, fn, items, *, errors="raise"):
            assert errors == "return"
            yield 1, RuntimeError("worker tcp://127.0.0.1:1 died")
            yield from ((0, r) for _, r in super().as_completed(fn, items[:1], errors=errors))

    rows = run_batch(jobs, tmp_path / "b", Lossy(mc.Scheduler("sync")))
    assert [r["status"] for r in rows] == ["ok", "failed"]
    assert rows[1]["failure"] == "internal" and "RuntimeError: worker tcp://127.0.0.1:1 died" in rows[1]["message"]
    assert [r["name"] for r in summary_rows(tmp_path / "b")] == ["data1", "data2"]
