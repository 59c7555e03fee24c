"""The arm planner's shadow client (a p.DIRECT client with one Panda and copies of the scene's fixed
bodies), kept between the episodes of one process.

Building one is a fifth of a world's build (a client, pybullet_data's Panda, twenty-odd furniture
URDFs, and a second Panda for the other arm): an eval worker built it afresh for each of hundreds
of episodes in the same three layouts. Now `ArmPlanner.close` hands its client back here and the
next planner for the same fixed bodies (the same files' contents at the same poses) takes it:

- what an episode added goes: its obstacle boxes are removed, the other arms' Pandas are hidden
  and kept as spares for the next episode's other arms (a spare's pose and joints are set before
  it is used, as a new one's are), and every furniture joint it moved is set back;
- the arm is parked far from everything and collision detection runs until the broadphase has
  let go of every pair an episode left (a new client has none), so the next episode's first check
  meets the furniture as it would in a new client.

A planner takes its client whole: the one it hands back forgets it first (its `cid` is -1), so a
skill still running on a closed world fails on its next call, as it did on a disconnected client,
instead of moving the next episode's arm. At most `IDLE` clients wait; more are disconnected.
"""

from __future__ import annotations

import hashlib
import shutil
import tempfile
import threading
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from mhrc.world.quiet import pybullet as p  # no C banner on stdout

from .scene import StaticBody, load_statics

IDLE = 2  # clients kept waiting in one process (about 25 MB each; an eval worker meets its grid one task and scene at a time)
_FAR = (0.0, 0.0, 50.0)  # where the arm waits between episodes: above everything
_HIDDEN = (0.0, 0.0, -50.0)  # where hidden obstacles wait (the arm's filter group never meets them there)
_FLUSH = 24  # collision detections that clear the broadphase's pairs once nothing overlaps (it cleans them a tenth at a time)


def statics_key(statics: list[StaticBody]) -> tuple[tuple[str, str, tuple[float, float, float], float], ...]:
    """What a shadow client's fixed bodies are: each one's name, file contents, pose (a layout's
    assets are written to a new directory for every world, so the path alone says nothing)."""
    return tuple(
        (s.name, hashlib.sha1(Path(s.path).read_bytes()).hexdigest(), tuple(s.position), s.yaw)  # type: ignore[misc]
        for s in statics
    )


@dataclass(eq=False)
class Shadow:
    """One planning client and the bodies that outlive an episode in it."""

    cid: int
    panda: str  # the shadow Panda's URDF (a temporary file of this client's)
    arm: int
    bodies: dict[str, int]  # static name -> body id
    key: tuple[object, ...]
    spares: list[int] = field(default_factory=list)  # hidden Pandas an episode's other arms may take
    moved: dict[tuple[int, int], float] = field(default_factory=dict)  # (body, joint) -> its value when loaded
    _remove_tmp: weakref.finalize | None = None  # type: ignore[type-arg]

    @classmethod
    def build(
        cls, statics: list[StaticBody], key: tuple[object, ...], panda_urdf: str, setup: Callable[[Shadow], None]
    ) -> Shadow:
        """A new client: the arm from `panda_urdf` (text), the fixed bodies (`key`: their
        `statics_key`); `setup(shadow)` sets the collision filters (ArmPlanner's)."""
        cid = p.connect(p.DIRECT)
        tmp = tempfile.mkdtemp(prefix="mhrc-planner-")
        panda = str(Path(tmp) / "panda.urdf")  # every Panda of this client: the arm and the other arms
        Path(panda).write_text(panda_urdf, encoding="utf-8")
        arm = p.loadURDF(panda, useFixedBase=True, physicsClientId=cid)
        shadow = cls(cid, panda, arm, load_statics(cid, statics), key)
        shadow._remove_tmp = weakref.finalize(shadow, shutil.rmtree, tmp, True)
        setup(shadow)
        return shadow

    def note_joint(self, body: int, joint: int) -> None:
        """Remember a furniture joint's value as loaded, before an episode first moves it."""
        if (body, joint) not in self.moved:
            self.moved[(body, joint)] = p.getJointState(body, joint, physicsClientId=self.cid)[0]

    def clear(self, boxes: list[int], other_arms: list[int]) -> None:
        """Undo an episode: see the module's docstring."""
        cid = self.cid
        for body in boxes:
            p.removeBody(body, physicsClientId=cid)
        for body in other_arms:
            p.resetBasePositionAndOrientation(body, _HIDDEN, (0, 0, 0, 1), physicsClientId=cid)
        self.spares.extend(other_arms)
        for (body, joint), value in self.moved.items():
            p.resetJointState(body, joint, value, physicsClientId=cid)
        self.moved.clear()
        p.resetBasePositionAndOrientation(self.arm, _FAR, (0, 0, 0, 1), physicsClientId=cid)
        for _ in range(_FLUSH):
            p.performCollisionDetection(physicsClientId=cid)

    def close(self) -> None:
        if self.cid >= 0:
            p.disconnect(self.cid)
            self.cid = -1
        if self._remove_tmp is not None:
            self._remove_tmp()


class ShadowPool:
    """Idle shadow clients, each with its fixed bodies' `statics_key`, the oldest disconnected first."""

    def __init__(self, idle: int = IDLE) -> None:
        self.idle = idle
        self._lock = threading.Lock()
        self._waiting: list[Shadow] = []  # oldest first

    def take(self, key: tuple[object, ...]) -> Shadow | None:
        """A waiting client whose fixed bodies have this `statics_key`, if any."""
        with self._lock:
            for shadow in self._waiting:
                if shadow.key == key:
                    self._waiting.remove(shadow)
                    return shadow
        return None

    def give(self, shadow: Shadow, boxes: list[int], other_arms: list[int]) -> None:
        """Take back a client its planner has let go of (its episode's boxes and other arms)."""
        try:
            shadow.clear(boxes, other_arms)
        except p.error:  # disconnected meanwhile (a process shutting down): nothing to keep
            shadow.close()
            return
        with self._lock:
            self._waiting.append(shadow)
            extra = self._waiting[: max(0, len(self._waiting) - self.idle)]
            del self._waiting[: len(extra)]
        for s in extra:
            s.close()

    def __len__(self) -> int:
        return len(self._waiting)

    def close(self) -> None:
        """Disconnect every waiting client."""
        with self._lock:
            waiting, self._waiting = self._waiting, []
        for s in waiting:
            s.close()


POOL = ShadowPool()
