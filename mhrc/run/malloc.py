"""Memory between episodes of one long-lived process (an eval worker).

An episode's threads (asyncio's executor running PyBullet, zenoh's runtime) free what they
allocated, but glibc keeps the freed pages in its per-thread arenas (up to eight per core): a
worker's resident size grew by tens of MB an episode without any object alive
(bench/bench_memory.py). Two measures, both glibc's, elsewhere nothing:

- `limit_arenas()` (once, before a worker's first episode): at most ARENAS arenas, so threads share
  the pages one of them freed instead of each keeping its own. The heuristic grid's worker then
  levels off at about 260 MB instead of growing past 400.
- `release()` after an episode: hands the heap's free pages back to the OS (`malloc_trim`), but only
  when the process is resident above TRIM_ABOVE_MB. Trimming after every episode (before) kept a
  worker near 110-170 MB, at the price of faulting the same pages in again next episode (some
  12,000 an episode): in eight paired runs of the default grid, seven took less CPU without it, 6%
  on average, most of it the kernel's; the difference is within the noise of a single run.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os
import sys

ARENAS = 2
TRIM_ABOVE_MB = 384
_M_ARENA_MAX = -8  # glibc's malloc.h


@functools.cache
def _libc() -> ctypes.CDLL | None:
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.malloc_trim.argtypes = [ctypes.c_size_t]
        libc.malloc_trim.restype = ctypes.c_int
        libc.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
        libc.mallopt.restype = ctypes.c_int
    except (OSError, AttributeError):  # not glibc (musl has neither malloc_trim nor M_ARENA_MAX)
        return None
    return libc


@functools.cache
def limit_arenas() -> bool:
    """At most ARENAS malloc arenas in this process from now on (idempotent); whether there was a way to."""
    libc = _libc()
    return libc is not None and libc.mallopt(_M_ARENA_MAX, ARENAS) == 1


def resident_mb() -> float:
    """This process's resident size (MB), 0.0 where /proc does not say."""
    try:
        with open("/proc/self/statm", encoding="ascii") as f:
            pages = int(f.read().split()[1])
    except (OSError, ValueError, IndexError):
        return 0.0
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def release(*, above_mb: float = TRIM_ABOVE_MB) -> bool:
    """Return the heap's free pages to the OS if this process is resident above `above_mb` (0: always);
    whether it did."""
    libc = _libc()
    if libc is None or (above_mb > 0 and resident_mb() <= above_mb):
        return False
    libc.malloc_trim(0)
    return True
