"""The world's time policies (DESIGN.md, "Time"), one module each behind `Scheduler`,
registered by name for `WorldConfig.schedule`."""

from __future__ import annotations

from .base import Executed, Scheduler, TaskResultLike, World
from .lockstep import LockstepScheduler
from .sequential import SequentialScheduler

SCHEDULERS: dict[str, type[Scheduler]] = {"sequential": SequentialScheduler, "lockstep": LockstepScheduler}


class UnknownScheduler(ValueError):
    """A schedule name no scheduler is registered under."""


def make_scheduler(name: str, world: World) -> Scheduler:
    """The scheduler registered as `name`, driving `world`."""
    try:
        cls = SCHEDULERS[name]
    except KeyError:
        known = ", ".join(sorted(SCHEDULERS))
        raise UnknownScheduler(f"unknown schedule {name!r}: choose one of the known schedulers ({known})") from None
    return cls(world)


__all__ = ["SCHEDULERS", "Executed", "LockstepScheduler", "Scheduler", "SequentialScheduler", "TaskResultLike", "UnknownScheduler", "World", "make_scheduler"]
