"""What a new user sees of `mhrc up` at the console (issue 20): `--quiet`, the summary table,
lines in tick order, the start timeout, a model server that is not there, and an agent whose
tick another process took. Real worlds, real Zenoh on loopback, the real command line."""

from __future__ import annotations

import asyncio
import contextlib
import io
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from json_rows import records
from rich.console import Console
from sweep import sweep
from waits import served

from mhrc.agents.heuristic import heuristic_policy
from mhrc.agents.policy import Decision, Policy
from mhrc.core.bus import Bus, Sample
from mhrc.core.endpoints import free_port
from mhrc.core.keys import Keys
from mhrc.core.protocol import (
    ActionAck,
    ActionRequest,
    ActionResult,
    AttachReply,
    AttachRequest,
    EpisodeStarted,
    Observation,
    RobotAttached,
    RobotMessage,
    ScenarioEvent,
    Wait,
    decode,
    decode_event,
    encode,
)
from mhrc.core.records import TraceLine
from mhrc.testing import world_on_loopback


def mhrc(*args: str, cwd: Path, timeout: float = 240) -> subprocess.CompletedProcess[str]:
    """The real command line, in `cwd` (where runs/ goes)."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "200"}
    return subprocess.run(
        [sys.executable, "-m", "mhrc", *args], cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env
    )


# --------------------------------------------------------------------------- 6. a tick taken by another process


class GatedPolicy:
    """A real policy whose first decision waits until `gate` is set, so a test can act first."""

    def __init__(self, inner: Policy, gate: asyncio.Event) -> None:
        self.inner, self.gate, self.name = inner, gate, inner.name

    async def decide(self, obs: Observation) -> Decision:
        await self.gate.wait()
        return await self.inner.decide(obs)

    def record(self, result: ActionResult) -> None:
        self.inner.record(result)


async def _attach_by_hand(bus: Bus, keys: Keys, robot: str) -> None:
    """Attach `robot` with a live token and never act: the lockstep tick stays open."""
    await served(bus, keys.attach(robot))  # the world's attach queryable reached this session
    replies = await bus.get(keys.attach(robot), AttachRequest(robot=robot, agent_id=f"hand-{robot}"), timeout=2.0)
    assert replies, f"the world never answered {robot}'s attach"
    assert decode(replies[0], AttachReply).accepted
    bus.declare_token(keys.alive_robot(robot))


@pytest.mark.slow
async def test_an_agent_whose_tick_was_taken_backs_off_instead_of_resubmitting_in_a_loop(tmp_path: Path) -> None:
    """On the open bus another process can act for alice with her (public) agent id. Her own
    request for that tick is then rejected; re-attaching gives her the same tick, so before
    the fix she planned, sent and was rejected again at once, hundreds of times a second.
    Now she waits for the tick to close, and then plays on."""
    async with world_on_loopback(seed=0, horizon=5, trace=tmp_path / "trace.jsonl") as world:
        bus = await world.client()
        keys = Keys(world.run)
        attached: dict[str, str] = {}
        started = asyncio.Event()

        def on_event(sample: Sample) -> None:
            ev = decode_event(sample.payload)
            if isinstance(ev, RobotAttached):
                attached[ev.robot] = ev.agent_id
            elif isinstance(ev, EpisodeStarted):
                started.set()

        acks: list[ActionAck] = []
        many, stolen_ack, own_accepted = asyncio.Event(), asyncio.Event(), asyncio.Event()
        stolen = ""

        def on_ack(sample: Sample) -> None:
            ack = decode(sample.payload, ActionAck)
            acks.append(ack)
            if ack.goal_id == stolen:
                stolen_ack.set()
            elif ack.accepted:
                own_accepted.set()
            if sum(not a.accepted for a in acks) >= 50:
                many.set()

        bus.subscribe(keys.world_event, on_event)
        bus.subscribe(keys.action_ack("alice"), on_ack)
        gate = asyncio.Event()
        await world.agent("alice", GatedPolicy(heuristic_policy("alice"), gate))
        for robot in ("bob", "david"):
            await _attach_by_hand(bus, keys, robot)
        await asyncio.wait_for(started.wait(), 30)
        assert "alice" in attached

        # another process takes alice's action of tick 0
        req = ActionRequest(robot="alice", agent_id=attached["alice"], tick=0, action=Wait())
        stolen = req.goal_id
        bus.put(keys.action_request("alice"), req)
        await asyncio.wait_for(stolen_ack.wait(), 10)
        assert acks[-1].accepted

        gate.set()  # alice plans tick 0 now: her request is rejected, the tick being taken
        with contextlib.suppress(TimeoutError):  # a bound on the run, not an assertion on time
            await asyncio.wait_for(many.wait(), 3.0)
        rejected = [a for a in acks if not a.accepted]
        assert 1 <= len(rejected) <= 5, f"{len(rejected)} rejections: {rejected[-1].reason}"
        assert not own_accepted.is_set()

        # bob and david act: tick 0 closes, and alice plays tick 1
        for robot in ("bob", "david"):
            bus.put(
                keys.action_request(robot), ActionRequest(robot=robot, agent_id=f"hand-{robot}", tick=0, action=Wait())
            )
        await asyncio.wait_for(own_accepted.wait(), 30)


# --------------------------------------------------------------------------- 1, 2. --quiet and the summary table


TABLE_ROW = re.compile(r"^[│┌└├]")


def _table_rows(text: str) -> dict[str, str]:
    rows = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip("│ ").split("│")]
        if line.startswith("│") and len(cells) == 2:
            rows[cells[0]] = cells[1]
    return rows


@pytest.mark.parametrize("processes", sweep([False, True], ids=["in-process", "processes"]))
def test_quiet_prints_only_the_summary_table_with_the_reports_makespan(processes: bool, tmp_path: Path) -> None:
    from mhrc.analysis.metrics import from_trace
    from mhrc.core.records import read_records

    trace = tmp_path / "t.jsonl"
    run = mhrc("up", "--quiet", "--trace", str(trace), *(["--processes"] if processes else []), cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-3000:]
    lines = run.stdout.splitlines()
    assert lines[0].startswith("episode ") and lines[0].endswith(": success"), run.stdout  # the table's title
    assert all(TABLE_ROW.match(line) for line in lines[1:]), run.stdout  # and nothing but the table
    assert run.stderr == "", run.stderr  # nothing went wrong, so nothing on stderr either (--secure: no warning)
    rows = _table_rows(run.stdout)
    assert "simulated time" not in rows  # the sum of every robot's skill time, which no report shows
    report = from_trace(read_records(trace))
    assert rows["makespan"] == f"{report.makespan:.1f} s simulated"  # the report's figure, under the report's name


def test_the_summary_table_shows_the_makespan_not_the_sum_of_skill_times() -> None:
    from mhrc.core.protocol import EpisodeDone, Metrics
    from mhrc.run.console import summary_table

    metrics = Metrics(
        success=True,
        partial_success=1.0,
        placed=4,
        total=4,
        temporal_steps=17,
        action_steps=42,
        action_steps_per_robot={"alice": 17, "bob": 9, "david": 16},
        sim_time=215.2,
        makespan=147.08,
    )
    out = io.StringIO()
    Console(file=out, width=120).print(summary_table(EpisodeDone(run="r", reason="success", metrics=metrics)))
    rows = _table_rows(out.getvalue())
    assert rows["makespan"] == "147.1 s simulated" and "215" not in out.getvalue()


def test_the_summary_table_calls_the_sum_over_robots_actions_not_action_steps() -> None:
    """The summary's AS is the steps in which any robot acted (docs/evaluation.md); the table's
    42 is every robot's actions summed, so it must not be called "action steps" too."""
    from mhrc.core.protocol import EpisodeDone, Metrics
    from mhrc.run.console import summary_table

    metrics = Metrics(
        success=True,
        partial_success=1.0,
        placed=4,
        total=4,
        temporal_steps=17,
        action_steps=42,
        action_steps_per_robot={"alice": 17, "bob": 9, "david": 16},
    )
    out = io.StringIO()
    Console(file=out, width=120).print(summary_table(EpisodeDone(run="r", reason="success", metrics=metrics)))
    rows = _table_rows(out.getvalue())
    assert rows["actions (all robots)"] == "42 (alice 17, bob 9, david 16)"
    assert not any("action steps" in label for label in rows)


