"""Coordination protocols (issue 45): the registry and its typed refusals, the protocol recorded
in the episode's header, and the centralized planner in whole episodes on real PyBullet and real
Zenoh (loopback), in the schedules whose rounds differ (lockstep waits for every robot's
observation of a tick; sequential plans at each robot's turn)."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from mhrc.agents.protocols import PROTOCOLS, CoordinationProtocol, ProtocolRefused, Refusal, Seating, protocol
from mhrc.agents.protocols.centralized import Seat
from mhrc.analysis.observability import check
from mhrc.core import security
from mhrc.core.bus import Bus, Sample, open_client
from mhrc.core.endpoints import endpoint, free_port
from mhrc.core.keys import Keys
from mhrc.core.protocol import ActionRequest, EpisodeStarted, Wait, decode
from mhrc.core.records import read_records
from mhrc.core.team import PAPER_TEAM
from mhrc.run.config import ConfigError, EpisodeConfig, ProtocolConfigError
from mhrc.run.coordinated import seat
from mhrc.run.inprocess import up_in_process


def test_every_protocol_lists_in_one_line_and_mhrc_is_the_default() -> None:
    assert list(PROTOCOLS) == ["mhrc", "centralized", "leader"]
    for p in PROTOCOLS.values():
        assert "\n" not in p.line() and p.line().startswith(p.name)
    assert EpisodeConfig.build().protocol == "mhrc"
    assert protocol("mhrc").build is None  # each robot's own agent, as before


def test_an_old_episode_header_reads_as_the_papers_protocol() -> None:
    old = b'{"v":2,"kind":"episode_started","run":"r","task":"pack_objects","scene":"kitchen","seed":0,"n_objects":4,"robots":["alice"],"horizon":5}'
    assert decode(old, EpisodeStarted).protocol == "mhrc"


def test_refusals_are_typed() -> None:
    with pytest.raises(ProtocolConfigError) as unknown:
        EpisodeConfig.build(protocol="nope")
    assert unknown.value.code is Refusal.UNKNOWN_PROTOCOL and "centralized" in str(unknown.value)
    assert isinstance(unknown.value, ConfigError)
    heuristic_only = CoordinationProtocol(
        "h", "a protocol with its heuristic form only"
    )  # (every shipped one has both)
    refused = heuristic_only.refusal(PAPER_TEAM, llm=True)
    assert refused is not None and refused.code is Refusal.NO_LLM_FORM
    cfg = EpisodeConfig.build(protocol="centralized")
    with pytest.raises(ProtocolConfigError) as partial:  # the planner drives the whole team or nothing
        seat(cfg, ("alice", "bob"))
    assert partial.value.code is Refusal.NOT_ALL_ROBOTS and "david" in str(partial.value)
    duo = EpisodeConfig.build(protocol="centralized", ablation="no_mobile")  # the episode's whole team: no David
    assert set(seat(duo, ("alice", "bob"))) == {"alice", "bob"}
    with pytest.raises(ProtocolConfigError):
        seat(duo, ("alice",))
    with pytest.raises(ProtocolRefused):
        protocol("nope")


def test_the_centralized_seats_share_one_planner() -> None:
    seats = protocol("centralized").build(Seating(PAPER_TEAM, PAPER_TEAM.names, "sequential"))  # type: ignore[misc]
    planners = {id(s.planner) for s in seats.values() if isinstance(s, Seat)}
    assert set(seats) == set(PAPER_TEAM.names) and len(planners) == 1


async def _centralized(tmp_path: Path, schedule: str) -> None:
    trace = tmp_path / "trace.jsonl"
    cfg = EpisodeConfig.build(
        protocol="centralized",
        task="pack_objects",
        scene="kitchen",
        n_objects=3,
        seed=1,
        horizon=40,
        schedule=schedule,
        trace=trace,
    ).resolved()
    done = await asyncio.wait_for(up_in_process(cfg), 240)
    assert done.metrics.success, (done.reason, done.metrics)
    assert done.metrics.messages == 0  # one planner: nothing is told by message
    records = read_records(trace)
    started = [r.msg for r in records if isinstance(r.msg, EpisodeStarted)]
    assert [s.protocol for s in started] == ["centralized"]
    seen = check(records)  # the planner's robots saw only what they could know
    assert seen.unchecked is None and seen.leaks == []


@pytest.mark.slow
@pytest.mark.parametrize("schedule", ["lockstep", "sequential", "async"])
async def test_the_centralized_planner_solves_an_episode(tmp_path: Path, schedule: str) -> None:
    await _centralized(tmp_path, schedule)


async def test_the_planner_cannot_act_for_a_robot_it_was_not_given(tmp_path: Path) -> None:
    """On the secured bus the planner logs in as each robot it was given; a request for another
    robot, sent on one of its sessions, is dropped by the world's router (its access rules), while
    its own robots' requests arrive."""
    files = security.make_run_credentials("sec", PAPER_TEAM.names, tmp_path / "cred")
    k = Keys("sec")
    port = free_port()
    ep = endpoint("127.0.0.1", port, tls=True)
    world = await Bus.open(mode="router", listen=[ep], security=security.load(files["world"]))
    got: list[str] = []
    arrived = asyncio.Event()

    def on_request(sample: Sample) -> None:
        got.append(decode(sample.payload, ActionRequest).robot + "@" + k.robot_of(sample.key))
        if got.count("alice@alice") == 2 and "bob@bob" in got:  # each link's last: what came before it, came
            arrived.set()

    sessions = []
    try:
        world.subscribe(k.any_action_request, on_request)
        sessions = [await open_client(ep, 5, security=security.load(files[r])) for r in ("alice", "bob")]
        await asyncio.sleep(1.0)  # the world's subscription reached the planner's sessions
        alice, bob = sessions
        alice.put(k.action_request("alice"), ActionRequest(robot="alice", agent_id="p", tick=0, action=Wait()))
        alice.put(k.action_request("david"), ActionRequest(robot="david", agent_id="p", tick=0, action=Wait()))
        alice.put(k.action_request("alice"), ActionRequest(robot="alice", agent_id="p", tick=1, action=Wait()))
        bob.put(k.action_request("david"), ActionRequest(robot="david", agent_id="p", tick=0, action=Wait()))
        bob.put(k.action_request("bob"), ActionRequest(robot="bob", agent_id="p", tick=0, action=Wait()))
        # each link delivers in order, two links in no order between them: a request for david, sent
        # before each link's last, would have come before it
        await asyncio.wait_for(arrived.wait(), 30)
        assert sorted(got) == ["alice@alice", "alice@alice", "bob@bob"]
    finally:
        for s in sessions:
            await s.close()
        await world.close()


