"""What a skill may use, and nothing more: the physical world (PyBullet client, scene, robots,
objects, containers), each robot's knowledge, the episode's motion noise (its rates and its
random stream) and the aids that shape the feedback.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mhrc.core.protocol import MotionNoise

from ..observe import Knowledge
from ..physics import ObjectState, PhysicalWorld
from ..robots import RobotBody


@dataclass(frozen=True)
class SkillContext:
    """The narrow view of one episode a skill acts through (see the package docstring)."""

    world: PhysicalWorld
    knowledge: Knowledge
    rng: np.random.Generator  # motion noise: its own stream, apart from the task generator's
    noise: MotionNoise  # its rates (mhrc.core.fidelity.motion_noise): none with --noise off or the exact_motion aid

    @property
    def aids(self) -> frozenset[str]:
        return self.world.aids

    @property
    def advice(self) -> bool:
        """Whether failed actions' feedback may say what to do next (the feedback_advice aid; not the paper's)."""
        return "feedback_advice" in self.world.aids

    def motion_error(self, slip_p: float, slip: tuple[float, float], sigma: float) -> tuple[float, float]:
        """One draw from the motion noise: with chance `slip_p` a slip of a length in `slip`, else a
        small error (Rayleigh, scale `sigma`), in a uniform direction; none, and nothing drawn, when
        the episode has no noise (--noise off, the exact_motion aid)."""
        if self.noise.setting == "off":
            return 0.0, 0.0
        slipped, size, heading = self.rng.random(3)
        if slipped < slip_p:
            dist = slip[0] + (slip[1] - slip[0]) * size
        else:
            dist = sigma * math.sqrt(-2.0 * math.log1p(-size))
        return dist * math.cos(2 * math.pi * heading), dist * math.sin(2 * math.pi * heading)

    def grasp(self, r: RobotBody, obj: ObjectState) -> None:
        """`r` grips `obj`, and knows it holds it."""
        self.world.grasp(r, obj)
        self.knowledge.holds(r.name, obj)
