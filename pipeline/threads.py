"""The adjustment's own BLAS threads (threadpoolctl), whoever calls it.

The bundle's linear algebra is many small dense products and factorisations (per point, per photo,
per supernode).  Threaded OpenBLAS makes them much slower, not faster: a 441 × 441 Cholesky took
260 ms with two OpenBLAS threads on a busy 2-core machine against 4.8 ms with one, and BAL
problem-49 ran 4.3–4.7 × pycolmap's time through the library against 0.49 × single-threaded
(``docs/benchmarks.md``, "Threads").  So :func:`~.adjust.adjust` and
:func:`~.workflow.adjust_block` run under :func:`blas_threads` — BLAS limited to
``BLAS_THREADS`` (one) thread for their duration, the caller's setting restored afterwards — and
a Python caller, a Dask worker and the CLI get the same speed.  ``BundleSettings.threads`` (the
``threads`` setting) is the adjustment's own parallelism: Python threads over compiled kernels that
release the GIL; BLAS never gets more than one thread per such thread.  The CLI limits the whole
process through :func:`limit_process` (the same mechanism, for the stages besides the bundle).

The limiter is built once per process (threadpoolctl's scan of the loaded libraries takes a few
ms) and skipped when every BLAS pool already has one thread, so repeated small adjustments (data
snooping, Monte Carlo) pay nothing.
"""

from __future__ import annotations

import contextlib
import functools
import threading

__all__ = ["BLAS_THREADS", "blas_threads", "limit_process", "blas_thread_counts", "single_blas"]

BLAS_THREADS = 1
"""BLAS threads inside an adjustment (measured: more never paid on the bundle's systems)."""

_lock = threading.Lock()
_controller = None


def _get_controller():
    """threadpoolctl's controller of the BLAS/OpenMP libraries loaded now (numpy's and scipy's
    OpenBLAS are loaded by the time the adjustment runs)."""
    global _controller
    with _lock:
        if _controller is None:
            import numpy  # noqa: F401  -- the libraries must be loaded before they are scanned
            import scipy.linalg  # noqa: F401
            from threadpoolctl import ThreadpoolController

            _controller = ThreadpoolController()
        return _controller


def blas_thread_counts() -> list[int]:
    """The current thread count of every BLAS/OpenMP pool threadpoolctl sees."""
    return [int(lib.num_threads) for lib in _get_controller().lib_controllers]


def blas_threads(n: int = BLAS_THREADS):
    """Context manager: BLAS/OpenMP pools limited to ``n`` threads (at least 1) inside, restored
    on exit; a no-op when no pool has more."""
    n = max(1, int(n))
    ctl = _get_controller()
    if all(lib.num_threads <= n for lib in ctl.lib_controllers):
        return contextlib.nullcontext()
    return ctl.limit(limits=n)


def limit_process(n: int = BLAS_THREADS) -> None:
    """BLAS/OpenMP pools limited to ``n`` threads for the rest of the process (the CLI)."""
    _get_controller().limit(limits=max(1, int(n)))


def single_blas(fn):
    """Decorator: ``fn`` runs under :func:`blas_threads` (the adjustment's entry points)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with blas_threads():
            return fn(*args, **kwargs)

    return wrapper
