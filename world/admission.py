"""Which action requests the world accepts: the checks a request passes, in order, before its
scheduler may execute it (docs/architecture.md, "Time"; docs/protocol.md, "The tick rule").

1. The payload is an `ActionRequest` of at most MAX_REQUEST_BYTES (`malformed`: too long, not
   JSON, nested deeper than the parser's bound, a field out of its bounds; docs/protocol.md, "Limits").
2. Its sender drives its robot now and the episode runs (the roster's: `wrong_key`,
   `no_such_robot`, `episode_over`, `not_attached`, `other_agent`).
3. Its goal id is new: a goal executes at most once, as a ROS 2 action server refuses a goal id
   it knows. A goal id its robot had accepted earlier in the episode (still pending, executing
   or finished) is refused (`duplicate_goal`) in every schedule.
4. The scheduler's verdict (`stale_tick`, `tick_taken`, `not_your_turn`, `busy`).

The goal ids kept are the accepted ones, per robot: as many as the requests the episode admits
(at most one per robot per tick, the horizon bounding the ticks), not as many as it is sent.
A rejection is logged at most once per interval for each robot and code, with the count held
back since the last line: a flood of repeats costs a line per interval, not a line a message.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

from mhrc.core.logs import Throttle
from mhrc.core.protocol import ActionRequest, ProtocolError, RejectCode, Rejection, decode
from mhrc.core.protocol.base import MAX_NAME, MAX_REQUEST_BYTES, loads
from mhrc.core.protocol.exchange import GOAL_ID

from .roster import Roster
from .schedulers import Scheduler

if TYPE_CHECKING:
    from structlog.typing import FilteringBoundLogger

LOG_INTERVAL = 5.0  # s: at most one line per robot and reject code in this time
_WARNED = {
    RejectCode.MALFORMED: "malformed action request rejected",
    RejectCode.DUPLICATE_GOAL: "duplicate goal rejected",
}  # an agent's bug


class Admission:
    """The world's door for action requests: decodes, checks and hands the accepted ones to the scheduler."""

    def __init__(self, roster: Roster, scheduler: Scheduler, log: FilteringBoundLogger) -> None:
        self.roster = roster
        self.scheduler = scheduler
        self._goals: dict[str, set[str]] = {
            robot: set() for robot in roster.robots
        }  # robot -> goal ids accepted this episode
        self._throttle = Throttle(interval=LOG_INTERVAL)
        self._log = log

    def request(self, robot: str, payload: bytes, *, over: bool) -> tuple[str, Rejection | None]:
        """The goal id of `payload`, sent on `robot`'s request key, and None when the scheduler
        accepted it, or why it was refused (`over`: the episode has ended)."""
        rejection: Rejection | None
        try:
            req = decode(payload, ActionRequest, max_bytes=MAX_REQUEST_BYTES)
        except ProtocolError as exc:
            goal_id, rejection = (
                _goal_id_of(payload),
                Rejection(RejectCode.MALFORMED, f"malformed action request: {exc}"),
            )
        else:
            goal_id = req.goal_id
            rejection = (
                self.roster.check_request(robot, req, over=over) or self._repeated(req) or self.scheduler.admit(req)
            )
            if rejection is None:
                self._goals[robot].add(goal_id)
                return goal_id, None
        self._note(robot, goal_id, rejection)
        return goal_id, rejection

    def _repeated(self, req: ActionRequest) -> Rejection | None:
        if req.goal_id not in self._goals[req.robot]:
            return None
        return Rejection(
            RejectCode.DUPLICATE_GOAL,
            f"goal {req.goal_id} was accepted from {req.robot} before in this episode and a goal runs once: send each action with a fresh goal_id",
        )

    def malformed_attach(self, robot: str, exc: ProtocolError) -> str:
        """The reason a malformed attach query is refused, logged as a malformed request is (throttled)."""
        reason = f"malformed attach request: {exc}"
        self._note(robot, "attach", Rejection(RejectCode.MALFORMED, reason))
        return reason

    def _note(self, robot: str, goal_id: str, rejection: Rejection) -> None:
        """Log a rejection, unless one of its robot and code was logged less than LOG_INTERVAL ago."""
        who = (
            robot if robot in self.roster.robots else "?"
        )  # the robot in a key is the sender's choice: keep the throttle's keys few
        log_now, held = self._throttle.due(f"{rejection.code.value}/{who}")
        if not log_now:
            return
        fields = {
            "robot": robot[:MAX_NAME],  # a key chunk of the sender's choice, on the open bus
            "goal": goal_id[:MAX_NAME],
            "reason": rejection.reason,
            "code": rejection.code.value,
            **({"and_before": held} if held else {}),
        }
        warned = _WARNED.get(rejection.code)
        if warned is None:
            self._log.info("action rejected", **fields)
        else:
            self._log.warning(warned, **fields)


_GOAL_ID = re.compile(GOAL_ID)
_GOAL_FIELD = re.compile(rb'"goal_id"\s*:\s*"([A-Za-z0-9_-]{1,64})"')


def _goal_id_of(payload: bytes) -> str:
    """Best-effort goal id of a malformed request, so its sender can match the rejection: its
    `goal_id` if that is a valid one, else the first valid-looking one in its first bytes (a
    document too deep or with a number too long for the parser), else "unknown"."""
    try:
        data = loads(payload[:MAX_REQUEST_BYTES])
        goal = data.get("goal_id") if isinstance(data, dict) else None
        return goal if isinstance(goal, str) and _GOAL_ID.fullmatch(goal) else "unknown"
    except ProtocolError:
        found = _GOAL_FIELD.search(payload[:4096])
        return found.group(1).decode() if found else "unknown"
