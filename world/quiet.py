"""PyBullet without its banner: `from mhrc.world.quiet import pybullet as p`.

pybullet's C extension prints `pybullet build time: ...` with C stdio when it is imported (on
stderr in the wheels of 2025, on stdout in older builds, where on a pipe it sits in C's buffer
and lands at exit in the middle of a command's own output: `mhrc up --json` would not parse).
Every module that needs pybullet imports it through this one helper, which points file
descriptors 1 and 2 at /dev/null for the import and flushes C's buffers before restoring them.
The import stays lazy: importing this module imports nothing.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import sys
import threading
from collections.abc import Iterator
from typing import Any

_lock = threading.Lock()


def _c_fflush() -> None:
    """Flush C stdio's stdout buffer (where the banner waits when stdout is not a terminal)."""
    try:
        import ctypes

        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError, TypeError):  # no C library to ask (e.g. Windows): nothing buffered to lose
        pass


@contextlib.contextmanager
def silenced_output(fds: tuple[int, ...] = (1, 2)) -> Iterator[None]:
    """Discard everything written to these file descriptors (stdout and stderr: Python and C
    alike) inside the block; they are restored, C's buffers flushed first, on the way out."""
    with _lock:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (AttributeError, OSError, ValueError):
                pass
        saved: dict[int, int] = {}
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            for fd in fds:
                try:
                    saved[fd] = os.dup(fd)
                except OSError:  # not open: nothing to silence
                    continue
                os.dup2(devnull, fd)
            yield
        finally:
            _c_fflush()
            for fd, copy in saved.items():
                os.dup2(copy, fd)
                os.close(copy)
            os.close(devnull)


def quiet_import(name: str) -> Any:
    """`importlib.import_module(name)`, its first import with stdout and stderr silenced
    (an import error is still raised, not printed)."""
    if name in sys.modules:
        return sys.modules[name]
    with silenced_output():
        return importlib.import_module(name)


def __getattr__(name: str) -> Any:
    if name == "pybullet":
        return quiet_import("pybullet")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
