"""The world's schedulers by name, in their registry's order (mhrc.world.schedulers.SCHEDULERS, a
test keeps the two equal): the configuration and the command line check `--schedule` against
these without importing the schedulers (nor asyncio with them)."""

from __future__ import annotations

SCHEDULES = ("sequential", "lockstep", "async")  # sequential is the paper's
