"""Bad input on the command line (issue 20): one line naming the option, exit 2, nothing left
behind; and the certificates `--days` asks for. Every command runs for real, in a process of
its own, in an empty directory that must stay empty.

Bad input on the wire (issue 38): a hostile participant with a robot's login (alice's, on a
secured world on loopback) sends payloads nested 5k-100k deep, a tick of 10**5000, megabyte ids
and names, non-finite and absurd moves. Each is rejected at its ack with `malformed`, counted
(not copied) in the trace and logged throttled; none crashes a handler."""

from __future__ import annotations

import asyncio
import contextlib
import datetime
import json
import resource
import subprocess
import sys
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import pytest
from cryptography import x509
from structlog.testing import capture_logs
from waits import served, until

from mhrc.core import security
from mhrc.core.bus import Bus, open_client
from mhrc.core.keys import Keys
from mhrc.core.protocol import (
    ActionAck,
    AttachReply,
    AttachRequest,
    RejectCode,
    Thought,
    decode,
    new_goal_id,
)
from mhrc.core.records import JunkCount, read_records
from mhrc.run.config import ROBOTS
from mhrc.testing import LoopbackWorld, world_on_loopback


def _mhrc(*args: str, cwd: Path, preexec_fn: Callable[[], None] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mhrc", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=preexec_fn,
    )


def _refused(result: subprocess.CompletedProcess[str], option: str) -> str:
    """The command failed as bad input: exit 2, no traceback, one `Error:` line that names `option`."""
    assert result.returncode == 2, (result.returncode, result.stderr[-2000:])
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    errors = [line for line in result.stderr.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and option in errors[0], result.stderr
    return errors[0]


# ------------------------------------------------------------------------- mhrc credentials
@pytest.mark.parametrize("days", ["inf", "1e9", "nan", "-1", "0", "36501"])
def test_credentials_refuses_days_that_make_no_certificate_and_writes_nothing(tmp_path: Path, days: str) -> None:
    line = _refused(_mhrc("credentials", "--out", "creds/run", "--days", days, cwd=tmp_path), "--days")
    assert "must be at least a minute (0.000694) and at most 36500" in line
    assert list(tmp_path.iterdir()) == []


def test_credentials_help_states_the_range_of_days(tmp_path: Path) -> None:
    out = _mhrc("credentials", "--help", cwd=tmp_path)
    assert out.returncode == 0 and "at most 36500" in " ".join(out.stdout.split())


def test_credentials_refuses_a_host_no_certificate_can_name_and_writes_nothing(tmp_path: Path) -> None:
    _refused(_mhrc("credentials", "--out", "creds", "--host", "wörld", cwd=tmp_path), "--host")
    assert list(tmp_path.iterdir()) == []


def test_credentials_that_cannot_be_written_leave_no_directory_behind(tmp_path: Path) -> None:
    """A write that fails half way (here: no file may grow past 0 bytes) takes back the
    directories the command created; a directory that was there before stays."""

    def no_file_may_grow() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (0, 0))

    _refused(_mhrc("credentials", "--out", "new/run", cwd=tmp_path, preexec_fn=no_file_may_grow), "--out")
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "mine").mkdir()
    _refused(_mhrc("credentials", "--out", "mine/run", cwd=tmp_path, preexec_fn=no_file_may_grow), "--out")
    assert [p.name for p in tmp_path.iterdir()] == ["mine"] and list((tmp_path / "mine").iterdir()) == []


@pytest.mark.parametrize("days", [0.001, 7.0])
def test_certificates_are_valid_until_now_plus_days(tmp_path: Path, days: float) -> None:
    """Not 5 minutes short of it (the start is backdated for clock skew, the end is not): a tiny
    --days is a short certificate, never one written already expired."""
    t0 = datetime.datetime.now(datetime.timezone.utc)
    security.make_run_credentials("days", ("alice",), tmp_path, days=days)
    t1 = datetime.datetime.now(datetime.timezone.utc)
    span = datetime.timedelta(days=days)
    for name in ("ca.pem", "world.pem"):
        cert = x509.load_pem_x509_certificate((tmp_path / name).read_bytes())
        # certificates hold whole seconds: the end may be up to a second before now + days
        assert t0 + span - datetime.timedelta(seconds=1) <= cert.not_valid_after_utc <= t1 + span, (
            name,
            cert.not_valid_after_utc,
            t0,
            t1,
        )
        assert cert.not_valid_before_utc <= t0 - datetime.timedelta(minutes=4), name  # backdated for clock skew
        assert cert.not_valid_after_utc > t1, f"{name} was written already expired"


