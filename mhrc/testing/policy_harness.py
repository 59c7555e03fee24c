"""`PolicyHarness`: a policy's unit test with nothing started (no bus, no world, no simulator),
and `observation` / `outcome` to build what the policy reads, tersely.

The loop is the agent's own (`mhrc.agents.agent`): the policy decides on an observation, the
action's result (its outcome and the next observation) goes back through `record`, and the next
decision is made on that result's observation. Here the test plays the world: it hands over the
observations and says how each action went, and reads the `Decision`s the policy made::

    harness = PolicyHarness(heuristic_policy("bob"))
    first = await harness.decide(observation("bob", objects={"phone": "table_0"}, targets=["phone"]))
    assert first.action.call() == "pick(phone)"
    harness.answer(observation=observation("bob", holding="phone", targets=["phone"], tick=1))
    assert (await harness.decide(harness.next_observation)).action.call() == "place(phone, tray)"

Observations built by `observation` are plausible, not a world's: the robots' statuses and
skills, a few pieces of kitchen furniture with stand poses and the tray on Bob's table, the
objects you name where you name them. They are the protocol's own models, so a field the world
would refuse is refused here too.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from mhrc.agents.policy import Decision, Policy
from mhrc.core.protocol import (
    Action,
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
from mhrc.world.kinds import KINDS, TEAM

__all__ = ["FURNITURE", "PolicyHarness", "Step", "World", "observation", "outcome"]

_STATUS = {  # as the world reports its three robots at the start of an episode in the kitchen (kinds: mhrc.world.robots)
    "alice": RobotStatus(
        name="alice",
        kind=KINDS[TEAM["alice"]].label,
        skills=list(KINDS[TEAM["alice"]].skills),
        base=Pose2D(x=-1.5, y=1.2),
        arm_base=(-1.3, 1.2, 0.65),
        reach=KINDS[TEAM["alice"]].reach,
    ),
    "bob": RobotStatus(
        name="bob",
        kind=KINDS[TEAM["bob"]].label,
        skills=list(KINDS[TEAM["bob"]].skills),
        arm_base=(-3.75, 0.0, 0.7),
        reach=KINDS[TEAM["bob"]].reach,
    ),
    "david": RobotStatus(
        name="david",
        kind=KINDS[TEAM["david"]].label,
        skills=list(KINDS[TEAM["david"]].skills),
        base=Pose2D(x=4.3, y=0.5, yaw=3.1416),
    ),
}
_BRIEFS = {
    "alice": (
        "Explore the whole house and hand Bob the objects the task needs.",
        "Ask Bob which objects are needed; then search the house for them, pick them up and put them on table_0 close to Bob.",
    ),
    "bob": (
        "Put the listed objects into the tray.",
        "Put every object on the list into the tray on table_0. When you cannot pick up one of them, ask Alice. The list: {targets}.",
    ),
    "david": (
        "Search the whole house for the objects the task needs.",
        "Do as Alice arranges: search the house and tell Alice about each new find without delay.",
    ),
}


def _furniture(
    name: str,
    kind: str,
    at: tuple[float, float, float],
    stands: Sequence[tuple[float, float, float]] = (),
    *,
    openable: bool = False,
    place: tuple[float, float, float] | None = None,
) -> FurnitureView:
    return FurnitureView(
        name=name,
        kind=kind,
        position=at,
        openable=openable,
        is_open=False if openable else None,
        stand_poses=[Pose2D(x=x, y=y, yaw=yaw) for x, y, yaw in stands],
        place_pose=place,
    )


FURNITURE: dict[str, FurnitureView] = {  # a few of the kitchen's, where the world puts them
    f.name: f
    for f in (
        _furniture(
            "table_0",
            "kitchen island",
            (-2.9, 0.0, 0.7),
            [(-2.9, 0.75, -1.57), (-2.0, 0.0, 3.14), (-2.9, -0.75, 1.57)],
            place=(-3.33, -0.28, 0.7),
        ),
        _furniture("tray", "tray", (-3.4, 0.25, 0.72), place=(-3.4, 0.25, 0.72)),
        _furniture(
            "table_2",
            "dining table",
            (-2.3, -3.35, 0.72),
            [(-2.3, -2.5, -1.57), (-1.2, -3.35, 3.14)],
            place=(-2.3, -3.2, 0.72),
        ),
        _furniture("cabinet_0", "kitchen cabinet", (-3.6, 3.65, 1.2), [(-3.6, 2.9, 1.57)], openable=True),
        _furniture("fridge", "fridge", (-4.5, 3.6, 1.8), [(-4.5, 2.8, 1.57)], openable=True),
    )
}


def observation(
    robot: str = "bob",
    *,
    tick: int = 0,
    objects: Mapping[str, str] | Iterable[ObjectView] = (),
    targets: Sequence[str] = (),
    holding: str | None = None,
    messages: Iterable[tuple[str, str] | RobotMessage] = (),
    furniture: Iterable[str | FurnitureView] | None = None,
    teammates: Iterable[str] | None = None,
    **fields: Any,
) -> Observation:
    """A plausible `Observation` of `robot` (alice, bob or david) at `tick`.

    `objects` maps an object to the furniture it lies on (``{"phone": "table_0"}``; inside it,
    for furniture that opens), or gives `ObjectView`s; `targets` is Bob's task list (his task
    text names it); `holding` what the robot holds; `messages` the new ones, ``(sender, text)``
    pairs or `RobotMessage`s; `furniture` names from `FURNITURE` or views of your own (all of
    `FURNITURE` by default); `teammates` the robots attached besides this one (the other two by
    default). Any other field of `Observation` (``goals``, ``ordered``, ``task_status``, ...)
    is passed as it is."""
    if robot not in _STATUS:
        raise ValueError(f"no default status for robot {robot!r}: observation() knows {', '.join(_STATUS)}")
    views = [FURNITURE[f] if isinstance(f, str) else f for f in (FURNITURE if furniture is None else furniture)]
    where = {f.name: f for f in views}
    things = (
        [_object(name, on, where) for name, on in objects.items()] if isinstance(objects, Mapping) else list(objects)
    )
    others = [r for r in _STATUS if r != robot] if teammates is None else list(teammates)
    brief, detail = _BRIEFS[robot]
    values: dict[str, object] = {  # Observation's fields, checked by it with the caller's `fields` over them
        "robot": robot,
        "tick": tick,
        "status": _STATUS[robot].model_copy(update={"holding": holding}),
        "furniture": views,
        "objects": things,
        "task_brief": brief,
        "task_detail": detail.format(targets=", ".join(targets) or "nothing"),
        "targets": list(targets),
        "task_status": "In the tray: nothing yet." if robot == "bob" else None,
        "teammates": {r: list(_STATUS[r].skills) if r in _STATUS else [] for r in others},
        "new_messages": [
            m
            if isinstance(m, RobotMessage)
            else RobotMessage(sender=m[0], to=robot, content=m[1], tick=max(tick - 1, 0))
            for m in messages
        ],
    }
    return Observation.model_validate(values | fields)


def _object(name: str, on: str, where: Mapping[str, FurnitureView]) -> ObjectView:
    if on not in where:
        raise ValueError(
            f"object {name!r} lies on {on!r}, which is not among the observation's furniture ({', '.join(where)})"
        )
    f = where[on]
    x, y, z = f.place_pose or f.position
    return ObjectView(name=name, position=(x, y, z + 0.01), yaw=0.0, on=on, inside=f.openable)


def outcome(code: OutcomeCode | str = OutcomeCode.OK, feedback: str | None = None, **details: Any) -> SkillOutcome:
    """A `SkillOutcome`: ``outcome()`` a success, ``outcome("out_of_reach", "The phone is too far.")``
    a failure with its code (an `OutcomeCode` or its value) and the sentence the robot reads."""
    code = OutcomeCode(code)
    if code is OutcomeCode.OK:
        return SkillOutcome.ok(feedback or "Done.", **details)
    return SkillOutcome.fail(code, feedback or f"The action failed ({code.value}).", **details)


World = Callable[[Action, Observation], "tuple[SkillOutcome, Observation | None]"]
"""How a test's world answers an action: its outcome and the next observation (None: the same, one tick later)."""


