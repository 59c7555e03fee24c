"""`to_the_end`: await a clean-up step that a cancellation must not cut short.

A task cancelled while it awaits a thread (`asyncio.to_thread`) or a session's close stops
awaiting, but the step goes on without it, and what comes after it in the `finally` (closing
the bus, the simulator) never runs: a zenoh session left open keeps the process from exiting.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable
from typing import TypeVar

T = TypeVar("T")


async def to_the_end(step: Awaitable[T]) -> T:
    """Await `step` to its end even if the awaiting task is cancelled meanwhile; the cancellation
    is raised again once the step is over."""
    fut = asyncio.ensure_future(step)
    try:
        return await asyncio.shield(fut)
    except asyncio.CancelledError:
        await asyncio.wait({fut})  # the step ends before the cancellation goes on
        raise
