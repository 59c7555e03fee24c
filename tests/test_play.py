"""`mhrc play`'s parts that need no browser: the forms a robot's observation gives (choices from
what it knows, a skill that cannot work disabled with the reason), a submission refused with a
code (stale, not a choice, oversized, malformed) while the decision stays open, and a port in use."""

from __future__ import annotations

import asyncio
import json
import socket

import pytest
from click.testing import CliRunner

from mhrc.cli import main
from mhrc.core.protocol import Navigate, Pick, Place
from mhrc.play.forms import Refusal, Refused, action_of, forms
from mhrc.play.house import scene_of
from mhrc.play.human import HumanPolicy
from mhrc.testing.policy_harness import observation


def _form(obs, skill):  # type: ignore[no-untyped-def]
    return next(f for f in forms(obs) if f.skill == skill)


def test_forms_offer_what_the_robot_knows_and_say_why_a_skill_cannot_work() -> None:
    alice = observation("alice", objects={"apple": "table_2"})
    assert [f.skill for f in forms(alice)] == ["navigate", "move", "open", "pick", "place", "communicate", "wait"]
    assert _form(alice, "pick").fields[0].choices == ["apple"] and _form(alice, "pick").disabled is None
    assert _form(alice, "place").disabled == "your gripper is empty: pick something first"
    assert "table_2" in _form(alice, "navigate").fields[0].choices
    holding = observation("alice", objects={"apple": "table_2"}, holding="apple")
    assert _form(holding, "pick").disabled == "your gripper holds apple: place it first"
    assert _form(holding, "place").fields[0].choices == ["apple"]
    david = observation("david", teammates=[])
    assert [f.skill for f in forms(david)] == ["navigate", "communicate", "wait"]  # no arm, no pick
    assert _form(david, "communicate").disabled == "no teammate is attached to hear you"


def test_a_submission_becomes_the_protocols_action() -> None:
    alice = observation("alice", tick=3, objects={"apple": "table_2"}, holding=None)
    assert action_of({"tick": 3, "skill": "pick", "object": "apple"}, alice) == Pick(obj="apple")
    assert action_of({"tick": 3, "skill": "navigate", "target": "table_2", "stand_pose": "1"}, alice) == Navigate(
        target="table_2", stand_pose=1
    )
    holding = observation("alice", tick=3, holding="apple")
    assert action_of({"tick": 3, "skill": "place", "object": "apple", "location": "table_0"}, holding) == Place(
        obj="apple", location="table_0"
    )


@pytest.mark.parametrize(
    ("submission", "code", "says"),
    [
        ({"tick": 2, "skill": "wait"}, Refusal.STALE_TICK, "the request is for tick 2 but alice is at tick 3"),
        ({"tick": 3, "skill": "pick", "object": "garage"}, Refusal.NOT_A_CHOICE, "object 'garage' is not one of"),
        ({"tick": 3, "skill": "navigate", "target": "table_2", "stand_pose": "9"}, Refusal.NOT_A_CHOICE, "stand_pose"),
        ({"tick": 3, "skill": "communicate", "to": "bob", "content": "x" * 4001}, Refusal.MALFORMED, "4000"),
        ({"tick": 3, "skill": "place", "object": "apple", "location": "tray"}, Refusal.UNAVAILABLE, "gripper is empty"),
        ({"tick": 3, "skill": "fly"}, Refusal.NOT_CAPABLE, "no skill 'fly'"),
        ({"tick": 3, "skill": "wait", "target": "x"}, Refusal.MALFORMED, "wait takes no target"),
        ({"tick": 3, "skill": "move", "dx": "1e9", "dy": "0"}, Refusal.MALFORMED, "within"),
        ({"skill": "wait"}, Refusal.MALFORMED, "no tick"),
    ],
)
def test_a_submission_that_cannot_be_sent_is_refused_with_a_code(submission, code, says) -> None:  # type: ignore[no-untyped-def]
    alice = observation("alice", tick=3, objects={"apple": "table_2"})
    with pytest.raises(Refused) as refused:
        action_of(submission, alice)
    assert refused.value.code is code and says in refused.value.reason, refused.value.reason


