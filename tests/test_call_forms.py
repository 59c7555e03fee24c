"""A skill's call form is declared once, on its model (mhrc.core.protocol.actions): a skill declared
there and nowhere else is parsed from a reply, offered in the structured-output schema and on the
play page's forms, and checked by the hallucination diagnostics."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Literal

import pytest
from pydantic import Field

from mhrc.agents.parse import ReplyFormatError, parse_command, signature
from mhrc.agents.structured import decision_schema, parse_structured
from mhrc.analysis.diagnostics import diagnose
from mhrc.core.protocol import ActionResult, Observation, SkillOutcome, Turn
from mhrc.core.protocol.actions import CALLS, SKILLS, ActionModel, Arg, ArgKind, declare
from mhrc.core.records import LineKind, TraceLine
from mhrc.play.forms import action_of, forms
from mhrc.testing.policy_harness import observation


class Hand(ActionModel):
    """A skill of this test only: hand an object lying somewhere to a teammate."""

    ARGS = (Arg("obj", ArgKind.PICKABLE, word="object"), Arg("to", ArgKind.TEAMMATE, shown="robot"))
    skill: Literal["hand"] = "hand"
    obj: str = Field(max_length=64)
    to: str = Field(max_length=64)


@pytest.fixture
def hand() -> Iterator[type[Hand]]:
    declare(Hand)
    try:
        yield Hand
    finally:
        CALLS.pop("hand")


def _alice(**kw: object) -> Observation:
    obs = observation("alice", objects={"apple": "table_0"}, **kw)  # type: ignore[arg-type]
    return obs.model_copy(update={"status": obs.status.model_copy(update={"skills": [*obs.status.skills, "hand"]})})


def test_the_shipped_skills_are_declared_in_the_protocols_order() -> None:
    assert SKILLS == ("navigate", "move", "open", "pick", "place", "communicate", "wait")
    assert [signature(s) for s in SKILLS] == [
        "navigate(furniture, stand_pose_id)",
        "move(dx, dy)",
        "open(furniture)",
        "pick(object)",
        "place(object, location)",
        "communicate(content, robot)",
        "wait()",
    ]


def test_a_declared_skill_is_parsed(hand: type[Hand]) -> None:
    assert signature("hand") == "hand(object, robot)"
    assert parse_command("Analysis: Bob needs it.\nCommand: hand(the apple, Bob).") == Hand(obj="apple", to="bob")
    assert parse_command("**Command:** hand(object=apple, robot=bob)") == Hand(obj="apple", to="bob")
    assert Hand(obj="apple", to="bob").call() == "hand(apple, bob)"
    with pytest.raises(ReplyFormatError, match=r"hand takes 2 argument\(s\): hand\(object, robot\); got 1"):
        parse_command("Command: hand(apple)")


def test_a_declared_skill_is_offered_in_the_structured_schema(hand: type[Hand]) -> None:
    obs = _alice()
    variants = {v["properties"]["skill"]["const"]: v for v in decision_schema(obs)["properties"]["command"]["anyOf"]}
    assert list(variants["hand"]["properties"]) == ["skill", "object", "to"]
    assert variants["hand"]["properties"]["object"]["enum"] == ["apple"]
    assert variants["hand"]["properties"]["to"]["enum"] == ["bob", "david"]
    action, _ = parse_structured('{"analysis": "", "command": {"skill": "hand", "object": "apple", "to": "Bob"}}')
    assert action == Hand(obj="apple", to="bob")
    # a robot without the skill is not offered it
    plain = observation("alice", objects={"apple": "table_0"})
    assert "hand" not in [
        v["properties"]["skill"]["const"] for v in decision_schema(plain)["properties"]["command"]["anyOf"]
    ]


def test_a_declared_skill_is_a_form_on_the_play_page(hand: type[Hand]) -> None:
    obs = _alice()
    form = next(f for f in forms(obs) if f.skill == "hand")
    assert [(f.name, f.kind, f.choices) for f in form.fields] == [
        ("object", "choice", ["apple"]),
        ("to", "choice", ["bob", "david"]),
    ]
    assert form.disabled is None
    assert action_of({"tick": 0, "skill": "hand", "object": "apple", "to": "bob"}, obs) == Hand(obj="apple", to="bob")
    held = next(f for f in forms(_alice(holding="cup")) if f.skill == "hand")
    assert held.disabled == "your gripper holds cup: place it first"  # the reason its argument's kind gives


def test_a_declared_skill_is_diagnosed(hand: type[Hand]) -> None:
    """A hand of an object the robot planned on without knowing it is a hallucination; of one it knew, none."""
    obs = _alice()
    lines = [
        TraceLine(1, 0.0, "mhrc/r/robot/alice/turn", LineKind.PUT, msg=Turn(robot="alice", tick=0, observation=obs))
    ]
    for n, (tick, thing) in enumerate([(0, "ghost"), (1, "apple")], 2):
        if tick:
            turn = Turn(robot="alice", tick=tick, observation=obs.model_copy(update={"tick": tick}))
            lines.append(TraceLine(n * 2, 0.0, "mhrc/r/robot/alice/turn", LineKind.PUT, msg=turn))
        result = ActionResult.model_construct(
            goal_id=f"g{n}",
            robot="alice",
            tick=tick,
            action=Hand(obj=thing, to="bob"),
            outcome=SkillOutcome.ok("Handed."),
            observation=obs,
            done=False,
        )  # (a skill of this test only: the protocol's union does not hold it, so it is not validated)
        lines.append(TraceLine(n * 2 + 1, 0.0, "mhrc/r/robot/alice/action/result", LineKind.PUT, msg=result))
    d = diagnose(lines)
    assert (d.hallucinations, d.hallucinated_names) == (1, {"ghost": 1})
