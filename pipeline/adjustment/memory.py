"""Handing memory the adjustment has freed back to the operating system (peak resident memory).

numpy takes arrays below glibc's ``mmap`` threshold from the C heap, and glibc raises that threshold
(up to 32 MB) each time a larger mapped array is freed — so after the first iterations nearly every
per-observation array lives in the heap.  Freed, their pages stay with the process: the heap only
shrinks from its top, and the holes the solve leaves are too scattered to be reused by the next phase
whole.  At 2 000 photos 0.2 GB of freed pages were still resident when the outputs were written
(docs/benchmarks.md, "Whole runs").  :func:`release_freed` asks the C library to give the free pages
back (``malloc_trim``) at the boundaries of the phases: after the solve, after external reliability,
after the stage's tables.  Nothing alive is touched and no number changes; on a C library without
``malloc_trim`` (macOS, Windows, musl) it does nothing.
"""

from __future__ import annotations

import ctypes
import sys
from functools import lru_cache

__all__ = ["release_freed"]


@lru_cache(maxsize=1)
def _malloc_trim():
    if not sys.platform.startswith("linux"):
        return None
    try:
        trim = ctypes.CDLL(None).malloc_trim        # the process's own C library (glibc)
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


def release_freed() -> bool:
    """Return the C heap's free pages to the operating system; ``True`` when the C library can."""
    trim = _malloc_trim()
    if trim is None:
        return False
    trim(0)
    return True