def test_the_summary_table_names_a_protocol_other_than_the_papers() -> None:
    """`mhrc up --protocol centralized` says how the team coordinated; the paper's table is as it was."""
    from mhrc.core.protocol import EpisodeDone, Metrics
    from mhrc.run.console import summary_table

    done = EpisodeDone(
        run="r",
        reason="success",
        metrics=Metrics(
            success=True,
            partial_success=1.0,
            placed=1,
            total=1,
            temporal_steps=3,
            action_steps=3,
            action_steps_per_robot={"alice": 3},
        ),
    )
    tables = {}
    for protocol in (None, "mhrc", "centralized"):
        out = io.StringIO()
        Console(file=out, width=120).print(summary_table(done, protocol=protocol))
        tables[protocol] = out.getvalue()
    assert tables[None] == tables["mhrc"] and "protocol" not in tables["mhrc"]
    assert _table_rows(tables["centralized"])["protocol"] == "centralized"


def test_every_schedule_has_a_gloss_for_the_header() -> None:
    from mhrc.run.config import SCHEDULES
    from mhrc.run.console import SCHEDULE_GLOSS

    assert set(SCHEDULE_GLOSS) == set(SCHEDULES)


# --------------------------------------------------------------------------- 3. lines in tick order


TICK_LINE = re.compile(r"^tick +(\d+) +(alice|bob|david) ")
CLOSED_LINE = re.compile(r"^tick +(\d+) closed: ")
MESSAGE_LINE = re.compile(r"^ +(alice|bob|david) -> (alice|bob|david): ")


