"""Monte Carlo on a real Dask cluster (LocalCluster, worker processes on 127.0.0.1): identical
results with 1 and 2 workers and in this process."""

import numpy as np
import pytest

from baarda.pipeline import montecarlo as mc
from baarda.pipeline.stats import LinearModel, rrr


def _cluster(n_workers: int):
    from distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address="127.0.0.1:0")
    client = Client(cluster)
    client.wait_for_workers(n_workers, timeout=60)
    return cluster, client


@pytest.fixture(scope="module")
def clients():
    """``{1: client of a 1-worker cluster, 2: client of a 2-worker cluster}``, stopped here."""
    made = {n: _cluster(n) for n in (1, 2)}
    try:
        yield {n: client for n, (_, client) in made.items()}
    finally:
        for cluster, client in made.values():
            client.close()
            cluster.close()


def _draw(rng, i):
    return rng.standard_normal(4).tolist()


def test_map_realisations_identical_with_1_and_2_workers(clients):
    here = mc.map_realisations(_draw, 200, 2024, chunk=9)
    for n, client in clients.items():
        assert mc.map_realisations(_draw, 200, 2024, client=client, chunk=9) == here, f"{n} worker(s)"
    ref = [np.random.default_rng(s).standard_normal(4).tolist() for s in np.random.SeedSequence(2024).spawn(200)]
    assert here == ref


def test_tasks_really_run_on_both_workers(clients):
    import os

    with mc.Engine(client=clients[2]) as eng:
        pids = eng.map(lambda i: (__import__("time").sleep(0.2), os.getpid())[1], range(6))
    assert len(set(pids)) == 2 and os.getpid() not in pids


def test_rrr_critical_value_identical_with_1_and_2_workers(clients):
    g = np.random.default_rng(3)
    A = np.c_[np.ones(12), np.linspace(-5, 5, 12), np.linspace(-5, 5, 12) ** 2]
    l = A @ [1.0, -0.5, 0.1] + 0.1 * g.standard_normal(12)
    l[4] += 2.0                                   # 20 σ at the fifth row
    full = LinearModel(A, l, np.diag(g.uniform(0.5, 2, 12)), sigma0=0.1)   # the correlated-P path too
    for m in (LinearModel(A, l, sigma0=0.1), full):
        here = rrr(m, 3, alpha=0.01, n_sim=3000, rng=7)
        for n, client in clients.items():
            with mc.Engine(client=client) as eng:
                r = rrr(m, 3, alpha=0.01, n_sim=3000, rng=7, mapper=eng)
                assert eng.tasks_sent == 12          # 250 realisations a task
            assert (r.H, r.H_ci, r.n_degenerate) == (here.H, here.H_ci, here.n_degenerate), f"{n} worker(s)"
            np.testing.assert_array_equal(r.p_value, here.p_value)
        assert here.rejected_labels == ["5"]


def test_method_study_identical_on_the_cluster(clients):
    from baarda.plugins.testfield.method_study import MethodStudyConfig, method_study

    cfg = MethodStudyConfig(repetitions=3, methods=("bundle, no APs", "independent models"), single_model=False)
    here = method_study(cfg, 5)
    for n, client in clients.items():
        with mc.Engine(client=client) as eng:
            seen = []
            there = method_study(cfg, 5, mapper=lambda fn, items: eng.map(fn, items, progress=lambda d, t: seen.append(d)))
        assert sorted(seen) == [1, 2, 3]
        assert len(there["rows"]) == len(here["rows"]) == 6
        for a, b in zip(here["rows"], there["rows"]):
            assert (a["variant"], a["repetition"], a["Sx"], a["Sy"], a["Sz"]) == \
                   (b["variant"], b["repetition"], b["Sx"], b["Sy"], b["Sz"]), f"{n} worker(s)"
        assert there["variants"]["independent models"]["Sxy"] == here["variants"]["independent models"]["Sxy"]


