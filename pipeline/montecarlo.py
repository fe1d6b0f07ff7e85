"""Monte Carlo realisations and batches of runs through Dask (engine layer, not a numerics library).

Everything that repeats a computation many times goes through one function,
:func:`map_realisations`, or through an :class:`Engine` used as a ``map``:

* **Seeds per realisation.**  Realisation ``i`` of a Monte Carlo with seed ``s`` draws from
  ``np.random.default_rng(SeedSequence(s).spawn(n)[i])`` (:func:`realisation_seeds`), whoever
  computes it.  Realisations are grouped into tasks of ``chunk`` consecutive realisations; the
  chunks depend on ``n`` and ``chunk`` only, never on the number of workers, so the results are
  identical on one process, two workers or a cluster.
* **Where tasks run.**  :class:`Scheduler` names it: ``local`` (default: a
  ``distributed.LocalCluster`` of worker processes on 127.0.0.1, started the first time a job is
  big enough to gain from it), ``processes`` (dask's multiprocessing scheduler), ``sync`` (this
  process, one task after the other) or the address of a running Dask scheduler
  (``tcp://host:8786``).  Inside a task — a batch's run on a worker, say — every nested
  Monte Carlo runs in-process with the same seeds.
* **The current engine.**  ``baarda run`` and ``baarda batch`` install one with :func:`using`;
  stages get it through :func:`mapper` (``None`` when none is installed: run in-process).  The
  numerics libraries never import this module or dask: they take a ``mapper`` argument, any
  callable with the signature of the built-in ``map`` (``mapper(fn, items) → results in order``).

dask and distributed are imported lazily, only when tasks leave this process.
"""

from __future__ import annotations

import contextlib
import math
import os
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Iterator, Sequence

import numpy as np

from .errors import InputError

__all__ = ["Scheduler", "Engine", "map_realisations", "realisation_seeds", "root_seed", "spans",
           "using", "current", "mapper", "in_task", "cpu_count"]

SCHEDULER_KINDS = ("local", "processes", "sync")
"""Named schedulers; anything else given to ``--scheduler`` is a Dask scheduler's address."""