@pytest.mark.parametrize(
    ("summary", "schedule"),
    sweep(
        [(True, "lockstep"), (False, "lockstep"), (True, "sequential"), (False, "sequential")],
        fast=2,
        ids=[
            "table-at-the-end-lockstep",
            "table-by-mhrc-up-lockstep",
            "table-at-the-end-sequential",
            "table-by-mhrc-up-sequential",
        ],
    ),
)
async def test_the_console_prints_each_tick_in_order_and_nothing_after_the_table(
    schedule: str, summary: bool, tmp_path: Path
) -> None:
    """Results, messages and the tick events travel on different keys; the console must still
    read in tick order: a tick's results, then its messages, then "tick N closed"; the table
    last, after every result (`mhrc world`'s printer prints it; `mhrc up` after the run)."""
    from mhrc.core.records import messages as messages_of
    from mhrc.core.records import read_records
    from mhrc.run.config import EpisodeConfig
    from mhrc.run.console import SCHEDULE_GLOSS, ProgressPrinter, summary_table
    from mhrc.run.inprocess import up_in_process

    out = io.StringIO()
    console = Console(file=out, width=400, highlight=False, soft_wrap=True)
    printer = ProgressPrinter(console, summary=summary)
    cfg = EpisodeConfig.build(seed=0, schedule=schedule, trace=tmp_path / "t.jsonl").resolved()
    done = await up_in_process(cfg, observe=printer.attach)
    printer.close()  # as `mhrc up` does once the run returned (with summary: the table is out already)
    if not summary:
        console.print(summary_table(done))
    lines = out.getvalue().splitlines()
    header = next(line for line in lines if line.startswith(f"episode {cfg.run}:"))
    assert header.endswith(f", {schedule} schedule ({SCHEDULE_GLOSS[schedule]})"), header  # why TS differs

    closed_at = {int(m.group(1)): i for i, line in enumerate(lines) if (m := CLOSED_LINE.match(line))}
    assert sorted(closed_at) == list(range(done.metrics.temporal_steps)), "a tick closed line is missing"
    assert list(closed_at.values()) == sorted(closed_at.values()), "tick closed lines out of order"
    results = [(i, int(m.group(1)), m.group(2)) for i, line in enumerate(lines) if (m := TICK_LINE.match(line))]
    assert cfg.trace is not None
    published = messages_of(read_records(cfg.trace), ActionResult)
    assert len(results) == len(published), "a result is missing"
    for i, tick, robot in results:
        assert closed_at.get(tick - 1, -1) < i < closed_at[tick], f"line {i} ({lines[i]!r}) is outside tick {tick}"
    sent = {(tick, robot): i for i, tick, robot in results if "communicate(" in lines[i]}
    messages = [(i, m.group(1)) for i, line in enumerate(lines) if (m := MESSAGE_LINE.match(line))]
    assert len(messages) == done.metrics.messages
    for i, sender in messages:
        tick = min(t for t, at in closed_at.items() if at > i)  # the tick whose closed line follows the message
        assert sent.get((tick, sender), len(lines)) < i, (
            f"message line {i} ({lines[i]!r}) before its communicate result"
        )
    title = next(i for i, line in enumerate(lines) if line.startswith(f"episode {cfg.run}: success"))
    assert title > closed_at[done.metrics.temporal_steps - 1] and all(
        TABLE_ROW.match(line) for line in lines[title + 1 :]
    )


