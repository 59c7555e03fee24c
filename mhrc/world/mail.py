"""Robot-to-robot messages inside the world service: sent by `communicate`, kept in each
receiver's inbox until the time policy hands them over with an observation.

What a message tells its receiver's scene graph is fixed when it is sent (`Sim.message`, the
sender's beliefs then) and learned only once it is delivered: a robot acting later in the same
sequential tick must not know it yet. Learning happens in the simulator's thread, under its
lock (`learn`), never in the bus callbacks that deliver.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence

from mhrc.core.protocol import RobotMessage

Teller = Callable[[str, str, str], Callable[[], None]]  # (receiver, sender, text) -> what it tells, when called


class Mailroom:
    """Every robot's inbox, and what the messages in it will tell."""

    def __init__(self, robots: Sequence[str], message: Teller) -> None:
        self.robots = tuple(robots)
        self._message = message
        self._inbox: dict[str, list[RobotMessage]] = {r: [] for r in self.robots}
        self._sent: dict[str, list[Callable[[], None]]] = {r: [] for r in self.robots}  # per receiver, not yet delivered
        self._due: list[Callable[[], None]] = []  # delivered, applied at the simulator's next use (its thread, its lock)

    def send(self, sender: str, to: str, content: str, tick: int) -> None:
        """`sender`'s message to `to` goes into `to`'s inbox; what it tells is fixed now."""
        self._inbox[to].append(RobotMessage(sender=sender, to=to, content=content, tick=tick))
        self._sent[to].append(self._message(to, sender, content))

    def delivered(self, robots: Iterable[str]) -> None:
        """The messages to `robots` are delivered: what they tell becomes due."""
        for r in robots:
            self._due += self._sent[r]
            self._sent[r] = []

    def learn(self) -> None:
        """Apply what delivered messages tell (in the simulator's thread, holding its lock)."""
        due, self._due = self._due, []
        for learn in due:
            learn()

    def take(self, robot: str) -> list[RobotMessage]:
        """Empty `robot`'s inbox: the messages go with its observation now."""
        taken, self._inbox[robot] = self._inbox[robot], []
        return taken

    def take_all(self) -> dict[str, list[RobotMessage]]:
        """Deliver every inbox: the messages per robot (every robot a key), what they tell due."""
        self.delivered(self.robots)
        out = {r: self._inbox[r] for r in self.robots}
        self._inbox = {r: [] for r in self.robots}
        return out

    def hold(self, robot: str, messages: Sequence[RobotMessage]) -> None:
        """Put back messages no observation carried, ahead of any sent since."""
        self._inbox[robot] = list(messages) + self._inbox[robot]
