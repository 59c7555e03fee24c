"""Robot-to-robot messages inside the world service: sent by `communicate`, kept in each
receiver's inbox until the time policy hands them over with an observation.

What a message tells its receiver's scene graph is fixed when it is sent (`Sim.message`, the
sender's beliefs then) and learned only once it is delivered: a robot acting later in the same
sequential tick must not know it yet. Learning happens in the simulator's thread, under its
lock (`learn`), never in the bus callbacks that deliver.

The mailroom is used from two threads: the simulator's (`send`, `learn`, and `delivered` in a
lockstep batch) and the event loop's (attach, the schedulers' deliveries). Every access holds
the mailroom's own lock, so a message sent while a robot re-attaches is neither dropped from
its inbox nor from what it will tell (issue 32).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Sequence

from mhrc.core.protocol import RobotMessage

Teller = Callable[[str, str, str], Callable[[], None]]  # (receiver, sender, text) -> what it tells, when called


class Mailroom:
    """Every robot's inbox, and what the messages in it will tell."""

    def __init__(self, robots: Sequence[str], message: Teller) -> None:
        self.robots = tuple(robots)
        self._message = message
        self._lock = threading.Lock()  # held by every read or write of the three below, never while calling out
        self._inbox: dict[str, list[RobotMessage]] = {r: [] for r in self.robots}
        self._sent: dict[str, list[Callable[[], None]]] = {
            r: [] for r in self.robots
        }  # per receiver, not yet delivered
        self._due: list[
            Callable[[], None]
        ] = []  # delivered, applied at the simulator's next use (its thread, its lock)

    def send(self, sender: str, to: str, content: str, tick: int) -> None:
        """`sender`'s message to `to` goes into `to`'s inbox; what it tells is fixed now."""
        tells = self._message(to, sender, content)  # reads the simulator: its thread, outside the mailroom's lock
        with self._lock:
            self._inbox[to].append(RobotMessage(sender=sender, to=to, content=content, tick=tick))
            self._sent[to].append(tells)

    def delivered(self, robots: Iterable[str]) -> None:
        """The messages to `robots` are delivered: what they tell becomes due."""
        with self._lock:
            self._deliver(robots)

    def _deliver(self, robots: Iterable[str]) -> None:
        for r in robots:
            self._due += self._sent[r]
            self._sent[r] = []

    def learn(self) -> None:
        """Apply what delivered messages tell (in the simulator's thread, holding its lock)."""
        with self._lock:
            due, self._due = self._due, []
        for learn in due:
            learn()

    def deliver(self, robot: str) -> list[RobotMessage]:
        """Empty `robot`'s inbox and make what those messages tell due, in one step: the messages
        go with its next observation, which then knows what they tell (and nothing sent since)."""
        with self._lock:
            self._deliver([robot])
            taken, self._inbox[robot] = self._inbox[robot], []
        return taken

    def take_all(self) -> dict[str, list[RobotMessage]]:
        """Deliver every inbox: the messages per robot (every robot a key), what they tell due."""
        with self._lock:
            self._deliver(self.robots)
            out = {r: self._inbox[r] for r in self.robots}
            self._inbox = {r: [] for r in self.robots}
        return out

    def hold(self, robot: str, messages: Sequence[RobotMessage]) -> None:
        """Put back messages no observation carried, ahead of any sent since."""
        with self._lock:
            self._inbox[robot] = list(messages) + self._inbox[robot]