def _line(key: str, msg: dict[str, Any]) -> TraceLine:
    """A hand-built trace line with `msg` on `key`."""
    (line,) = records([{"t": 0.0, "key": key, "kind": "put", "msg": msg}])
    return line


class _Replay:
    """Stands where a Bus stands for `ProgressPrinter.attach`: keeps its handlers by key pattern,
    so a test can hand it a real trace's samples in an order the bus may deliver them in."""

    def __init__(self) -> None:
        self.handlers: list[tuple[re.Pattern[str], Any]] = []

    def subscribe(self, key_expr: str, handler: Any) -> None:
        self.handlers.append((re.compile("^" + re.escape(key_expr).replace(r"\*", "[^/]+") + "$"), handler))

    def deliver(self, record: TraceLine) -> None:
        assert record.msg is not None
        sample = Sample(record.key, encode(record.msg))
        for pattern, handler in self.handlers:
            if pattern.match(sample.key):
                handler(sample)


async def test_messages_that_come_after_the_end_still_print_before_the_table(tmp_path: Path) -> None:
    """Each key has its own delivery thread, so a tick's messages may come after its results,
    its closed line and even `episode_done` (CI saw it: seed 0's last tick sends one). The
    printer holds the table until they came, and prints them with their tick."""
    from mhrc.core.records import read_records
    from mhrc.run.config import EpisodeConfig
    from mhrc.run.console import ProgressPrinter
    from mhrc.run.inprocess import up_in_process

    cfg = EpisodeConfig.build(seed=0, trace=tmp_path / "t.jsonl").resolved()
    done = await up_in_process(cfg)
    assert cfg.trace is not None
    records = [r for r in read_records(cfg.trace) if r.msg is not None]
    last = done.metrics.temporal_steps - 1
    late = [r for r in records if "/inbox/" in r.key]
    assert any(isinstance(r.msg, RobotMessage) and r.msg.tick == last for r in late), (
        "the episode no longer sends a message in its last tick: pick another seed"
    )

    out = io.StringIO()
    printer = ProgressPrinter(Console(file=out, width=400, highlight=False, soft_wrap=True), summary=True)
    replay = _Replay()
    printer.attach(replay, cfg.run)  # type: ignore[arg-type]
    for record in records:
        if "/inbox/" not in record.key:
            replay.deliver(record)
    for record in late:  # every message after everything else, the end included
        replay.deliver(record)
    printer.close()
    lines = out.getvalue().splitlines()

    messages = [i for i, line in enumerate(lines) if MESSAGE_LINE.match(line)]
    assert len(messages) == done.metrics.messages == len(late)
    title = next(i for i, line in enumerate(lines) if line.startswith(f"episode {cfg.run}: success"))
    assert max(messages) < title, "a message printed after the table"
    closed_at = {int(m.group(1)): i for i, line in enumerate(lines) if (m := CLOSED_LINE.match(line))}
    assert max(messages) < closed_at[last], "the last tick's message is not printed with its tick"


EVENT_LINE = re.compile(r"^tick +(\d+) event (.*)$")


