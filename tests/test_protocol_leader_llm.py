"""The LLM form of `leader`: every robot's agent a model (the scripted model server, real HTTP on
loopback), DynaHMRC's loop carried out in the messages the models write, on real PyBullet and real
Zenoh: self-descriptions and bids, an election, allocations, execution, reports, and the episode
solved. The stage each prompt shows is followed by code from those messages."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest
from test_protocol_centralized_llm import made_clients

from mhrc.agents.protocols import PROTOCOLS, leader_talk
from mhrc.agents.protocols.leader_llm import Stages, read
from mhrc.core.protocol import ActionResult, Communicate
from mhrc.core.records import read_records
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.testing import ScriptedModelServer

A_DESC = "alice here: mobile manipulator; I can navigate, move, open, pick, place. My bid to lead: 9.0."
B_DESC = "bob here: tabletop manipulator; I can pick, place. My bid to lead: 5.0."
ELECTED = "Election held by david: david leads."
TASK = "bob reports: the targets are phone, book, soap; I take phone myself."
W = "Command: wait()"


def say(text: str, to: str) -> str:
    return f'Command: communicate("{text}", {to})'


# pack_objects in the bathroom, 3 objects, seed 0: phone and book on table_0 (only the phone within
# Bob's reach), soap in the closed laundry_chest. One row per tick (lockstep): alice, bob, david.
TICKS = [
    (say(A_DESC, "david"), say(B_DESC, "david"), W),  # stage 1: to david, the convener (a scout)
    (W, W, say(ELECTED, "alice")),  # stage 2: david bids 2 in his mind and elects himself
    (W, W, say(ELECTED, "bob")),
    (W, say(TASK, "david"), say("Leader david assigns alice: explore(laundry_chest).", "alice")),  # stage 3
    ("Command: navigate(laundry_chest, 0)", "Command: pick(phone)", W),  # stage 4
    ("Command: open(laundry_chest)", "Command: place(phone, tray)", W),
    (say("alice reports: done explore(laundry_chest); found: soap.", "david"), W, W),
    (W, W, say("Leader david assigns alice: fetch(soap).", "alice")),
    ("Command: pick(soap)", W, say("Leader david assigns alice: fetch(book).", "alice")),
    ("Command: navigate(table_0, 0)", W, W),
    ("Command: place(soap, table_0)", W, W),
    (say("alice reports: done fetch(soap).", "david"), "Command: pick(soap)", W),
    ("Command: navigate(table_0, 2)", "Command: place(soap, tray)", W),
    ("Command: pick(book)", W, W),
    ("Command: navigate(table_0, 0)", W, W),
    ("Command: place(book, table_0)", W, W),
    (say("alice reports: done fetch(book).", "david"), "Command: pick(book)", W),
    (W, "Command: place(book, tray)", W),
]


def test_the_stages_follow_the_messages() -> None:
    team = ("alice", "bob", "david")
    alice = Stages("alice", team, attached=set(team))
    alice.skills = {"alice": ("navigate", "pick"), "bob": ("pick", "place"), "david": ("navigate",)}
    assert alice.convener() == "david" and alice.leader is None
    alice.sent(Communicate(to="david", content=A_DESC))
    assert alice.described_to == "david"
    alice.hear(read('"election held by David: David leads"'))  # type: ignore[arg-type]  # quoted, no period
    assert alice.leader == "david"
    alice.hear(read("Leader david assigns alice: fetch(book)."))  # type: ignore[arg-type]
    assert [j.call() for j in alice.jobs] == ["fetch(book)"]
    alice.sent(Communicate(to="david", content="alice reports: done fetch(book)."))
    assert alice.jobs == []
    alice.attached.discard("david")  # the leader detached: a new election, convened by bob
    alice.lost_leader()
    assert alice.leader is None and alice.described_to is None and alice.convener() == "bob"
    assert PROTOCOLS["leader"].forms == ("heuristic", "llm")


def _prompts(server: ScriptedModelServer, robot: str) -> list[str]:
    return [body["messages"][-1]["content"] for body in server.requests_of(robot)]


async def test_an_election_allocation_and_reports_in_messages_solve_the_episode(tmp_path: Path) -> None:
    script = {r: [row[i] for row in TICKS] for i, r in enumerate(("alice", "bob", "david"))}
    server = ScriptedModelServer(script)
    try:
        trace = tmp_path / "t.jsonl"
        cfg = EpisodeConfig.build(
            protocol="leader",
            task="pack_objects",
            scene="bathroom",
            seed=0,
            n_objects=3,
            horizon=len(TICKS) + 4,
            schedule="lockstep",
            llm="openai:scripted",
            base_url=server.url,
            trace=trace,
        )
        done = await asyncio.wait_for(up_in_process(cfg.resolved()), 120)
    finally:
        server.close()
    assert done.metrics.success, (done.reason, done.metrics)
    records = read_records(trace)
    results = [r.msg for r in records if isinstance(r.msg, ActionResult)]
    assert all(m.outcome.succeeded for m in results), [m for m in results if not m.outcome.succeeded]
    said = [leader_talk.parse(m.action.content) for m in results if isinstance(m.action, Communicate)]
    kinds = [type(s).__name__ for s in said]
    assert {"Describe", "Elected", "TaskList", "Assign", "Done"} <= set(kinds), kinds
    alice, david = _prompts(server, "alice"), _prompts(server, "david")
    assert "Stage 1" in alice[0] and 'communicate("alice here: mobile manipulator' in alice[0]
    assert "you are the convener" in david[1] and "alice 9.0" in david[1] and "bob 5.0" in david[1]
    assert "Leader: david." in alice[3] and "Stage 4" in alice[4] and "explore(laundry_chest)" in alice[4]
    assert "Stage 3" in david[7] and "done explore(laundry_chest); found soap" in david[7]
    assert "the targets are phone, book, soap" not in david[3] and "Targets: phone, book, soap" in david[4]


async def test_with_structured_each_robot_answers_one_json_decision(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """--structured: each request carries the robot's decision schema and a JSON reply is its command.
    Each robot's model client is closed once the episode is over."""
    made = made_clients(monkeypatch)
    bid = {"skill": "communicate", "content": A_DESC, "to": "david"}
    script = {"alice": [json.dumps({"analysis": "I bid to the convener.", "command": bid})]}
    server = ScriptedModelServer(script, when_done=json.dumps({"analysis": "", "command": {"skill": "wait"}}))
    try:
        trace = tmp_path / "t.jsonl"
        cfg = EpisodeConfig.build(
            protocol="leader",
            task="pack_objects",
            scene="bathroom",
            seed=0,
            n_objects=3,
            horizon=1,
            schedule="lockstep",
            llm="openai:scripted",
            base_url=server.url,
            structured=True,
            trace=trace,
        )
        await asyncio.wait_for(up_in_process(cfg.resolved()), 120)
    finally:
        server.close()
    first = server.requests_of("alice")[0]
    assert (
        "json_schema" in json.dumps(first.get("response_format")) and "JSON object" in first["messages"][-1]["content"]
    )
    sent = [r.msg.action for r in read_records(trace) if isinstance(r.msg, ActionResult) and r.msg.robot == "alice"]
    assert sent == [Communicate(to="david", content=A_DESC)]
    assert len(made) == 3 and all(c.closed for c in made)
