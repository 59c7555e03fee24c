"""Memory between episodes of one long-lived process (an eval worker).

An episode's threads (asyncio's executor running PyBullet, zenoh's runtime) free what they
allocated, but glibc keeps the freed pages in its per-thread arenas: a worker's resident size
grew by tens of MB an episode without any object alive (bench/bench_memory.py). `release()`
after an episode hands them back to the OS (`malloc_trim`); elsewhere it does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import sys
from collections.abc import Callable


@functools.cache
def _trim() -> Callable[[int], int] | None:
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim = libc.malloc_trim
    except (OSError, AttributeError):  # not glibc (musl has no malloc_trim): nothing to hand back
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim  # type: ignore[no-any-return]


def release() -> bool:
    """Return the heap's free pages to the OS; whether there was a way to."""
    trim = _trim()
    if trim is None:
        return False
    trim(0)
    return True