async def test_scenario_events_print_as_their_tick_opens_and_the_table_says_how_the_team_recovered(
    tmp_path: Path,
) -> None:
    """A dynamic episode (issue 25) at the console: each scenario event's line comes right after
    the closed line of the tick before it (it fires as its tick opens) and before that tick's
    results; the table ends with each event's recovery as the metrics score it."""
    from mhrc.analysis.metrics import from_trace
    from mhrc.core.records import messages as messages_of
    from mhrc.core.records import read_records
    from mhrc.run.config import EpisodeConfig
    from mhrc.run.console import ProgressPrinter, summary_table
    from mhrc.run.inprocess import up_in_process

    out = io.StringIO()
    console = Console(file=out, width=400, highlight=False, soft_wrap=True)
    printer = ProgressPrinter(console, summary=False)
    cfg = EpisodeConfig.build(seed=0, events="busy_house", trace=tmp_path / "t.jsonl").resolved()
    done = await up_in_process(cfg, observe=printer.attach)
    printer.close()
    assert cfg.trace is not None
    recovery = from_trace(read_records(cfg.trace)).recovery
    console.print(summary_table(done, recovery))
    lines = out.getvalue().splitlines()
    events = [(i, int(m.group(1)), m.group(2)) for i, line in enumerate(lines) if (m := EVENT_LINE.match(line))]
    fired = messages_of(read_records(cfg.trace), ScenarioEvent)
    assert [(t, text) for _, t, text in events] == [(e.tick, e.text) for e in fired] and len(events) == 4
    for i, tick, _ in events:
        assert CLOSED_LINE.match(lines[i - 1]) and int(CLOSED_LINE.match(lines[i - 1]).group(1)) == tick - 1, lines[
            i - 1 : i + 1
        ]  # type: ignore[union-attr]
        first_result = next(
            j for j, line in enumerate(lines) if (m := TICK_LINE.match(line)) and int(m.group(1)) == tick
        )
        assert i < first_result
    said = _table_rows(out.getvalue()).get("scenario events", "")
    for e in recovery:
        steps = e["ticks_to_recover"]
        assert (
            f"{e['kind']}@{e['tick']} "
            + ("skipped" if not e["applied"] else "unrecovered" if steps is None else f"recovered in {steps} step")
            in said
        ), said


# --------------------------------------------------------------------------- 4. nobody attaches within --start-timeout


async def test_a_world_nobody_attaches_to_ends_at_the_start_timeout(tmp_path: Path) -> None:
    from mhrc.world.service_config import NobodyAttached

    async with world_on_loopback(seed=0, start_timeout=0.5, trace=tmp_path / "t.jsonl") as world:
        with pytest.raises(NobodyAttached) as err:
            await world.done(timeout=60)
    assert err.value.missing == ("alice", "bob", "david")
    assert "--start-timeout" in str(err.value) and "alice, bob, david never attached" in str(err.value)


@pytest.mark.parametrize(
    "args",
    sweep(
        [
            ["world", "--insecure"],
            ["up", "--insecure", "--external", "alice", "--external", "bob", "--external", "david"],
        ],
        ids=["world", "up-all-external"],
    ),
)
def test_start_timeout_with_nobody_attached_is_one_line_and_a_failure(args: list[str], tmp_path: Path) -> None:
    run = mhrc(
        *args, "--start-timeout", "1", cwd=tmp_path, timeout=120
    )  # before: waited forever (up had no such option)
    assert run.returncode == 1, (run.returncode, run.stderr[-2000:])
    errors = [
        line
        for line in run.stderr.splitlines()
        if re.match(r"mhrc (world|up): ", line) or "warning" in line or "rror" in line
    ]
    assert len(errors) == 1 and errors[0].startswith(f"mhrc {args[0]}: "), run.stderr
    assert "--start-timeout 1 s" in errors[0] and "alice, bob, david never attached" in errors[0]
    assert "Traceback" not in run.stderr and "episode" not in run.stdout


# --------------------------------------------------------------------------- 5. a model server that is not there


