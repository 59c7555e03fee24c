"""What issue 38 (and two items of 37) left after tests/test_bad_day.py and tests/test_bad_input.py:
a port taken is said before anything is announced, credentials are never picked up by git nor
written into /dev, an agent's thought cannot fill the trace, and every printer shows a
participant's text inert.

Commands are real `mhrc` subprocesses in an empty directory; the wire tests use alice's login on a
secured world on loopback (tests/test_bad_input.py's Mallory)."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from pathlib import Path

import pytest


def _mhrc(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "mhrc", *args], cwd=cwd, capture_output=True, text=True, timeout=120)


# --------------------------------------------------------------------------- a port taken (issue 37)


@pytest.mark.parametrize("secure", [True, pytest.param(False, marks=pytest.mark.slow)])
def test_a_taken_port_is_one_line_before_the_world_is_announced(secure: bool, tmp_path: Path) -> None:
    """`mhrc up --port P` with P taken by a listener: one line, exit 2, and neither "world on
    tcp/...:P" (it was printed first, then the run failed) nor credentials nor a run directory."""
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        out = _mhrc("up", "--port", str(port), "--horizon", "2", *([] if secure else ["--insecure"]), cwd=tmp_path)
    assert out.returncode == 2, out.stderr[-2000:]
    assert "Traceback" not in out.stderr, out.stderr[-2000:]
    said = [line for line in out.stderr.splitlines() if line.startswith("mhrc")]
    assert len(said) == 1 and f"port {port} is already in use" in said[0], out.stderr
    assert "world on" not in out.stdout and "credentials in" not in out.stderr, (out.stdout, out.stderr)
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- credentials and git (issue 37)


def _git(*args: str, cwd: Path) -> str:
    return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, check=True).stdout


@pytest.mark.parametrize("split", [False, True])
def test_credentials_written_in_a_checkout_are_never_picked_up_by_git(split: bool, tmp_path: Path) -> None:
    """`mhrc credentials --out creds` (as docs/security.md once showed) inside a git checkout, then
    `git add -A`: nothing of it is staged (before: the world's private key and every password were)."""
    _git("init", "-q", cwd=tmp_path)
    (tmp_path / "README").write_text("a checkout\n")
    made = _mhrc("credentials", "--out", "creds", "--days", "1", *(["--split"] if split else []), cwd=tmp_path)
    assert made.returncode == 0, made.stderr
    assert any((tmp_path / "creds").rglob("world.key"))
    _git("add", "-A", cwd=tmp_path)
    staged = _git("diff", "--cached", "--name-only", cwd=tmp_path).split()
    assert staged == ["README"], staged
    assert _git("status", "--porcelain", "--ignored", cwd=tmp_path).count("creds/") == 1  # ignored, whole


