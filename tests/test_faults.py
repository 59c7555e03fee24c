"""Faults a user causes on purpose (issue 14): Ctrl-C once and twice on `mhrc eval` and on
`mhrc up --processes`, as a terminal sends it (SIGINT to the whole foreground process group).

Every command runs in a session of its own, so its process group is exactly it and its
children; "no stray processes" means that group is empty afterwards. Time bounds are generous
(the goal is 3 s; the figures go in the closing note, not into assertions that a loaded
machine could fail)."""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from waits import until_sync

HANG = 120.0  # s: not a speed bound (exits take 1-3 s): a command that never exits fails here, its group killed
ROOT = Path(__file__).resolve().parents[1]


def _start(args: list[str], tmp_path: Path) -> subprocess.Popen[str]:
    """The command in its own process group, like a command in a terminal; its output goes to
    files (a progress bar would fill a pipe nobody reads)."""
    out = (tmp_path / "stdout.txt").open("w")
    err = (tmp_path / "stderr.txt").open("w")
    return subprocess.Popen(
        [sys.executable, "-m", "mhrc", *args],
        cwd=tmp_path,
        stdout=out,
        stderr=err,
        text=True,
        start_new_session=True,
    )


def _stderr(tmp_path: Path) -> str:
    return (tmp_path / "stderr.txt").read_text(errors="replace")


def _until(predicate: Any, timeout: float, what: str, proc: subprocess.Popen[str]) -> None:
    def seen() -> bool:
        if proc.poll() is not None:
            pytest.fail(f"the command ended (exit {proc.returncode}) before {what}")
        return bool(predicate())

    try:
        until_sync(seen, what, timeout)
    except AssertionError:
        _kill_group(proc)
        raise


def _interrupt(proc: subprocess.Popen[str], times: int = 1) -> None:
    """Send Ctrl-C `times` times to the command's process group and wait for it to exit."""
    for i in range(times):
        os.killpg(proc.pid, signal.SIGINT)
        if i + 1 < times:
            time.sleep(0.3)
    try:
        proc.wait(timeout=HANG)
    except subprocess.TimeoutExpired:
        _kill_group(proc)
        pytest.fail(f"still running {HANG} s after {times} Ctrl-C")


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    # a zombie still counts for killpg until reaped: look at the states
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            stat = Path(f"/proc/{pid}/stat").read_text()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()
        if int(fields[2]) == pgid and fields[0] != "Z":
            return True
    return False


def _no_strays(pgid: int, timeout: float = 10.0) -> None:
    try:
        until_sync(lambda: not _group_alive(pgid), "the command's processes gone after it exited", timeout)
    except AssertionError:
        os.killpg(pgid, signal.SIGKILL)
        raise


def _kill_group(proc: subprocess.Popen[str]) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait()


def _rows(path: Path) -> list[dict[str, Any]]:
    if not path.exists():
        return []
    text = path.read_text()
    assert text == "" or text.endswith("\n"), "a row was cut off"
    return [json.loads(line) for line in text.splitlines()]


EVAL = [
    "eval",
    "--tasks",
    "pack_objects",
    "--scenes",
    "kitchen,bedroom",
    "--objects",
    "3,4,5",
    "--workers",
    "2",
    "--out",
    "ev",
]


