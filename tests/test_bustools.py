"""Bus tools (`mhrc bus list`, `mhrc bus echo`, `mhrc doctor`) against real worlds and agents on
loopback, and every command's output free of pybullet's banner."""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import subprocess
import sys
import threading
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import pytest
from waits import robots_alive, subscribed

from mhrc.cli.bustools import bus_echo, group_tokens, split_endpoint
from mhrc.cli.message_lines import MODELS, describe_sample
from mhrc.core.bus import Bus, Sample
from mhrc.core.endpoints import free_port
from mhrc.core.protocol import PROTOCOL_VERSION
from mhrc.run.attach import run_agent

MHRC = [sys.executable, "-m", "mhrc"]
BANNER = "pybullet build time"


def mhrc(*args: str, timeout: float = 60, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*MHRC, *args], capture_output=True, text=True, timeout=timeout, cwd=cwd)


async def amhrc(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    """`mhrc ARGS` as a subprocess, without blocking the loop (the world here keeps serving)."""
    return await asyncio.to_thread(mhrc, *args, timeout=timeout)


@contextlib.asynccontextmanager
async def agents(run: str, endpoint: str, robots: tuple[str, ...]) -> AsyncIterator[list[asyncio.Task[Any]]]:
    tasks = [asyncio.create_task(run_agent(r, run, endpoint)) for r in robots]
    try:
        yield tasks
    finally:
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


@contextlib.contextmanager
def silent_tcp_listener() -> Iterator[int]:
    """A plain TCP server that accepts connections and never says a word: not zenoh."""
    srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    srv.bind(("127.0.0.1", 0))
    srv.listen()
    srv.settimeout(0.2)
    stop = threading.Event()
    conns: list[socket.socket] = []

    def serve() -> None:
        while not stop.is_set():
            try:
                conn, _ = srv.accept()
                conns.append(conn)
            except (TimeoutError, OSError):
                continue

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield srv.getsockname()[1]
    finally:
        stop.set()
        thread.join(2)
        for c in conns:
            c.close()
        srv.close()


# --------------------------------------------------------------------------- live world


async def test_list_and_doctor_show_the_run_and_its_robots(mhrc_world) -> None:  # type: ignore[no-untyped-def]
    # the world waits for all three robots: with two attached it stays alive and unstarted
    async with mhrc_world(run="bt-list", n_objects=3) as world:
        ep = world.config.endpoint
        client = await world.client()
        try:
            async with agents("bt-list", ep, ("alice", "bob")):
                await world.attached("alice", "bob")
                listed, listed_json, doc = await asyncio.gather(
                    amhrc("bus", "list", "--connect", ep),
                    amhrc("bus", "list", "--json", "--connect", ep),
                    amhrc("doctor", "--connect", ep),
                )
        finally:
            await client.close()
    assert listed.returncode == 0, listed.stderr
    assert listed.stdout.strip() == "run bt-list: world alive; robots attached: alice, bob"
    assert json.loads(listed_json.stdout) == {
        "endpoint": ep,
        "groups": [{"run": "bt-list", "world": True, "robots": ["alice", "bob"]}],
    }
    assert doc.returncode == 0, doc.stdout + doc.stderr
    lines = doc.stdout.splitlines()
    assert lines[0].startswith(f"ok   {ep}: zenoh router ")
    assert f"run bt-list: world speaks protocol v{PROTOCOL_VERSION}" in doc.stdout
    assert "robots attached: alice, bob" in doc.stdout and lines[-1] == "healthy"
    for out in (listed, listed_json, doc):
        assert BANNER not in out.stdout + out.stderr and "Traceback" not in out.stderr


async def test_echo_prints_an_episodes_action_results(mhrc_world) -> None:  # type: ignore[no-untyped-def]
    async with mhrc_world(run="bt-echo", n_objects=3, tick_delay=0.2) as world:
        ep = world.config.endpoint
        client = await world.client()  # the world listens (open_client waits for it) before the echoes connect
        # Each echo's key also matches a probe key of no run (the world records only its own run's
        # keys): a subscriber of the probe is the echo, subscribed. The second echo's key is wider
        # than the first's, with a probe of its own.
        text = asyncio.create_task(
            amhrc(
                "bus",
                "echo",
                "mhrc/*/robot/*/action/result",
                "--connect",
                ep,
                "--count",
                "4",
                "--timeout",
                "60",
                timeout=90,
            )
        )
        await subscribed(client, "mhrc/probe/robot/x/action/result")
        as_json = asyncio.create_task(
            amhrc(
                "bus",
                "echo",
                "mhrc/**/action/result",
                "--json",
                "--connect",
                ep,
                "--count",
                "4",
                "--timeout",
                "60",
                timeout=90,
            )
        )
        await subscribed(client, "mhrc/probe/action/result")
        async with agents("bt-echo", ep, ("alice", "bob", "david")):
            out_text, out_json = await asyncio.gather(text, as_json)
    assert out_text.returncode == 0, out_text.stderr
    lines = out_text.stdout.splitlines()
    assert len(lines) == 4
    for line in lines:
        clock, k, kind, summary = line.split(" ", 3)
        assert len(clock) == len("12:34:56.789") and clock[2] == ":"
        assert k.startswith("mhrc/bt-echo/robot/") and k.endswith("/action/result") and kind == "action_result"
        robot = k.split("/")[3]
        assert summary.startswith(robot + " ") and (" succeeded " in summary or " failed (" in summary)
    assert out_json.returncode == 0, out_json.stderr
    rows = [json.loads(line) for line in out_json.stdout.splitlines()]
    assert len(rows) == 4
    for row in rows:
        assert set(row) == {"t", "key", "kind", "msg"} and row["kind"] == "put"
        assert row["msg"]["kind"] == "action_result" and row["msg"]["v"] == PROTOCOL_VERSION
    for out in (out_text, out_json):
        assert BANNER not in out.stdout + out.stderr and "Traceback" not in out.stderr


async def test_echo_shows_undecodable_payloads_without_crashing() -> None:
    ep = f"tcp/127.0.0.1:{free_port()}"
    router = await Bus.open(mode="router", listen=[ep])
    lines: list[str] = []
    rows: list[str] = []
    try:
        text = asyncio.create_task(bus_echo(ep, "mhrc/junk/**", count=6, timeout=30, write=lines.append))
        js = asyncio.create_task(bus_echo(ep, "mhrc/junk/**", as_json=True, count=6, timeout=30, write=rows.append))
        payloads = [b"\x00\xffnot json", b'{"kind": "action_result", "robot": "alice"}', b'{"hello": 1}']
        while not (text.done() and js.done()):
            for p in payloads:
                router.put("mhrc/junk/x", p)
            await asyncio.sleep(0.1)
        assert await text == 0 and await js == 0
    finally:
        await router.close()
    kinds = {line.split(" ", 3)[2] for line in lines}
    assert kinds <= {"not-json", "invalid:action_result", "json"} and len(kinds) == 3
    assert any("undecodable payload (10 bytes)" in line for line in lines)
    assert any("not a valid action_result" in line for line in lines)
    parsed = [json.loads(r) for r in rows]
    errors = [r.get("error") for r in parsed]
    assert "not JSON" in errors and None in errors and any(e and "Field required" in e for e in errors)
    assert all(r["key"] == "mhrc/junk/x" for r in parsed)


# --------------------------------------------------------------------------- doctor, when something is wrong


def test_doctor_nothing_listens() -> None:
    port = free_port()
    out = mhrc("doctor", "--connect", f"tcp/127.0.0.1:{port}")
    assert out.returncode == 1
    assert out.stdout.splitlines() == [f"FAIL tcp/127.0.0.1:{port}: nothing listens there (connection refused)"]
    assert out.stderr == ""


@pytest.mark.slow
def test_doctor_non_zenoh_listener() -> None:
    with silent_tcp_listener() as port:
        out = mhrc("doctor", "--connect", f"tcp/127.0.0.1:{port}")
    assert out.returncode == 1
    assert out.stdout.splitlines() == [
        f"FAIL tcp/127.0.0.1:{port}: something accepts TCP connections there, but no zenoh handshake within 2 s: "
        f"it is not zenoh (or a secured world: connect to tls/127.0.0.1:{port} with --credentials)"
    ]
    assert "Traceback" not in out.stderr


def test_bus_tools_fail_in_one_line_when_nothing_listens() -> None:
    port = free_port()
    for args in (["bus", "list"], ["bus", "echo", "mhrc/**"]):
        out = mhrc(*args, "--connect", f"tcp/127.0.0.1:{port}")
        assert out.returncode == 1 and out.stdout == ""
        assert (
            out.stderr.strip()
            == f"mhrc {' '.join(args[:2])}: tcp/127.0.0.1:{port}: nothing listens there (connection refused)"
        )
    out = mhrc("bus", "echo", "mhrc//bad", "--connect", f"tcp/127.0.0.1:{port}")
    assert out.returncode == 1 and "is not a key expression" in out.stderr and "Traceback" not in out.stderr


# --------------------------------------------------------------------------- pure parts


def test_group_tokens() -> None:
    groups = group_tokens(
        [
            "mhrc/r1/alive/world",
            "mhrc/r1/alive/robot/bob",
            "mhrc/r1/alive/robot/alice",
            "mhrc/r2/alive/robot/david",
        ]
    )
    assert [g.describe() for g in groups] == [
        "run r1: world alive; robots attached: alice, bob",
        "run r2: no world; robots attached: david",
    ]


def test_split_endpoint_and_known_kinds() -> None:
    assert split_endpoint("tcp/127.0.0.1:7447") == ("tcp", "127.0.0.1", 7447)
    assert split_endpoint("tcp/[::1]:7447") == ("tcp", "::1", 7447)
    assert split_endpoint("localhost:7447") == ("tcp", "localhost", 7447)
    assert {
        "action_request",
        "action_ack",
        "action_result",
        "message",
        "thought",
        "episode_done",
        "world_state",
    } <= set(MODELS)
    assert describe_sample(Sample("k", b"", is_put=False)).kind == "delete"


# --------------------------------------------------------------------------- no pybullet banner


@pytest.mark.slow
def test_commands_print_no_pybullet_banner(tmp_path: Path) -> None:
    cmds = [["--help"], ["scenes"], ["up", "--quiet", "--json", "--objects", "3"]]
    if "schema" in mhrc("--help").stdout:
        cmds.append(["schema"])
    for args in cmds:
        out = mhrc(*args, timeout=180, cwd=tmp_path)  # `up` writes runs/RUN/trace.jsonl here
        assert out.returncode == 0, (args, out.stderr)
        assert BANNER not in out.stdout and BANNER not in out.stderr, args
    up = mhrc("up", "--quiet", "--json", "--objects", "3", "--seed", "1", timeout=180, cwd=tmp_path)
    assert json.loads(up.stdout)["total"] == 3


@pytest.mark.parametrize(
    "module",
    [
        "mhrc.world.sim",
        "mhrc.world.render",
        "mhrc.world.arm",
        "mhrc.world.robots",
        "mhrc.world.scene",
        "mhrc.world.skills",
    ],
)
def test_importing_pybullet_modules_is_silent(module: str) -> None:
    out = subprocess.run([sys.executable, "-c", f"import {module}"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout == "" and out.stderr == "", out.stderr


# --------------------------------------------------------------------------- a secured run, read with the observer's login


@pytest.mark.slow
async def test_the_observers_login_reads_a_secured_run(tmp_path: Path) -> None:
    """`mhrc doctor` and `mhrc bus echo 'mhrc/**'` with the observer's login: a healthy world is
    called healthy (its state answered), and echo prints the run's messages, as the README says;
    a robot's login is told which login asks the world's state, without calling it unhealthy."""
    from mhrc.core.bus import open_client
    from mhrc.run.config import EpisodeConfig
    from mhrc.run.inprocess import up_in_process

    cfg = (
        EpisodeConfig.build(seed=0, n_objects=4, tick_delay=0.2, trace=tmp_path / "t.jsonl")
        .resolved()
        .with_credentials(tmp_path / "cred")
    )
    observer, alice = str(cfg.credentials_file("observer")), str(cfg.credentials_file("alice"))
    world = asyncio.create_task(up_in_process(cfg, robots=("alice", "bob")))  # waits for david: alive, not started
    client = await open_client(cfg.endpoint, 60, security=cfg.participant("observer"))
    try:
        await robots_alive(client, cfg.run, {"alice", "bob"})
        doc, as_alice = await asyncio.gather(
            amhrc("doctor", "--connect", cfg.endpoint, "--credentials", observer),
            amhrc("doctor", "--connect", cfg.endpoint, "--credentials", alice),
        )
        assert doc.returncode == 0, doc.stdout + doc.stderr
        assert (
            f"run {cfg.run}: world speaks protocol v{PROTOCOL_VERSION}" in doc.stdout
            and doc.stdout.splitlines()[-1] == "healthy"
        )
        assert as_alice.returncode == 0, as_alice.stdout
        assert "observer's login" in as_alice.stdout
        echo = asyncio.create_task(
            amhrc(
                "bus",
                "echo",
                "mhrc/**",
                "--connect",
                cfg.endpoint,
                "--credentials",
                observer,
                "--count",
                "5",
                "--timeout",
                "60",
                timeout=90,
            )
        )
        listing = await amhrc(
            "bus", "list", "--connect", cfg.endpoint, "--credentials", observer
        )  # echo is subscribed by now
        assert listing.stdout.startswith(f"run {cfg.run}: world alive"), listing.stdout + listing.stderr
        david = asyncio.create_task(run_agent("david", cfg.run, cfg.endpoint, security=cfg.participant("david")))
        out = await echo
        assert out.returncode == 0, out.stdout + out.stderr
        assert len(out.stdout.splitlines()) == 5 and all(f"mhrc/{cfg.run}/" in line for line in out.stdout.splitlines())
        await asyncio.wait_for(world, 300)
        await david
    finally:
        await client.close()
        world.cancel()
        await asyncio.gather(world, return_exceptions=True)