def test_a_secured_run_with_a_trace_on_a_device_keeps_its_credentials_in_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`--trace /dev/null` (or /dev/full) with credentials: they go to runs/RUN/credentials, not
    next to the trace (as root, mhrc wrote /dev/credentials)."""
    from mhrc.run.config import EpisodeConfig

    monkeypatch.chdir(tmp_path)
    before = Path("/dev/credentials").exists()
    try:
        cfg = EpisodeConfig(run="devtrace", trace=Path("/dev/null")).resolved().with_credentials()
        assert cfg.credentials == Path("runs/devtrace/credentials")
        assert (tmp_path / "runs" / "devtrace" / "credentials" / "world.key").is_file()
        assert Path("/dev/credentials").exists() == before
    finally:
        if not before and Path("/dev/credentials").is_dir():  # what the old code left in /dev
            for f in Path("/dev/credentials").iterdir():
                f.unlink()
            Path("/dev/credentials").rmdir()


# --------------------------------------------------------------------------- helpers for the wire tests


def _lines(trace: Path) -> list[dict[str, object]]:
    return [json.loads(line) for line in trace.read_text().splitlines()]


# --------------------------------------------------------------------------- an agent's thoughts (issue 38)


async def test_thoughts_out_of_bounds_are_counted_not_copied(tmp_path: Path) -> None:
    """Alice's login puts on her thought key: 10 thoughts with a 3 MB reply, 10 with a 1 MB policy
    name, 10 payloads of 3 MB that are not JSON, one with a negative latency (~100 MB in all). The trace keeps a count
    and a 200-character excerpt of each kind, never a copy (before: each was copied whole), and
    the well-formed thought put last is recorded as sent."""
    from test_bad_input import _junk, _mallory

    from mhrc.core.protocol import Thought

    def thought(**fields: object) -> bytes:
        return json.dumps({"v": 2, "kind": "thought", "robot": "alice", "tick": 0, "policy": "p"} | fields).encode()

    async with _mallory(tmp_path) as mallory:
        key = mallory.keys.thought("alice")
        for _ in range(10):
            mallory.bus.put(key, thought(reply="r" * 3_000_000))
            mallory.bus.put(key, thought(policy="p" * 1_000_000))
            mallory.bus.put(key, b"\x1b[2J" + b"x" * 3_000_000)
        mallory.bus.put(key, thought(latency=-1.0))
        await mallory.recorded()
    trace = mallory.world.trace
    size = trace.stat().st_size
    longest = max(len(line) for line in trace.read_text().splitlines())
    assert size < 200_000 and longest < 64 * 1024, (size, longest)
    junk = _junk(trace, "/agent/alice/thought")
    assert sum(j.count for j in junk) == 31, junk
    assert all(j.code == "malformed" and 0 < len(j.excerpt) <= 200 for j in junk), junk
    recorded = [
        Thought.model_validate(line["msg"])
        for line in _lines(trace)
        if str(line["key"]).endswith("/thought") and line["kind"] == "put"
    ]
    assert [t.policy for t in recorded] == ["sentinel"], recorded


async def test_a_flood_of_well_formed_thoughts_is_counted_not_copied(tmp_path: Path) -> None:
    """Alice's login puts 300 thoughts, each within the bounds (a 100 kB reply, 30 MB in all), and
    no action request, then one request. An agent thinks once per action, so the trace keeps the
    first THOUGHTS_AHEAD of them and counts the rest as junk (`thoughts_ahead`); before, every one
    was copied whole."""
    from test_bad_input import _junk, _mallory, _request
    from waits import until

    from mhrc.core.trace import THOUGHTS_AHEAD

    async with _mallory(tmp_path) as mallory:
        key = mallory.keys.thought("alice")
        for i in range(300):
            mallory.bus.put(
                key,
                json.dumps(
                    {
                        "v": 2,
                        "kind": "thought",
                        "robot": "alice",
                        "tick": 0,
                        "policy": f"flood-{i}",
                        "reply": "r" * 100_000,
                    }
                ).encode(),
            )
        mallory.put(json.dumps(_request("after-the-flood")).encode())
        assert (await mallory.answered(["after-the-flood"]))["after-the-flood"].accepted
        trace = mallory.world.trace
        await until(lambda: "after-the-flood" in trace.read_text(), "the request after the flood recorded", timeout=30)
    recorded = [line for line in _lines(trace) if str(line["key"]).endswith("/agent/alice/thought")]
    assert [line["msg"]["policy"] for line in recorded if line["kind"] == "put"] == [  # type: ignore[index]
        f"flood-{i}" for i in range(THOUGHTS_AHEAD)
    ]
    junk = _junk(trace, "/agent/alice/thought")
    assert sum(j.count for j in junk) == 300 - THOUGHTS_AHEAD and {j.code for j in junk} == {"thoughts_ahead"}
    assert trace.stat().st_size < (THOUGHTS_AHEAD + 2) * 100_000


def test_an_honest_thought_is_never_cut_below_the_bounds() -> None:
    """The agent's side fits its texts to the bounds: a reply at the bound is kept whole, one past it cut to it."""
    from mhrc.core.protocol.thoughts import MAX_TEXT, fit

    assert fit("a" * MAX_TEXT) == "a" * MAX_TEXT
    assert fit("a" * (MAX_TEXT + 5)) == "a" * MAX_TEXT
    assert fit(None) is None


# --------------------------------------------------------------------------- a participant's text in the logs (issue 38)

EVIL = "\x1b]0;pwned\x07\x1b[2J"


@pytest.mark.slow
async def test_a_participants_text_reaches_the_worlds_log_inert(tmp_path: Path) -> None:
    """`mhrc world --log-level info`, a client attaching alice with an agent id full of terminal
    escapes and sending a request whose skill is one: the world's log lines (stderr) name them
    with their control characters gone (before: the escapes reached the operator's terminal raw,
    structlog prints a plain string as it is)."""
    import signal

    from waits import served, until

    from mhrc.core.bus import open_client
    from mhrc.core.endpoints import free_port
    from mhrc.core.keys import Keys
    from mhrc.core.protocol import ActionAck, AttachReply, AttachRequest, decode

    port = free_port()
    err = (tmp_path / "stderr.txt").open("w")
    world = subprocess.Popen(
        [sys.executable, "-m", "mhrc", "world", "--insecure", "--port", str(port), "--run", "evil"]
        + ["--objects", "3", "--log-level", "info", "--start-timeout", "60"],
        cwd=tmp_path,
        stdout=subprocess.DEVNULL,
        stderr=err,
    )
    keys = Keys("evil")
    acks: list[ActionAck] = []
    try:
        from mhrc.run.processes import wait_for_port

        wait_for_port("127.0.0.1", port, 60.0, world)  # type: ignore[arg-type]
        bus = await open_client(f"tcp/127.0.0.1:{port}", 30)
        try:
            bus.subscribe(keys.action_ack("alice"), lambda s: acks.append(decode(s.payload, ActionAck)))
            await served(bus, keys.attach("alice"))
            replies = await bus.get(keys.attach("alice"), AttachRequest(robot="alice", agent_id=EVIL + "[/]"))
            assert replies and decode(replies[0], AttachReply).accepted
            request = {"v": 2, "kind": "action_request", "goal_id": "g1", "robot": "alice", "agent_id": EVIL}
            bus.put(keys.action_request("alice"), json.dumps(request | {"tick": 0, "action": {"skill": EVIL}}).encode())
            await until(lambda: bool(acks), "the world's ack")
        finally:
            await bus.close()
    finally:
        world.send_signal(signal.SIGTERM)
        world.wait(timeout=60)
        err.close()
    log = (tmp_path / "stderr.txt").read_text()
    assert acks[0].code == "malformed" and "\x1b" in acks[0].reason  # the wire keeps what was sent, for programs
    assert "attached" in log and "malformed action request rejected" in log, log
    assert "]0;pwned[2J" in log and "\x1b" not in log and "\x07" not in log, repr(log[-2000:])
