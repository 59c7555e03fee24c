"""LLMPolicy with a scripted model on hand-built observations: parsing, feedback of format and
model errors, memory and its cap, the ablation switches, and replay of a recorded trace."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from mhrc.agents.llm import LLMError, ScriptedClient
from mhrc.agents.llm_policy import LLMPolicy, LLMUnreachable
from mhrc.agents.memory import Memory
from mhrc.agents.policy import Decision
from mhrc.agents.replay import ReplayClient, ReplayMismatch, replay_clients
from mhrc.core.protocol import (
    Action,
    ActionResult,
    Communicate,
    FurnitureView,
    Navigate,
    ObjectView,
    Observation,
    OutcomeCode,
    Pick,
    Pose2D,
    RobotMessage,
    RobotStatus,
    SkillOutcome,
    Thought,
    Wait,
)
from mhrc.core.protocol.thoughts import ReplyFailure

ALICE_SKILLS = ["navigate", "move", "open", "pick", "place", "communicate", "wait"]


def obs(
    tick: int = 0, *, messages: list[tuple[str, str, int]] = (), objects: list[ObjectView] = (), robot: str = "alice"
) -> Observation:  # type: ignore[assignment]
    """Alice (or Bob) in a small house: table_0 with the tray, a drawer unit, table_1."""
    arm = robot == "bob"
    return Observation(
        robot=robot,
        tick=tick,
        status=RobotStatus(
            name=robot,
            kind="tabletop manipulator" if arm else "mobile manipulator",
            skills=["pick", "place", "communicate", "wait"] if arm else ALICE_SKILLS,
            base=None if arm else Pose2D(x=-1.5, y=1.2),
            arm_base=(-3.75, 0.0, 0.7) if arm else (-1.3, 1.2, 0.65),
            reach=0.62 if arm else 0.72,
        ),
        furniture=[
            FurnitureView(
                name="table_0",
                kind="table",
                position=(-3.0, 0.0, 0.7),
                stand_poses=[Pose2D(x=-3.3, y=-0.85, yaw=1.5708)],
                place_pose=(-3.3, -0.22, 0.7),
            ),
            FurnitureView(
                name="drawer_unit",
                kind="drawer unit",
                position=(-3.0, 3.45, 0.6),
                openable=True,
                is_open=False,
                stand_poses=[Pose2D(x=-3.0, y=2.12)],
            ),
            FurnitureView(
                name="table_1",
                kind="table",
                position=(2.5, 2.5, 0.7),
                stand_poses=[Pose2D(x=2.2, y=1.7), Pose2D(x=2.8, y=1.7)],
                place_pose=(2.5, 2.45, 0.7),
            ),
            FurnitureView(
                name="tray", kind="tray on table_0", position=(-3.4, 0.19, 0.71), place_pose=(-3.4, 0.19, 0.71)
            ),
        ],
        objects=list(objects),
        task_brief="Pack the listed objects into the tray on table_0.",
        task_detail="Objects to pack: apple, soap." if arm else "Help Bob pack the listed objects.",
        targets=["apple", "soap"] if arm else [],
        task_status="In the tray: nothing yet." if arm else None,
        teammates={"bob": ["pick", "place", "communicate", "wait"], "david": ["navigate", "communicate", "wait"]}
        if not arm
        else {"alice": ALICE_SKILLS, "david": ["navigate", "communicate", "wait"]},
        new_messages=[RobotMessage(sender=s, to=robot, content=c, tick=t) for s, c, t in messages],
    )


def result(tick: int, action: Action, outcome: SkillOutcome, robot: str = "alice") -> ActionResult:
    return ActionResult(
        goal_id=f"g{tick}",
        robot=robot,
        tick=tick,
        action=action,
        outcome=outcome,
        observation=obs(tick + 1, robot=robot),
    )


def user(decision: Decision) -> str:
    assert decision.prompt is not None
    return decision.prompt.split("# Scene graph", 1)[1]


async def test_a_parsed_reply_becomes_the_action_and_the_decision_carries_everything() -> None:
    client = ScriptedClient(
        ["Analysis: the drawer is closed.\nReasoning: look inside.\nCommand: navigate(drawer_unit, 0)"]
    )
    policy = LLMPolicy("alice", client, temperature=0.3)
    d = await policy.decide(obs())
    assert d.action == Navigate(target="drawer_unit", stand_pose=0) and d.parse_error is None and d.failure is None
    assert policy.name == "llm:scripted"
    system, user_msg = client.prompts[0]
    assert (system["role"], user_msg["role"]) == ("system", "user")
    assert d.prompt == system["content"] + "\n\n" + user_msg["content"]
    assert d.reply is not None and d.reply.startswith("Analysis:")
    assert d.prompt_tokens == len(d.prompt) // 4 and d.completion_tokens == len(d.reply) // 4 and d.latency >= 0


async def test_an_unparseable_reply_makes_the_robot_wait_and_comes_back_as_feedback() -> None:
    for advice in (False, True):
        policy = LLMPolicy(
            "alice",
            ScriptedClient(["I would rather pick(apple) or place(apple, tray)", "Command: wait()"]),
            feedback_advice=advice,
        )
        d = await policy.decide(obs(0))
        assert (
            d.action == Wait() and d.parse_error is not None and "several commands" in d.parse_error
        )  # the trace keeps the reason
        assert d.failure is ReplyFailure.UNREADABLE
        assert d.reply == "I would rather pick(apple) or place(apple, tray)"
        policy.record(result(0, Wait(), SkillOutcome.ok("You waited.")))
        nxt = await policy.decide(obs(1))
        feedback = user(nxt).split("Feedback on your actions")[1].split("Messages you received")[0]
        if advice:  # the feedback_advice aid: the reason and how to answer
            assert (
                "- (latest) step 0: Your reply could not be executed (several commands found (pick, place)" in feedback
            )
            assert "Give your command on one line: Command: skill(arguments)." in feedback
        else:  # the paper's: only that the command could not be read (Table III has no format advice)
            assert feedback == " (oldest first):\n- (latest) step 0: Your command could not be read, so you waited.\n\n"
        assert "You waited." not in feedback  # the reason replaces the wait's own feedback
        assert "(latest) step 0: wait()" in user(nxt).split("Your actions so far")[1]


async def test_a_model_that_goes_down_later_is_a_wait_with_the_error_as_feedback() -> None:
    down = LLMError("m at http://127.0.0.1:9/v1 failed after 5 attempts: ConnectError")
    policy = LLMPolicy("alice", ScriptedClient(["Command: wait()", down, "Command: pick(apple)"]))
    await policy.decide(obs(0))
    d = await policy.decide(obs(1))
    assert (
        d.action == Wait()
        and d.reply is None
        and d.parse_error == "llm error: m at http://127.0.0.1:9/v1 failed after 5 attempts: ConnectError"
        and d.failure is ReplyFailure.MODEL_UNREACHABLE  # the code is set where the call failed
    )
    # no result came back for that step (e.g. the agent resynchronized): the reason is fed back anyway
    nxt = await policy.decide(obs(2))
    assert nxt.action == Pick(obj="apple")
    assert (
        "(latest) step 1: Your planner could not reach its model (m at http://127.0.0.1:9/v1 failed after 5 attempts"
        in user(nxt)
    )


async def test_a_model_down_for_the_whole_first_step_stops_the_robot_but_a_slow_one_does_not() -> None:
    down = LLMError("m at http://127.0.0.1:9/v1 failed after 5 attempts: ConnectError")
    with pytest.raises(LLMUnreachable, match="alice's model never answered during its first step: .*ConnectError"):
        await LLMPolicy("alice", ScriptedClient([down])).decide(obs(0))
    slow = LLMPolicy("alice", ScriptedClient(["Command: wait()"], latency=5.0), step_deadline=0.05)
    d = await slow.decide(obs(0))
    assert d.action == Wait() and d.parse_error == "llm error: no answer within the step deadline of 0.05 s"
    assert d.failure is ReplyFailure.MODEL_UNREACHABLE


async def test_results_messages_and_waits_go_into_memory() -> None:
    policy = LLMPolicy("alice", ScriptedClient(["Command: wait()"] * 3))
    await policy.decide(obs(0))
    policy.record(result(0, Wait(), SkillOutcome.ok("You waited.")))
    d = await policy.decide(
        obs(
            1,
            messages=[
                ("bob", "Alice, please bring these to table_0 within my reach: apple.", 0),
                ("david", "On table_1 I found: apple.", 0),
            ],
        )
    )
    policy.record(
        result(
            1,
            Pick(obj="apple"),
            SkillOutcome.fail(
                OutcomeCode.TOO_FAR,
                "The end effector cannot reach apple. Moving your base by "
                "dx=0.10, dy=0.25 would bring it within a good grasping distance.",
            ),
        )
    )
    d = await policy.decide(obs(2))
    text = user(d)
    assert (
        "- (latest) step 0: from Bob: Alice, please bring these" in text
        and "- (latest) step 0: from David: On table_1" in text
    )
    assert (
        "- (latest) step 1: pick(apple) FAILED: The end effector cannot reach apple. Moving your base by dx=0.10, dy=0.25"
        in text
    )
    assert "You waited." not in text  # a plain wait teaches nothing; it stays in the action history
    assert "- step 0: wait()\n- (latest) step 1: pick(apple)" in text
    assert [e.tag for e in policy.memory.feedback] == ["failed"] and [e.tag for e in policy.memory.actions] == [
        "wait",
        "pick",
    ]


async def test_bob_gets_only_the_outcome_feedback_and_sees_progress_in_his_observation() -> None:
    policy = LLMPolicy("bob", ScriptedClient(["Command: pick(apple)", "Command: wait()"]))
    await policy.decide(obs(0, robot="bob"))
    policy.record(result(0, Pick(obj="apple"), SkillOutcome.ok("You picked up apple."), robot="bob"))
    d = await policy.decide(obs(1, robot="bob"))
    first_step = "This is the first step of the task: do nothing else now; communicate with Alice and share what you know so far."
    assert [e.text for e in policy.memory.feedback] == [first_step, "pick(apple) succeeded: You picked up apple."]
    assert "Latest task progress:\nIn the tray: nothing yet." in user(d) and "Objects to pack: apple, soap." in user(d)


FEEDBACK = [
    ("navigate(table_1, 0)", True, "You reached stand pose 0 of table_1. On table_1: apple, book."),
    (
        "pick(apple)",
        False,
        "The end effector cannot reach apple: it is 0.21 m away from the closest pose your arm can get to. Moving your base by "
        "dx=0.10, dy=0.25 would bring it within a good grasping distance.",
    ),
    ("place(apple, table_0)", True, "You placed apple on table_0."),
    ("open(drawer_unit)", True, "You opened drawer_unit. Inside: soap, phone."),
]


def long_memory(steps: int = 50) -> Memory:
    m = Memory()
    for step in range(steps):
        call, ok, text = FEEDBACK[step % len(FEEDBACK)]
        m.add("actions", step, call, tag=call.split("(")[0])
        m.add(
            "feedback", step, f"{call} {'succeeded' if ok else 'FAILED'}: {text}", tag="succeeded" if ok else "failed"
        )
        if step % 5 == 0:
            m.add(
                "messages",
                step,
                f"from Bob: Alice, please bring these to table_0 within my reach: soap{step}.",
                tag="from bob",
            )
    return m


@pytest.mark.parametrize("cap", [7000, 9000, 11000])  # each below the whole 50-step prompt (about 12,000 characters)
def test_a_50_step_memory_stays_under_the_cap_with_the_latest_entries_whole(cap: int) -> None:
    capped, uncapped = (
        LLMPolicy("alice", ScriptedClient([]), prompt_cap_chars=cap),
        LLMPolicy("alice", ScriptedClient([]), prompt_cap_chars=None),
    )
    capped.memory = uncapped.memory = long_memory()
    small = "\n\n".join(m["content"] for m in capped.render(obs(50)))
    big = "\n\n".join(m["content"] for m in uncapped.render(obs(50)))
    assert len(small) <= cap < len(big)
    for latest in (
        "- (latest) step 49: pick(apple) FAILED: " + FEEDBACK[1][2],
        "- (latest) step 45: from Bob",
        "- (latest) step 49: pick(apple)\n",
    ):
        assert latest in small
    assert "- step 0: navigate(table_1, 0) succeeded" in big and "- step 0: navigate(table_1, 0) succeeded" not in small
    summary = next(line for line in small.splitlines() if "left out" in line)
    assert (
        summary.startswith("- (")
        and "earlier entries, steps 0-" in summary
        and "succeeded" in summary
        and "failed" in summary
    )
    # what is kept is a contiguous run of the newest entries, oldest first
    steps = [
        int(line.split("step ")[1].split(":")[0])
        for line in small.split("Your actions so far")[1].splitlines()
        if line.startswith("- step")
    ]
    assert steps == list(range(steps[0], 49)) and steps[0] > 0


def test_older_messages_outlast_older_feedback_under_a_tight_cap() -> None:
    m = long_memory()
    sections = m.render(budget=2500)
    assert "- step 0: from Bob" in sections["messages"]  # Bob's first request survives
    assert "left out" in sections["feedback"] and "left out" in sections["actions"]
    assert sum(len(s) for s in sections.values()) <= 2500
    # a budget too small for anything older keeps the latest entries all the same
    bare = m.render(budget=0)
    assert all(s.count("(latest)") == 1 for s in bare.values()) and all("left out" in s for s in bare.values())


async def test_ablations_change_the_prompt_as_documented() -> None:
    async def prompt_after_two_steps(**switches: Any) -> str:
        policy = LLMPolicy("alice", ScriptedClient([]), **switches)
        await policy.decide(
            obs(0, messages=[("bob", "Alice, please bring these to table_0 within my reach: soap.", 0)])
        )
        policy.record(
            result(
                0,
                Navigate(target="drawer_unit", stand_pose=0),
                SkillOutcome.ok("You reached stand pose 0 of drawer_unit."),
            )
        )
        await policy.decide(obs(1))
        policy.record(
            result(
                1,
                Pick(obj="soap"),
                SkillOutcome.fail(
                    OutcomeCode.NOT_REACHABLE_CONTAINER, "soap is inside drawer_unit, which is closed: open it first."
                ),
            )
        )
        d = await policy.decide(obs(2, messages=[("david", "On table_1 I found nothing.", 1)]))
        return d.prompt or ""

    full = await prompt_after_two_steps()
    for section in (
        "Feedback on your actions",
        "Messages you received",
        "Your actions so far",
        "You reached stand pose 0",
        "from Bob: Alice, please",
    ):
        assert section in full

    bob = LLMPolicy("bob", ScriptedClient([]), feedback=False)
    bob_prompt = (await bob.decide(obs(0, robot="bob"))).prompt or ""
    assert (
        "task progress" not in bob_prompt and "In the tray" not in bob_prompt
    )  # Table III counts the task status as feedback
    assert "first step of the task" not in bob_prompt

    no_feedback = await prompt_after_two_steps(feedback=False)
    assert (
        "Feedback on your actions" not in no_feedback
        and "FAILED" not in no_feedback
        and "You reached" not in no_feedback
    )
    assert (
        "from Bob: Alice, please" in no_feedback
        and "- step 0: navigate(drawer_unit, 0)\n- (latest) step 1: pick(soap)" in no_feedback
    )

    no_history = await prompt_after_two_steps(history=False)
    assert (
        "Your actions so far" not in no_history
        and "navigate(drawer_unit, 0)" not in no_history.split("# Scene graph")[1]
    )
    assert "from Bob" not in no_history  # delivered two steps ago: history
    assert "- (latest) from David: On table_1 I found nothing." in no_history  # delivered with this observation
    assert "- (latest) step 1: pick(soap) FAILED: soap is inside drawer_unit" in no_history  # the last action's result
    assert "You reached stand pose 0" not in no_history

    neither = await prompt_after_two_steps(feedback=False, history=False)
    assert (
        "FAILED" not in neither
        and "Feedback on your actions" not in neither
        and "On table_1 I found nothing." in neither
    )

    solo = await prompt_after_two_steps(teammates_absent=("david",))
    background = solo.split("## Background")[1].split("## Profile")[0]
    assert background.rstrip().endswith(
        "David is not part of the team in this episode."
    )  # the fact, no advice the paper lacks
    assert "take over" not in solo
    aided = await prompt_after_two_steps(teammates_absent=("david",), prompt_hints=True)
    assert "take over their part yourself" in aided
    team = aided.split("## Your teammates in this episode and their skills")[1].split("## Skills")[0]
    assert "- Bob: pick(object)" in team and "David" not in team


async def _record_episode(tmp_path: Path, replies: list[str | BaseException]) -> tuple[Path, list[Decision]]:
    """Play four steps for Alice with scripted replies and write her thoughts as the recorder would."""
    policy = LLMPolicy("alice", ScriptedClient(replies))
    decisions, lines = [], []
    for tick in range(4):
        d = await policy.decide(
            obs(
                tick,
                messages=[("bob", "Alice, please bring these to table_0 within my reach: soap.", 0)]
                if tick == 1
                else [],
            )
        )
        decisions.append(d)
        thought = Thought(
            robot="alice",
            tick=tick,
            policy=policy.name,
            prompt=d.prompt,
            reply=d.reply,
            action=d.action.call(),
            parse_error=d.parse_error,
            failure=d.failure,
            prompt_tokens=d.prompt_tokens,
            completion_tokens=d.completion_tokens,
            latency=d.latency,
        )
        lines.append(
            {
                "t": tick * 0.1,
                "key": "mhrc/run-1/agent/alice/thought",
                "kind": "put",
                "msg": thought.model_dump(mode="json"),
            }
        )
        thought = Thought(robot="bob", tick=tick, policy="heuristic", action="wait()").model_dump(mode="json")
        lines.append({"t": tick * 0.1 + 0.01, "key": "mhrc/run-1/agent/bob/thought", "kind": "put", "msg": thought})
        policy.record(
            result(
                tick,
                d.action,
                SkillOutcome.ok("Done.")
                if d.action.skill != "pick"
                else SkillOutcome.fail(OutcomeCode.TOO_FAR, "Too far."),
            )
        )
    path = tmp_path / "trace.jsonl"
    path.write_text("".join(json.dumps(line) + "\n" for line in lines), encoding="utf-8")
    return path, decisions


async def test_replay_reproduces_the_recorded_replies_and_stops_on_a_changed_prompt(tmp_path: Path) -> None:
    replies: list[str | BaseException] = [
        "Command: navigate(drawer_unit, 0)",
        "no idea",
        LLMError("model down"),
        "Command: pick(soap)",
    ]
    trace, recorded = await _record_episode(tmp_path, replies)

    clients = replay_clients(trace)
    assert list(clients) == ["alice"]  # Bob's heuristic thoughts carry no prompts
    policy = LLMPolicy("alice", clients["alice"])
    for tick, want in enumerate(recorded):
        d = await policy.decide(
            obs(
                tick,
                messages=[("bob", "Alice, please bring these to table_0 within my reach: soap.", 0)]
                if tick == 1
                else [],
            )
        )
        assert (d.action, d.prompt, d.reply, d.parse_error, d.prompt_tokens) == (
            want.action,
            want.prompt,
            want.reply,
            want.parse_error,
            want.prompt_tokens,
        )
        policy.record(
            result(
                tick,
                d.action,
                SkillOutcome.ok("Done.")
                if d.action.skill != "pick"
                else SkillOutcome.fail(OutcomeCode.TOO_FAR, "Too far."),
            )
        )
    assert clients["alice"].remaining == 0
    with pytest.raises(ReplayMismatch, match="asked for call 5"):
        await policy.decide(obs(4))

    # Bob's message lost on the way: the second prompt differs
    drifted = LLMPolicy("alice", ReplayClient(trace, "alice"))
    await drifted.decide(obs(0))
    drifted.record(result(0, Navigate(target="drawer_unit", stand_pose=0), SkillOutcome.ok("Done.")))
    with pytest.raises(
        ReplayMismatch,
        match=r"alice's prompt at call 2 \(tick 1\) differs .*: line \d+: recorded '- \(latest\) step 0: from Bob",
    ):
        await drifted.decide(obs(1))
    # another ablation asks something else from the first call on
    with pytest.raises(ReplayMismatch, match=r"call 1 \(tick 0\) differs"):
        await LLMPolicy("alice", ReplayClient(trace, "alice"), history=False).decide(obs(0))

    with pytest.raises(ReplayMismatch, match="no LLM prompts for bob"):
        ReplayClient(trace, "bob")


@pytest.mark.parametrize(
    "reply, action",
    [
        ("Command: navigate(furniture=table_1, stand_pose_id=1)", Navigate(target="table_1", stand_pose=1)),
        (
            'Command: communicate(content="Bob, I placed soap (the bar) on table_0.", robot=bob)',
            Communicate(content="Bob, I placed soap (the bar) on table_0.", to="bob"),
        ),
        (
            "Reasoning: the command I pick below is safe.\nCommand: pick(apple) -- this command grasps it",
            Pick(obj="apple"),
        ),
    ],
)
async def test_keyword_arguments_and_loose_mentions_of_command_still_parse(reply: str, action: Action) -> None:
    d = await LLMPolicy("alice", ScriptedClient([reply])).decide(obs())
    assert d.action == action and d.parse_error is None
