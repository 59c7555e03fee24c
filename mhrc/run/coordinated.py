"""A coordination protocol's side of the assembly: the policies of the robots one participant
drives, as the episode's protocol builds them (mhrc.agents.protocols). The paper's protocol
builds none: each robot's agent makes its own policy, as it always did."""

from __future__ import annotations

from collections.abc import Mapping

from mhrc.agents.policy import Policy
from mhrc.agents.protocols import Seating
from mhrc.run.config import EpisodeConfig


def seat(
    cfg: EpisodeConfig, robots: tuple[str, ...], specs: Mapping[str, str | None] | None = None
) -> Mapping[str, Policy]:
    """robot -> its policy under `cfg`'s protocol, for the `robots` this participant drives
    (empty for the paper's protocol); ConfigError (--protocol) when the protocol refuses them.
    `specs`: each robot's model spec as served (a gguf: file's local server), default `cfg`'s;
    a protocol's LLM form uses the first robot's."""
    p = cfg.coordination()
    if p.build is None:
        return {}
    from mhrc.run.config import ProtocolConfigError

    refused = p.refusal(cfg.team, robots=robots if p.whole_team else None)
    if refused is not None:
        raise ProtocolConfigError(f"--protocol: {refused}", refused.code)
    own = cfg.robot_specs()
    served = dict(specs) if specs is not None else own
    model = served.get(robots[0]) if robots else None
    options = cfg.client_options(own.get(robots[0])) if model is not None else {}
    return p.build(
        Seating(
            team=cfg.team,
            robots=robots,
            schedule=cfg.schedule,
            model=model,
            base_url=cfg.base_url,
            client_options=options,
            structured=cfg.structured,
        )
    )
