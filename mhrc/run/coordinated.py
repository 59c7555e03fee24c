"""A coordination protocol's side of the assembly: the policies of the robots one participant
drives, as the episode's protocol builds them (mhrc.agents.protocols). The paper's protocol
builds none: each robot's agent makes its own policy, as it always did."""

from __future__ import annotations

from collections.abc import Mapping

from mhrc.agents.policy import Policy
from mhrc.agents.protocols import Seating
from mhrc.run.config import EpisodeConfig


def seat(cfg: EpisodeConfig, robots: tuple[str, ...]) -> Mapping[str, Policy]:
    """robot -> its policy under `cfg`'s protocol, for the `robots` this participant drives
    (empty for the paper's protocol); ConfigError (--protocol) when the protocol refuses them."""
    p = cfg.coordination()
    if p.build is None:
        return {}
    from mhrc.run.config import ProtocolConfigError

    refused = p.refusal(cfg.team, robots=robots if p.whole_team else None)
    if refused is not None:
        raise ProtocolConfigError(f"--protocol: {refused}", refused.code)
    return p.build(Seating(team=cfg.team, robots=robots, schedule=cfg.schedule))
