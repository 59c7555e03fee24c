"""`mhrc up --processes` and `mhrc eval` as a user runs them: their children die with them even
when they are killed with SIGKILL, `--tick-delay` reaches the world process, and `--json` prints
nothing but JSON."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = [pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="reads children from /proc (Linux)"), pytest.mark.slow]


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


def _children_die_with_a_killed_parent(cmd: list[str], expected: int, running: float, what: str) -> None:
    """Start `cmd`, wait for its `expected` children, let them work `running` seconds, SIGKILL
    the parent: every child must be gone within 20 s."""
    parent = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    kids: set[int] = set()
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and len(kids) < expected:
            time.sleep(0.5)
            kids = children(parent.pid)
        assert len(kids) == expected, f"expected {expected} children ({what}), found {kids}"
        time.sleep(running)
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and any(alive(k) for k in kids):
            time.sleep(0.2)
        assert not any(alive(k) for k in kids), f"{what} outlived their SIGKILLed parent"
    finally:
        for k in kids:
            if alive(k):
                os.kill(k, signal.SIGKILL)
        if parent.poll() is None:
            parent.kill()


def test_the_world_and_agents_die_with_a_killed_parent(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "mhrc", "up", "--processes", "--quiet", "--tick-delay", "1", "--trace", str(tmp_path / "t.jsonl")]
    _children_die_with_a_killed_parent(cmd, 4, 2.0, "the world and 3 agents")  # running: ticks take a second each


def test_eval_workers_die_with_a_killed_coordinator(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "mhrc", "eval", "--tasks", "pack_objects", "--scenes", "kitchen", "--objects", "6", "--trials", "20",
           "--workers", "2", "--out", str(tmp_path / "ev")]  # fmt: skip
    _children_die_with_a_killed_parent(cmd, 2, 3.0, "the 2 workers")  # running: they are in episodes


def test_processes_json_prints_only_json_and_the_tick_delay_reaches_the_world(tmp_path: Path) -> None:
    trace = tmp_path / "t.jsonl"
    cmd = [sys.executable, "-m", "mhrc", "up", "--processes", "--json", "--horizon", "3", "--tick-delay", "0.5", "--trace", str(trace)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stderr[-2000:]
    metrics = json.loads(done.stdout)  # nothing but the JSON on stdout
    assert metrics["temporal_steps"] == 3
    assert "episode" in done.stderr  # the agents' lines went to stderr
    ticks = [json.loads(line)["t"] for line in trace.read_text().splitlines() if '"kind": "tick"' in line or '"kind":"tick"' in line]
    assert len(ticks) == 3 and all(b - a >= 0.45 for a, b in zip(ticks, ticks[1:]))  # the world paused between ticks