def test_the_environment_runs_the_papers_protocol_only() -> None:
    """In mhrc.env the caller gives every robot's command: a protocol's policies would have no
    robot left to decide for, so any protocol but mhrc is refused with a typed code, before anything is built."""
    import mhrc.env
    from mhrc.env.options import CALLER_DECIDES, EnvProtocolError

    for name, code in (("centralized", CALLER_DECIDES), ("leader", CALLER_DECIDES), ("nope", Refusal.UNKNOWN_PROTOCOL)):
        with pytest.raises(EnvProtocolError) as exc:
            mhrc.env.parallel_env(protocol=name)
        assert exc.value.code == code and "protocol" in str(exc.value)


@pytest.mark.slow
def test_up_processes_runs_the_centralized_planner_as_one_agent_process(tmp_path: Path) -> None:
    """`mhrc up --processes --protocol centralized` on the secured bus: the world and one planner
    process, logged in as every robot (one --credentials each), whose episode's header says so."""
    import json
    import subprocess
    import sys

    from mhrc.core.records import messages

    trace = tmp_path / "t.jsonl"
    done = subprocess.run(
        [sys.executable, "-m", "mhrc", "up", "--processes", "--protocol", "centralized", "--horizon", "6", "--json"]
        + ["--trace", str(trace), "--quiet"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out["temporal_steps"] == 6 and out["protocol"] == "centralized"
    records = read_records(trace)
    assert [m.protocol for m in messages(records, EpisodeStarted)] == ["centralized"]
    from mhrc.run.processes import agent_command, participants

    cfg = EpisodeConfig.build(protocol="centralized", credentials=tmp_path / "creds").resolved()
    (group,) = participants(cfg, cfg.robots)
    cmd = agent_command(group, cfg)
    assert group == cfg.robots and cmd.count("--robot") == 3 and cmd.count("--credentials") == 3
    assert cmd[cmd.index("--protocol") + 1] == "centralized"


def test_a_planner_process_under_no_mobile_is_told_the_episodes_robots() -> None:
    """`mhrc up --processes --protocol centralized --ablation no_mobile`: one planner for Alice and
    Bob, told the ablation, so that it seats the episode's robots instead of asking for David's."""
    from mhrc.run.processes import agent_command, participants

    cfg = EpisodeConfig.build(protocol="centralized", ablation="no_mobile").resolved()
    (group,) = participants(cfg, cfg.robots)
    cmd = agent_command(group, cfg)
    assert group == ("alice", "bob") and cmd[cmd.index("--ablation") + 1] == "no_mobile"
    paper = agent_command("alice", EpisodeConfig.build().resolved())
    assert "--ablation" not in paper  # the paper's agents' command lines as they were
