"""The leader protocol with every robot's agent its own OS process (`mhrc agent --protocol
leader`, each building its own robot's leader policy), on a real world on loopback: the elected
leader's process is killed with SIGKILL mid-episode, the others see it detach, hold a new
election, and the team still solves the episode."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from waits import until

from mhrc.agents.protocols import leader_talk
from mhrc.core.keys import Keys
from mhrc.core.protocol import ActionResult, Communicate, RobotDetached, TickClosed, decode_event
from mhrc.core.records import read_records
from mhrc.testing import world_on_loopback

ROBOTS = ("alice", "bob", "david")


@pytest.mark.slow
async def test_the_leaders_process_killed_with_sigkill_the_team_elects_again_and_solves_it(tmp_path: Path) -> None:
    trace = tmp_path / "t.jsonl"
    async with world_on_loopback(
        protocol="leader", task="pack_objects", scene="bathroom", n_objects=3, seed=0, horizon=50, trace=trace
    ) as world:
        ticks: list[int] = []
        client = await world.client()

        def on_event(sample: Any) -> None:
            ev = decode_event(sample.payload)
            if isinstance(ev, TickClosed):
                ticks.append(ev.tick)

        client.subscribe(Keys(world.run).world_event, on_event)
        procs: dict[str, subprocess.Popen[bytes]] = {}
        try:
            for r in ROBOTS:
                cmd = [sys.executable, "-m", "mhrc", "agent", "--robot", r, "--run", world.run]
                cmd += ["--connect", world.endpoint, "--insecure", "--protocol", "leader"]
                log = (tmp_path / f"{r}.txt").open("w")
                procs[r] = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
            await until(lambda: ticks and max(ticks) >= 3, "the third tick closed", timeout=120)
            os.kill(procs["david"].pid, signal.SIGKILL)  # david, the scout, was elected: kill -9 his agent
            done = await world.done(300)
        finally:
            for p in procs.values():
                if p.poll() is None:
                    os.killpg(p.pid, signal.SIGKILL)
                p.wait()
    assert procs["david"].returncode == -signal.SIGKILL
    assert done.metrics.success, (done.reason, done.metrics)
    records = read_records(trace)
    assert any(isinstance(r.msg, RobotDetached) and r.msg.robot == "david" for r in records)
    said = [
        (r.msg.robot, leader_talk.parse(r.msg.action.content))
        for r in records
        if isinstance(r.msg, ActionResult) and isinstance(r.msg.action, Communicate)
    ]
    leaders = [s.leader for _, s in said if isinstance(s, leader_talk.Assign)]
    assert leaders[0] == "david" and "bob" in leaders, leaders  # bob allocates after the new election
    assert any(robot == "alice" and isinstance(s, leader_talk.Status) for robot, s in said)  # told the new leader


def test_mhrc_agent_refuses_a_whole_team_protocol_in_one_line() -> None:
    """One agent drives one robot: a whole-team protocol's planner is refused before anything starts."""
    cmd = [sys.executable, "-m", "mhrc", "agent", "--robot", "alice", "--connect", "tcp/127.0.0.1:9", "--insecure"]
    done = subprocess.run([*cmd, "--protocol", "centralized"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "drives the whole team" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr and "insecure" not in done.stderr  # refused before the bus notice
