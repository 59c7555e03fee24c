"""Golden tests of the rendered prompts: each role at step 1 and at a later step.

The observations are built by hand in the shape the world sends (the example house of the
paper, Pack Objects), so these goldens change only when the prompts, the description function
or the memory change, not when the simulator does. The later step has all three histories
with their "(latest)" tags, a format error fed back and a failed action.

Regenerate after a deliberate prompt change and review the diff of tests/golden/:

    MHRC_UPDATE_GOLDEN=1 python -m pytest -q tests/test_prompts.py
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest
from mhrc.agents.llm import ScriptedClient
from mhrc.agents.llm_policy import LLMPolicy, TemplateError, load_template

from mhrc.protocol import (
    ActionResult,
    FurnitureView,
    ObjectView,
    Observation,
    OutcomeCode,
    Pose2D,
    RobotMessage,
    RobotStatus,
    SkillOutcome,
)

GOLDEN = Path(__file__).parent / "golden"
SKILLS = {
    "alice": ["navigate", "move", "open", "pick", "place", "communicate", "wait"],
    "bob": ["pick", "place", "communicate", "wait"],
    "david": ["navigate", "communicate", "wait"],
}
KINDS = {"alice": "mobile manipulator", "bob": "tabletop manipulator", "david": "mobile robot"}
BRIEF = "Pack the listed objects into the tray on table_0; nothing else goes in the tray."
HELP = "Help Bob pack the listed objects into the tray on table_0: find them, fetch them and hand them over."
TARGETS = ["phone", "book", "soap", "mug"]


def furniture(drawer_open: bool = False) -> list[FurnitureView]:
    def f(name: str, kind: str, pos: tuple[float, float, float], poses: list[tuple[float, float, float]], **kw: Any) -> FurnitureView:
        return FurnitureView(name=name, kind=kind, position=pos, stand_poses=[Pose2D(x=x, y=y, yaw=w) for x, y, w in poses], **kw)

    up, down = 1.5708, -1.5708
    return [
        f("table_0", "table", (-3.0, 0.0, 0.7), [(-3.3, -0.85, up), (-2.5, -0.85, up), (-2.5, 0.85, down)], place_pose=(-3.3, -0.22, 0.7)),
        f("drawer_unit", "drawer unit", (-3.0, 3.45, 0.6), [(-3.0, 2.12, up)], openable=True, is_open=drawer_open),
        f("counter", "counter", (-1.0, -3.5, 0.75), [(-1.3, -2.75, down), (-0.7, -2.75, down)], place_pose=(-1.0, -3.45, 0.75)),
        f("table_1", "table", (2.5, 2.5, 0.7), [(2.2, 1.7, up), (2.8, 1.7, up)], place_pose=(2.5, 2.45, 0.7)),
        f("sofa", "sofa", (4.3, -1.6, 0.45), [(3.45, -2.0, 0.0), (3.45, -1.2, 0.0)], place_pose=(4.1, -1.6, 0.45)),
        f("tray", "tray on table_0", (-3.4, 0.19, 0.71), [], place_pose=(-3.4, 0.19, 0.71)),
    ]


def observe(robot: str, tick: int = 0, *, base: tuple[float, float, float] | None = None, **update: Any) -> Observation:
    """A robot's observation of the example house at `tick`; `update` overrides fields."""
    bases = {"alice": (-1.5, 1.2, 0.0), "david": (4.0, 3.0, 3.1416)}
    b = base or bases.get(robot)
    status = RobotStatus(
        name=robot,
        kind=KINDS[robot],
        skills=SKILLS[robot],
        base=Pose2D(x=b[0], y=b[1], yaw=b[2]) if b else None,
        arm_base={"alice": (b[0] + 0.2, b[1], 0.65) if b else None, "bob": (-3.75, 0.0, 0.7)}.get(robot),
        reach={"alice": 0.72, "bob": 0.62}.get(robot),
        holding=update.pop("holding", None),
    )
    bob = robot == "bob"
    values: dict[str, Any] = {
        "robot": robot,
        "tick": tick,
        "status": status,
        "furniture": furniture(update.pop("drawer_open", False)),
        "objects": [
            ObjectView(name="phone", position=(-3.25, -0.24, 0.707), on="table_0"),
            ObjectView(name="book", position=(-2.4, 0.05, 0.715), on="table_0"),
        ]
        if bob
        else [],
        "task_brief": BRIEF,
        "task_detail": f"Objects to pack: {', '.join(TARGETS)}." if bob else HELP,
        "targets": TARGETS if bob else [],
        "task_status": f"In the tray: nothing yet. Not yet in the tray: {', '.join(TARGETS)}." if bob else None,
        "teammates": {r: SKILLS[r] for r in SKILLS if r != robot},
    }
    return Observation(**(values | update))


