"""Compiled per-element loops with numba, for every numerical library of baarda.

``JIT(__file__)`` makes a decorator for one module's kernels: ``numba.njit`` on first call (numba is
imported only when a kernel runs, so importing baarda stays cheap), with ``nogil`` and numpy's
error model, and an on-disk cache when one can be written — a read-only install without a user
cache compiles in each process instead.  numba keys its cache by the source file's stamp when the
kernel is compiled; a file edited since this process imported it would get this process's (old)
code under the new stamp, so such a kernel is compiled without a cache.

Used by the adjustment core (:mod:`baarda.pipeline.adjustment.kernels`) and the camera models
(:mod:`baarda.pipeline.camera.kernels`).
"""

from __future__ import annotations

import os
import threading
import warnings

__all__ = ["JIT", "source_stamp"]


def source_stamp(path) -> tuple[float, int] | None:
    """``(mtime, size)`` of ``path``, as numba's cache index keys a source file (None: unreadable)."""
    try:
        st = os.stat(path)
        return st.st_mtime, st.st_size
    except OSError:
        return None


class JIT:
    """The kernel decorator of one source file (``JIT(__file__)``); ``imported_stamp`` is the
    file's stamp when the module was imported."""

    def __init__(self, source):
        self.source = source
        self.imported_stamp = source_stamp(source)
        self.lock = threading.Lock()

    def __call__(self, fn) -> "Kernel":
        return Kernel(fn, self)

    def compile(self, fn):
        import numba

        opts = dict(nogil=True, error_model="numpy")
        cache = source_stamp(self.source) == self.imported_stamp
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", numba.NumbaWarning)
                return numba.njit(cache=cache, **opts)(fn)
        except RuntimeError:                           # "cannot cache function …: no locator available"
            return numba.njit(**opts)(fn)


class Kernel:
    """A function compiled on its first call (one compilation when threads call first together)."""

    def __init__(self, fn, owner: JIT):
        self.fn = fn
        self.owner = owner
        self.compiled = None
        self.__doc__ = fn.__doc__

    def __call__(self, *args):
        if self.compiled is None:
            with self.owner.lock:
                if self.compiled is None:
                    self.compiled = self.owner.compile(self.fn)
        return self.compiled(*args)
