"""The world's time policies (docs/architecture.md, "Time"), one module each behind `Scheduler`,
registered by name for `WorldConfig.schedule`."""

from __future__ import annotations

from .asynchronous import STEP_SECONDS, AsyncScheduler
from .base import Executed, Scheduler, SchedulerOptionError, TaskResultLike, World
from .lockstep import LockstepScheduler
from .sequential import SequentialScheduler

SCHEDULERS: dict[str, type[Scheduler]] = {
    "sequential": SequentialScheduler,
    "lockstep": LockstepScheduler,
    "async": AsyncScheduler,
}


class UnknownScheduler(ValueError):
    """A schedule name no scheduler is registered under."""


def make_scheduler(name: str, world: World, *, time_scale: float = 0.0) -> Scheduler:
    """The scheduler registered as `name`, driving `world` (SchedulerOptionError for a bad option)."""
    try:
        cls = SCHEDULERS[name]
    except KeyError:
        known = ", ".join(sorted(SCHEDULERS))
        raise UnknownScheduler(f"unknown schedule {name!r}: choose one of the known schedulers ({known})") from None
    return cls(world, time_scale=time_scale)


__all__ = [
    "SCHEDULERS",
    "STEP_SECONDS",
    "AsyncScheduler",
    "Executed",
    "SchedulerOptionError",
    "LockstepScheduler",
    "Scheduler",
    "SequentialScheduler",
    "TaskResultLike",
    "UnknownScheduler",
    "World",
    "make_scheduler",
]