def message(sender: str, to: str, content: str, tick: int) -> RobotMessage:
    return RobotMessage(sender=sender, to=to, content=content, tick=tick)


def ok(text: str) -> SkillOutcome:
    return SkillOutcome.ok(text)


# Four steps per role: (reply, outcome, the observation that follows it)
def script(robot: str) -> list[tuple[str, SkillOutcome, Observation]]:
    if robot == "alice":
        at_drawer = (-3.0, 2.12, 1.5708)
        soap = ObjectView(name="soap", position=(-3.1, 3.3, 0.45), on="drawer_unit", inside=True)
        return [
            (
                'Analysis: ...\nCommand: communicate("David, please explore these surfaces and tell me what lies on them: counter, table_1, sofa.", david)',
                ok("Message sent to david."),
                observe("alice", 1, new_messages=[message("bob", "alice", "Alice, please bring these to table_0 within my reach: book, soap, mug.", 0)]),
            ),
            ("Command: navigate(drawer_unit, 0)", ok("You reached stand pose 0 of drawer_unit. drawer_unit is closed: open it to see what is inside."), observe("alice", 2, base=at_drawer)),
            ("I should open the drawer now.", ok("You waited."), observe("alice", 3, base=at_drawer)),
            (
                "Command: open(drawer_unit)",
                ok("You opened drawer_unit. Inside: soap."),
                observe("alice", 4, base=at_drawer, drawer_open=True, objects=[soap], new_messages=[message("david", "alice", "On table_1 I found: mug.", 3)]),
            ),
        ]
    if robot == "bob":
        in_tray = ObjectView(name="phone", position=(-3.4, 0.19, 0.72), on="tray")
        book = ObjectView(name="book", position=(-2.4, 0.05, 0.715), on="table_0")
        status = "In the tray: phone. Not yet in the tray: book, soap, mug."
        return [
            ('Command: communicate("Alice, please bring these to table_0 within my reach: book, soap, mug.", alice)', ok("Message sent to alice."), observe("bob", 1)),
            ("Command: pick(phone)", ok("You picked up phone."), observe("bob", 2, holding="phone", objects=[book])),
            ("Command: place(phone, tray)", ok("You placed phone in the tray."), observe("bob", 3, objects=[in_tray, book], task_status=status, new_messages=[message("alice", "bob", "Bob, I will bring book, soap and mug.", 2)])),
            (
                "Command: pick(book)",
                SkillOutcome.fail(OutcomeCode.TOO_FAR, "The end effector cannot reach book: it is 0.73 m away from the closest pose your arm can get to."),
                observe("bob", 4, objects=[in_tray, book], task_status=status),
            ),
        ]
    return [
        ("Nothing to explore yet. Command: wait()", ok("You waited."), observe("david", 1, new_messages=[message("alice", "david", "David, please explore these surfaces and tell me what lies on them: counter, table_1, sofa.", 0)])),
        ("Command: navigate(table_1, 0)", SkillOutcome.fail(OutcomeCode.NO_PATH, "Navigation failed: there is no collision-free path to stand pose 0 of table_1."), observe("david", 2)),
        ("Command: navigate(table_1, 1)", ok("You reached stand pose 1 of table_1. On table_1: mug."), observe("david", 3, base=(2.8, 1.7, 1.5708), objects=[ObjectView(name="mug", position=(2.6, 2.4, 0.75), on="table_1")])),
        ('Command: communicate("On table_1 I found: mug.", alice)', ok("Message sent to alice."), observe("david", 4, base=(2.8, 1.7, 1.5708), objects=[ObjectView(name="mug", position=(2.6, 2.4, 0.75), on="table_1")])),
    ]


async def play(policy: LLMPolicy, robot: str) -> list[str]:
    """Run the role's script through decide/record; the prompt of every step, and the last one."""
    steps = script(robot)
    policy.client = ScriptedClient([reply for reply, _, _ in steps] + ["Command: wait()"])
    obs, prompts = observe(robot, 0), []
    for reply, outcome, nxt in steps:
        d = await policy.decide(obs)
        prompts.append(d.prompt or "")
        policy.record(ActionResult(goal_id=f"g{obs.tick}", robot=robot, tick=obs.tick, action=d.action, outcome=outcome, observation=nxt))
        obs = nxt
    d = await policy.decide(obs)
    return prompts + [d.prompt or ""]


