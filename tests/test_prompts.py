"""Golden tests of the rendered prompts: each role at step 1 and at a later step; the paper's
appendix (../shared/seed/MHRC_appendix.txt) element by element in the default prompts, none of
the prompt_hints aid's text there, and exactly that text with the aid.

The observations are built by hand in the shape the world sends (the example house of the
paper, Pack Objects), so these goldens change only when the prompts, the description function
or the memory change, not when the simulator does. The later step has all three histories
with their "(latest)" tags, a format error fed back and a failed action.

Regenerate after a deliberate prompt change and review the diff of tests/golden/:

    MHRC_UPDATE_GOLDEN=1 python -m pytest -q tests/test_prompts.py
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from mhrc.agents.llm import ScriptedClient
from mhrc.agents.llm_policy import LLMPolicy, TemplateError, load_hints, load_template, template_source
from mhrc.agents.replay import ReplayClient, ReplayMismatch
from mhrc.core.protocol import (
    ActionResult,
    FurnitureView,
    ObjectView,
    Observation,
    OutcomeCode,
    Pose2D,
    RobotMessage,
    RobotStatus,
    SkillOutcome,
    Thought,
)
from mhrc.world.briefs import Briefing, Role, brief, detail
from mhrc.world.tasks import get_task

GOLDEN = Path(__file__).parent / "golden"
SKILLS = {
    "alice": ["navigate", "move", "open", "pick", "place", "communicate", "wait"],
    "bob": ["pick", "place", "communicate", "wait"],
    "david": ["navigate", "communicate", "wait"],
}
KINDS = {"alice": "mobile manipulator", "bob": "tabletop manipulator", "david": "mobile robot"}
TARGETS = ["phone", "book", "soap", "mug"]
ROLES: dict[str, Role] = {"alice": "fetcher", "bob": "finisher", "david": "scout"}
PACK, CREW = get_task("pack_objects"), Briefing(finisher="Bob", fetcher="Alice", table="table_0")


def furniture(drawer_open: bool = False) -> list[FurnitureView]:
    def f(
        name: str, kind: str, pos: tuple[float, float, float], poses: list[tuple[float, float, float]], **kw: Any
    ) -> FurnitureView:
        return FurnitureView(
            name=name, kind=kind, position=pos, stand_poses=[Pose2D(x=x, y=y, yaw=w) for x, y, w in poses], **kw
        )

    up, down = 1.5708, -1.5708
    return [
        f(
            "table_0",
            "table",
            (-3.0, 0.0, 0.7),
            [(-3.3, -0.85, up), (-2.5, -0.85, up), (-2.5, 0.85, down)],
            place_pose=(-3.3, -0.22, 0.7),
        ),
        f("drawer_unit", "drawer unit", (-3.0, 3.45, 0.6), [(-3.0, 2.12, up)], openable=True, is_open=drawer_open),
        f(
            "counter",
            "counter",
            (-1.0, -3.5, 0.75),
            [(-1.3, -2.75, down), (-0.7, -2.75, down)],
            place_pose=(-1.0, -3.45, 0.75),
        ),
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
            ObjectView(name="book", position=(-2.4, 0.05, 0.715), yaw=1.5708, on="table_0"),
        ]
        if bob
        else [],
        "task_brief": brief(PACK, ROLES[robot], CREW),  # as the world words each role's task
        "task_detail": detail(PACK, ROLES[robot], CREW, TARGETS, {}),
        "targets": TARGETS if bob else [],
        "task_status": PACK.status(TARGETS, []) if bob else None,  # the default world's: no status_hints aid
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
                observe(
                    "alice",
                    1,
                    new_messages=[
                        message(
                            "bob", "alice", "Alice, please bring these to table_0 within my reach: book, soap, mug.", 0
                        )
                    ],
                ),
            ),
            (
                "Command: navigate(drawer_unit, 0)",
                ok("You reached stand pose 0 of drawer_unit. drawer_unit is closed: open it to see what is inside."),
                observe("alice", 2, base=at_drawer),
            ),
            ("I should open the drawer now.", ok("You waited."), observe("alice", 3, base=at_drawer)),
            (
                "Command: open(drawer_unit)",
                ok("You opened drawer_unit. Inside: soap."),
                observe(
                    "alice",
                    4,
                    base=at_drawer,
                    drawer_open=True,
                    objects=[soap],
                    new_messages=[message("david", "alice", "On table_1 I found: mug.", 3)],
                ),
            ),
        ]
    if robot == "bob":
        in_tray = ObjectView(name="phone", position=(-3.4, 0.19, 0.72), on="tray")
        book = ObjectView(name="book", position=(-2.4, 0.05, 0.715), yaw=1.5708, on="table_0")
        status = PACK.status(TARGETS, [SimpleNamespace(name="phone", on="tray")])  # type: ignore[list-item]
        return [
            (
                'Command: communicate("Alice, please bring these to table_0 within my reach: book, soap, mug.", alice)',
                ok("Message sent to alice."),
                observe("bob", 1),
            ),
            ("Command: pick(phone)", ok("You picked up phone."), observe("bob", 2, holding="phone", objects=[book])),
            (
                "Command: place(phone, tray)",
                ok("You placed phone in the tray."),
                observe(
                    "bob",
                    3,
                    objects=[in_tray, book],
                    task_status=status,
                    new_messages=[message("alice", "bob", "Bob, I will bring book, soap and mug.", 2)],
                ),
            ),
            (
                "Command: pick(book)",
                SkillOutcome.fail(
                    OutcomeCode.TOO_FAR,
                    "The end effector cannot reach book: it is 0.73 m away from the closest pose your arm can get to.",
                ),
                observe("bob", 4, objects=[in_tray, book], task_status=status),
            ),
        ]
    at_table_1, mug = (2.8, 1.7, 1.5708), ObjectView(name="mug", position=(2.6, 2.4, 0.75), on="table_1")
    return [
        (
            "Nothing to explore yet. Command: wait()",
            ok("You waited."),
            observe(
                "david",
                1,
                new_messages=[
                    message(
                        "alice",
                        "david",
                        "David, please explore these surfaces and tell me what lies on them: counter, table_1, sofa.",
                        0,
                    )
                ],
            ),
        ),
        (
            "Command: navigate(table_1, 0)",
            SkillOutcome.fail(
                OutcomeCode.NO_PATH, "Navigation failed: there is no collision-free path to stand pose 0 of table_1."
            ),
            observe("david", 2),
        ),
        (
            "Command: navigate(table_1, 1)",
            ok("You reached stand pose 1 of table_1. On table_1: mug."),
            observe("david", 3, base=at_table_1, objects=[mug]),
        ),
        (
            'Command: communicate("On table_1 I found: mug.", alice)',
            ok("Message sent to alice."),
            observe("david", 4, base=at_table_1, objects=[mug]),
        ),
    ]


async def play(policy: LLMPolicy, robot: str) -> list[str]:
    """Run the role's script through decide/record; the prompt of every step, and the last one."""
    steps = script(robot)
    policy.client = ScriptedClient([reply for reply, _, _ in steps] + ["Command: wait()"])
    obs, prompts = observe(robot, 0), []
    for reply, outcome, nxt in steps:
        d = await policy.decide(obs)
        prompts.append(d.prompt or "")
        policy.record(
            ActionResult(
                goal_id=f"g{obs.tick}", robot=robot, tick=obs.tick, action=d.action, outcome=outcome, observation=nxt
            )
        )
        obs = nxt
    d = await policy.decide(obs)
    return prompts + [d.prompt or ""]


