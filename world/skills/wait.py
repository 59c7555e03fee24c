"""The skill that does nothing for a second."""

from __future__ import annotations

from mhrc.core.protocol import SkillOutcome, Wait

from .. import feedback as fb
from ..robots import RobotBody
from .context import SkillContext
from .registry import skill


@skill(Wait)
def wait(ctx: SkillContext, r: RobotBody, a: Wait) -> SkillOutcome:
    return SkillOutcome.ok(fb.waited(), sim_time=1.0)
