"""Zenoh key expressions of the mhrc bus (see docs/architecture.md, "The bus").

Every id is one key chunk of `[a-z0-9_-]+`, so a run id scopes everything below it and many
runs can share one bus.
"""

from __future__ import annotations

import re
import secrets

ROOT = "mhrc"
_CHUNK = re.compile(r"^[a-z0-9_-]+$")


class InvalidId(ValueError):
    """An id that cannot be used as one key chunk."""


def check_id(value: str, what: str = "id") -> str:
    if not _CHUNK.match(value):
        raise InvalidId(f"{what} {value!r} must match [a-z0-9_-]+ (lowercase letters, digits, _ and -)")
    return value


def new_run_id() -> str:
    return "run-" + secrets.token_hex(4)


class Keys:
    """The keys of one run."""

    def __init__(self, run: str) -> None:
        self.run = check_id(run, "run id")
        self.base = f"{ROOT}/{run}"

    @property
    def all(self) -> str:
        return f"{self.base}/**"

    @property
    def world_event(self) -> str:
        return f"{self.base}/world/event"

    @property
    def world_state(self) -> str:
        return f"{self.base}/world/state"

    def attach(self, robot: str) -> str:
        return f"{self.base}/robot/{check_id(robot, 'robot')}/attach"

    def action_request(self, robot: str) -> str:
        return f"{self.base}/robot/{check_id(robot, 'robot')}/action/request"

    @property
    def any_action_request(self) -> str:
        return f"{self.base}/robot/*/action/request"

    def action_ack(self, robot: str) -> str:
        return f"{self.base}/robot/{check_id(robot, 'robot')}/action/ack"

    def action_result(self, robot: str) -> str:
        return f"{self.base}/robot/{check_id(robot, 'robot')}/action/result"

    def turn(self, robot: str) -> str:
        return f"{self.base}/robot/{check_id(robot, 'robot')}/turn"

    def inbox(self, to: str, sender: str) -> str:
        return f"{self.base}/robot/{check_id(to, 'robot')}/inbox/{check_id(sender, 'robot')}"

    def thought(self, robot: str) -> str:
        return f"{self.base}/agent/{check_id(robot, 'robot')}/thought"

    def generating(self, robot: str) -> str:
        return f"{self.base}/agent/{check_id(robot, 'robot')}/generating"

    @property
    def alive_world(self) -> str:
        return f"{self.base}/alive/world"

    def alive_robot(self, robot: str) -> str:
        return f"{self.base}/alive/robot/{check_id(robot, 'robot')}"

    @property
    def alive_any_robot(self) -> str:
        return f"{self.base}/alive/robot/*"

    def robot_of(self, key: str) -> str:
        """The robot id in a key of this run (`.../robot/<rid>/...` or `.../alive/robot/<rid>`)."""
        parts = key.split("/")
        i = parts.index("robot")
        return parts[i + 1]