def cpu_count() -> int:
    """CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:      # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


# ---------------------------------------------------------------------------------------------- seeds
def root_seed(seed: Any) -> np.random.SeedSequence:
    """The :class:`numpy.random.SeedSequence` a Monte Carlo spawns its realisations from.

    ``seed``: an int, a sequence of ints, a SeedSequence, or a Generator (its own seed sequence:
    ``default_rng(7)`` and ``7`` give the same realisations)."""
    if isinstance(seed, np.random.SeedSequence):
        return seed
    if isinstance(seed, np.random.Generator):
        ss = seed.bit_generator.seed_seq
        if not isinstance(ss, np.random.SeedSequence):
            raise ValueError("the generator was not seeded from a SeedSequence; pass an integer seed")
        return ss
    if seed is None:
        raise ValueError("a Monte Carlo needs a seed (an integer); results must be reproducible")
    return np.random.SeedSequence(seed)


def realisation_seeds(seed: Any, start: int, stop: int) -> list[np.random.SeedSequence]:
    """Seeds of realisations ``start … stop − 1``: exactly ``root_seed(seed).spawn(stop)[start:]``,
    built directly (a task holds only the root and its span)."""
    root = root_seed(seed)
    return [np.random.SeedSequence(root.entropy, spawn_key=tuple(root.spawn_key) + (i,),
                                   pool_size=root.pool_size) for i in range(start, stop)]


def spans(n: int, chunk: int) -> list[tuple[int, int]]:
    """``[(0, chunk), (chunk, 2 chunk), …]`` covering ``range(n)``."""
    chunk = max(1, int(chunk))
    return [(a, min(a + chunk, n)) for a in range(0, int(n), chunk)]


def default_chunk(n: int, tasks: int = 32, smallest: int = 1) -> int:
    """A chunk size that splits ``n`` realisations into about ``tasks`` tasks (a function of ``n``
    alone, so that results never depend on the workers)."""
    return max(smallest, math.ceil(n / tasks)) if n else 1


class _Realisations:
    """One task: realisations ``start … stop − 1`` of ``fn`` (picklable when ``fn`` is)."""

    def __init__(self, fn: Callable, root: np.random.SeedSequence, batched: bool):
        self.fn, self.root, self.batched = fn, root, batched

    def __call__(self, span: tuple[int, int]) -> list:
        start, stop = span
        seeds = realisation_seeds(self.root, start, stop)
        if self.batched:
            out = list(self.fn(seeds, range(start, stop)))
            if len(out) != stop - start:
                raise ValueError(f"a batched Monte Carlo function returned {len(out)} results for "
                                 f"{stop - start} realisations")
            return out
        return [self.fn(np.random.default_rng(s), i) for s, i in zip(seeds, range(start, stop))]


def map_realisations(fn: Callable, n: int, seed: Any, *, client: Any = None, chunk: int | None = None,
                     batched: bool = False, progress: Callable[[int, int], None] | None = None) -> list:
    """Run ``n`` realisations of ``fn`` and return their results in realisation order.

    ``fn(rng, i)`` computes realisation ``i`` from ``rng = default_rng(seeds[i])``; with
    ``batched=True``, ``fn(seeds, indices)`` computes a whole task's realisations at once (a list of
    SeedSequences and the range of their indices) and returns one result per realisation.
    ``client``: where the tasks run — an :class:`Engine`, a ``distributed.Client``, a scheduler's
    address, a :class:`Scheduler`, or None for the current engine (:func:`using`), else this
    process.  ``chunk``: realisations per task (default: ``n`` split into about 32 tasks).
    ``progress(done, n)`` is called as realisations finish.  The results depend on ``fn``, ``n``,
    ``seed`` and ``chunk`` only.
    """
    n = int(n)
    if n < 0:
        raise ValueError("the number of realisations must not be negative")
    root = root_seed(seed)
    parts = spans(n, chunk or default_chunk(n))
    task = _Realisations(fn, root, batched)
    sizes = [b - a for a, b in parts]
    done = [0]

    def step(k, total):     # tasks → realisations for the caller's progress
        done[0] += sizes[k] if k is not None else 0
        if progress:
            progress(done[0], n)

    with _engine_for(client) as eng:
        if eng is None:
            out = []
            for k, p in enumerate(parts):
                out.append(task(p))
                step(k, len(parts))
        else:
            out = eng.map(task, parts, progress_index=step)
    return [r for part in out for r in part]


# ---------------------------------------------------------------------------------------------- where
@dataclass(frozen=True)
class Scheduler:
    """Where tasks run: ``kind`` is ``local``, ``processes``, ``sync`` or ``address``."""

    kind: str = "local"
    address: str = ""
    workers: int | None = None

    @classmethod
    def parse(cls, text: str | None, workers: int | None = None, *, source: str = "--scheduler") -> "Scheduler":
        """``local`` | ``processes`` | ``sync`` | a scheduler address (``tcp://host:port``,
        ``host:port``); an InputError naming ``source`` otherwise."""
        text = (text or "local").strip()
        if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
            raise InputError(f"expected a positive number of workers, got {workers!r}", field="--workers")
        if text in SCHEDULER_KINDS:
            return cls(text, "", workers)
        addr = text if "://" in text else f"tcp://{text}"
        proto, _, rest = addr.partition("://")
        host, _, port = rest.rpartition(":")
        if proto not in ("tcp", "tls", "ucx", "inproc", "ws", "wss") or not host or not port.isdigit():
            raise InputError(f"expected local, processes, sync or a Dask scheduler address such as "
                             f"tcp://127.0.0.1:8786, got {text!r}", field=source)
        return cls("address", addr, workers)

    def describe(self) -> str:
        if self.kind == "address":
            return f"Dask scheduler at {self.address}"
        n = self.workers or cpu_count()
        return {"local": f"local Dask cluster, {n} worker process(es) on 127.0.0.1",
                "processes": f"dask multiprocessing scheduler, {n} process(es)",
                "sync": "this process, one task after the other"}[self.kind]


_IN_TASK = False


def in_task() -> bool:
    """True inside a task an engine runs (nested Monte Carlo then stays in-process)."""
    if _IN_TASK:
        return True
    import sys

    if "distributed" in sys.modules:
        try:
            from distributed import get_worker

            get_worker()
            return True
        except ValueError:
            return False
    return False


class _Task:
    """Runs ``fn(item)`` flagged as inside a task (nested maps run in-process)."""

    def __init__(self, fn: Callable):
        self.fn = fn

    def __call__(self, item):
        global _IN_TASK
        before, _IN_TASK = _IN_TASK, True
        try:
            return self.fn(item)
        finally:
            _IN_TASK = before


class Engine:
    """Runs lists of tasks where :class:`Scheduler` says; a ``map`` for the numerics libraries.

    ``engine(fn, items)`` (or :meth:`map`) returns ``[fn(x) for x in items]``, computed on the
    engine.  With the ``local`` scheduler the cluster is started the first time a map is worth
    it: the first task runs here and is timed, and only when the rest would take longer than
    ``min_seconds`` are the others sent to the cluster (same results either way).  Use as a
    context manager, or call :meth:`close`; a cluster this engine started is stopped then.
    """

    def __init__(self, scheduler: Scheduler | None = None, *, client: Any = None, min_seconds: float = 10.0,
                 log: Callable[[str], None] | None = None):
        self.scheduler = scheduler or Scheduler()
        self.min_seconds = float(min_seconds)
        self._client = client
        self._own: list = []            # what we started (cluster, client), closed by close()
        self._log = log
        self.tasks_sent = 0

    # -- life cycle
    def __enter__(self) -> "Engine":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        while self._own:
            obj = self._own.pop()
            with contextlib.suppress(Exception):
                obj.close()
            if obj is self._client:
                self._client = None

    @property
    def workers(self) -> int:
        return self.scheduler.workers or cpu_count()

    @property
    def distributed(self) -> bool:
        """Tasks go through a ``distributed`` client (local cluster or address)."""
        return self._client is not None or self.scheduler.kind in ("local", "address")

    def client(self):
        """The ``distributed.Client`` (started or connected on first use)."""
        if self._client is None:
            from distributed import Client, LocalCluster

            if self.scheduler.kind == "address":
                try:
                    self._client = Client(self.scheduler.address, timeout="10s")
                except (OSError, TimeoutError) as e:
                    raise InputError(f"cannot reach the Dask scheduler at {self.scheduler.address} "
                                     f"({str(e).splitlines()[0][:160] if str(e) else type(e).__name__})",
                                     field="--scheduler") from None
                self._own.append(self._client)
            elif self.scheduler.kind == "local":
                cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                       host="127.0.0.1", dashboard_address="127.0.0.1:0")
                self._own.append(cluster)
                self._client = Client(cluster)
                self._own.append(self._client)
            else:
                raise ValueError(f"the {self.scheduler.kind!r} scheduler has no distributed client")
            if self._log:
                self._log(f"dask: {self.scheduler.describe()}")
        return self._client

    # -- work
    def __call__(self, fn: Callable, items: Iterable) -> list:
        return self.map(fn, items)

    def map(self, fn: Callable, items: Iterable, *, progress: Callable[[int, int], None] | None = None,
            progress_index: Callable[[int, int], None] | None = None) -> list:
        """``[fn(x) for x in items]`` on the engine, in the order of ``items``.  ``progress(done,
        total)`` after each task; ``progress_index(k, total)`` with the index of the task done."""
        items = list(items)
        total = len(items)
        out: list = [None] * total
        count = [0]

        def done(k):
            count[0] += 1
            if progress:
                progress(count[0], total)
            if progress_index:
                progress_index(k, total)

        todo = list(range(total))
        remote = self._remote_wanted(total)
        if remote and self.scheduler.kind == "local" and self._client is None:
            # is the job worth a cluster?  time the first task here
            t0 = time.perf_counter()
            out[0] = _Task(fn)(items[0])
            done(0)
            todo = todo[1:]
            remote = (time.perf_counter() - t0) * len(todo) > self.min_seconds
        if not todo:
            return out
        if not remote:
            for k in todo:
                out[k] = _Task(fn)(items[k])
                done(k)
            return out
        if self.distributed:
            from distributed import as_completed

            client = self.client()
            futures = client.map(_Task(fn), [items[k] for k in todo], pure=False)
            self.tasks_sent += len(futures)
            index = {f.key: k for f, k in zip(futures, todo)}
            try:
                for f in as_completed(futures):
                    k = index[f.key]
                    out[k] = f.result()
                    done(k)
            finally:
                for f in futures:
                    f.release()
            return out
        # processes: dask's multiprocessing scheduler

        def got(k, r):
            out[k] = r
            done(k)

        self._processes(fn, items, todo, got)
        return out

    def as_completed(self, fn: Callable, items: Sequence, *, errors: str = "raise") -> Iterator[tuple[int, Any]]:
        """``(index, fn(items[index]))`` in the order tasks finish, every task on the engine (a
        batch: nothing is run here first).  A task that fails — ``fn`` raised, or its worker died
        (``distributed.KilledWorker``) — raises when it is reached, or with ``errors="return"`` is
        yielded as ``(index, the exception)`` and the other tasks go on."""
        items = list(items)
        if not items:
            return
        if (self.scheduler.kind == "sync" and self._client is None) or in_task():
            for k, x in enumerate(items):
                try:
                    r = _Task(fn)(x)
                except Exception as e:      # noqa: BLE001 - handed to the caller
                    if errors == "raise":
                        raise
                    r = e
                yield k, r
            return
        if self.distributed:
            from distributed import as_completed

            futures = self.client().map(_Task(fn), items, pure=False)
            self.tasks_sent += len(futures)
            index = {f.key: k for k, f in enumerate(futures)}
            try:
                for f in as_completed(futures):
                    try:
                        r = f.result()
                    except Exception as e:      # noqa: BLE001 - handed to the caller
                        if errors == "raise":
                            raise
                        r = e
                    yield index[f.key], r
            finally:
                for f in futures:
                    f.release()
            return
        import queue
        import threading

        results: queue.Queue = queue.Queue()
        end = object()

        def work():
            try:
                self._processes(fn, items, list(range(len(items))), lambda k, r: results.put((k, r)))
                results.put((end, None))
            except BaseException as e:     # noqa: BLE001 - raised in the consumer
                results.put((end, e))

        threading.Thread(target=work, daemon=True).start()
        while True:
            k, r = results.get()
            if k is end:
                if r is not None:
                    raise r
                return
            yield k, r

    def _processes(self, fn: Callable, items: Sequence, todo: list[int], on_result: Callable) -> None:
        """Tasks ``todo`` on dask's multiprocessing scheduler; ``on_result(k, result)`` as each ends."""
        import dask
        from dask.callbacks import Callback

        task = _Task(fn)
        parts = [dask.delayed(task, pure=False)(items[k]) for k in todo]
        keys = {p.key: k for p, k in zip(parts, todo)}

        class _Progress(Callback):
            def _posttask(self, key, result, dsk, state, worker_id):
                if key in keys:
                    on_result(keys[key], result)

        self.tasks_sent += len(parts)
        with _Progress():
            dask.compute(*parts, scheduler="processes", num_workers=self.workers)

    def _remote_wanted(self, total: int) -> bool:
        if in_task() or total == 0:
            return False
        if self._client is not None:
            return True
        if self.scheduler.kind == "sync":
            return False
        if self.scheduler.kind in ("local", "processes") and self.workers == 1:
            return False
        return True


