"""The skills: one function per action type, found by `SKILLS[type(action)]`.

Each takes a `SkillContext` (the physical world, each robot's knowledge, the motion noise and
the aids: not the whole simulator), the acting robot and the action; it runs the real planners
(A* for bases; IK and OMPL BIT* for arms), executes the result kinematically and returns a
`SkillOutcome` whose sentence comes from `feedback`. Bad arguments are failures, never
exceptions.

By default motion is not exact: a base stops where seeded noise puts it, off target now and
then, and a released object falls from a seeded error and settles under PyBullet physics, so
navigation can end off target and a placed object can miss its goal, as in Table III (the
noise's rates are mhrc's calibration: mhrc.core.fidelity). `--noise off` removes the noise, not
the physics; the exact_motion aid removes both. Only a robot kind that finishes the task (Bob) places on the task's goal fixtures.

Families, one module each: navigation (navigate, move), containers (open), manipulation (pick,
place) on the shared arm motions of reaching, and wait. A new skill is one function decorated
with `@skill(ActionType)` in its family's module (registry.py).
"""

from __future__ import annotations

from . import containers, manipulation, navigation, wait  # each registers its skills
from .context import SkillContext
from .registry import SKILLS, Skill, skill

__all__ = ["SKILLS", "Skill", "SkillContext", "containers", "manipulation", "navigation", "skill", "wait"]
