"""The Monte Carlo engine without a cluster: seeds per realisation, chunks, schedulers."""

import concurrent.futures

import numpy as np
import pytest

from baarda.pipeline import montecarlo as mc
from baarda.pipeline.errors import InputError
from baarda.pipeline.stats import LinearModel, rrr


def _draw(rng, i):
    return float(rng.standard_normal(3) @ np.arange(1.0, 4.0))


def _reference(n, seed):
    """Independent of the engine: numpy's own spawn, one generator per realisation."""
    return [_draw(np.random.default_rng(s), i) for i, s in enumerate(np.random.SeedSequence(seed).spawn(n))]


def test_realisation_seeds_are_numpys_spawned_children():
    kids = np.random.SeedSequence(42).spawn(30)
    got = mc.realisation_seeds(42, 10, 30)
    for a, b in zip(kids[10:], got):
        assert np.array_equal(a.generate_state(8), b.generate_state(8))
    # a Generator stands for its own seed sequence
    assert mc.root_seed(np.random.default_rng(42)).entropy == 42
    with pytest.raises(ValueError, match="seed"):
        mc.root_seed(None)


@pytest.mark.parametrize("chunk", [1, 7, 100, 1000])
def test_results_do_not_depend_on_the_chunks(chunk):
    assert mc.map_realisations(_draw, 100, 5, chunk=chunk) == _reference(100, 5)


def test_batched_function_gets_the_same_seeds():
    def batch(seeds, idx):
        assert len(seeds) == len(idx)
        return [_draw(np.random.default_rng(s), i) for s, i in zip(seeds, idx)]

    assert mc.map_realisations(batch, 50, 9, chunk=8, batched=True) == _reference(50, 9)

    def wrong(seeds, idx):
        return [0.0]

    with pytest.raises(ValueError, match="returned 1 results"):
        mc.map_realisations(wrong, 10, 9, chunk=5, batched=True)


def test_progress_counts_realisations():
    seen = []
    mc.map_realisations(_draw, 10, 1, chunk=4, progress=lambda d, n: seen.append((d, n)))
    assert seen == [(4, 10), (8, 10), (10, 10)]


def test_sync_and_processes_schedulers_give_the_same_results():
    ref = _reference(40, 3)
    with mc.Engine(mc.Scheduler("sync")) as e:
        assert mc.map_realisations(_draw, 40, 3, client=e, chunk=6) == ref
    with mc.Engine(mc.Scheduler("processes", workers=2)) as e:
        assert mc.map_realisations(_draw, 40, 3, client=e, chunk=6) == ref
        assert e.tasks_sent == 7
        assert sorted(e.as_completed(abs, [-2, 1, -3])) == [(0, 2), (1, 1), (2, 3)]


def test_local_engine_keeps_small_jobs_in_process():
    """The first task is timed here; a job this small never starts a cluster."""
    with mc.Engine(mc.Scheduler("local", workers=2), min_seconds=60) as e:
        assert mc.map_realisations(_draw, 40, 3, client=e, chunk=6) == _reference(40, 3)
        assert e.tasks_sent == 0 and e._client is None
    with mc.Engine(mc.Scheduler("local", workers=2), min_seconds=0) as e:
        assert e.map(abs, [-4]) == [4]                        # one task: never worth a cluster
        assert e.tasks_sent == 0 and e._client is None


def test_nested_maps_run_in_process():
    """Inside a task (a batch's run on a worker) the current engine is not used again."""
    with mc.Engine(mc.Scheduler("sync")) as e, mc.using(e):
        assert mc.mapper() is not None
        inner = e.map(lambda _: (mc.in_task(), mc.mapper()), [0])[0]
    assert inner == (True, None)
    assert mc.current() is None and not mc.in_task()


@pytest.mark.parametrize("text,kind,address", [
    ("local", "local", ""), ("processes", "processes", ""), ("sync", "sync", ""),
    ("127.0.0.1:8786", "address", "tcp://127.0.0.1:8786"),
    ("tcp://10.1.2.3:8786", "address", "tcp://10.1.2.3:8786")])
def test_scheduler_names(text, kind, address):
    s = mc.Scheduler.parse(text, 2)
    assert (s.kind, s.address, s.workers) == (kind, address, 2)


@pytest.mark.parametrize("text", ["lokal", "tcp://host", "http://x:1", "host:port"])
def test_bad_scheduler_is_an_input_error(text):
    with pytest.raises(InputError, match="field '--scheduler': expected local, processes, sync or a Dask"):
        mc.Scheduler.parse(text)


# ------------------------------------------------------------------------------------------- RRR
X = np.array([-4, -3, -2, -1, 0, 1, 2, 3, 4, 10.0])


def _model():
    g = np.random.default_rng(1)
    return LinearModel(np.c_[np.ones(X.size), X], -2 - X + 0.5 * g.standard_normal(X.size), sigma0=0.5)


def test_rrr_through_any_map_is_identical():
    """The library takes any map: built-in (default), an executor's, the engine's."""
    m = _model()
    ref = rrr(m, 2, alpha=0.05, n_sim=4000, rng=5, chunk=500)
    with concurrent.futures.ThreadPoolExecutor(2) as ex:
        th = rrr(m, 2, alpha=0.05, n_sim=4000, rng=5, chunk=500, mapper=ex.map)
    with mc.Engine(mc.Scheduler("processes", workers=2)) as e:
        pr = rrr(m, 2, alpha=0.05, n_sim=4000, rng=5, chunk=500, mapper=e)
    for r in (th, pr):
        assert r.H == ref.H and r.H_ci == ref.H_ci
        np.testing.assert_array_equal(r.p_value, ref.p_value)


def test_rrr_realisation_i_uses_seed_child_i():
    """With a fixed suspect and one realisation per task, each simulated H is the recursive
    residual share of that realisation's own draws (computed here without RRR's code)."""
    m = LinearModel(np.c_[np.ones(6), X[:6]], np.zeros(6), sigma0=0.5)
    n_sim = 9
    # independent reference: realisation i draws e ~ N(0, I) from child i; H = 1 − RSS(C)/RSS(C ∪ s)
    A = np.c_[np.ones(6), X[:6]]
    s, C = 5, [0, 1, 2, 3, 4]
    ref = []
    for child in np.random.SeedSequence(11).spawn(n_sim):
        e = np.random.default_rng(child).standard_normal(6)

        def rss(rows):
            x, *_ = np.linalg.lstsq(A[rows], e[rows], rcond=None)
            return float(np.sum((e[rows] - A[rows] @ x) ** 2))

        ref.append(1 - rss(C) / rss(C + [s]))
    r = rrr(m, 1, alpha=0.2, n_sim=n_sim, rng=11, suspects=[5], chunk=1)
    q = np.sort(ref)[int(np.ceil(0.8 * n_sim)) - 1]
    assert r.H == pytest.approx(q, rel=1e-9)
    # and chunking changes nothing but rounding
    r4 = rrr(m, 1, alpha=0.2, n_sim=n_sim, rng=11, suspects=[5], chunk=4)
    assert r4.H == pytest.approx(r.H, rel=1e-12)
