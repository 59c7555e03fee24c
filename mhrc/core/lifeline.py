"""Children that die with their parent: a process started by `mhrc up --processes` or `mhrc eval`
(the world, the agents, eval workers) must not outlive it, even when the parent is killed with
SIGKILL and has no chance to clean up (the episode would otherwise run on for hours with a hung
model).

The parent puts its pid in the child's environment (`PARENT_ENV`); the child, first thing, asks
the kernel for SIGTERM when its parent dies (Linux `PR_SET_PDEATHSIG`) and, everywhere, watches
`os.getppid()` from a daemon thread. SIGTERM then cancels the child's main task like Ctrl-C, so
its Zenoh sessions close and its trace is flushed in `finally` blocks.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time

PARENT_ENV = "MHRC_DIE_WITH_PARENT"  # the pid of the parent whose death ends this process
PR_SET_PDEATHSIG = 1
POLL = 0.5  # s between getppid() checks


def child_env(env: dict[str, str] | None = None) -> dict[str, str]:
    """The environment for a child that must die with this process."""
    return dict(os.environ if env is None else env, **{PARENT_ENV: str(os.getpid())})


def die_with_parent() -> bool:
    """If started by a parent that asked for it, end this process (SIGTERM) when that parent
    dies; returns whether it was asked. Call it first thing in the child."""
    value = os.environ.get(PARENT_ENV)
    if not value or not value.isdigit():
        return False
    parent = int(value)
    if sys.platform.startswith("linux"):
        import ctypes  # here, not at the top: every command imports this module for PARENT_ENV
        import ctypes.util

        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    if os.getppid() != parent:  # the parent died before we could ask
        os.kill(os.getpid(), signal.SIGTERM)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(POLL)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="mhrc-lifeline", daemon=True).start()
    return True