def check_golden(name: str, text: str) -> None:
    path = GOLDEN / name
    if os.environ.get("MHRC_UPDATE_GOLDEN"):
        path.parent.mkdir(exist_ok=True)
        path.write_text(text, encoding="utf-8")
    assert path.exists(), f"{path} is missing: run with MHRC_UPDATE_GOLDEN=1 and review it"
    assert text == path.read_text(encoding="utf-8"), (
        f"{name} changed: if deliberate, regenerate with MHRC_UPDATE_GOLDEN=1"
    )


ROBOTS = ("alice", "bob", "david")
# Text of the prompt_hints aid that the observation adds (the rest is the kind's <kind>_hints.txt)
DYNAMIC_HINTS = (
    "m from your arm base",
    "m from you",
    "reach about",
    "Arm base:",
    "not a navigation target",
    "(drawer unit)",
    "(table)",
    "(tray on table_0)",
)
# Sentences of the old prompts that the issue moves into the aid: none may be in the default
AID_PHRASES = (
    "Current step",
    "at stand pose",
    "not at any stand pose",
    "open it to see inside",
    "told you",
    "at most 1 m",
    "give your command",
    "take over their part",
    "## Your teammates",
    "0.20 m ahead",
    "0.30 to 0.58",
    "compare it with your reach",
    "with your reach",
    "Do not repeat work",
    "Do not visit a surface twice",
    "Until Alice asks",
    "please explore these surfaces",
    "I placed soap on table_0 for you",
    "On table_1 I found:",
    "please bring these to table_0 within my reach",
    "hand the open surfaces",
    "not a navigation target",
    "reach about",
    "from your arm base",
    "## Hints",
)