@dataclass
class Step:
    """One turn of the loop: the observation decided on, the decision, and the result recorded
    (None until `PolicyHarness.answer`)."""

    observation: Observation
    decision: Decision
    result: ActionResult | None = None

    @property
    def action(self) -> str:
        """The decided action in the paper's syntax (``"pick(phone)"``)."""
        return self.decision.action.call()


@dataclass
class PolicyHarness:
    """Drives one `Policy` as an agent would, in memory: `decide` on an observation, `answer`
    with how the action went (the result goes to the policy's `record`), and so on; `steps`
    keeps every turn. A policy that raises fails the test where it raised.

    ``await harness.step(obs, outcome("no_path", "No path to table_2."))`` decides and answers
    at once; `run` plays several turns against a `world` function of your own."""

    policy: Policy
    steps: list[Step] = field(default_factory=list)
    _goals: itertools.count[int] = field(default_factory=lambda: itertools.count(1), repr=False)

    @property
    def decisions(self) -> list[Decision]:
        return [s.decision for s in self.steps]

    @property
    def actions(self) -> list[str]:
        """Every decided action in the paper's syntax, in order."""
        return [s.action for s in self.steps]

    @property
    def results(self) -> list[ActionResult]:
        return [s.result for s in self.steps if s.result is not None]

    @property
    def next_observation(self) -> Observation:
        """The observation the next decision is made on: the last result's."""
        if not self.steps or self.steps[-1].result is None:
            raise RuntimeError("no result yet: answer() the last decision first")
        return self.steps[-1].result.observation

    async def decide(self, obs: Observation) -> Decision:
        """The policy's decision on `obs`, kept as a new step."""
        if self.steps and self.steps[-1].result is None:
            raise RuntimeError(
                f"the decision of step {len(self.steps) - 1} has no result yet: answer() it before deciding again"
            )
        decision = await self.policy.decide(obs)
        self.steps.append(Step(obs, decision))
        return decision

    def answer(
        self,
        result: SkillOutcome | OutcomeCode | str = OutcomeCode.OK,
        *,
        observation: Observation | None = None,
        done: bool = False,
    ) -> ActionResult:
        """Tell the policy how its last action went: `result` (a `SkillOutcome`, or an outcome
        code for `outcome`), and `observation`, what it sees next (by default the observation it
        decided on, one tick later). Returns the `ActionResult` given to its `record`."""
        if not self.steps or self.steps[-1].result is not None:
            raise RuntimeError("no decision to answer: decide() first")
        step = self.steps[-1]
        seen = observation or step.observation.model_copy(
            update={"tick": step.observation.tick + 1, "new_messages": []}
        )
        step.result = ActionResult(
            goal_id=f"{step.observation.robot}-{next(self._goals)}",
            robot=step.observation.robot,
            tick=step.observation.tick,
            action=step.decision.action,
            outcome=result if isinstance(result, SkillOutcome) else outcome(result),
            observation=seen,
            done=done,
        )
        self.policy.record(step.result)
        return step.result

    async def step(
        self,
        obs: Observation,
        result: SkillOutcome | OutcomeCode | str = OutcomeCode.OK,
        *,
        observation: Observation | None = None,
    ) -> Decision:
        """`decide` on `obs`, then `answer` with `result` and `observation`."""
        decision = await self.decide(obs)
        self.answer(result, observation=observation)
        return decision

    async def run(self, first: Observation, turns: int, world: World | None = None) -> list[str]:
        """Play `turns` turns from `first`: each action is answered by `world(action, obs)`, which
        returns its outcome and the next observation (by default: it succeeded, and the robot sees
        the same, one tick later). Returns the actions of these turns in the paper's syntax."""
        obs, start = first, len(self.steps)
        for _ in range(turns):
            decision = await self.decide(obs)
            result, seen = world(decision.action, obs) if world is not None else (outcome(), None)
            obs = self.answer(result, observation=seen).observation
        return self.actions[start:]
