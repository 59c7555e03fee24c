"""Each robot's scene graph as its own memory: the paper's partial observability.

"Scene graphs are updated from the robot's own observations and the messages it receives":
a robot's belief of an object (where it lies, what it is on or in, who holds it) and of a
container (open or closed) is what it last saw or was last told, never the live truth. The
store reads nothing of the simulator: observe.Knowledge hands it what a robot sees (`see`,
`note`) and what a message carries (`told`), and observe.observation reads it back.

Every belief carries a stamp, the moment (an episode-wide counter) its content was seen, so
a message only replaces what the receiver knows with something newer.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable
from dataclasses import dataclass, field

from mhrc.core.protocol import ObjectView


@dataclass(frozen=True)
class Belief:
    view: ObjectView
    stamp: int  # when its content was seen, by whoever saw it


@dataclass
class Beliefs:
    """One robot's memory of the objects it knows of and of the containers' open states."""

    objects: dict[str, Belief] = field(default_factory=dict)
    opened: dict[str, bool] = field(default_factory=dict)  # container -> believed open; absent: closed
    at: str | None = None  # the furniture the robot stands at, and so keeps seeing

    def is_open(self, container: str) -> bool:
        return self.opened.get(container, False)

    def see(
        self, name: str, places: Collection[str], is_open: bool | None, visible: Iterable[ObjectView], stamp: int
    ) -> None:
        """The robot looks at furniture `name` and sees whether it is open (`is_open`, None for a
        surface) and, unless it is a closed container, `visible`: what lies on or in it, that is on
        any of `places` (`name`, and for Bob's table the fixtures on it). An object it believed
        there and no longer sees there is remembered as gone from there (`last_seen_on`)."""
        if is_open is not None:
            self.opened[name] = is_open
            if not is_open:
                return  # a closed container hides what is in it: those beliefs stay as they were
        seen = {v.name: v for v in visible}
        for v in seen.values():
            self.objects[v.name] = Belief(v, stamp)
        for obj, b in list(self.objects.items()):
            if obj not in seen and b.view.on in places and b.view.held_by is None:
                gone = b.view.model_copy(
                    update={"on": None, "inside": False, "last_seen_on": b.view.on, "told_by": None}
                )
                self.objects[obj] = Belief(gone, stamp)

    def note(self, view: ObjectView, stamp: int) -> None:
        """The robot knows `view` first hand: what it holds or has just let go of."""
        self.objects[view.name] = Belief(view, stamp)

    def told(self, sender: str, other: Beliefs, names: Iterable[str]) -> list[str]:
        """A message from `sender` (whose memory is `other`) named `names`: each the sender knows of
        becomes known with the sender's belief, unless this robot already knows something newer.
        Returns the names learned or updated."""
        out = []
        for obj in names:
            theirs, mine = other.objects.get(obj), self.objects.get(obj)
            if theirs is None or (mine is not None and mine.stamp >= theirs.stamp):
                continue
            if mine is not None and theirs.view.last_seen_on not in (None, mine.view.on):
                continue  # "gone from elsewhere" says nothing against where this robot knows it to be
            self.objects[obj] = Belief(theirs.view.model_copy(update={"told_by": sender}), theirs.stamp)
            out.append(obj)
        return out