def test_control_study_identical_on_the_cluster(clients):
    from baarda.plugins.testfield.control_study import control_study
    from baarda.plugins.testfield.study_config import ControlStudyConfig

    cfg = ControlStudyConfig(repetitions=2, cases=(4,), single_model=False)
    here = control_study(cfg, 8)
    with mc.Engine(client=clients[2]) as eng:
        there = control_study(cfg, 8, mapper=eng)
    key = lambda r: (r["repetition"], r["case"], r["aps"], r["Sx"], r["Sy"], r["Sz"], tuple(r["kept"]))  # noqa: E731
    assert [key(r) for r in there["rows"]] == [key(r) for r in here["rows"]]
    assert len(here["rows"]) == 4


def test_study_stage_uses_the_current_engine(clients, tmp_path):
    """What `baarda run --scheduler …` does: the stage hands its realisations to the engine."""
    from baarda.pipeline.testing import run_stage
    from baarda.plugins.testfield.method_study_stage import MethodStudy

    opts = {"repetitions": 2, "seed": 4, "methods": ["bundle, no APs"], "single_model": False}
    here = run_stage(MethodStudy, {}, opts, tmp_path=tmp_path / "a")
    with mc.Engine(client=clients[2]) as eng, mc.using(eng):
        there = run_stage(MethodStudy, {}, opts, tmp_path=tmp_path / "b")
        assert eng.tasks_sent == 2
    assert there.summary["variants"] == here.summary["variants"]


def test_local_engine_starts_and_stops_its_own_cluster():
    """`--scheduler local`: the first task runs here, the rest on a LocalCluster it starts."""
    with mc.Engine(mc.Scheduler("local", workers=2), min_seconds=0) as eng:
        got = mc.map_realisations(_draw, 60, 11, client=eng, chunk=10)
        assert eng.tasks_sent == 5 and eng._client is not None
        client = eng._client
    assert eng._client is None and client.status == "closed"
    assert got == mc.map_realisations(_draw, 60, 11, chunk=10)


def _die_on_one(x):
    import os

    if x == 1:
        __import__("time").sleep(1.0)     # the others finish first
        os._exit(3)                        # the worker process dies
    if x == 2:
        raise ValueError("task two fails")
    return x * 10


def test_a_dead_worker_or_failing_task_does_not_stop_the_others():
    import dask
    from distributed import Client, KilledWorker, LocalCluster

    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address="127.0.0.1:0") as cluster, Client(cluster) as client:
            with mc.Engine(client=client) as eng:
                got = dict(eng.as_completed(_die_on_one, [0, 1, 2, 3, 4, 5], errors="return"))
    assert sorted(got) == [0, 1, 2, 3, 4, 5]              # every task accounted for, none raised
    assert isinstance(got[1], KilledWorker)
    # a task queued on the dying worker may die with it (allowed-failures 0); the rest come back
    others = [got[k] for k in (0, 3, 4, 5)]
    assert all(v == 10 * k or isinstance(v, KilledWorker) for k, v in zip((0, 3, 4, 5), others))
    assert sum(not isinstance(v, KilledWorker) for v in others) >= 2
    assert isinstance(got[2], ValueError) and "task two fails" in str(got[2])


def test_run_command_sends_a_study_to_a_cluster_by_address(clients, tmp_path, capsys):
    """`baarda run --scheduler tcp://…`: the study's realisations go to the running cluster; the
    run's tables equal those of a run in this process."""
    from baarda.pipeline.cli import main

    p = tmp_path / "study.toml"
    p.write_text('[project]\nname = "study"\nseed = 3\n\n[[stage]]\nuse = "testfield-method-study"\nid = "study"\n'
                 '[stage.options]\nrepetitions = 3\nmethods = ["bundle, no APs"]\nsingle_model = false\n',
                 encoding="utf-8")
    address = clients[2].scheduler.address
    assert address.startswith("tcp://127.0.0.1:")
    assert main(["run", str(p), "--out", str(tmp_path / "dask"), "--quiet", "--scheduler", address]) == 0
    assert main(["run", str(p), "--out", str(tmp_path / "here"), "--quiet", "--scheduler", "sync"]) == 0
    capsys.readouterr()
    tables = sorted(f.name for f in (tmp_path / "here").glob("*.csv"))
    assert tables
    for name in tables:
        assert (tmp_path / "dask" / name).read_text() == (tmp_path / "here" / name).read_text(), name