# ------------------------------------------------------------------------- --trace and eval --out
UNWRITABLE = "/dev/null/t.jsonl"  # under a file: no directory can be made there, whoever runs the test


@pytest.mark.parametrize(
    "args",
    [
        ["up", "--trace", UNWRITABLE],
        ["up", "--insecure", "--trace", UNWRITABLE],
        ["up", "--processes", "--trace", UNWRITABLE],
        ["world", "--insecure", "--trace", UNWRITABLE],
        ["up", "--trace", "."],  # a directory, not a file
    ],
    ids=["up", "up-insecure", "up-processes", "world", "a-directory"],
)
def test_a_trace_that_cannot_be_written_is_refused_before_anything_starts(tmp_path: Path, args: list[str]) -> None:
    result = _mhrc(*args, cwd=tmp_path)
    line = _refused(result, "--trace")
    assert "/dev/null" in line or "directory" in line
    assert list(tmp_path.iterdir()) == []  # no runs/, no credentials
    assert "open tcp bus" not in result.stderr  # a refused command line ends with its error alone


def test_an_eval_out_that_cannot_be_created_is_refused_before_anything_starts(tmp_path: Path) -> None:
    line = _refused(
        _mhrc(
            "eval",
            "--tasks",
            "pack_objects",
            "--scenes",
            "kitchen",
            "--objects",
            "3",
            "--workers",
            "1",
            "--out",
            "/dev/null/x",
            cwd=tmp_path,
        ),
        "--out",
    )
    assert "/dev/null is not a directory" in line
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------- --protocol (issue 45)
NO_SERVER = ("--llm", "llamacpp:m", "--base-url", "http://127.0.0.1:9/v1")  # a spec that needs no key


@pytest.mark.parametrize(
    ("args", "option", "said"),
    [
        (["up", "--processes", "--protocol", "centralized", "--external", "bob"], "--external", "none can be external"),
        (["play", "--robot", "bob", "--no-browser", "--protocol", "centralized"], "--protocol", "cannot leave bob"),
        (
            ["play", "--robot", "david", "--no-browser", "--protocol", "leader"],
            "--protocol",
            "cannot take david's part",
        ),
        (["eval", "--protocol", "mhrc", "--protocol", "nope", *NO_SERVER], "--protocol", "unknown protocol 'nope'"),
        (
            ["agent", "--insecure", "--connect", "tcp/127.0.0.1:9", "--protocol", "centralized", "--robot", "alice"],
            "--protocol",
            "it was not given bob, david",
        ),
        (
            ["agent", "--insecure", "--connect", "tcp/127.0.0.1:9", "--robot", "alice", "--robot", "bob"],
            "--robot",
            "one robot per agent under protocol 'mhrc'",
        ),
    ],
    # unknown names: test_cli_light
    ids=["external", "play", "play-leader", "eval", "planner-partial", "two-robots"],
)
def test_a_protocol_that_cannot_run_is_refused_before_anything_starts(
    tmp_path: Path, args: list[str], option: str, said: str
) -> None:
    result = _mhrc(*args, cwd=tmp_path)
    assert said in _refused(result, option)
    assert list(tmp_path.iterdir()) == []  # no runs/, no credentials, no trace


def test_a_planner_without_a_robots_credentials_is_refused_before_it_connects(tmp_path: Path) -> None:
    """On the secured bus the centralized planner acts only for the robots whose logins it was
    given: a robot of the team without one is one line naming it, before anything connects."""
    creds = security.make_run_credentials("r1", ROBOTS, tmp_path / "creds")
    cwd = tmp_path / "here"
    cwd.mkdir()
    planner = ["agent", "--connect", "tls/127.0.0.1:9", "--protocol", "centralized"]
    planner += [x for r in ROBOTS for x in ("--robot", r)]
    result = _mhrc(*planner, "--credentials", str(creds["alice"]), "--credentials", str(creds["bob"]), cwd=cwd)
    assert "no credentials for david" in _refused(result, "--credentials")
    result = _mhrc(
        *planner, *(x for r in ("alice", "bob", "david", "observer") for x in ("--credentials", str(creds[r]))), cwd=cwd
    )
    assert "credentials of 'observer', not a robot this planner drives" in _refused(result, "--credentials")
    assert list(cwd.iterdir()) == []


