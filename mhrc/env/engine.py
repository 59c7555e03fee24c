"""What both environment APIs share: one episode of the real world (world/sim.py's `Sim` under
a world scheduler, `DirectWorld`), a seat per robot (its prompt, memory and expert), the reward
and the infos.

Reward: the change in the number of target objects where the task wants them (`placed`, the
task's own evaluation) since the last step, the same for every robot (the team's); the paper
defines no reward. Negative when an object leaves its goal. At the end, every robot's infos
carry the paper's metrics (`metrics`, as `mhrc up`'s episode_done) and why it ended (`reason`).
"""

from __future__ import annotations

from typing import Required, TypedDict

import numpy as np

from mhrc.core.jsontypes import JsonObject
from mhrc.core.protocol import ActionResult, EpisodeDone, Message
from mhrc.run.config import EpisodeConfig
from mhrc.world.sim import Sim

from .seats import Seat
from .world import DirectWorld

FRAME = (480, 640)  # rgb_array's height and width: the video's default frame size


class Outcome(TypedDict):
    """A robot's last action as its infos tell it."""

    action: str  # its call
    code: str  # the world's OutcomeCode
    succeeded: bool
    feedback: str


class News(TypedDict, total=False):
    """What reached a robot in the last step."""

    unreadable: str  # why its command could not be read (it waited)
    outcome: Outcome


class RobotInfo(News, total=False):
    """A robot's infos (PettingZoo's per-agent dict; docs/env.md)."""

    tick: Required[int]
    system_prompt: str  # at the reset
    expert_action: str  # with expert=True, the heuristic's next command
    reason: str  # at the end: why the episode ended
    metrics: JsonObject  # at the end: the paper's metrics, as episode_done carries them


class EnvCore:
    """The episode behind an environment: `reset`, then `act` for each robot as its turn comes."""

    def __init__(self, cfg: EpisodeConfig, *, schedule: str, expert: bool, render_mode: str | None) -> None:
        self.cfg = cfg
        self.schedule = schedule
        self.expert = expert
        self.render_mode = render_mode
        self.robots: tuple[str, ...] = cfg.robots
        self.sim: Sim | None = None
        self.world: DirectWorld | None = None
        self.seats: dict[str, Seat] = {}
        self.placed = 0
        self.news: dict[str, News] = {}  # robot -> what reached it in the last step (for its infos)

    # ------------------------------------------------------------------ the episode
    def reset(self, seed: int | None) -> None:
        """A new episode (of `seed`, else the environment's seed): every robot attached and the
        first observations given (sequential: the first robot's only)."""
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0):
            raise ValueError(f"seed must be a non-negative integer, not {seed!r}")
        self.close()
        cfg = self.cfg
        self.sim = cfg.sim(None if seed is None else int(seed), visuals=self.render_mode is not None)
        self.world = DirectWorld(self.sim, schedule=self.schedule, horizon=cfg.horizon)
        self.seats = {r: Seat.make(r, cfg, expert=self.expert) for r in self.robots}
        self.news = {r: {} for r in self.robots}
        for robot, obs in self.world.start().items():
            self.seats[robot].see(obs)
        self.placed = self.world.core.evaluation.placed

    def act(self, robot: str, command: object) -> None:
        """`robot`'s command for its current tick: read as the LLM agent reads a reply (unreadable:
        it waits, and that is its feedback), through the world's admission, then run when due."""
        world = self._world()
        action, unreadable = self.seats[robot].command(command)
        rejection = world.submit(robot, action)
        if rejection is not None:  # the APIs hand over only what the world accepts: a bug, said plainly
            raise RuntimeError(f"the world refused {robot}'s action ({rejection.code.value}): {rejection.reason}")
        # its earlier news was read
        self.news[robot] = News(unreadable=unreadable) if unreadable is not None else News()
        for result in world.results:
            self._deliver(result)
        for turn in world.turns:
            self.seats[turn.robot].see(turn.observation)
        world.results.clear()
        world.turns.clear()

    def _deliver(self, result: ActionResult) -> None:
        seat = self.seats[result.robot]
        seat.record(result)
        seat.see(result.observation)
        news = self.news.setdefault(result.robot, News())
        news["outcome"] = Outcome(
            action=result.action.call(),
            code=result.outcome.code.value,
            succeeded=result.outcome.succeeded,
            feedback=result.outcome.feedback,
        )

    def reward(self) -> float:
        """The change in placed objects since the last call (the team's reward)."""
        placed = self._world().core.evaluation.placed
        reward, self.placed = float(placed - self.placed), placed
        return reward

    @property
    def events(self) -> list[Message]:
        """Every world event of the episode so far, in order, as `mhrc up`'s world/event carries
        them (episode_started, snapshots, tick_closed, scenario events, episode_done), and the
        robots' messages as they were delivered."""
        return list(self._world().events)

    @property
    def done(self) -> EpisodeDone | None:
        return self._world().done

    @property
    def turn(self) -> str | None:
        return self._world().turn

    def ended(self) -> tuple[bool, bool]:
        """(terminated, truncated): terminated at success, truncated at the horizon."""
        done = self.done
        if done is None:
            return False, False
        return done.reason == "success", done.reason != "success"

    def observation(self, robot: str) -> dict[str, str]:
        return dict(self.seats[robot].shown)

    def info(self, robot: str, *, first: bool = False) -> RobotInfo:
        """`robot`'s infos: the tick, what reached it in the last step (its action's outcome, why its
        command could not be read), the expert's next command, the system prompt at the reset, and at
        the end the paper's metrics and why the episode ended."""
        seat, world = self.seats[robot], self._world()
        info: RobotInfo = {"tick": world.tick, **self.news.get(robot, News())}
        if first:
            info["system_prompt"] = seat.system
        if self.expert and seat.expert_action is not None and world.done is None:
            info["expert_action"] = seat.expert_action
        if world.done is not None:
            info["reason"] = world.done.reason
            info["metrics"] = world.done.metrics.model_dump(mode="json")
        return info

    def render(self) -> np.ndarray | None:
        """The video's frame of the world as it is now (mhrc.viewer.video, its default view)."""
        if self.render_mode is None or self.sim is None:
            return None
        from mhrc.viewer.video import OVERVIEW, camera  # here: the video's imports (imageio, PIL) only for frames

        height, width = FRAME
        return camera(self.sim, OVERVIEW, width, height)

    def close(self) -> None:
        if self.sim is not None:
            self.sim.close()
        self.sim, self.world = None, None

    def _world(self) -> DirectWorld:
        if self.world is None:
            raise RuntimeError("the environment has no episode: call reset() first")
        return self.world
