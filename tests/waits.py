"""Waiting on what a test can observe, instead of sleeping for it to happen.

`until` and `until_sync` poll a condition a test can see (an agent's state, a file, a process)
and fail the test, naming what never came, if it is still false after a generous timeout; the
timeout bounds a hang, it is never a claim about speed. On the bus, Zenoh tells a publisher or a querier whether something matches it (its matching status): a
subscriber's or a queryable's declaration has reached that session exactly when it does. `Bus`
has no call for it, so these helpers declare their probe on the bus's own zenoh session.
"""

from __future__ import annotations

import asyncio
import inspect
import os
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zenoh

from mhrc.core.bus import Bus
from mhrc.testing.world import robots_attached

TIMEOUT = 30.0  # s: generous; a declaration that never arrives fails the test instead of hanging it


async def until(condition: Callable[[], object], what: str, timeout: float = TIMEOUT, every: float = 0.01) -> None:
    """Return once `condition()` is true, checked every `every` seconds on the running loop;
    fail the test with `what` (the thing awaited) after `timeout`. A condition may be a coroutine
    function (one that asks a server, say): its answer is awaited."""
    deadline = time.monotonic() + timeout
    while not await _holds(condition):
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout:g} s")
        await asyncio.sleep(every)


async def _holds(condition: Callable[[], object]) -> object:
    got = condition()
    return await got if inspect.isawaitable(got) else got


def until_sync(
    condition: Callable[[], object],
    what: str,
    timeout: float = TIMEOUT,
    every: float = 0.1,
    running: subprocess.Popen[Any] | None = None,
    said: Callable[[], object] = str,
) -> None:
    """`until` for a test without a loop (subprocesses, /proc): blocks the thread between checks.
    `running`: the process whose work is awaited; its end fails the test at once, with `said()`
    (its stderr's tail, say)."""
    deadline = time.monotonic() + timeout
    while not condition():
        if running is not None and running.poll() is not None:
            raise AssertionError(f"{what}: the process ended first (exit {running.returncode}) {said()}")
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout:g} s")
        time.sleep(every)


async def _matched(entity: Any, what: str, timeout: float) -> None:
    loop = asyncio.get_running_loop()
    ready = asyncio.Event()

    def on_status(status: Any) -> None:
        if status.matching:
            loop.call_soon_threadsafe(ready.set)

    # on zenoh's own thread (indirect=False), as the bus's callbacks run: a Python thread of its own
    # would outlive the listener a moment (test_bus counts the threads the bus starts)
    listener = entity.declare_matching_listener(zenoh.handlers.Callback(on_status, indirect=False))
    try:
        if not entity.matching_status.matching:
            try:
                await asyncio.wait_for(ready.wait(), timeout)
            except TimeoutError:
                raise AssertionError(f"{what} never reached this session within {timeout:.0f} s") from None
    finally:
        listener.undeclare()
        entity.undeclare()


async def subscribed(bus: Bus, key: str, timeout: float = TIMEOUT) -> None:
    """Return once a put on `key` from `bus` has a subscriber to reach."""
    await _matched(bus._session.declare_publisher(key), f"a subscriber of {key}", timeout)


async def served(bus: Bus, key: str, timeout: float = TIMEOUT) -> None:
    """Return once a get on `key` from `bus` has a queryable to answer it."""
    await _matched(bus._session.declare_querier(key), f"a queryable of {key}", timeout)


async def robots_alive(bus: Bus, run: str, robots: set[str], timeout: float = TIMEOUT) -> None:
    """Return once `bus` sees the world accept the attach of every robot named (mhrc.testing's
    wait, as a test failure rather than a timeout)."""
    try:
        await robots_attached(bus, run, robots, timeout)
    except TimeoutError as exc:
        raise AssertionError(str(exc)) from None


def interrupt_after_first_row(
    args: list[str], cwd: Path, rows: Path, timeout: float, env: dict[str, str] | None = None
) -> tuple[int, str, str]:
    """Run `mhrc eval` (`args`, a whole command line) in its own process group, wait until its
    first row is written to `rows`, then send the group SIGINT, as a terminal's Ctrl-C. Returns the
    exit code, the rows written before the signal, and stderr (a file, not a terminal: one line per
    episode, no bar). The process never outlives the call (SIGKILL if it did not stop in 120 s)."""
    err = cwd / "stderr.txt"
    with err.open("w") as stderr:
        proc = subprocess.Popen(
            args, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=stderr, text=True, start_new_session=True
        )
    try:
        until_sync(
            lambda: rows.exists() and rows.read_text().endswith("\n"),
            "an episode finished",
            timeout,
            every=0.02,
            running=proc,
            said=lambda: err.read_text()[-3000:],
        )
        before = rows.read_text()
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return proc.returncode, before, err.read_text()
