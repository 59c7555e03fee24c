"""Prompt size (characters, estimated tokens = chars/4) per role: at steps 1, 25 and 50 of a
synthetic long episode, with and without the prompt cap; and at steps 1 and 25 of a real
heuristic-driven episode, with the paper's prompts and with the prompt_hints aid.

The synthetic observations are hand-built in the paper's example house (15 pieces of
furniture, 6 target objects found along the way); every step goes through LLMPolicy.decide and
record with a scripted model, so the memory fills the way a real episode fills it: one action
and one feedback entry per step, a message every few steps.

The heuristic episode runs the heuristic team on the simulator (as tests/test_table3.py does:
actions in robot order, messages arriving with the next observation); beside each robot an
LLMPolicy renders the prompt it would be given for the same observation and history.

    python bench/bench_prompt_size.py [--cap 12000] [--out bench/results/prompt_size.json]
"""

from __future__ import annotations

import argparse
import asyncio
from pathlib import Path
from typing import Any

from report import emit

from mhrc.agents.llm import ScriptedClient, estimate_tokens
from mhrc.agents.llm_policy import SMALL_CONTEXT_CAP, LLMPolicy
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
)
from mhrc.world.briefs import Briefing, Role, brief, detail
from mhrc.world.tasks import get_task

STEPS = (1, 25, 50)
HEURISTIC_STEPS = (1, 25)
HEURISTIC_EPISODE = {"task": "pack_objects", "scene": "kitchen", "seed": 0, "n_objects": 6}
SKILLS = {
    "alice": ["navigate", "move", "open", "pick", "place", "communicate", "wait"],
    "bob": ["pick", "place", "communicate", "wait"],
    "david": ["navigate", "communicate", "wait"],
}
# name, kind, x, y, openable, surface
HOUSE = [
    ("table_0", "table", -3.0, 0.0, False, True),
    ("drawer_unit", "drawer unit", -3.0, 3.45, True, False),
    ("dishwasher", "dishwasher", -1.2, 3.5, True, False),
    ("microwave", "microwave", 0.2, 3.6, True, False),
    ("fridge", "fridge", 1.4, 3.5, True, False),
    ("table_1", "table", 2.5, 2.5, False, True),
    ("table_2", "table", 2.5, -2.8, False, True),
    ("table_3", "table", 6.0, 2.0, False, True),
    ("table_4", "table", 6.5, -2.5, False, True),
    ("cabinet_0", "cabinet", -4.5, -3.0, True, False),
    ("cabinet_1", "cabinet", 4.5, 3.6, True, False),
    ("sofa", "sofa", 4.3, -1.6, False, True),
    ("bookcase", "bookcase", 8.0, 0.0, False, True),
    ("tub", "tub", 8.5, 3.0, False, True),
    ("washbasin", "washbasin", 8.5, -3.2, False, True),
]
TARGETS = ["apple", "fork", "soap", "toy_duck", "phone", "book"]
ROLES: dict[str, Role] = {"alice": "fetcher", "bob": "finisher", "david": "scout"}
PACK, CREW = (
    get_task("pack_objects"),
    Briefing(finisher="Bob", fetcher="Alice", table="table_0"),
)  # as the world words each role's task
WHERE = {
    "apple": "fridge",
    "fork": "drawer_unit",
    "soap": "washbasin",
    "toy_duck": "tub",
    "phone": "table_0",
    "book": "table_0",
}