# ------------------------------------------------------------------------- a hostile robot on the wire (issue 38)
class Mallory:
    """Alice's login in hostile hands: attaches alice, puts raw payloads on her request key and
    collects the world's acks by goal id."""

    def __init__(self, world: LoopbackWorld, bus: Bus) -> None:
        self.world, self.bus, self.keys = world, bus, Keys(world.run)
        self.acks: dict[str, ActionAck] = {}
        self._news = asyncio.Event()
        bus.subscribe(self.keys.action_ack("alice"), self._on_ack)

    def _on_ack(self, sample: Any) -> None:
        ack = decode(sample.payload, ActionAck)
        self.acks[ack.goal_id] = ack
        self._news.set()

    async def attach(self) -> None:
        await served(self.bus, self.keys.attach("alice"))
        replies = await self.bus.get(
            self.keys.attach("alice"), AttachRequest(robot="alice", agent_id="mallory"), timeout=30
        )
        assert replies and decode(replies[0], AttachReply).accepted
        self.bus.declare_token(self.keys.alive_robot("alice"))

    def put(self, payload: bytes) -> None:
        self.bus.put(self.keys.action_request("alice"), payload)

    async def answered(self, goals: list[str], timeout: float = 60) -> dict[str, ActionAck]:
        """The acks of `goals`, once every one came; AssertionError naming the unanswered after `timeout`."""

        async def every() -> None:
            while not set(goals) <= set(self.acks):
                self._news.clear()
                await self._news.wait()

        try:
            await asyncio.wait_for(every(), timeout)
        except TimeoutError:
            raise AssertionError(f"no ack for {sorted(set(goals) - set(self.acks))}") from None
        return {g: self.acks[g] for g in goals}

    async def recorded(self) -> None:
        """Once the trace holds a thought put after everything else: the recorder's one subscriber
        takes alice's puts in the order sent, so it has handled every one before it."""
        sentinel = Thought(robot="alice", tick=0, policy="sentinel", action=new_goal_id())
        self.bus.put(self.keys.thought("alice"), sentinel)
        # the file, not a sleep standing in for it
        await until(
            lambda: str(sentinel.action) in self.world.trace.read_text(),
            "the recorder writing the thought put last",
            timeout=30,
            every=0.05,
        )


@contextlib.asynccontextmanager
async def _mallory(tmp_path: Path) -> AsyncIterator[Mallory]:
    """A secured world on loopback (tls, a login per participant, its recorder writing the trace)
    and a client session with alice's login, closed in finally."""
    creds = tmp_path / "cred"
    security.make_run_credentials("hostile", ROBOTS, creds)
    async with world_on_loopback(
        run="hostile", credentials=creds, seed=0, n_objects=3, trace=tmp_path / "trace.jsonl"
    ) as world:
        bus = await open_client(world.endpoint, 30, security=world.config.participant("alice"))
        try:
            mallory = Mallory(world, bus)
            await mallory.attach()
            yield mallory
        finally:
            await bus.close()


def _request(goal: str, **fields: Any) -> dict[str, Any]:
    return {
        "v": 2,
        "kind": "action_request",
        "goal_id": goal,
        "robot": "alice",
        "agent_id": "mallory",
        "tick": 0,
        "action": {"skill": "wait"},
    } | fields


def _junk(trace: Path, key_end: str) -> list[JunkCount]:
    return [r.junk for r in read_records(trace) if r.junk is not None and r.key.endswith(key_end)]


