"""Episodes the robots never played (issue 31): a team let go before its first action measured the
machine, not the method. Real worlds on loopback Zenoh, real episodes; the agents' fault is made
by a raw client that attaches every robot and never declares their liveliness tokens (an
overloaded or frozen team's tokens missing at the world's deadline)."""

from __future__ import annotations

import asyncio
import csv
import io
import zlib
from collections import Counter, deque
from pathlib import Path
from typing import Any

from waits import served

from mhrc.core.keys import Keys
from mhrc.core.protocol import AttachReply, AttachRequest, EpisodeDone, RobotDetached, decode, decode_event
from mhrc.core.records import read_records
from mhrc.eval.engine import EvalSpec
from mhrc.eval.episode import run_job, worker_name
from mhrc.eval.jobs import Job, WorkerResult
from mhrc.testing import world_on_loopback

DEADLINE = 1.0  # s: the world's token deadline in these tests (30 by default)


async def _stalled_episode(config: dict[str, Any], trace: Path) -> tuple[list[RobotDetached], EpisodeDone]:
    """One episode of `config` on a real world whose token deadline is DEADLINE: one client attaches
    every robot and declares no liveliness token. The world's detach events and its end, as the
    client saw them; the trace is complete at `trace`."""
    events: list[Any] = []
    ended = asyncio.Event()

    def on_event(sample: Any) -> None:
        event = decode_event(sample.payload)
        events.append(event)
        if isinstance(event, EpisodeDone):
            ended.set()

    async with world_on_loopback(**config, token_deadline=DEADLINE, trace=trace) as world:
        client = await world.client()  # closed with the world
        keys = Keys(world.run)
        client.subscribe(keys.world_event, on_event)
        await served(client, keys.attach("alice"))  # the world's scene is built and it takes attaches
        for robot in world.config.robots:
            replies = await client.get(
                keys.attach(robot), AttachRequest(robot=robot, agent_id=f"{robot}-stalled"), timeout=30
            )
            assert replies and decode(replies[0], AttachReply).accepted, robot
        await asyncio.wait_for(ended.wait(), 120)  # every event before it, on the same key, has come
        await world.done(60)  # and the trace is written
    detached = [e for e in events if isinstance(e, RobotDetached)]
    return detached, next(e for e in events if isinstance(e, EpisodeDone))


class _Stalling:
    """An executor (mhrc.eval.engine.Executor) that runs each attempt in this process, as a pool
    worker does (run_job), except the first `stall[key]` attempts of a key: those are stalled
    episodes of the job's config."""

    def __init__(self, tmp: Path, stall: dict[str, int]) -> None:
        self.tmp, self.stall = tmp, stall
        self.attempts: Counter[str] = Counter()
        self._jobs: deque[Job] = deque()

    async def __aenter__(self) -> _Stalling:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    def submit(self, job: Job) -> None:
        self._jobs.append(job)

    async def next(self) -> WorkerResult:
        job = self._jobs.popleft()
        self.attempts[job.key] += 1
        if self.attempts[job.key] > self.stall.get(job.key, 0):
            return await run_job(job, worker_name())
        trace = self.tmp / f"{job.key.replace('/', '_')}-{self.attempts[job.key]}.jsonl"
        await _stalled_episode(job.config.model_dump(exclude={"run"}, exclude_defaults=True), trace)
        return WorkerResult(key=job.key, worker="stalled", trace_z=zlib.compress(trace.read_bytes()))

    async def stop(self, grace: float) -> list[WorkerResult]:
        return []


async def test_a_team_without_tokens_is_let_go_at_the_deadline_and_its_episode_is_invalid(tmp_path: Path) -> None:
    """The world detaches each tokenless robot at its configured deadline, with its agent's id; the
    episode ends at tick 0 (no_agents), and its metrics (an eval row's) say invalid, with the typed
    cause not_played, instead of a TS-0 failure that pulls a setting's mean down."""
    from mhrc.analysis.metrics import Invalid, from_trace

    config = {"task": "pack_objects", "scene": "kitchen", "seed": 0, "n_objects": 3, "schedule": "sequential"}
    detached, done = await _stalled_episode(config, tmp_path / "t.jsonl")
    assert sorted((d.robot, d.agent_id) for d in detached) == [
        ("alice", "alice-stalled"),
        ("bob", "bob-stalled"),
        ("david", "david-stalled"),
    ]
    assert (done.reason, done.metrics.temporal_steps, done.metrics.action_steps) == ("no_agents", 0, 0)
    m = from_trace(read_records(tmp_path / "t.jsonl"))
    assert (m.valid, m.invalid_code) == (False, Invalid.NOT_PLAYED)
    assert m.invalid_reason is not None


async def test_an_unplayed_episode_is_run_again_and_never_averaged_into_a_score(tmp_path: Path) -> None:
    """`mhrc eval`'s engine: an episode its robots never played is run again, as an infrastructure
    failure is. One that is played the second time gives an ordinary row; one never played is
    written as an invalid row with its code, and the summaries leave it out."""
    from mhrc.eval.engine import RETRIES, _drive

    spec = EvalSpec(tasks=("pack_objects",), scenes=("kitchen",), objects=(3,), trials=2, horizon=20)
    never, second = "pack_objects/kitchen/3/0", "pack_objects/kitchen/3/1"
    executor = _Stalling(tmp_path, {never: RETRIES + 1, second: 1})
    rows = [r.flat() for r in await _drive(spec.validate(), tmp_path / "ev", False, executor, None)]
    assert executor.attempts == {never: RETRIES + 1, second: 2}
    by_key = {r["key"]: r for r in rows}
    assert sorted(by_key) == [never, second]  # one row each: a retried attempt leaves none
    assert (by_key[never]["valid"], by_key[never]["invalid_code"], by_key[never]["reason"]) == (
        False,
        "not_played",
        "no_agents",
    )
    assert by_key[never]["temporal_steps"] == 0
    played = by_key[second]
    assert (played["valid"], played["invalid_code"], played["worker"]) == (True, None, worker_name())
    assert played["temporal_steps"] > 0
    assert not (tmp_path / "ev" / "errors.jsonl").exists()
    (cell,) = csv.DictReader(io.StringIO((tmp_path / "ev" / "summary.csv").read_text()))
    assert (cell["episodes"], cell["invalid_left_out"]) == ("1", "1")
    assert float(cell["ts"]) == played["temporal_steps"]  # the unplayed episode's TS 0 is not averaged in
    assert float(cell["succ"]) == float(played["success"])
