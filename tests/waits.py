"""Waiting on what a test can observe on the bus, instead of sleeping for a declaration to travel.

Zenoh tells a publisher or a querier whether something matches it (its matching status): a
subscriber's or a queryable's declaration has reached that session exactly when it does. `Bus`
has no call for it, so these helpers declare their probe on the bus's own zenoh session.
"""

from __future__ import annotations

import asyncio
from typing import Any

from mhrc.core.bus import Bus
from mhrc.testing.world import robots_attached

TIMEOUT = 30.0  # s: generous; a declaration that never arrives fails the test instead of hanging it


async def _matched(entity: Any, what: str, timeout: float) -> None:
    loop = asyncio.get_running_loop()
    ready = asyncio.Event()

    def on_status(status: Any) -> None:
        if status.matching:
            loop.call_soon_threadsafe(ready.set)

    listener = entity.declare_matching_listener(on_status)
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
