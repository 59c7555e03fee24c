"""A map frame of the report: where every robot and object was after a tick, and which containers
were open. A frame is a world `snapshot`, or for a trace without snapshots (protocol version 1)
the robots' own observations (no objects). mhrc.viewer.model builds them; the page's script draws
them from `as_data`."""

from __future__ import annotations

from dataclasses import dataclass, field

from mhrc.core.protocol import ObjectPose, RobotPose


@dataclass(frozen=True)
class Frame:
    """One frame of the map, after the actions of `goals` executed at `tick`."""

    tick: int
    goals: list[str]  # goal ids of the actions whose outcome this frame shows first
    robots: dict[str, RobotPose]
    objects: dict[str, ObjectPose] = field(default_factory=dict)
    open: dict[str, bool] = field(default_factory=dict)  # openable furniture -> open

    def as_data(self) -> dict[str, object]:
        """The frame as the page's script reads it (JSON)."""
        return {
            "tick": self.tick,
            "goals": self.goals,
            "robots": {name: p.model_dump(mode="json") for name, p in self.robots.items()},
            "objects": {name: p.model_dump(mode="json") for name, p in self.objects.items()},
            "open": self.open,
        }