def check_golden(name: str, text: str) -> None:
    path = GOLDEN / name
    if os.environ.get("MHRC_UPDATE_GOLDEN"):
        path.parent.mkdir(exist_ok=True)
        path.write_text(text, encoding="utf-8")
    assert path.exists(), f"{path} is missing: run with MHRC_UPDATE_GOLDEN=1 and review it"
    assert text == path.read_text(encoding="utf-8"), f"{name} changed: if deliberate, regenerate with MHRC_UPDATE_GOLDEN=1"


@pytest.mark.parametrize("robot", ["alice", "bob", "david"])
async def test_prompts_at_step_1_and_step_5(robot: str) -> None:
    prompts = await play(LLMPolicy(robot, ScriptedClient([])), robot)
    first, later = prompts[0], prompts[-1]
    check_golden(f"{robot}_step1.txt", first)
    check_golden(f"{robot}_step5.txt", later)

    assert first.startswith(f"You are {robot.capitalize()},") and "Think step by step." in first
    assert first.count("- (none yet)") == 3 and "(latest)" not in first
    # the later step: each history's newest entry tagged, the oldest shown before it
    _, rest = later.split("Feedback on your actions")
    feedback, rest = rest.split("Messages you received")
    messages, actions = rest.split("Your actions so far")
    assert feedback.count("(latest)") == 1 and messages.count("(latest)") >= 1
    assert "(latest) step 3:" in actions and "- step 0:" in actions


def test_alice_at_step_5_sees_only_what_she_was_told_or_saw() -> None:
    text = (GOLDEN / "alice_step5.txt").read_text(encoding="utf-8")
    assert "soap: inside drawer_unit" in text and "phone" not in text.split("# Scene graph")[1].split("# Your status")[0]
    assert "could not be executed" in text  # the unparseable reply at step 2 came back as feedback
    assert "at stand pose 0 of drawer_unit" in text and "drawer_unit (drawer unit): position (-3.00, 3.45, 0.60), yaw 0 deg; open" in text
    assert "(latest) step 3: from David: On table_1 I found: mug." in text


def test_bob_sees_reach_progress_and_no_stand_poses() -> None:
    text = (GOLDEN / "bob_step5.txt").read_text(encoding="utf-8")
    assert "book: on table_0, at (-2.40, 0.05, 0.71), 1.35 m from your arm base\n" in text
    assert "(within your reach)" not in text and "(out of your reach)" not in text  # reach labels are an aid, not the paper's prompt
    assert "phone: in the tray" in text and "# Latest task progress\nIn the tray: phone." in text
    assert "stand poses" not in text and "Gripper: empty." in text
    assert "Object list: phone, book, soap, mug." in text


def test_skill_signatures_in_the_prompts_are_what_the_parser_accepts() -> None:
    from mhrc.agents.parse import SIGNATURES, parse_command

    for robot, skills in SKILLS.items():
        text = (GOLDEN / f"{robot}_step1.txt").read_text(encoding="utf-8")
        for skill in skills:
            assert f"- {SIGNATURES[skill]}:" in text
        example = text.split("Command: exactly one skill call on one line, e.g. ")[1].split("\n")[0]
        assert parse_command(f"Command: {example}").skill in skills


def test_custom_templates_are_checked_when_loaded(tmp_path: Path) -> None:
    (tmp_path / "bob_system.txt").write_text("You are $robot. Skills:\n$skills\n$colour", encoding="utf-8")
    (tmp_path / "bob_user.txt").write_text("$scene_graph\n$status\nCommand?", encoding="utf-8")
    with pytest.raises(TemplateError, match=r"unknown placeholder\(s\) \$colour"):
        load_template("bob", "system", tmp_path)
    with pytest.raises(TemplateError, match="missing"):
        load_template("alice", "user", tmp_path)
    (tmp_path / "bob_system.txt").write_text("You are $robot. Skills:\n$skills", encoding="utf-8")
    policy = LLMPolicy("bob", ScriptedClient([]), prompts_dir=tmp_path)
    system, user = (m["content"] for m in policy.render(observe("bob")))
    assert system.startswith("You are Bob. Skills:\n- pick(object):")
    assert user.startswith("Furniture:\n- table_0 (table)") and user.endswith("Gripper: empty.\nCommand?\n")