@pytest.mark.parametrize("robot", ROBOTS)
async def test_prompts_at_step_1_and_step_5(robot: str) -> None:
    prompts = await play(LLMPolicy(robot, ScriptedClient([])), robot)
    first, later = prompts[0], prompts[-1]
    check_golden(f"{robot}_step1.txt", first)
    check_golden(f"{robot}_step5.txt", later)

    assert first.startswith(
        f"You are {robot.capitalize()}, a smart robot"
    )  # the role first (mhrc.testing reads the robot from it) and "Think step by step." in first
    if robot == "bob":  # the appendix's first feedback: before acting, talk to Alice
        assert first.count("- (none yet)") == 2 and "- (latest) step 0: This is the first step of the task" in first
    else:
        assert first.count("- (none yet)") == 3 and "(latest)" not in first
    # the later step: each history's newest entry tagged, the oldest shown before it
    _, rest = later.split("Feedback on your actions")
    feedback, rest = rest.split("Messages you received")
    messages, actions = rest.split("Your actions so far")
    assert feedback.count("(latest)") == 1 and messages.count("(latest)") >= 1
    assert "(latest) step 3:" in actions and "- step 0:" in actions


def test_each_golden_says_what_produced_it_and_the_default_ones_hold_no_aids_text() -> None:
    """tests/golden/README.md names what produced every golden (the default world or a named aid);
    a default one holds no text of the status_hints aid (Bob's status says only what is in the tray)."""
    listed = {m for m in re.findall(r"^\| `([^`]+)` \|", (GOLDEN / "README.md").read_text(encoding="utf-8"), re.M)}
    assert listed == {p.name for p in GOLDEN.iterdir() if p.name != "README.md"}
    aid = PACK.status(TARGETS, [], frozenset({"status_hints"})).removeprefix(PACK.status(TARGETS, []))
    assert aid.strip().startswith("Not yet in the tray")
    for robot in ROBOTS:
        for step in (1, 5):
            text = (GOLDEN / f"{robot}_step{step}.txt").read_text(encoding="utf-8")
            assert "Not yet in the tray" not in text and "Every listed object is in the tray" not in text, robot


def _sections(text: str, heads: list[str]) -> list[str]:
    """The text under each heading, in the order given; fails if a heading is missing or out of order."""
    at = [text.index(h) for h in heads]
    assert at == sorted(at), f"sections out of order: {heads}"
    return [text[a:b] for a, b in zip(at, at[1:] + [len(text)])]