@pytest.mark.slow
@pytest.mark.parametrize("times", [1, 2])
def test_ctrl_c_on_eval_exits_soon_and_keeps_every_finished_row(times: int, tmp_path: Path) -> None:
    proc = _start(EVAL, tmp_path)
    rows_path = tmp_path / "ev" / "episodes.jsonl"
    _until(lambda: len(_rows(rows_path)) >= 2, 240, "two finished episodes", proc)
    before = _rows(rows_path)
    _interrupt(proc, times)
    err = _stderr(tmp_path)
    assert proc.returncode == 130 or (times == 2 and proc.returncode == -signal.SIGINT), (proc.returncode, err[-2000:])
    after = _rows(rows_path)
    assert [r["key"] for r in after[: len(before)]] == [r["key"] for r in before], "a finished row was lost"
    assert len({r["key"] for r in after}) == len(after), "a row was written twice"
    if times == 1:
        assert (
            "interrupted: stopping the workers" in err
            and "every finished episode is kept in" in err
            and "finish the grid with: mhrc eval --resume --out ev" in err
        ), err[-2000:]
    else:  # the second quit at once, unless the first had already finished stopping when it came
        assert "quitting at once" in err or "\nstopped: " in err, err[-2000:]
    assert "Traceback" not in err, err[-3000:]
    _no_strays(proc.pid)
    print(f"{times} Ctrl-C: exited with {len(after)} rows kept")
    # --resume continues that grid where it stopped, never duplicating (another grid is refused, not merged)
    resumed = subprocess.run(
        [sys.executable, "-m", "mhrc", "eval", "--resume", "--out", "ev", "--workers", "2"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    keys = [r["key"] for r in _rows(rows_path)]
    assert len(keys) == len(set(keys)) == 6 and "pack_objects/kitchen/3/0" in keys


@pytest.mark.slow
def test_ctrl_c_on_up_processes_leaves_a_complete_trace(tmp_path: Path) -> None:
    trace = tmp_path / "t.jsonl"
    proc = _start(["up", "--processes", "--quiet", "--tick-delay", "0.3", "--trace", str(trace)], tmp_path)

    def ticks() -> int:
        if not trace.exists():
            return 0
        return trace.read_text().count('"kind": "tick"') + trace.read_text().count('"kind":"tick"')

    _until(lambda: ticks() >= 3, 120, "three ticks in the trace", proc)
    _interrupt(proc, 1)
    err = _stderr(tmp_path)
    assert proc.returncode == 130 and "Traceback" not in err, err[-3000:]
    # said once, by the parent (the world's and agents' processes ignore Ctrl-C and are stopped by it)
    said = [line for line in err.splitlines() if line.strip() and not line.startswith("credentials in")]
    assert len(said) == 1 and re.fullmatch(
        rf"interrupted at tick \d+, the trace is at {re.escape(str(trace))}", said[0]
    ), err
    lines = trace.read_text().splitlines()
    done = [json.loads(line)["msg"] for line in lines if '"episode_done"' in line]
    assert done and done[-1]["reason"] == "stopped", "the trace lacks the final episode_done"
    assert all(json.loads(line) for line in lines)  # every line whole
    _no_strays(proc.pid)


@pytest.mark.slow
def test_double_ctrl_c_on_up_processes_exits_at_once(tmp_path: Path) -> None:
    proc = _start(
        ["up", "--processes", "--quiet", "--tick-delay", "0.3", "--trace", str(tmp_path / "t.jsonl")], tmp_path
    )
    _until(
        lambda: (tmp_path / "t.jsonl").exists() and '"tick"' in (tmp_path / "t.jsonl").read_text(), 120, "a tick", proc
    )
    _interrupt(proc, 2)
    err = _stderr(tmp_path)
    # 130, or killed by the second SIGINT itself when it lands while Python finalizes (handlers reset): either way, at once
    assert proc.returncode in (130, -signal.SIGINT) and "Traceback" not in err, (proc.returncode, err[-3000:])
    _no_strays(proc.pid)


# --------------------------------------------------------------------------- noise under attack


@pytest.mark.slow
async def test_a_flood_of_junk_costs_counts_not_copies(tmp_path: Path) -> None:
    """2,000 malformed requests of 1 kB each on Alice's key while the episode runs: the world
    goes on and the team still succeeds; the world logs one warning per interval with the count
    held back, and the trace holds `junk` counts instead of 2,000 copies and 2,000 rejections."""
    import io

    import structlog

    from mhrc.analysis.metrics import from_trace
    from mhrc.core import logs
    from mhrc.core.bus import Bus
    from mhrc.core.keys import Keys
    from mhrc.core.protocol import ActionRequest
    from mhrc.core.records import read_records
    from mhrc.run.config import EpisodeConfig
    from mhrc.run.inprocess import up_in_process

    flood = 2000
    junk = (
        b'{"v": 2, "robot": "alice", "agent_id": "x", "tick": 0, "action": {"skill": "teleport"}, "pad": "'
        + b"x" * 900
        + b'"}'
    )

    def attack(bus: Bus, run: str) -> None:
        """From the world's own session, as soon as the world has subscribed (its token says so)."""

        def flood_now() -> None:
            for _ in range(flood):
                bus.put(Keys(run).action_request("alice"), junk)

        when_the_world_listens(bus, run, flood_now)

    clean = await up_in_process(EpisodeConfig.build(seed=0, n_objects=3, trace=tmp_path / "clean.jsonl").resolved())
    out = io.StringIO()
    structlog.configure(
        processors=[structlog.processors.add_log_level, structlog.dev.ConsoleRenderer(colors=False)],
        wrapper_class=structlog.make_filtering_bound_logger(30),
        logger_factory=structlog.PrintLoggerFactory(file=out),
    )
    try:
        done = await up_in_process(
            EpisodeConfig.build(seed=0, n_objects=3, trace=tmp_path / "t.jsonl").resolved(), observe=attack
        )
    finally:
        logs.configure("info")
    assert done.reason == clean.reason == "success" and done.metrics.temporal_steps == clean.metrics.temporal_steps
    warnings = [line for line in out.getvalue().splitlines() if "malformed action request rejected" in line]
    assert 1 <= len(warnings) <= 5, len(warnings)  # one per 5 s interval, not one per message
    rows = read_records(tmp_path / "t.jsonl")
    counted = {
        key: sum(r.junk.count for r in rows if r.junk is not None and r.key.endswith(key))
        for key in ("/action/request", "/action/ack")
    }
    assert counted == {"/action/request": flood, "/action/ack": flood}, counted
    assert not any(isinstance(r.msg, ActionRequest) and "teleport" in r.msg.model_dump_json() for r in rows)
    size, clean_size = (tmp_path / "t.jsonl").stat().st_size, (tmp_path / "clean.jsonl").stat().st_size
    assert size < 1.2 * clean_size + 10_000, (size, clean_size)  # 2 MB of junk would have been copied
    assert from_trace(rows).rejected_actions == flood
    print(f"junk flood: trace {size} B against {clean_size} B without it; {len(warnings)} warning line(s)")


async def test_a_flood_of_rejected_requests_costs_counts_not_copies(tmp_path: Path) -> None:
    """2,000 well-formed requests on Alice's key from an agent the world does not know: each is
    rejected; the trace copies the first few (request and ack) and counts the rest as `junk`,
    and the metrics and diagnostics still count every rejection, by reason."""
    from mhrc.analysis.diagnostics import diagnose
    from mhrc.analysis.metrics import from_trace
    from mhrc.core.bus import Bus
    from mhrc.core.keys import Keys
    from mhrc.core.protocol import ActionAck, ActionRequest, Wait
    from mhrc.core.records import read_records
    from mhrc.core.trace import REJECTIONS_IN_FULL
    from mhrc.run.config import EpisodeConfig
    from mhrc.run.inprocess import up_in_process

    flood = 2000
    forged = [ActionRequest(robot="alice", agent_id="not-attached", tick=0, action=Wait()) for _ in range(flood)]

    def attack(bus: Bus, run: str) -> None:
        def flood_now() -> None:
            for req in forged:
                bus.put(Keys(run).action_request("alice"), req)

        when_the_world_listens(bus, run, flood_now)

    done = await up_in_process(
        EpisodeConfig.build(seed=0, n_objects=3, trace=tmp_path / "t.jsonl").resolved(), observe=attack
    )
    assert done.reason == "success"
    rows = read_records(tmp_path / "t.jsonl")
    ids = {r.goal_id for r in forged}
    copied = [r for r in rows if getattr(r.msg, "goal_id", None) in ids]
    counted = {
        key: sum(r.junk.count for r in rows if r.junk is not None and r.key.endswith(key))
        for key in ("/action/request", "/action/ack")
    }
    requests = sum(1 for r in copied if isinstance(r.msg, ActionRequest))
    acks = sum(1 for r in copied if isinstance(r.msg, ActionAck))
    assert requests == acks and 1 <= acks < 40 * REJECTIONS_IN_FULL, (
        requests,
        acks,
    )  # a few per interval, each request beside its ack
    assert counted == {"/action/request": flood - requests, "/action/ack": flood - acks}, counted
    assert (tmp_path / "t.jsonl").stat().st_size < 1_000_000  # 2,000 of each copied came to ~1 MB
    assert from_trace(rows).rejected_actions >= flood
    assert diagnose(rows).rejected_by_reason.get("not_attached", 0) >= flood


def when_the_world_listens(bus: Any, run: str, act: Callable[[], None]) -> None:
    """Call `act` once, on the loop, when the world's liveliness token appears: the world declares
    it after its subscriptions (its episode task may start after an observer's first callback)."""
    from mhrc.core.keys import Keys

    fired = False

    def on_token(sample: Any) -> None:
        nonlocal fired
        if sample.is_put and not fired:
            fired = True
            act()

    bus.watch_liveliness(Keys(run).alive_world, on_token)


# --------------------------------------------------------------------------- startup errors


@pytest.mark.slow
@pytest.mark.parametrize("holder", ["another program", "another mhrc world"])
def test_a_port_in_use_is_one_line_and_exit_2(holder: str, tmp_path: Path) -> None:
    import socket

    from mhrc.core.endpoints import free_port

    port = free_port()
    sock = None
    world = None
    try:
        if holder == "another program":
            sock = socket.socket()
            sock.bind(("127.0.0.1", port))
            sock.listen()
        else:
            (tmp_path / "first").mkdir()
            world = _start(
                ["world", "--port", str(port), "--run", "first", "--insecure", "--quiet"], tmp_path / "first"
            )
            from mhrc.core.endpoints import ListenError, check_listen

            def listening() -> bool:
                assert world is not None and world.poll() is None, "the first world ended before it listened"
                try:
                    check_listen("127.0.0.1", port)
                except ListenError:
                    return True
                return False

            until_sync(listening, "the first world listening", 60)
        for args in (
            ["world", "--port", str(port), "--insecure"],
            ["up", "--port", str(port)],
            ["up", "--processes", "--port", str(port), "--insecure"],
            ["up", "--processes", "--port", str(port)],
        ):
            out = subprocess.run(
                [sys.executable, "-m", "mhrc", *args], cwd=tmp_path, capture_output=True, text=True, timeout=HANG
            )
            lines = [line for line in out.stderr.splitlines() if line.startswith("mhrc:")]
            assert out.returncode == 2, (args, out.returncode, out.stderr[-2000:])
            assert len(lines) == 1 and f"port {port} is already in use" in lines[0] and "--port" in lines[0], out.stderr
            proto = "tcp" if "--insecure" in args else "tls"  # the endpoint as the world would have listened
            assert f"{proto}/127.0.0.1:{port}" in lines[0], (args, lines[0])
            assert "Traceback" not in out.stderr and "Unable to connect" not in out.stderr, out.stderr
    finally:
        if sock is not None:
            sock.close()
        if world is not None:
            _kill_group(world)


@pytest.mark.slow
def test_a_world_killed_under_its_agent_is_one_line_and_exit_2(tmp_path: Path) -> None:
    """`mhrc agent` whose world is killed (SIGKILL) mid-episode, and one with no world at all:
    one line naming the cause, exit 2, no traceback."""
    from mhrc.core.endpoints import free_port

    port = free_port()
    (tmp_path / "w").mkdir()
    (tmp_path / "a").mkdir()
    world = _start(["world", "--port", str(port), "--run", "gone", "--insecure", "--tick-delay", "0.5"], tmp_path / "w")
    agent = None
    try:
        _until(lambda: "world listening" in _stderr(tmp_path / "w"), 60, "the world listening", world)
        agent = _start(
            [
                "agent",
                "--robot",
                "alice",
                "--run",
                "gone",
                "--connect",
                f"tcp/127.0.0.1:{port}",
                "--insecure",
                "--log-level",
                "info",
            ],
            tmp_path / "a",
        )
        _until(lambda: "attached" in _stderr(tmp_path / "a"), 60, "alice attached", agent)
        os.killpg(world.pid, signal.SIGKILL)
        try:
            code = agent.wait(timeout=HANG)
        except subprocess.TimeoutExpired:
            pytest.fail(f"the agent still ran {HANG} s after its world was killed")
        err = _stderr(tmp_path / "a")
        lines = [line for line in err.splitlines() if line.startswith("mhrc agent alice:")]
        assert code == 2 and len(lines) == 1 and "world disappeared" in lines[0] and "Traceback" not in err, err[-2000:]
        nobody = subprocess.run(
            [
                sys.executable,
                "-m",
                "mhrc",
                "agent",
                "--robot",
                "bob",
                "--connect",
                f"tcp/127.0.0.1:{port}",
                "--insecure",
                "--attach-timeout",
                "3",
            ],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert nobody.returncode == 2 and "Traceback" not in nobody.stderr, nobody.stderr[-2000:]
        assert len([line for line in nobody.stderr.splitlines() if line.startswith("mhrc")]) == 1, nobody.stderr
    finally:
        _kill_group(world)
        if agent is not None:
            _kill_group(agent)


@pytest.mark.slow
def test_an_agent_failing_before_the_start_ends_the_episode_at_once(tmp_path: Path) -> None:
    """Alice's agent fails before it attaches (here: a replay of a heuristic trace, which holds no
    prompts to replay): the world would wait for her forever; `mhrc up` says why in one line and
    exits 2 instead (it hung until killed before)."""
    (tmp_path / "h").mkdir()
    heuristic = tmp_path / "h" / "trace.jsonl"
    first = subprocess.run(
        [sys.executable, "-m", "mhrc", "up", "--insecure", "-q", "--trace", str(heuristic)],
        cwd=tmp_path / "h",
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert first.returncode == 0, first.stderr[-2000:]
    out = subprocess.run(
        [sys.executable, "-m", "mhrc", "up", "--insecure", "-q", "--llm", f"alice=replay:{heuristic}"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=HANG,
    )
    lines = [line for line in out.stderr.splitlines() if line.startswith("mhrc up:")]
    assert out.returncode == 2 and len(lines) == 1 and "holds no LLM prompts for alice" in lines[0], out.stderr[-2000:]
    assert "Traceback" not in out.stderr, out.stderr[-2000:]


# --------------------------------------------------------------------------- a frozen agent


@pytest.mark.slow
@pytest.mark.parametrize("schedule", ["lockstep", "sequential"])
async def test_an_agent_frozen_and_resumed_attaches_again(schedule: str, tmp_path: Path) -> None:
    """David's agent (its own process) is frozen with SIGSTOP until the world has detached him
    (his lease expired), then resumed: he attaches again and plays on, instead of exiting with
    "the world disappeared" while the world was fine; under the sequential schedule he is
    mostly frozen while awaiting his turn, which probes and attaches again the same way."""
    from mhrc.core.protocol import RobotAttached, RobotDetached
    from mhrc.testing import world_on_loopback

    # under lockstep Alice and Bob play on while David is frozen, and can finish the task without
    # him: the episode must outlast his resumption, which a loaded machine slows (a CI run ended
    # the episode 14 s after his detach, before he attached again; here it takes about 2 s)
    delay = 0.8 if schedule == "lockstep" else 0.4
    async with world_on_loopback(
        seed=0, n_objects=4, tick_delay=delay, schedule=schedule, trace=tmp_path / "t.jsonl"
    ) as world:
        events: list[Any] = []
        news = asyncio.Event()
        client = await world.client()

        def on_event(sample: Any) -> None:
            from mhrc.core.protocol import decode_event

            events.append(decode_event(sample.payload))
            news.set()

        from mhrc.core.keys import Keys

        client.subscribe(Keys(world.run).world_event, on_event)
        log = (tmp_path / "david.txt").open("w")
        david = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "mhrc",
                "agent",
                "--robot",
                "david",
                "--run",
                world.run,
                "--connect",
                world.endpoint,
                "--insecure",
            ],
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        try:
            alice = await world.agent("alice", "heuristic")
            bob = await world.agent("bob", "heuristic")

            async def until(pred: Any) -> None:
                while not pred():
                    news.clear()
                    await asyncio.wait_for(news.wait(), 120)

            if schedule == "sequential":  # frozen at once: David, last in the order, awaits his first turn
                await until(lambda: sum(isinstance(e, RobotAttached) and e.robot == "david" for e in events) == 1)
            else:  # frozen mid-episode, awaiting a result
                await until(
                    lambda: (
                        sum(isinstance(e, RobotAttached) and e.robot == "david" for e in events) == 1
                        and any(getattr(e, "kind", "") == "tick" for e in events)
                    )
                )
            os.kill(david.pid, signal.SIGSTOP)
            await until(
                lambda: any(isinstance(e, RobotDetached) and e.robot == "david" for e in events)
            )  # his lease ran out
            os.kill(david.pid, signal.SIGCONT)
            await until(lambda: sum(isinstance(e, RobotAttached) and e.robot == "david" for e in events) >= 2)
            done = await world.done(180)
            code = await asyncio.to_thread(david.wait, 60)
        finally:
            if david.poll() is None:
                os.killpg(david.pid, signal.SIGKILL)
                david.wait()
            await client.close()
        out = (tmp_path / "david.txt").read_text()
        assert code == 0 and "world disappeared" not in out and f"david: episode {world.run} ended" in out, out[-2000:]
        assert done.reason == "success", done.metrics
        await asyncio.gather(alice, bob, return_exceptions=True)


@pytest.mark.slow
async def test_an_agent_that_attaches_without_a_token_is_detached_not_waited_for(tmp_path: Path) -> None:
    """A client that attaches and never declares its liveliness token (killed or frozen right
    after the attach reply, or a hand-written agent that skips it) is detached at the world's token
    deadline, with the reason and its agent id, so the sequential schedule does not wait for it forever."""
    from mhrc.core.keys import Keys
    from mhrc.core.protocol import AttachReply, AttachRequest, RobotAttached, RobotDetached, decode, decode_event
    from mhrc.testing import world_on_loopback

    grace = 3.0  # s: the world's token deadline (30 by default)
    async with world_on_loopback(
        seed=0, n_objects=3, schedule="sequential", token_deadline=grace, trace=tmp_path / "t.jsonl"
    ) as world:
        client = await world.client()
        detached: list[RobotDetached] = []
        seen: list[
            RobotAttached | RobotDetached
        ] = []  # alice's attach and detach, in the world's order (one publisher, one key)
        got = asyncio.Event()

        def on_event(sample: Any) -> None:
            event = decode_event(sample.payload)
            if isinstance(event, RobotAttached | RobotDetached) and event.robot == "alice":
                seen.append(event)
            if isinstance(event, RobotDetached):
                detached.append(event)
                got.set()

        try:
            k = Keys(world.run)
            client.subscribe(k.world_event, on_event)
            replies: list[bytes] = []
            deadline = time.monotonic() + 120
            while not replies and time.monotonic() < deadline:  # until the world serves attaches (its scene is built)
                replies = await client.get(
                    k.attach("alice"), AttachRequest(robot="alice", agent_id="tokenless"), timeout=2
                )
            assert replies and decode(replies[0], AttachReply).accepted
            await asyncio.wait_for(got.wait(), grace + 30)
            assert (
                detached[0].robot == "alice"
                and detached[0].agent_id == "tokenless"
                and "no liveliness token" in detached[0].reason
            )
            assert (
                f"within {grace:g} s of attaching" in detached[0].reason
            )  # the token deadline, not any other cause, let it go
            # the world admitted the tokenless agent, then let it go: the deadline ran from an attach that happened
            assert [(type(e).__name__, e.agent_id) for e in seen] == [
                ("RobotAttached", "tokenless"),
                ("RobotDetached", "tokenless"),
            ]
            # a real agent takes the robot afterwards, and the episode is played to the end
            agents = [await world.agent(r, "heuristic") for r in ("alice", "bob", "david")]
            done = await world.done(180)
            assert done.reason == "success"
            await asyncio.gather(*agents, return_exceptions=True)
        finally:
            await client.close()