# (reply, succeeded, feedback): what each role's model says and the world answers, cycled
SCRIPT: dict[str, list[tuple[str, bool, str]]] = {
    "alice": [
        (
            "Command: navigate(fridge, 0)",
            True,
            "You reached stand pose 0 of fridge. fridge is closed: open it to see what is inside.",
        ),
        ("Command: open(fridge)", True, "You opened fridge. Inside: apple, milk."),
        (
            "Command: pick(apple)",
            False,
            "The end effector cannot reach apple: it is 0.21 m away from the closest pose your arm can get to. Moving "
            "your base by dx=0.10, dy=0.25 would bring it within a good grasping distance.",
        ),
        ("Command: move(0.10, 0.25)", True, "You moved by dx=0.10 m, dy=0.25 m."),
        ("Command: pick(apple)", True, "You picked up apple."),
        ("Command: navigate(table_0, 1)", True, "You reached stand pose 1 of table_0. On table_0: phone, book, tray."),
        ("Command: place(apple, table_0)", True, "You placed apple on table_0."),
        ('Command: communicate("Bob, I placed apple on table_0 for you.", bob)', True, "Message sent to bob."),
    ],
    "bob": [
        (
            'Command: communicate("Alice, please bring these to table_0 within my reach: apple, fork, soap, toy_duck, book.", alice)',
            True,
            "Message sent to alice.",
        ),
        ("Command: pick(phone)", True, "You picked up phone."),
        ("Command: place(phone, tray)", True, "You placed phone in the tray."),
        (
            "Command: pick(book)",
            False,
            "The end effector cannot reach book: it is 0.73 m away from the closest pose your arm can get to.",
        ),
        ("Command: wait()", True, "You waited."),
        ("Command: wait()", True, "You waited."),
    ],
    "david": [
        ("Command: navigate(table_3, 0)", True, "You reached stand pose 0 of table_3. There is nothing on table_3."),
        ('Command: communicate("On table_3 I found nothing.", alice)', True, "Message sent to alice."),
        (
            "Command: navigate(tub, 0)",
            False,
            "Navigation failed: there is no collision-free path to stand pose 0 of tub.",
        ),
        ("Command: navigate(tub, 1)", True, "You reached stand pose 1 of tub. On tub: toy_duck."),
        ('Command: communicate("On tub I found: toy_duck.", alice)', True, "Message sent to alice."),
        ("Command: wait()", True, "You waited."),
    ],
}
MESSAGES = {
    "alice": [
        ("bob", "Alice, please bring these to table_0 within my reach: apple, fork, soap, toy_duck, book."),
        ("david", "On tub I found: toy_duck."),
        ("david", "On table_3 I found nothing."),
    ],
    "bob": [("alice", "Bob, I placed apple on table_0 for you.")],
    "david": [
        (
            "alice",
            "David, please explore these surfaces and tell me what lies on them: table_1, table_2, table_3, table_4, sofa, bookcase, tub, washbasin.",
        )
    ],
}


def furniture(opened: set[str]) -> list[FurnitureView]:
    out = []
    for name, kind, x, y, openable, surface in HOUSE:
        poses = [Pose2D(x=x - 0.3, y=y - 0.85, yaw=1.5708), Pose2D(x=x + 0.3, y=y - 0.85, yaw=1.5708)]
        out.append(
            FurnitureView(
                name=name,
                kind=kind,
                position=(x, y, 0.7),
                openable=openable,
                is_open=(name in opened) if openable else None,
                stand_poses=poses,
                place_pose=(x, y, 0.7) if surface else None,
            )
        )
    out.append(
        FurnitureView(name="tray", kind="tray on table_0", position=(-3.4, 0.19, 0.71), place_pose=(-3.4, 0.19, 0.71))
    )
    return out


