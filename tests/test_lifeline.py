"""`mhrc up --processes` and `mhrc eval` as a user runs them: their children die with them even
when they are killed with SIGKILL, `--tick-delay` reaches the world process, and `--json` prints
nothing but JSON."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from waits import until_sync

pytestmark = [
    pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="reads children from /proc (Linux)"),
    pytest.mark.slow,
]


def children(pid: int) -> set[int]:
    out: set[int] = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        text = (task / "children").read_text().split()
        out |= {int(c) for c in text}
    return out


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"


def _cmdline(pid: int) -> list[str]:
    try:
        return Path(f"/proc/{pid}/cmdline").read_text().split("\0")
    except FileNotFoundError:
        return []


def _ticks(trace: Path) -> list[int]:
    """The ticks the world closed, as its trace holds them so far (a line being written is skipped)."""
    ticks = []
    for line in trace.read_text().splitlines() if trace.is_file() else []:
        try:
            msg = json.loads(line).get("msg") or {}
        except ValueError:
            continue
        if msg.get("kind") == "tick":
            ticks.append(msg["tick"])
    return ticks


def _children_die_with_a_killed_parent(
    cmd: list[str], expected: int, working: Callable[[], bool], what: str, env: dict[str, str] | None = None
) -> None:
    """Start `cmd`, wait for its `expected` children and for `working()` (they are busy, not
    starting), SIGKILL the parent: every child must be gone within 20 s."""
    parent = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True, env=env
    )
    kids: set[int] = set()

    def started() -> bool:
        kids.clear()
        kids.update(children(parent.pid))
        return len(kids) >= expected

    try:
        until_sync(started, f"{expected} children ({what})", 60, every=0.5)
        assert len(kids) == expected, f"expected {expected} children ({what}), found {kids}"
        until_sync(working, f"{what} at work", 120)
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        until_sync(
            lambda: not any(alive(k) for k in kids), f"{what} gone after their parent was SIGKILLed", 20, every=0.2
        )
    finally:
        for k in kids:
            if alive(k):
                os.kill(k, signal.SIGKILL)
        if parent.poll() is None:
            parent.kill()


def test_the_world_and_agents_die_with_a_killed_parent(tmp_path: Path) -> None:
    trace = tmp_path / "t.jsonl"
    cmd = [sys.executable, "-m", "mhrc", "up", "--processes", "--quiet", "--tick-delay", "1", "--trace", str(trace)]
    _children_die_with_a_killed_parent(
        cmd, 4, lambda: bool(_ticks(trace)), "the world and 3 agents"
    )  # killed mid-episode: ticks take a second each


def test_eval_workers_die_with_a_killed_coordinator(tmp_path: Path) -> None:
    """The workers' episodes write their traces under TMPDIR: one with a tick is a worker in an episode."""
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    cmd = [
        sys.executable,
        "-m",
        "mhrc",
        "eval",
        "--tasks",
        "pack_objects",
        "--scenes",
        "kitchen",
        "--objects",
        "6",
        "--trials",
        "20",
        "--workers",
        "2",
        "--out",
        str(tmp_path / "ev"),
    ]
    in_episode = lambda: any(_ticks(t) for t in scratch.glob("*/trace.jsonl"))  # noqa: E731
    _children_die_with_a_killed_parent(cmd, 2, in_episode, "the 2 workers", env={**os.environ, "TMPDIR": str(scratch)})


def test_processes_json_prints_only_json_and_the_tick_delay_reaches_the_world(tmp_path: Path) -> None:
    """The world process is started with the tick delay (the pause itself is the world's
    `asyncio.sleep`, not something to time here); stdout holds the metrics' JSON alone."""
    trace = tmp_path / "t.jsonl"
    cmd = [
        sys.executable,
        "-m",
        "mhrc",
        "up",
        "--processes",
        "--json",
        "--horizon",
        "3",
        "--tick-delay",
        "0.5",
        "--trace",
        str(trace),
    ]
    out, err = tmp_path / "stdout.txt", tmp_path / "stderr.txt"
    with out.open("w") as stdout_file, err.open("w") as stderr_file:  # files: a pipe nobody reads yet could fill
        parent = subprocess.Popen(cmd, stdout=stdout_file, stderr=stderr_file, start_new_session=True)
    worlds: list[list[str]] = []

    def world_started() -> bool:
        worlds[:] = [argv for argv in map(_cmdline, children(parent.pid)) if argv[2:4] == ["mhrc", "world"]]
        return bool(worlds) or parent.poll() is not None

    try:
        until_sync(world_started, "the world process", 60, every=0.05)
        parent.wait(timeout=180)
    finally:
        if parent.poll() is None:
            parent.kill()
    stdout, stderr = out.read_text(), err.read_text()
    assert parent.returncode == 0, stderr[-2000:]
    assert len(worlds) == 1 and worlds[0][worlds[0].index("--tick-delay") + 1] == "0.5", worlds
    metrics = json.loads(stdout)  # nothing but the JSON on stdout
    assert metrics["temporal_steps"] == 3
    assert "episode" in stderr  # the agents' lines went to stderr
    ticks = _ticks(trace)
    assert len(ticks) == 3 and ticks == sorted(set(ticks))  # the world closed every tick, one after another
