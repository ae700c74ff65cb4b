"""glibc's malloc: fewer arenas for the command line, freed heap returned (issue 13: peak memory).

XLA's thread pools make glibc open a malloc arena per thread (up to 8 per core), and each
arena keeps the memory freed in it. In one process with the default 4-log posterior
(``benchmarks/posterior_default.py`` logs, ``sample_posterior`` after a fit) the peak resident
set was 1 350 MB with glibc's default and 890 MB with two arenas; loading the four logs alone
went from 553 MB to 262 MB. :func:`limit_arenas` sets that limit with ``mallopt`` and must run
before JAX starts its threads (the command line calls it first). A library user gets the same
with ``MALLOC_ARENA_MAX=2`` in the environment; an explicit ``MALLOC_ARENA_MAX`` is left alone.
:func:`trim` hands the heap freed so far back to the operating system (``malloc_trim``).
"""

from __future__ import annotations

import ctypes
import os
import sys

__all__ = ["ARENAS", "limit_arenas", "trim"]

ARENAS = 2
_M_ARENA_MAX = -8          # glibc's malloc.h


def _libc():
    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL("libc.so.6")
    except OSError:
        return None


def limit_arenas(arenas: int = ARENAS) -> bool:
    """Limit glibc's malloc arenas to ``arenas``; ``False`` where that does not apply (not
    Linux, not glibc, or ``MALLOC_ARENA_MAX`` already set)."""
    libc = _libc()
    if libc is None or "MALLOC_ARENA_MAX" in os.environ:
        return False
    try:
        return bool(libc.mallopt(_M_ARENA_MAX, int(arenas)))
    except AttributeError:                  # musl or another libc without mallopt
        return False


def trim() -> bool:
    """Return the free pages of every arena to the operating system (glibc's
    ``malloc_trim(0)``): freed memory otherwise stays resident, in holes the next allocations
    may not fit. ``False`` where that does not apply (not Linux, not glibc)."""
    libc = _libc()
    try:
        return libc is not None and bool(libc.malloc_trim(0))
    except AttributeError:
        return False
