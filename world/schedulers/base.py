"""The interface between the world service and its time policy (docs/architecture.md, "Time").

The service keeps the bus: it attaches robots, checks each request's robot, agent and payload,
acks it with the scheduler's verdict, answers state queries, starts and finishes the episode.
The scheduler decides the rest: which checked requests to accept, when their actions execute,
when their results go out and when the clock advances. Schedulers see the service only
through `World`, so they never import it.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import ClassVar, Protocol

from mhrc.core.protocol import (
    ActionRequest,
    ActionResult,
    Message,
    Observation,
    Rejection,
    RobotMessage,
    SkillOutcome,
    Turn,
    Wait,
)

# How long an action takes on the world's clock (simulated seconds). Skills measure their own
# time (navigation by path length and base speed, arm motions by trajectory and joint speeds);
# `wait` takes WAIT_SECONDS, and an action that takes less than MIN_ACTION_SECONDS (a message,
# a skill that failed before moving) takes MIN_ACTION_SECONDS, so no robot acts in zero time.
MIN_ACTION_SECONDS = 0.5
WAIT_SECONDS = 1.0


def duration(req: ActionRequest, outcome: SkillOutcome) -> float:
    """The simulated seconds `req`'s action took, as every scheduler counts it."""
    if isinstance(req.action, Wait):
        return WAIT_SECONDS
    return max(outcome.sim_time, MIN_ACTION_SECONDS)


class SchedulerOptionError(ValueError):
    """An option a scheduler cannot run with (e.g. a negative time scale)."""


class TaskResultLike(Protocol):
    """A task's evaluation as the schedulers read it (read-only: world.tasks.TaskResult is frozen)."""

    @property
    def success(self) -> bool: ...
    @property
    def placed(self) -> int: ...
    @property
    def total(self) -> int: ...
    @property
    def partial_success(self) -> float: ...


@dataclass(frozen=True)
class Executed:
    """What a batch of actions did: outcomes in batch order, the task's evaluation after the
    batch, and each actor's observation of the next tick (messages not yet attached)."""

    outcomes: list[SkillOutcome]
    evaluation: TaskResultLike
    observations: dict[str, Observation]


class World(Protocol):
    """The world service as a scheduler sees it (WorldService implements it)."""

    @property
    def run_id(self) -> str: ...
    @property
    def robots(self) -> tuple[str, ...]:
        """Every robot of the episode, in the fixed robot order."""

    @property
    def attached(self) -> Mapping[str, str]:
        """robot -> agent id, for the robots attached now."""

    @property
    def horizon(self) -> int: ...

    async def execute(
        self, batch: Sequence[ActionRequest], tick: int, *, deliver: bool = False, opens: int | None = None
    ) -> Executed:
        """Run the actions in order in the simulator, at `tick`, and count them for the metrics;
        with `deliver`, the observations returned already know what the batch's messages tell
        (a schedule that hands the messages over with them); with `opens`, tick `opens` opens
        after the actions: the evaluation and observations come after its scenario events."""

    async def open_tick(self, tick: int) -> None:
        """Tick `tick` opens: the scenario's events due by then fire (--events; world/dynamics.py),
        before any observation of it goes out."""

    async def observe(self, robot: str, tick: int) -> Observation:
        """`robot`'s observation of the world as it is now, labelled `tick` (no messages attached)."""

    def deliver_messages(self) -> dict[str, list[RobotMessage]]:
        """Publish the messages not yet in any observation on their inbox keys and hand them
        over, per robot (every robot a key), to go into the receivers' observations."""

    def hold_messages(self, robot: str, messages: Sequence[RobotMessage]) -> None:
        """Put back messages no observation carried: they go out (again) with the next delivery
        and reach `robot` with its next observation (an attach reply included)."""

    def release(self, results: Sequence[ActionResult]) -> None:
        """Publish results that go out together; the episode's end names each robot's last
        released result, so an agent that sees `episode_done` first still waits for its own."""

    def give_turn(self, turn: Turn) -> None:
        """Publish `turn` on its robot's turn key (to a robot that attached with wait_turn)."""

    def publish_event(self, event: Message) -> None: ...
    def finish(self, reason: str) -> None:
        """End the episode (`success`, `horizon`, ...); later calls do nothing."""


class Scheduler(ABC):
    """A time policy of the world: one small class per policy, the same agent code for all.

    A scheduler must guarantee that
    - every request it admits gets exactly one result, unless its robot detaches or the
      episode ends first (`EpisodeDone.final_results` then tells the agent whether to wait);
    - a robot has at most one action per tick: a request that arrives while its previous one is
      admitted and unanswered (pending, executing in the simulator, or awaiting its release)
      is rejected, never held over to a later tick;
    - a robot's results go out in the order of its requests;
    - the messages an action sends reach their receivers with a later observation, never lost;
    - the episode finishes on success, and at the latest when `tick` reaches the horizon.
    """

    name: ClassVar[str]
    tick: int  # the world's step count: TS when the episode ends
    makespan: float  # simulated seconds on the world's clock so far (the end of the last action counted)

    def __init__(self, world: World, *, time_scale: float = 0.0) -> None:
        """`time_scale` is the async scheduler's (simulated seconds per wall second); the
        stepped schedulers have no wall clock and ignore it."""
        self.world = world
        self.makespan = 0.0

    @abstractmethod
    def admit(self, req: ActionRequest) -> Rejection | None:
        """Accept `req` (return None) or say why not. The service has already checked that it
        comes from the agent attached to its robot while the episode runs, with a goal id new
        to the episode (world/admission.py)."""

    @abstractmethod
    def ready(self) -> bool:
        """Whether `step` has work to do now (the service waits for news otherwise)."""

    @abstractmethod
    async def step(self) -> None:
        """Execute what is due, release its results, advance the clock, and finish the
        episode on success or at the horizon."""

    @abstractmethod
    def forget(self, robot: str) -> None:
        """`robot` detached: drop whatever it had pending."""

    def on_attach(self, robot: str) -> bool:
        """`robot` attached (or attached again): True when it must wait for its turn
        (`AttachReply.wait_turn`, then a `Turn`) instead of planning on the world of now."""
        return False

    def tick_of(self, robot: str) -> int:
        """The tick `robot`'s next request must name (and its attach observation carries)."""
        return self.tick

    def start(self) -> None:
        """The episode starts now (the attached robots are about to get their observations)."""

    def wake_at(self) -> float | None:
        """Simulated time is not only moved by news: the event loop time (`loop.time()`) at
        which `ready` may turn true by itself; None when only a request or a detach can."""
        return None

    def started_fields(self) -> dict[str, float]:
        """What `EpisodeStarted` records of this scheduler beyond its name."""
        return {}