@pytest.mark.parametrize("processes", [False, True], ids=["in-process", "processes"])
def test_no_model_server_is_one_line_exit_2_and_nothing_left_behind(processes: bool, tmp_path: Path) -> None:
    url = f"http://127.0.0.1:{free_port()}/v1"  # nothing listens there
    run = mhrc(
        "up",
        "--llm",
        "ollama:llama3.1:8b",
        "--base-url",
        url,
        *(["--processes"] if processes else []),
        cwd=tmp_path,
        timeout=120,
    )
    assert run.returncode == 2, (run.returncode, run.stderr[-3000:])
    assert run.stdout == ""  # no world line, no table
    assert run.stderr.splitlines() == [
        f"mhrc up: nothing listens at {url}, the model server of alice, bob, david (connection refused): "
        "start the server there, or point --base-url at one"
    ], run.stderr
    assert not (tmp_path / "runs").exists()  # no credentials, no trace


@pytest.mark.parametrize("processes", sweep([False, True], ids=["in-process", "processes"]))
def test_a_model_that_refuses_every_request_is_one_error_no_table_no_vanished_robots(
    processes: bool, tmp_path: Path
) -> None:
    """A server that is there but has no such model (HTTP 404, as Ollama answers for a model not
    pulled): the run stops with the model's error, not with robots 'vanished' and a table of
    zeros (and with --processes it ends at all: every agent gone before the start was a hang)."""
    from mhrc.testing import ModelReply, ScriptedModelServer

    with ScriptedModelServer(
        lambda body: ModelReply(status=404, body={"error": "model 'llama3.1:8b' not found"})
    ) as server:
        run = mhrc(
            "up",
            "--insecure",
            "--llm",
            "ollama:llama3.1:8b",
            "--base-url",
            server.url,
            *(["--processes"] if processes else []),
            cwd=tmp_path,
            timeout=120,
        )
    assert run.returncode == 2, (run.returncode, run.stderr[-3000:])
    assert "success" not in run.stdout and "┌" not in run.stdout, run.stdout  # no summary table
    assert "Traceback" not in run.stderr
    if processes:  # each agent process says its own error; the world saw them go (not fixed here)
        assert "answered HTTP 404: no model 'llama3.1:8b'" in run.stderr
        return
    assert "vanished" not in run.stdout + run.stderr and "detached" not in run.stdout, run.stdout + run.stderr
    errors = [line for line in run.stderr.splitlines() if not line.startswith("insecure:")]
    assert len(errors) == 1 and errors[0].startswith("mhrc up: ") and "HTTP 404: no model 'llama3.1:8b'" in errors[0], (
        run.stderr
    )


@pytest.mark.slow
def test_the_open_bus_is_said_once_under_processes(tmp_path: Path) -> None:
    """`mhrc up --processes --insecure`: the warning about the open bus comes once, from the
    command the user typed, not again from each of its world and agent processes."""
    done = subprocess.run(
        [sys.executable, "-m", "mhrc", "up", "--processes", "--insecure", "--objects", "3", "--quiet"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stderr.count("insecure: the open tcp bus") == 1, done.stderr


def test_unparsed_thoughts_held_for_their_results_are_bounded() -> None:
    """A login putting thoughts with a parse error for ticks to come (each held until its result
    prints) cannot grow the console without bound: at most MAX_HELD_THOUGHTS (tick, robot) pairs,
    two lines each, and only thoughts about the robot whose key they came on (issue 38)."""
    from mhrc.run.console import MAX_HELD_THOUGHTS, ProgressPrinter

    printer = ProgressPrinter(Console(file=io.StringIO()), summary=False)
    bus = _Replay()
    printer.attach(bus, "r")  # type: ignore[arg-type]
    key = Keys("r").thought("alice")
    for i in range(MAX_HELD_THOUGHTS + 500):
        thought = {"v": 2, "kind": "thought", "robot": "alice", "tick": i, "policy": "p", "parse_error": "no"}
        bus.deliver(_line(key, thought))
    for _ in range(5):  # the same tick again and again
        bus.deliver(_line(key, thought | {"tick": 3}))
    bus.deliver(_line(key, thought | {"robot": "bob", "tick": 1}))  # bob's, on alice's key
    held = printer._thoughts
    assert len(held) == MAX_HELD_THOUGHTS and (MAX_HELD_THOUGHTS + 1, "alice") not in held
    assert len(held[(3, "alice")]) == 2 and (1, "bob") not in held
