"""Which robots have a live agent: the world service's watch on the agents' liveliness tokens.

An agent declares its token (`mhrc/<run>/alive/robot/<rid>`) before it attaches and holds it
while it plays (docs/architecture.md, "Attach"). A token that goes away is a robot detached. An
attached robot whose token has not appeared `deadline` seconds after its attach (its agent frozen
or killed right after attaching, or a hand-written client that skips the token) is detached too:
nothing else would ever say it left, and the sequential schedule would wait for its turn forever.
The presence decides; the service does the detaching and the talking on the bus.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from mhrc.core.bus import Bus, Sample
from mhrc.core.keys import Keys

from .roster import Roster

LIVELINESS_QUERY = 2.0  # s: asking the router for a token whose put this session may not have seen yet

Detach = Callable[[str, str], None]  # (robot, why a person reads)


class Presence:
    """The robots whose agent's token is declared now, and the deadline of each attach's token."""

    def __init__(
        self, bus: Bus, keys: Keys, roster: Roster, *, deadline: float, detach: Detach, over: Callable[[], bool]
    ) -> None:
        if deadline <= 0:
            raise ValueError(f"the token deadline must be more than 0 s (got {deadline})")
        self.deadline = deadline
        self.tokens: set[str] = set()  # robots whose liveliness token is declared now
        self._bus = bus
        self._keys = keys
        self._roster = roster
        self._detach = detach
        self._over = over
        self._checks: set[asyncio.Task[None]] = set()

    def watch(self) -> None:
        """Follow the robots' tokens (those declared already too)."""
        self._bus.watch_liveliness(self._keys.alive_any_robot, self._on_token)

    def expect(self, robot: str, agent_id: str) -> None:
        """`agent_id` has just attached `robot`: detach it unless its token exists `deadline` seconds from now."""
        check = asyncio.create_task(self._check(robot, agent_id), name=f"token-{robot}")
        self._checks.add(check)
        check.add_done_callback(self._checks.discard)

    def close(self) -> None:
        """The episode is over: no deadline is kept any more."""
        for check in list(self._checks):
            check.cancel()

    def _on_token(self, sample: Sample) -> None:
        robot = self._keys.robot_of(sample.key)
        if sample.is_put:
            self.tokens.add(robot)
            return
        self.tokens.discard(robot)
        if robot in self._roster.attached:
            self._detach(robot, "agent vanished (liveliness lost)")

    async def _check(self, robot: str, agent_id: str) -> None:
        await asyncio.sleep(self.deadline)  # a deadline, not a wait for something to happen
        if self._over() or self._roster.attached.get(robot) != agent_id or robot in self.tokens:
            return
        key = self._keys.alive_robot(robot)
        if await self._bus.alive(key, timeout=LIVELINESS_QUERY):  # its put may have gone unseen: ask
            return
        if not self._over() and self._roster.attached.get(robot) == agent_id:
            self._detach(
                robot, f"its agent declared no liveliness token ({key}) within {self.deadline:g} s of attaching"
            )
