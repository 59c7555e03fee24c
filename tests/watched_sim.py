"""A test's stand-in for the world's simulator: the real one (`EpisodeConfig.sim`), with a hook after
each action it executes and each message it carries. Injected as `world_on_loopback`'s
`simulator` (``mhrc_world(simulator=watched(after))``), as httpx's MockTransport is injected: the
world's own code runs unchanged, nothing of it is patched."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from mhrc.core.protocol import Action, Communicate, SkillOutcome
from mhrc.run.config import EpisodeConfig
from mhrc.world.sim import Sim

After = Callable[[str, Action, SkillOutcome], None]  # (robot, action, outcome), in the simulator's thread


class WatchedSim:
    """`sim` as it is, but `after(robot, action, outcome)` runs once each action executed (a message:
    once the world handed it to the simulator to be told, as sent)."""

    def __init__(self, sim: Sim, after: After) -> None:
        self._sim, self._after = sim, after

    def __getattr__(self, name: str) -> Any:
        return getattr(self._sim, name)

    def execute(self, robot: str, action: Action) -> SkillOutcome:
        outcome = self._sim.execute(robot, action)
        self._after(robot, action, outcome)
        return outcome

    def message(self, receiver: str, sender: str, text: str) -> Callable[[], None]:
        tells = self._sim.message(receiver, sender, text)
        self._after(sender, Communicate(content=text, to=receiver), SkillOutcome.ok("sent"))
        return tells


def watched(after: After) -> Callable[[EpisodeConfig], WatchedSim]:
    """The `simulator` argument that builds the configuration's real simulator, watched by `after`."""
    return lambda cfg: WatchedSim(cfg.sim(), after)