@pytest.mark.parametrize("robot", ROBOTS)
def test_the_system_prompt_carries_the_appendix_in_its_order(robot: str) -> None:
    system = (GOLDEN / f"{robot}_step1.txt").read_text(encoding="utf-8").split("# Scene graph")[0]
    heads = [
        "You are",
        "## Background",
        "## Profile",
        "## Constraints",
        "## Skills",
        "## Response format",
        "Think step by step.",
    ]
    role, background, profile, constraints, skills, fmt, _ = _sections(system, heads)
    low = {
        k: v.lower()
        for k, v in {"role": role, "background": background, "profile": profile, "constraints": constraints}.items()
    }
    # role: name and capabilities; the arms' ideal picking distance
    assert f"you are {robot}" in low["role"]
    assert ("navigate" in low["role"]) is (robot != "bob") and ("manipulate" in low["role"]) is (robot != "david")
    assert ("no more than 1 m" in role) is (robot != "david")
    # background: who the teammates are and what they can do, as the appendix tells each robot
    # (Bob and David know only Alice; no skill table)
    assert "cooperating" in background and "communicating" in background
    assert "wait()" not in background and "pick(object)" not in background
    if robot == "alice":
        assert (
            "Bob is a robot arm" in background and "manipulate" in background and "David is a mobile base" in background
        )
    else:
        assert (
            "Alice" in background and "navigate" in background and "Bob" not in background and "David" not in background
        )
        assert ("manipulate" in background) is (robot == "david")
    if robot == "david":
        assert "You do what Alice asks of you" in background
    # profile: an unexplored house whose scene graph shows furniture, not what lies on or in it; the robot's job
    if robot == "bob":
        assert (
            "You stand on table_0" in profile
            and "ask Alice for help" in profile
            and "answer her as soon as you can" in profile
        )
    else:
        assert "unexplored" in profile and "not which objects lie on them or inside them" in profile
    if robot == "alice":
        assert "explore the whole house, find the objects the task needs, pick them up and move them" in profile
    if robot == "david":
        assert "needs no opening" in profile
    # constraints as the appendix gives them
    expected = {
        "alice": [
            "Your first step in the episode: communicate with Bob and ask him whether he needs your help finding objects",
            "placed an object on the table, tell Bob right away",
            "you may give David the objects that still have to be found",
            "cannot go on without another robot, execute wait()",
            "When a pick fails, first navigate to the furniture again at another stand pose id, and only after that adjust your position with move",
        ],
        "bob": [
            "Your first step in the episode: communicate with Alice and tell her what you need, judging from the whole task",
            "Answer a request as soon as it arrives",
            "Do not send the same content again and again",
            "cannot go on without another robot, execute wait()",
        ],
        "david": [
            "Follow Alice's instructions and explore the whole house together with her",
            "Tell Alice what you discover without delay",
        ],
    }[robot]
    for item in expected:
        assert item in constraints, item
    assert len(re.findall(r"^\d\. ", constraints, re.M)) == {"alice": 5, "bob": 3, "david": 2}[robot]
    # skills with signatures, then the Command / Analysis / Reasoning format
    from mhrc.agents.parse import signature

    for skill in SKILLS[robot]:
        assert f"- {signature(skill)}: " in skills
    assert [line.split(":")[0] for line in fmt.splitlines() if re.match(r"\d\. ", line)] == [
        "1. Command",
        "2. Analysis",
        "3. Reasoning",
    ]
    assert "exactly one action per reply" in fmt and "only things that are in your scene graph" in fmt