def observe(robot: str, step: int, messages: list[RobotMessage]) -> Observation:
    """The robot's view at `step`: one more target known every eight steps, containers opening."""
    known = TARGETS[: 2 + step // 8] if robot != "bob" else ["phone", "book"] + TARGETS[: step // 10]
    objects = [
        ObjectView(name=o, position=(-3.2, 0.1, 0.72), on=WHERE[o], inside=WHERE[o] in ("fridge", "drawer_unit"))
        for o in known
    ]
    bob = robot == "bob"
    return Observation(
        robot=robot,
        tick=step,
        status=RobotStatus(
            name=robot,
            kind={"alice": "mobile manipulator", "bob": "tabletop manipulator", "david": "mobile robot"}[robot],
            skills=SKILLS[robot],
            base=None if bob else Pose2D(x=-1.5, y=1.2),
            arm_base={"alice": (-1.3, 1.2, 0.65), "bob": (-3.75, 0.0, 0.7)}.get(robot),
            reach={"alice": 0.72, "bob": 0.62}.get(robot),
        ),
        furniture=furniture({"fridge", "drawer_unit"} if step > 10 else set()),
        objects=objects,
        task_brief=brief(PACK, ROLES[robot], CREW),
        task_detail=detail(PACK, ROLES[robot], CREW, TARGETS, {}),
        targets=TARGETS if bob else [],
        task_status=f"In the tray: phone. Not yet in the tray: {', '.join(TARGETS[:-2])}, book." if bob else None,
        teammates={r: SKILLS[r] for r in SKILLS if r != robot},
        new_messages=messages,
    )


async def sizes(robot: str, cap: int | None) -> dict[int, dict[str, int]]:
    script = SCRIPT[robot]
    policy = LLMPolicy(
        robot, ScriptedClient([script[i % len(script)][0] for i in range(max(STEPS))]), prompt_cap_chars=cap
    )
    out: dict[int, dict[str, int]] = {}
    for step in range(1, max(STEPS) + 1):
        inbox = []
        if step % 4 == 0:  # a message every fourth step
            sender, content = MESSAGES[robot][(step // 4) % len(MESSAGES[robot])]
            inbox = [RobotMessage(sender=sender, to=robot, content=content, tick=step - 1)]
        obs = observe(robot, step, inbox)
        d = await policy.decide(obs)
        if step in STEPS:
            text = d.prompt or ""
            out[step] = {"chars": len(text), "est_tokens": estimate_tokens(text)}
        _, ok, feedback = script[(step - 1) % len(script)]
        outcome = SkillOutcome.ok(feedback) if ok else SkillOutcome.fail(OutcomeCode.TOO_FAR, feedback)
        policy.record(
            ActionResult(goal_id=f"g{step}", robot=robot, tick=step, action=d.action, outcome=outcome, observation=obs)
        )
    return out


async def heuristic_sizes() -> dict[str, Any]:
    """Each robot's prompt size at HEURISTIC_STEPS of a heuristic-driven episode (step n is the
    prompt for tick n - 1, so step 1 is the first prompt), paper prompts and prompt_hints."""
    from mhrc.agents.heuristic import heuristic_policy
    from mhrc.core.protocol import Communicate
    from mhrc.world.sim import Sim

    variants: dict[str, dict[str, Any]] = {"paper": {}, "prompt_hints": {"prompt_hints": True}}
    out: dict[str, Any] = {"episode": HEURISTIC_EPISODE, "steps": list(HEURISTIC_STEPS), "roles": {}}
    with Sim(**HEURISTIC_EPISODE) as sim:  # type: ignore[arg-type]
        robots = sim.robots
        team = {r: heuristic_policy(r) for r in robots}
        prompters = {(r, v): LLMPolicy(r, ScriptedClient([]), **kw) for r in robots for v, kw in variants.items()}
        sizes_: dict[str, dict[str, dict[int, dict[str, int]]]] = {r: {v: {} for v in variants} for r in robots}
        obs = {r: sim.observe(r, 0) for r in robots}
        for tick in range(max(HEURISTIC_STEPS)):
            inbox: dict[str, list[RobotMessage]] = {r: [] for r in robots}
            batch = []
            for r in robots:
                action = (await team[r].decide(obs[r])).action
                for v in variants:
                    p = prompters[(r, v)]
                    p.client = ScriptedClient(["Command: wait()"])
                    text = (await p.decide(obs[r])).prompt or ""
                    if tick + 1 in HEURISTIC_STEPS:
                        sizes_[r][v][tick + 1] = {"chars": len(text), "est_tokens": estimate_tokens(text)}
                batch.append((r, action))
            done = False
            outcomes = []
            for r, a in batch:
                if isinstance(a, Communicate):
                    inbox[a.to].append(RobotMessage(sender=r, to=a.to, content=a.content, tick=tick))
                    sim.tell(a.to, r, a.content)
                    outcomes.append(SkillOutcome.ok(f"Message sent to {a.to}."))
                else:
                    outcomes.append(sim.execute(r, a))
            done = sim.evaluate().success
            for (r, a), outcome in zip(batch, outcomes):
                o = sim.observe(r, tick + 1).model_copy(update={"new_messages": inbox[r]})
                result = ActionResult(
                    goal_id=f"{r}-{tick}", robot=r, tick=tick, action=a, outcome=outcome, observation=o, done=done
                )
                team[r].record(result)
                for v in variants:
                    prompters[(r, v)].record(result)
                obs[r] = o
            if done:
                out["solved_at_tick"] = tick
                break
        out["roles"] = sizes_
    return out


async def run(cap: int) -> dict[str, Any]:
    report: dict[str, Any] = {
        "bench": "prompt_size",
        "cap_chars": cap,
        "steps": list(STEPS),
        "est_tokens": "chars // 4",
        "roles": {},
    }
    for robot in SCRIPT:
        report["roles"][robot] = {"capped": await sizes(robot, cap), "uncapped": await sizes(robot, None)}
    report["heuristic"] = await heuristic_sizes()
    return report


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cap", type=int, default=SMALL_CONTEXT_CAP, help="prompt cap in characters (default %(default)s)")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    emit(asyncio.run(run(args.cap)), args.out)


if __name__ == "__main__":
    from mhrc.core import logs

    logs.configure()
    main()