@contextlib.contextmanager
def _engine_for(client: Any):
    """An engine for ``client`` (see :func:`map_realisations`); engines made here are closed after."""
    if client is None:
        eng = current()
        yield None if eng is None or in_task() else eng
        return
    if isinstance(client, Engine):
        yield client
        return
    if isinstance(client, Scheduler):
        with Engine(client) as eng:
            yield eng
        return
    if isinstance(client, str):
        with Engine(Scheduler.parse(client)) as eng:
            yield eng
        return
    yield Engine(Scheduler("address", "a given client"), client=client)   # a distributed.Client


# ---------------------------------------------------------------------------------------------- current
_CURRENT: list[Engine] = []


@contextlib.contextmanager
def using(engine: Engine):
    """Make ``engine`` the current one inside the block (what :func:`mapper` returns)."""
    _CURRENT.append(engine)
    try:
        yield engine
    finally:
        _CURRENT.remove(engine)


def current() -> Engine | None:
    """The engine installed by :func:`using`, or None."""
    return _CURRENT[-1] if _CURRENT else None


def mapper(progress: Callable[[int, int], None] | None = None) -> Callable | None:
    """A ``map``-like callable on the current engine for a stage to hand to a numerics routine
    (``progress(done, total)`` as tasks finish), or None when no engine is installed or this is
    already a task (the routine then runs in-process)."""
    eng = current()
    if eng is None or in_task():
        return None

    def run(fn, items):
        return eng.map(fn, items, progress=progress)

    return run