@pytest.mark.parametrize("robot", ROBOTS)
def test_the_user_prompt_carries_the_appendix_in_its_order(robot: str) -> None:
    user = "# Scene graph" + (GOLDEN / f"{robot}_step5.txt").read_text(encoding="utf-8").split("# Scene graph")[1]
    heads = ["# Scene graph", "# Your status", "# Task"] + (["Latest task progress:"] if robot == "bob" else [])
    heads += ["Feedback on your actions", "Messages you received", "Your actions so far"]
    graph, status, task, *rest = _sections(user, heads)
    # the house's furniture (robots that navigate): position, orientation, state, stand poses, place pose;
    # Bob sees only what is on his table: the tray (with its place pose) and the objects there
    if robot == "bob":
        assert "table_0" not in graph and "drawer_unit" not in graph and "stand poses" not in graph
        assert "- tray: position (-3.40, 0.19, 0.71), yaw 0 deg; place pose (-3.40, 0.19, 0.71)" in graph
    else:
        assert (
            "- drawer_unit: position (-3.00, 3.45, 0.60), yaw 0 deg; " + ("open;" if robot == "alice" else "closed;")
            in graph
        )
        assert "stand poses 0 = (-3.30, -0.85, yaw 90 deg)" in graph and "place pose (-3.30, -0.22, 0.70)" in graph
    # known objects in the appendix's fields: position, nothing about where they lie or who told
    known = {
        "alice": "- soap: position (-3.10, 3.30, 0.45)\n",
        "bob": "- book: position (-2.40, 0.05, 0.71), yaw 90 deg\n",
        "david": "- mug: position (2.60, 2.40, 0.75)\n",
    }[robot]
    assert known in graph
    # status: position, orientation (where the base moves), gripper (where there is one); not the step, not the stand pose
    if robot == "bob":
        assert "Your base is fixed at (-3.75, 0.00, 0.70): you cannot move." in status
    else:
        assert re.search(r"^Position: \(-?[\d.]+, -?[\d.]+\); orientation: yaw -?\d+ deg\.$", status, re.M)
    assert ("Gripper: empty." in status) is (robot != "david")
    assert "step" not in status and "stand pose" not in status
    # each robot's own brief and detail (the appendix's Task section of its role)
    assert task.startswith("# Task\nBrief: ") and "\nDetails: " in task
    first_line = {
        "alice": "Brief: Explore the whole house and hand Bob the objects the task needs.",
        "bob": "Brief: Put the listed objects into the tray.",
        "david": "Brief: Search the whole house for the objects the task needs.",
    }
    assert first_line[robot] in task
    assert "fetch" not in task  # David cannot fetch; nobody is told to
    if robot == "bob":
        assert task.count("phone, book, soap, mug") == 1  # the list once
        assert (
            "ask Alice to move it" in task
            and "ask Alice to search for them and bring them" in task
            and "Nothing that is not on the list goes into the tray" in task
        )
        assert (
            rest[0] == "Latest task progress:\nIn the tray: phone.\n\n"
        )  # the default world's status (no status_hints)
    for section in rest[-3:]:
        assert "(latest) step" in section


@pytest.mark.parametrize("robot", ROBOTS)
async def test_the_default_prompts_hold_none_of_the_aids_text(robot: str) -> None:
    hints = load_hints(robot)
    assert hints.startswith("## Hints\n") and len(hints.splitlines()) >= 5
    for prompt in await play(LLMPolicy(robot, ScriptedClient([])), robot):
        text = prompt.split("Feedback on your actions")[0]  # the histories quote what the (scripted) models wrote
        for phrase in AID_PHRASES + DYNAMIC_HINTS:
            assert phrase not in text, phrase
        for line in hints.splitlines()[1:]:
            assert line.strip("- ").strip() not in text, line


def _without_hints(text: str, hints: str) -> str:
    """An aided prompt with exactly the aid's text taken out."""
    assert text.count(hints) == 1
    text = text.replace(hints + "\n\n", "")
    text = re.sub(r"## Your teammates in this episode and their skills\n(- .*\n)+\n", "", text)
    text = re.sub(r", \d+\.\d\d m from (your arm base|you)", "", text)
    text = re.sub(r"\nArm base: \([^)]*\); reach about \d+\.\d\d m from it\.", "", text)
    text = re.sub(r"You are \w+, a [\w ]+\. Current step: \d+\.\n", "", text)
    text = re.sub(r"; (at stand pose \d+ of \w+|not at any stand pose)\.", ".", text)
    text = text.replace("; no stand pose (not a navigation target)", "").replace(
        "closed (open it to see inside)", "closed"
    )
    text = re.sub(
        r"^(- \w+): .*?, at (\([^)]*\))(, yaw -?\d+ deg)?$", r"\1: position \2\3", text, flags=re.M
    )  # where it lies, who told
    return re.sub(r"^(- \w+) \([^)]*\):", r"\1:", text, flags=re.M)


