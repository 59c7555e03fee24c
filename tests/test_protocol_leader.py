"""The leader protocol (DynaHMRC's loop): its sentences read back, the election's rule, and whole
episodes on real PyBullet and real Zenoh (loopback): the stages in the trace as `communicate`
actions, and a new election when the leader's agent is killed mid-episode."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest

from mhrc.agents.protocols import Seating, leader_talk, protocol
from mhrc.agents.protocols.leader import LeaderPolicy
from mhrc.analysis.observability import check
from mhrc.core.bus import Bus
from mhrc.core.keys import Keys
from mhrc.core.protocol import ActionResult, RobotDetached, Thought, TickClosed, decode_event
from mhrc.core.records import read_records
from mhrc.core.team import PAPER_TEAM
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process


def test_every_sentence_reads_back() -> None:
    said = [
        leader_talk.describe("alice", "mobile manipulator", ["navigate", "pick", "communicate"], 9.0),
        leader_talk.elected("david", "bob"),
        leader_talk.assign("david", "alice", "fetch", "book"),
        leader_talk.done("alice", "explore", "fridge", ["soap", "apple"]),
        leader_talk.done("alice", "fetch", "book", []),
        leader_talk.failed("alice", "fetch", "book", "too_far", "another robot should try"),
        leader_talk.task_list("bob", ["bread", "ham"], True, ["bread"]),
        leader_talk.task_list("bob", ["mug"], False, []),
        leader_talk.status("alice", "fetch", "book"),
        leader_talk.status("alice", None, None),
        leader_talk.make_way("alice", "erin", "counter"),
    ]
    parsed = [leader_talk.parse(s) for s in said]
    assert parsed == [
        leader_talk.Describe("alice", "mobile manipulator", ("navigate", "pick"), 9.0),
        leader_talk.Elected("david", "bob"),
        leader_talk.Assign("david", "alice", "fetch", "book"),
        leader_talk.Done("alice", "explore", "fridge", ("soap", "apple")),
        leader_talk.Done("alice", "fetch", "book", ()),
        leader_talk.Failed("alice", "fetch", "book", "too_far", "another robot should try"),
        leader_talk.TaskList("bob", ("bread", "ham"), True, ("bread",)),
        leader_talk.TaskList("bob", ("mug",), False, ()),
        leader_talk.Status("alice", "fetch", "book"),
        leader_talk.Status("alice", None, None),
        leader_talk.MakeWay("alice", "erin", "counter"),
    ]
    assert leader_talk.parse("On table_2 I found: sponge.") is None  # another protocol's message: not ours


def test_the_lowest_bid_leads_and_ties_go_by_team_order() -> None:
    p = LeaderPolicy("alice", ("alice", "bob", "carol", "david"))
    p.attached = {"alice", "bob", "carol", "david"}
    p.skills = {"alice": ("navigate", "pick"), "bob": ("pick", "place"), "carol": ("navigate",), "david": ("navigate",)}
    assert p._convener() == "carol"  # the lowest bid by role, first in the team's order
    p.bids = {"alice": 9.0, "bob": 5.0, "carol": 2.0, "david": 2.0}
    p._elect()
    assert p.leader == "carol"
    p.attached.discard("carol")  # carol detached: her bid goes, and the election is held again
    p._lost_leader()
    assert p.leader is None and "carol" not in p.bids and p._convener() == "david"
    p._elect()
    assert p.leader == "david"


def test_each_robot_gets_its_own_policy() -> None:
    seats = protocol("leader").build(Seating(PAPER_TEAM, PAPER_TEAM.names, "sequential"))  # type: ignore[misc]
    assert {type(s) for s in seats.values()} == {LeaderPolicy} and len({id(s) for s in seats.values()}) == 3


def _said(records: list[Any]) -> list[tuple[str, Any]]:
    out = []
    for r in records:
        if isinstance(r.msg, ActionResult) and r.msg.action.skill == "communicate":
            out.append((r.msg.robot, leader_talk.parse(r.msg.action.content)))  # type: ignore[union-attr]
    return out


@pytest.mark.slow
async def test_the_leader_protocol_solves_an_episode_with_every_stage_in_its_trace(tmp_path: Path) -> None:
    trace = tmp_path / "trace.jsonl"
    cfg = EpisodeConfig.build(
        protocol="leader",
        task="pack_objects",
        scene="bathroom",
        n_objects=4,
        seed=0,
        horizon=50,
        schedule="sequential",
        trace=trace,
    ).resolved()
    done = await asyncio.wait_for(up_in_process(cfg), 300)
    assert done.metrics.success, (done.reason, done.metrics)
    records = read_records(trace)
    said = _said(records)
    kinds = {type(s).__name__ for _, s in said}
    assert {"Describe", "TaskList", "Assign", "Done"} <= kinds, kinds
    assert {s.leader for _, s in said if isinstance(s, leader_talk.Assign)} == {"david"}  # the scout bid lowest
    assert all(s is not None for _, s in said)  # every message has one of the protocol's shapes
    seen = check(records)
    assert seen.unchecked is None and seen.leaks == []
    _shows_who_leads_and_the_jobs(trace, tmp_path)


def _shows_who_leads_and_the_jobs(trace: Path, tmp_path: Path) -> None:
    """The report and the Rerun recording show the protocol, who leads and what was allocated to whom."""
    from mhrc.viewer.load import load_trace
    from mhrc.viewer.model import build_view
    from mhrc.viewer.page import render_page

    records = read_records(trace)
    told = [r.msg.coordination for r in records if isinstance(r.msg, Thought) and r.msg.coordination is not None]
    assert {c.leader for c in told} == {None, "david"}  # none before the election
    assert any(c.job and c.by == "david" for c in told)
    html = render_page(build_view(load_trace(trace)))
    section = html[html.index('<section id="coordination">') : html.index('<section id="lanes-section">')]
    assert "Coordination (leader)" in section and "<td>david</td>" in section  # the leader, from his tick
    assert "<th>protocol</th><td>leader</td>" in html
    row = section[section.index('<tr data-robot="alice">') :]  # the fetcher's jobs, in order (bob finishes)
    assert "fetch(" in row[: row.index("</tr>")]
    assert 'class="coordination dim">job <code>' in html  # each step the job it worked on
    pytest.importorskip("rerun")
    from test_rerun import read_back, verify

    from mhrc.viewer.rerun import Mode, Target
    from mhrc.viewer.rerun.record import write_recording

    out = tmp_path / "leader.rrd"
    write_recording(trace, Target(Mode.FILE, out))
    verify(out)
    got = read_back(out)
    assert any("leader david" in t for t in got.texts("/agents/alice/coordination"))
    assert any(t.startswith("job fetch(") for t in got.texts("/agents/alice/coordination"))


@pytest.mark.slow
async def test_when_the_leaders_agent_is_killed_the_team_elects_again_and_solves_the_episode(tmp_path: Path) -> None:
    """David, the scout, leads the paper's trio; his agent's task is cancelled once the third tick
    closed. Alice and Bob see him detach, elect again (Bob bids lower than Alice), tell the new
    leader what they work on, and the team finishes the task."""
    trace = tmp_path / "trace.jsonl"
    cfg = EpisodeConfig.build(
        protocol="leader",
        task="pack_objects",
        scene="bathroom",
        n_objects=3,
        seed=0,
        horizon=50,
        schedule="sequential",
        trace=trace,
    ).resolved()
    killed: list[int] = []

    def observe(bus: Bus, run: str) -> None:
        loop = asyncio.get_running_loop()

        def on_event(sample: Any) -> None:
            ev = decode_event(sample.payload)
            if isinstance(ev, TickClosed) and ev.tick >= 3 and not killed:
                killed.append(ev.tick)
                for t in asyncio.all_tasks(loop):
                    if t.get_name() == "agent-david":
                        loop.call_soon_threadsafe(t.cancel)

        bus.subscribe(Keys(run).world_event, on_event)

    done = await asyncio.wait_for(up_in_process(cfg, observe=observe), 300)
    assert killed, "the episode ended before the leader could be killed"
    assert done.metrics.success, (done.reason, done.metrics)
    records = read_records(trace)
    assert any(isinstance(r.msg, RobotDetached) and r.msg.robot == "david" for r in records)
    said = _said(records)
    leaders = [s.leader for _, s in said if isinstance(s, leader_talk.Assign)]
    assert leaders[0] == "david" and "bob" in leaders, leaders  # bob allocates after the new election
    assert any(robot == "alice" and isinstance(s, leader_talk.Status) for robot, s in said)  # told the new leader
