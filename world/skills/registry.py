"""The skill registry: action type -> the function that runs it. A new skill is one function
decorated with `@skill(ActionType)` in the module of its family."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

from pydantic import BaseModel

from mhrc.core.protocol import SkillOutcome

from ..robots import RobotBody
from .context import SkillContext

A = TypeVar("A", bound=BaseModel)
Skill = Callable[[SkillContext, RobotBody, Any], SkillOutcome]

SKILLS: dict[type[BaseModel], Skill] = {}


def skill(
    action: type[A],
) -> Callable[
    [Callable[[SkillContext, RobotBody, A], SkillOutcome]], Callable[[SkillContext, RobotBody, A], SkillOutcome]
]:
    """Class of action -> decorator that registers the function running it (once per action type)."""

    def register(
        run: Callable[[SkillContext, RobotBody, A], SkillOutcome],
    ) -> Callable[[SkillContext, RobotBody, A], SkillOutcome]:
        if action in SKILLS:
            raise ValueError(
                f"{action.__name__} already runs as {SKILLS[action].__qualname__}: register one skill per action type"
            )
        SKILLS[action] = run
        return run

    return register