@pytest.mark.parametrize("robot", ROBOTS)
async def test_prompt_hints_adds_exactly_its_text(robot: str) -> None:
    plain = await play(LLMPolicy(robot, ScriptedClient([])), robot)
    aided = await play(LLMPolicy(robot, ScriptedClient([]), prompt_hints=True), robot)
    hints = load_hints(robot)
    for p, a in zip(plain, aided):
        assert _without_hints(a, hints) == p
        constraints_end, skills_at = a.index("## Constraints"), a.index("## Skills")
        assert constraints_end < a.index(hints) < skills_at
    # and it does add each kind of text it stands for
    last = aided[-1]
    assert (
        ("(tray on table_0)" if robot == "bob" else "(drawer unit)") in last
        and ("m from your arm base" in last) is (robot != "david")
        and ("reach about" in last) is (robot != "david")
    )
    assert ("not a navigation target" in last) is (robot != "bob")
    assert ("m from you\n" in last) is (robot == "david")


def test_the_pick_window_and_message_templates_live_in_the_aid() -> None:
    alice, bob, david = (load_hints(r) for r in ROBOTS)
    assert (
        "0.20 m ahead" in alice
        and "0.30 to 0.58 m" in alice
        and 'to Bob: "Bob, I placed soap on table_0 for you."' in alice
    )
    assert "Right at the start, hand the open surfaces" in alice and "Do not repeat work" in alice
    assert "compare it with your reach" in bob and "please bring these to table_0 within my reach" in bob
    assert (
        "Until Alice asks" in david and "Do not visit a surface twice" in david and "On sofa I found nothing." in david
    )


def test_skill_signatures_in_the_prompts_are_what_the_parser_accepts() -> None:
    from mhrc.agents.parse import parse_command, signature

    for robot, skills in SKILLS.items():
        text = (GOLDEN / f"{robot}_step1.txt").read_text(encoding="utf-8")
        for skill in skills:
            assert f"- {signature(skill)}:" in text
            call = signature(skill).replace("stand_pose_id", "0").replace("dx", "0.1").replace("dy", "0.2")
            # the paper's own order (Command first) and its example's (Command last) both parse
            assert (
                parse_command(
                    f"Command: {call}\nAnalysis: I could also navigate(sofa, 0).\nReasoning: it matters."
                ).skill
                == skill
            )
            assert parse_command(f"Analysis: ...\nReasoning: ...\nCommand: {call}").skill == skill


def test_alice_at_step_5_sees_only_what_she_was_told_or_saw() -> None:
    text = (GOLDEN / "alice_step5.txt").read_text(encoding="utf-8")
    assert (
        "soap: position (-3.10, 3.30, 0.45)" in text
        and "phone" not in text.split("# Scene graph")[1].split("# Your status")[0]
    )
    # the unparseable reply at step 2 came back as feedback saying only that (Table III has no format advice)
    assert (
        "- step 2: Your command could not be read, so you waited.\n" in text and "Command: skill(arguments)" not in text
    )
    assert "drawer_unit: position (-3.00, 3.45, 0.60), yaw 0 deg; open" in text
    assert "(latest) step 3: from David: On table_1 I found: mug." in text


def test_bob_sees_progress_and_no_stand_poses() -> None:
    text = (GOLDEN / "bob_step5.txt").read_text(encoding="utf-8")
    assert "book: position (-2.40, 0.05, 0.71), yaw 90 deg\n" in text
    assert (
        "(within your reach)" not in text and "(out of your reach)" not in text
    )  # reach labels are an aid, not the paper's prompt
    assert "phone: position (-3.40, 0.19, 0.72)" in text and "Latest task progress:\nIn the tray: phone." in text
    assert "stand poses" not in text and "Gripper: empty." in text
    assert "The list: phone, book, soap, mug." in text


# --------------------------------------------------------------------------- your own templates

SYSTEM_OK = "You are $robot. Skills:\n$skills"
USER_OK = "$scene_graph\n$status\n$task\n$progress\n$feedback\n$messages\n$actions\nCommand?"


