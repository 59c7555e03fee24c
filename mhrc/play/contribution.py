"""How much each robot did in one episode, the person's robot among them: its share of the
actions (wait excluded), the objects it moved (mhrc.analysis.teamwork: a successful pick and a
successful place count one each) and the messages it sent, read from the episode's trace."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mhrc.analysis.metrics import EpisodeMetrics, from_trace
from mhrc.core.records import read_records


@dataclass(frozen=True)
class Contribution:
    robot: str
    actions: int
    action_share: float
    moves: int
    move_share: float
    messages: int

    def line(self, you: bool = False) -> str:
        who = f"{self.robot} (you)" if you else self.robot
        return (
            f"{who}: {self.actions} actions ({self.action_share:.0%}), {self.moves} moves ({self.move_share:.0%}), "
            f"{self.messages} messages"
        )


def contributions(m: EpisodeMetrics) -> list[Contribution]:
    """Each robot's share of the episode's work, in the team's order."""
    acts, moves = sum(m.action_steps_per_robot.values()), sum(m.moves_per_robot.values())
    return [
        Contribution(
            r,
            m.action_steps_per_robot.get(r, 0),
            m.action_steps_per_robot.get(r, 0) / acts if acts else 0.0,
            m.moves_per_robot.get(r, 0),
            m.moves_per_robot.get(r, 0) / moves if moves else 0.0,
            m.messages_per_robot.get(r, 0),
        )
        for r in m.robots
    ]


def from_trace_file(trace: Path) -> list[Contribution]:
    return contributions(from_trace(read_records(trace)))
