"""What a hostile robot's login costs the operator (issue 38), and how long a full disk takes to stop a run.

A secured world on loopback (TLS, a login per participant, its recorder writing the trace) and a
client with alice's login. Each case, on a world of its own, puts its payloads on alice's keys, waits for every ack (and
for a well-formed thought put last to be on disk), and measures the world's log lines it added
and, once the world closed, the trace's bytes beyond those of a world sent nothing. The
baseline, in the same run: 30 well-formed requests.
Then `mhrc up --trace /dev/full` (in-process and --processes): the wall time to its exit, its exit
code and its stderr lines, beside the same episode with a trace on disk. Prints JSON (or writes
it with --out).

    python bench/bench_hostile.py [--out bench/results/hostile.json]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from report import emit
from structlog.testing import capture_logs

from mhrc.core import security
from mhrc.core.bus import Bus, open_client
from mhrc.core.keys import Keys
from mhrc.core.protocol import ActionAck, AttachReply, AttachRequest, Thought, decode, new_goal_id
from mhrc.run.config import ROBOTS
from mhrc.testing import LoopbackWorld, world_on_loopback


def _request(goal: str, **fields: Any) -> bytes:
    base = {"v": 2, "kind": "action_request", "goal_id": goal, "robot": "alice", "agent_id": "mallory", "tick": 0}
    return json.dumps(base | {"action": {"skill": "wait"}} | fields).encode()


def _nested(goal: str, depth: int) -> bytes:
    return (_request(goal)[:-1].decode() + ', "pad": ' + "[" * depth + "]" * depth + "}").encode()


def _thought(**fields: Any) -> bytes:
    return json.dumps({"v": 2, "kind": "thought", "robot": "alice", "tick": 0, "policy": "p"} | fields).encode()


CASES: dict[str, Callable[[int], tuple[str, bytes | None, bytes]]] = {
    # name -> i -> (the key: request or thought, the goal id whose ack is awaited or None, the payload)
    "nothing sent": lambda i: ("request", None, b""),
    "baseline: 30 well-formed requests": lambda i: ("request", f"ok-{i}".encode(), _request(f"ok-{i}")),
    "30 requests with a 3 MB agent_id": lambda i: (
        "request",
        f"big-{i}".encode(),
        _request(f"big-{i}", agent_id="A" * 3_000_000),
    ),
    "1 request picking a 1 MB object name": lambda i: (
        "request",
        b"name",
        _request("name", action={"skill": "pick", "obj": "o" * 1_000_000}),
    ),
    "30 requests nested 50,000 deep": lambda i: ("request", f"deep-{i}".encode(), _nested(f"deep-{i}", 50_000)),
    "10 thoughts with a 3 MB reply": lambda i: ("thought", None, _thought(reply="r" * 3_000_000)),
}
COUNTS = {
    "nothing sent": 0,
    "baseline: 30 well-formed requests": 30,
    "30 requests with a 3 MB agent_id": 30,
    "1 request picking a 1 MB object name": 1,
    "30 requests nested 50,000 deep": 30,
    "10 thoughts with a 3 MB reply": 10,
}


async def _flushed(world: LoopbackWorld, bus: Bus, keys: Keys) -> None:
    """Once the recorder has handled everything alice put before: a thought put last is on disk."""
    marker = new_goal_id()
    bus.put(keys.thought("alice"), Thought(robot="alice", tick=0, policy="sentinel", action=marker))
    while marker not in world.trace.read_text():
        await asyncio.sleep(0.05)


async def one_case(tmp: Path, name: str) -> dict[str, Any]:
    """A fresh secured world, alice attached by hand, the case's payloads put; the trace's size
    once the world has closed (the recorder's pending junk counts written) and the log lines."""
    creds = tmp / "cred"
    if not creds.exists():
        security.make_run_credentials("hostile", ROBOTS, creds)
    trace = tmp / f"trace-{len(list(tmp.glob('trace-*')))}.jsonl"
    sent, t0 = 0, time.perf_counter()
    with capture_logs() as logs:
        async with world_on_loopback(run="hostile", credentials=creds, seed=0, n_objects=3, trace=trace) as world:
            keys = Keys(world.run)
            bus = await open_client(world.endpoint, 30, security=world.config.participant("alice"))
            try:
                acks: set[str] = set()
                bus.subscribe(keys.action_ack("alice"), lambda s: acks.add(decode(s.payload, ActionAck).goal_id))
                replies: list[bytes] = []
                while not replies:  # until the world's attach queryable answers
                    replies = await bus.get(
                        keys.attach("alice"), AttachRequest(robot="alice", agent_id="mallory"), timeout=5
                    )
                assert decode(replies[0], AttachReply).accepted
                await _flushed(world, bus, keys)
                before = len(logs)
                t0 = time.perf_counter()
                goals = []
                for i in range(COUNTS[name]):
                    kind, goal, payload = CASES[name](i)
                    bus.put(keys.action_request("alice") if kind == "request" else keys.thought("alice"), payload)
                    sent += len(payload)
                    if goal is not None:
                        goals.append(goal.decode())
                while not set(goals) <= acks:
                    await asyncio.sleep(0.01)
                await _flushed(world, bus, keys)
                seconds = time.perf_counter() - t0
                lines = len(logs) - before
            finally:
                await bus.close()
    return {"bytes_sent": sent, "trace_bytes": trace.stat().st_size, "log_lines": lines, "seconds": round(seconds, 3)}


async def hostile(tmp: Path) -> dict[str, Any]:
    out = {"nothing sent": await one_case(tmp, "nothing sent")}
    out["nothing sent"]["trace_bytes_added"] = 0
    for name in CASES:
        if name != "nothing sent":
            out[name] = await one_case(tmp, name)
            out[name]["trace_bytes_added"] = out[name]["trace_bytes"] - out["nothing sent"]["trace_bytes"]
    return out


def _said(stderr: str) -> dict[str, int]:
    """Each distinct stderr line (its clock left out, cut to 100 characters) and how often it came."""
    said: dict[str, int] = {}
    for line in stderr.splitlines():
        text = re.sub(r"^\d\d:\d\d:\d\d ", "", line)
        text = re.sub(r"(agent|run)=\S+", r"\1=...", text)[:100].rstrip()
        said[text] = said.get(text, 0) + 1
    return said


def full_disk(tmp: Path) -> dict[str, Any]:
    """`mhrc up --trace /dev/full` beside the same episode with its trace on disk, each as a subprocess."""
    episode = ["--insecure", "--objects", "3", "--horizon", "5", "--quiet"]
    out: dict[str, Any] = {}
    for processes in (False, True):
        for trace in ("/dev/full", str(tmp / "trace.jsonl")):
            args = [sys.executable, "-m", "mhrc", "up", *episode, "--trace", trace]
            args += ["--processes"] if processes else []
            t0 = time.perf_counter()
            done = subprocess.run(args, cwd=tmp, capture_output=True, text=True, timeout=300)
            name = f"{'processes' if processes else 'in-process'}, trace {'/dev/full' if trace == '/dev/full' else 'on disk'}"
            out[name] = {
                "seconds_to_exit": round(time.perf_counter() - t0, 2),
                "exit_code": done.returncode,
                "stderr_lines": len(done.stderr.splitlines()),
                "tracebacks": done.stderr.count("Traceback"),
                "stderr_said": _said(done.stderr),
            }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        report = {
            "bench": "hostile_participant_and_full_disk",
            "hostile_robot": asyncio.run(hostile(Path(d))),
            "full_disk": full_disk(Path(d)),
        }
    emit(report, args.out)


if __name__ == "__main__":
    from mhrc.core import logs

    logs.configure()
    main()