def test_custom_templates_are_checked_when_loaded(tmp_path: Path) -> None:
    (tmp_path / "bob_system.txt").write_text("You are $robot. Skills:\n$skills\n$colour", encoding="utf-8")
    (tmp_path / "bob_user.txt").write_text(USER_OK, encoding="utf-8")
    with pytest.raises(TemplateError, match=r"--prompts: .*bob_system.txt: unknown placeholder\(s\) \$colour"):
        load_template("bob", "system", tmp_path)
    # a part the directory has no file for (neither alice_user.txt nor mobile_manipulator_user.txt): the built-in one
    assert template_source("alice", "user", tmp_path) == template_source("alice", "user")
    assert (template_source("alice", "user", tmp_path) or ("", ""))[1] == "mhrc.prompts/mobile_manipulator_user.txt"
    (tmp_path / "bob_user.txt").write_text(
        "$scene_graph\n$status\n$task\n$feedback\n$messages\nCommand?", encoding="utf-8"
    )
    with pytest.raises(TemplateError, match=r"bob_user.txt: required placeholder\(s\) \$actions, \$progress missing"):
        load_template("bob", "user", tmp_path)
    (tmp_path / "bob_system.txt").write_text("You are $robot.", encoding="utf-8")
    with pytest.raises(TemplateError, match=r"bob_system.txt: required placeholder\(s\) \$skills missing"):
        load_template("bob", "system", tmp_path)

    (tmp_path / "bob_system.txt").write_text(SYSTEM_OK, encoding="utf-8")
    (tmp_path / "bob_user.txt").write_text(USER_OK, encoding="utf-8")
    policy = LLMPolicy("bob", ScriptedClient([]), prompts_dir=tmp_path)
    system, user = (m["content"] for m in policy.render(observe("bob")))
    assert system.startswith("You are Bob. Skills:\n- pick(object):")
    assert user.startswith("Furniture:\n- tray: ") and user.endswith(
        "Your actions so far (oldest first):\n- (none yet)\nCommand?\n"
    )
    # a template without $hints gets the aid's text at its end, and without $teammates the aid's
    # table of the teammates' skills after it; a hints file of your own replaces the built-in one
    team = "\n\n## Your teammates in this episode and their skills\n- Alice: navigate(furniture, stand_pose_id), move(dx, dy), open(furniture)"
    aided = LLMPolicy("bob", ScriptedClient([]), prompts_dir=tmp_path, prompt_hints=True).render(observe("bob"))[0][
        "content"
    ]
    assert load_hints("bob") + team in aided and aided.endswith(
        "- David: navigate(furniture, stand_pose_id), communicate(content, robot), wait()\n"
    )
    (tmp_path / "bob_hints.txt").write_text("## Hints\n- Be quick.\n", encoding="utf-8")
    aided = LLMPolicy("bob", ScriptedClient([]), prompts_dir=tmp_path, prompt_hints=True).render(observe("bob"))[0][
        "content"
    ]
    assert (
        "Skills:\n- pick(object): pick up that object\n- place(object, location): put the object in your gripper at that location\n"
        "- communicate(content, robot): send content to that robot; when objects are missing and you need help, sum up how things stand in it\n"
        "- wait(): do nothing this step\n\n## Hints\n- Be quick." + team
    ) in aided and load_hints("bob") not in aided


def _mhrc(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "mhrc", *args], cwd=cwd, capture_output=True, text=True, timeout=180)


def _thought_line(robot: str, tick: int, prompt: str, reply: str) -> str:
    t = Thought(robot=robot, tick=tick, policy="llm:m", prompt=prompt, reply=reply, action="wait()")
    return (
        json.dumps(
            {
                "t": 0.1 * tick,
                "key": f"mhrc/run-1/agent/{robot}/thought",
                "kind": "put",
                "msg": t.model_dump(mode="json"),
            }
        )
        + "\n"
    )