def test_a_refused_submission_leaves_the_decision_open_and_the_next_one_decides() -> None:
    async def play() -> tuple[list[dict], object]:  # type: ignore[type-arg]
        told: list[dict] = []  # type: ignore[type-arg]
        policy = HumanPolicy("alice")
        policy.connect(told.append)
        deciding = asyncio.create_task(policy.decide(observation("alice", tick=5)))
        await asyncio.sleep(0)
        policy.submit("not json")
        policy.submit(json.dumps({"tick": 4, "skill": "wait"}))
        policy.submit(b"{" + b" " * 20_000 + b"}")
        assert not deciding.done()
        policy.submit(json.dumps({"tick": 5, "skill": "wait"}))
        return told, await deciding

    told, decision = asyncio.run(play())
    assert [m["code"] for m in told if m["type"] == "refused"] == ["malformed", "stale_tick", "malformed"]
    assert told[0]["type"] == "view" and told[-1]["type"] == "accepted"
    assert decision.action.skill == "wait" and decision.latency >= 0  # type: ignore[attr-defined]


def test_a_port_in_use_is_one_line_and_exit_2() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        result = CliRunner().invoke(main, ["play", "--robot", "david", "--port", str(port), "--no-browser"])
    assert result.exit_code == 2
    assert (
        result.output.strip()
        == f"mhrc play: --port: 127.0.0.1:{port} is in use (Address already in use); pick another port, or 0 for a free one"
    )


def test_the_map_of_a_world_elsewhere_is_the_layout_whose_furniture_the_robot_knows() -> None:
    assert scene_of(observation("david")) == "kitchen"
    assert scene_of(observation("david", furniture=[])) is None


def test_a_robot_not_in_the_team_is_refused_before_anything_starts() -> None:
    result = CliRunner().invoke(main, ["play", "--robot", "zed", "--no-browser"])
    assert result.exit_code == 2 and "--robot: 'zed' is not in this episode's team" in result.output


def test_an_existing_run_is_refused_as_mhrc_up_refuses_it(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """`mhrc play --run NAME` keeps an earlier episode's trace: one line, exit 2; with --overwrite
    and a port in use, the port is refused first and the trace is still kept."""
    monkeypatch.chdir(tmp_path)
    trace = tmp_path / "runs" / "first" / "trace.jsonl"
    trace.parent.mkdir(parents=True)
    trace.write_text('{"an": "earlier episode"}\n')
    result = CliRunner().invoke(main, ["play", "--robot", "david", "--run", "first", "--no-browser"])
    assert result.exit_code == 2
    assert result.output.strip() == (
        "mhrc play: --run first: runs/first/trace.jsonl holds an earlier episode's trace; choose another --run "
        "(or leave it out for a new one), or pass --overwrite to replace it"
    )
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = str(taken.getsockname()[1])
        result = CliRunner().invoke(main, ["play", "--robot", "david", "--run", "first", "--overwrite", "--port", port])
    assert result.exit_code == 2 and "is in use" in result.output
    assert trace.read_text() == '{"an": "earlier episode"}\n'


def test_a_reloaded_tab_replaces_its_socket_and_another_tab_is_refused() -> None:
    """The same tab (its id) reloaded takes over from its old socket, which is told so; a page of
    another tab is refused while one drives; a page gone leaves the seat free after the grace."""
    from mhrc.play.session import REPLACED, PlaySession, SecondDriver

    async def pages() -> tuple[list[dict], list[dict], str, bool]:  # type: ignore[type-arg]
        session = PlaySession("david", run="r", connect="tcp/127.0.0.1:9", attach_timeout=0.2)
        session.reload_grace = 0.0
        old: list[dict] = []  # type: ignore[type-arg]
        new: list[dict] = []  # type: ignore[type-arg]
        first, second, other = object(), object(), object()
        session.open(first, old.append, tab="tab-1")
        session.open(second, new.append, tab="tab-1")  # the same tab, reloaded
        with pytest.raises(SecondDriver) as refused:
            session.open(other, lambda m: None, tab="tab-2")
        await session.close(first)  # the old socket's close comes late: it no longer drives
        still = session.driven
        await session.close(second)
        await asyncio.sleep(0.05)  # the grace (0 s here) runs out
        session.open(other, lambda m: None, tab="tab-2")  # the seat is free: no SecondDriver now
        taken = session.driven
        await session.close(other)
        await asyncio.sleep(0.05)
        return old, new, str(refused.value), still and taken

    old, new, refused, held = asyncio.run(pages())
    assert [m["type"] for m in old][-1] == REPLACED and new[0]["type"] == "hello"
    assert "one driver per robot" in refused and held
