"""`poll`: the one way this package asks again until an answer comes, where no event can say so.

A freshly connected Zenoh session may not see the liveliness tokens at once, and a world that is
still starting up refuses sessions for a moment: there polling is unavoidable. Everywhere else
the code waits on an event, a future or liveliness."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import TypeVar

T = TypeVar("T")


async def poll(attempt: Callable[[], Awaitable[T | None]], *, timeout: float, every: float) -> T | None:
    """Await `attempt()` until it returns something other than None, `every` seconds apart; None
    once `timeout` seconds have passed (the last attempt starts before the deadline, so at least
    one is made). An exception from `attempt` ends the polling and propagates."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while True:
        answer = await attempt()
        if answer is not None or loop.time() >= deadline:
            return answer
        await asyncio.sleep(min(every, max(0.0, deadline - loop.time())))