def test_up_refuses_prompts_missing_a_placeholder_before_anything_starts(tmp_path: Path) -> None:
    prompts, work = tmp_path / "prompts", tmp_path / "work"
    prompts.mkdir()
    work.mkdir()
    trace = tmp_path / "trace.jsonl"
    trace.write_text(_thought_line("alice", 0, "x", "Command: wait()"), encoding="utf-8")
    for robot in ROBOTS:
        (prompts / f"{robot}_system.txt").write_text(SYSTEM_OK, encoding="utf-8")
        (prompts / f"{robot}_user.txt").write_text(
            USER_OK.replace("$progress\n", "") if robot != "bob" else USER_OK, encoding="utf-8"
        )
    (prompts / "alice_user.txt").write_text("$scene_graph\n$status\n$task\n$feedback\n$actions\n", encoding="utf-8")
    out = _mhrc("up", "--insecure", "-q", "--llm", f"alice=replay:{trace}", "--prompts", str(prompts), cwd=work)
    errors = [line for line in out.stderr.splitlines() if line.startswith("Error:")]
    assert out.returncode == 2 and "Traceback" not in out.stderr and len(errors) == 1, out.stderr[-3000:]
    assert "--prompts" in errors[0] and "alice_user.txt" in errors[0] and "$messages" in errors[0], errors[0]
    assert list(work.iterdir()) == []  # nothing left behind

    # without david_system.txt, David's kind's file in the directory is his (and it is checked as well)
    (prompts / "david_system.txt").unlink()
    (prompts / "mobile_base_system.txt").write_text(SYSTEM_OK + "\n$colour", encoding="utf-8")
    out = _mhrc("up", "--insecure", "-q", "--llm", f"david=replay:{trace}", "--prompts", str(prompts), cwd=work)
    errors = [line for line in out.stderr.splitlines() if line.startswith("Error:")]
    assert (
        out.returncode == 2
        and len(errors) == 1
        and "--prompts" in errors[0]
        and "mobile_base_system.txt: unknown placeholder(s) $colour" in errors[0]
    ), out.stderr[-3000:]
    assert list(work.iterdir()) == []


# --------------------------------------------------------------------------- replays of older prompts

OLD = GOLDEN / "recorded_before_issue21_alice_step1.txt"  # Alice's first prompt as mhrc wrote it before issue 21


def test_a_trace_recorded_with_the_old_prompts_is_refused_with_the_reason(tmp_path: Path) -> None:
    trace = tmp_path / "trace.jsonl"
    trace.write_text(_thought_line("alice", 0, OLD.read_text(encoding="utf-8"), "Command: wait()"), encoding="utf-8")
    client = ReplayClient(trace, "alice")
    with pytest.raises(
        ReplayMismatch,
        match=r"recorded with other prompts than the ones alice is given now: .*lacks 'You are Alice, a smart robot .*/mobile_manipulator_system.txt",
    ):
        LLMPolicy("alice", client)


@pytest.mark.parametrize("options", [{}, {"prompt_hints": True}, {"structured": True}, {"prompt_cap_chars": 3000}])
async def test_a_trace_recorded_with_the_current_prompts_replays(tmp_path: Path, options: dict[str, Any]) -> None:
    recorded = await LLMPolicy("alice", ScriptedClient(["Command: wait()"]), **options).decide(observe("alice"))
    trace = tmp_path / "trace.jsonl"
    trace.write_text(_thought_line("alice", 0, recorded.prompt or "", "Command: navigate(sofa, 1)"), encoding="utf-8")
    d = await LLMPolicy("alice", ReplayClient(trace, "alice"), **options).decide(observe("alice"))
    assert d.prompt == recorded.prompt and d.reply == "Command: navigate(sofa, 1)"


@pytest.mark.slow
def test_up_refuses_to_replay_a_trace_recorded_with_the_old_prompts(tmp_path: Path) -> None:
    trace = tmp_path / "old.jsonl"
    trace.write_text(_thought_line("alice", 0, OLD.read_text(encoding="utf-8"), "Command: wait()"), encoding="utf-8")
    out = _mhrc(
        "up", "--insecure", "-q", "--llm", f"alice=replay:{trace}", "--trace", str(tmp_path / "new.jsonl"), cwd=tmp_path
    )
    lines = [line for line in out.stderr.splitlines() if line.startswith("mhrc up:")]
    assert out.returncode == 2 and "Traceback" not in out.stderr and len(lines) == 1, out.stderr[-3000:]
    assert "recorded with other prompts" in lines[0] and "record the episode again" in lines[0], lines[0]
