"""Which agent drives which robot: the world service's rules for attaching, for the sender of
an action request, and for what a team lacks once agents leave.

One agent per robot, attached from one session: another agent id is refused while the robot is
held, and so is the held id from another session (a copy, never a second driver). The roster
decides and remembers; the service does the talking on the bus.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from mhrc.core.protocol import EPISODE_OVER, ActionRequest, AttachRequest, RejectCode, Rejection

if TYPE_CHECKING:
    from structlog.typing import FilteringBoundLogger


class Roster:
    """The robots of an episode and the agents attached to them now."""

    def __init__(self, robots: Sequence[str], log: FilteringBoundLogger) -> None:
        self.robots = tuple(robots)
        self.attached: dict[str, str] = {}  # robot -> agent id
        self._sessions: dict[
            str, str
        ] = {}  # robot -> the attaching session's secret (its attach query's `session` parameter)
        self._log = log

    def _no_such_robot(self, robot: str) -> str:
        return f"there is no robot {robot!r} in this episode ({', '.join(self.robots)})"

    def refuse_attach(self, robot: str, req: AttachRequest, session: str, *, over: bool) -> str | None:
        """Why `req`, sent on `robot`'s key from `session`, cannot attach (`over`: the episode
        has ended), or None when it can."""
        if req.robot != robot:
            return f"attach for {req.robot!r} sent on the key of {robot!r}"
        if robot not in self.robots:
            return self._no_such_robot(robot)
        if over:
            return EPISODE_OVER
        holder = self.attached.get(robot)
        if holder is not None and holder != req.agent_id:
            self._log.warning("duplicate attach rejected", robot=robot, agent=req.agent_id)
            return f"robot {robot} is already attached to another agent ({holder})"
        if holder is not None and self._sessions.get(robot, "") != session:
            # the live agent's id, from another session: a copy, never a second driver of one robot
            self._log.warning("duplicate attach with a live agent's id rejected", robot=robot, agent=req.agent_id)
            return f"robot {robot} is already attached to a live agent with id {holder} in another session"
        return None

    def attach(self, robot: str, agent_id: str, session: str) -> bool:
        """Record an attach `refuse_attach` let through; True if the robot was not attached before
        (False: its agent attached again, e.g. after a lost reply)."""
        first = robot not in self.attached
        self.attached[robot] = agent_id
        self._sessions[robot] = session
        return first

    def detach(self, robot: str) -> str:
        """`robot`'s agent is gone; returns its id."""
        return self.attached.pop(robot)

    def check_request(self, robot: str, req: ActionRequest, *, over: bool) -> Rejection | None:
        """Why a request on `robot`'s key is refused before any scheduler sees it, or None."""
        if req.robot != robot:
            return Rejection(RejectCode.WRONG_KEY, f"request for {req.robot!r} sent on the key of {robot!r}")
        if robot not in self.robots:
            return Rejection(RejectCode.NO_SUCH_ROBOT, self._no_such_robot(robot))
        if over:
            return Rejection(RejectCode.EPISODE_OVER, EPISODE_OVER)
        holder = self.attached.get(robot)
        if holder is None:
            return Rejection(RejectCode.NOT_ATTACHED, f"robot {robot} is not attached: attach first")
        if holder != req.agent_id:
            return Rejection(RejectCode.OTHER_AGENT, f"robot {robot} is attached to another agent")
        return None

    def stranded(self, finishers: frozenset[str], capabilities: Callable[[str], frozenset[str]]) -> str:
        """Why the robots attached now cannot finish the task on their own, or "": nobody left
        among `finishers`, or nobody left that navigates and picks."""
        left = set(self.attached)
        if finishers and not left & finishers:
            return (
                f"nobody attached can finish the task (only {', '.join(sorted(finishers))} places on the goal fixtures)"
            )
        fetchers = [r for r in self.robots if {"navigate", "pick"} <= capabilities(r)]
        if fetchers and not left & set(fetchers):
            return f"nobody attached can fetch objects from the rooms (only {', '.join(fetchers)} navigates and picks)"
        return ""