async def test_deeply_nested_json_and_a_huge_tick_are_rejected_at_the_ack(tmp_path: Path) -> None:
    """30 documents nested 5k-100k deep (arrays and objects, at the top and inside the action) and
    a tick of 10**5000: each gets its ack, `malformed`, under its own goal id; the world's log has
    no handler crash and fewer lines than payloads; the trace counts them all as junk."""
    payloads: dict[str, bytes] = {}
    for i, depth in enumerate([5_000, 10_000, 20_000, 50_000, 100_000] * 6):
        goal = f"deep-{i}"
        head = json.dumps(_request(goal))[:-1]
        if i % 3 == 0:
            payloads[goal] = (head + ', "pad": ' + "[" * depth + "]" * depth + "}").encode()
        elif i % 3 == 1:
            payloads[goal] = (head + ', "pad": ' + '{"a": ' * depth + "1" + "}" * depth + "}").encode()
        else:
            payloads[goal] = (
                json.dumps(_request(goal))
                .replace('{"skill": "wait"}', '{"skill": "wait", "x": ' + "[" * depth + "]" * depth + "}")
                .encode()
            )
    payloads["huge-tick"] = json.dumps(_request("huge-tick")).replace('"tick": 0', '"tick": 1' + "0" * 5000).encode()
    with capture_logs() as logs:
        async with _mallory(tmp_path) as mallory:
            for payload in payloads.values():
                mallory.put(payload)
            acks = await mallory.answered(list(payloads))
            await mallory.recorded()
    assert {g: (a.accepted, a.code) for g, a in acks.items()} == dict.fromkeys(payloads, (False, RejectCode.MALFORMED))
    assert all(len(a.reason) < 2000 for a in acks.values())
    crashes = [e for e in logs if e.get("log_level") in ("error", "critical") or e["event"] == "bus handler failed"]
    assert crashes == []
    warned = [e for e in logs if e["event"] == "malformed action request rejected"]
    assert 1 <= len(warned) < len(payloads), len(warned)  # throttled: a line per interval, with the count held back
    assert sum(j.count for j in _junk(mallory.world.trace, "/action/request")) == len(payloads)
    assert sum(j.count for j in _junk(mallory.world.trace, "/action/ack")) == len(payloads)


async def test_megabyte_ids_and_names_cannot_fill_the_trace(tmp_path: Path) -> None:
    """30 requests with a 3 MB agent_id and one picking a 1 MB object name (95 MB sent): each is
    rejected `malformed` (an agent id is at most 128 characters, a name 64) and the trace keeps
    their count and a 200-character excerpt, never a copy or an echo."""
    big = [f"big-{i}" for i in range(30)]
    with capture_logs():
        async with _mallory(tmp_path) as mallory:
            for goal in big:
                mallory.put(json.dumps(_request(goal, agent_id="A" * 3_000_000)).encode())
            mallory.put(json.dumps(_request("long-name", action={"skill": "pick", "obj": "o" * 1_000_000})).encode())
            mallory.put(
                json.dumps(_request("long-id", agent_id="A" * 129)).encode()
            )  # short payloads, one field too long
            mallory.put(json.dumps(_request("long-obj", action={"skill": "pick", "obj": "o" * 65})).encode())
            acks = await mallory.answered([*big, "long-name", "long-id", "long-obj"])
            await mallory.recorded()
    size = mallory.world.trace.stat().st_size
    longest = max(len(line) for line in mallory.world.trace.read_text().splitlines())
    assert size < 1_000_000 and longest < 64 * 1024, (size, longest)
    assert {g: (a.accepted, a.code) for g, a in acks.items()} == dict.fromkeys(
        [*big, "long-name", "long-id", "long-obj"], (False, RejectCode.MALFORMED)
    )
    assert "more than the 65536" in acks["big-0"].reason and "more than the 65536" in acks["long-name"].reason
    assert "agent_id" in acks["long-id"].reason and "action.pick.obj" in acks["long-obj"].reason
    junk = _junk(mallory.world.trace, "/action/request")
    assert sum(j.count for j in junk) == len(big) + 3
    assert all(0 < len(j.excerpt) <= 200 for j in junk)


@pytest.mark.parametrize(
    "dx, dy",
    [("NaN", "0"), ("0", "Infinity"), ("-Infinity", "0"), ("1e999", "0"), ("-1e308", "0"), ("0", "1e6")],
    ids=["nan", "inf", "-inf", "overflow", "-1e308", "a-thousand-km"],
)
async def test_non_finite_and_absurd_moves_are_rejected_at_the_ack(tmp_path: Path, dx: str, dy: str) -> None:
    """Python's and pydantic's JSON both read NaN, Infinity and 1e999 (as inf): a move must be
    finite and within 100 m a side, or the world would run (and echo, as `null`) what no schema allows."""
    payload = (
        json.dumps(_request("bad-move", action={"skill": "move", "dx": "DX", "dy": "DY"}))
        .replace('"DX"', dx)
        .replace('"DY"', dy)
    )
    with capture_logs():
        async with _mallory(tmp_path) as mallory:
            mallory.put(payload.encode())
            ack = (await mallory.answered(["bad-move"]))["bad-move"]
    assert (ack.accepted, ack.code) == (False, RejectCode.MALFORMED), ack
    assert ("action.move.dx" if dx != "0" else "action.move.dy") in ack.reason
