"""to_the_end: a clean-up step cancelled in the middle still runs to its end (a zenoh session
left open by a cancelled close kept `mhrc world` from exiting after SIGTERM)."""

from __future__ import annotations

import asyncio
import threading

import pytest

from mhrc.core.uncancelled import to_the_end


async def test_a_step_cancelled_in_the_middle_runs_to_its_end_and_the_cancellation_follows() -> None:
    started, release, ended = threading.Event(), threading.Event(), []

    def step() -> str:
        started.set()
        release.wait(30)
        ended.append("closed")
        return "closed"

    async def cleanup() -> None:
        await to_the_end(asyncio.to_thread(step))
        ended.append("after")  # never: the cancellation goes on once the step is over

    task = asyncio.ensure_future(cleanup())
    await asyncio.to_thread(started.wait, 30)
    task.cancel()
    await asyncio.sleep(0)  # the cancellation reaches the task while its step still runs
    assert not task.done() and ended == []
    release.set()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert ended == ["closed"]


async def test_without_a_cancellation_the_steps_result_comes_back() -> None:
    async def step() -> int:
        return 7

    assert await to_the_end(step()) == 7
