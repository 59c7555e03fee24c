"""A coordination protocol's side of the assembly: the policies of the robots one participant
drives, as the episode's protocol builds them (mhrc.agents.protocols). The paper's protocol
builds none: each robot's agent makes its own policy, as it always did."""

from __future__ import annotations

import asyncio
from collections.abc import Mapping
from typing import TYPE_CHECKING

from mhrc.agents.policy import Policy
from mhrc.agents.protocols import CoordinationProtocol, Seating
from mhrc.core.bus import open_client
from mhrc.core.protocol import EpisodeDone
from mhrc.run.config import EpisodeConfig

if TYPE_CHECKING:
    from mhrc.core.security import Credentials


def check_seating(cfg: EpisodeConfig, robots: tuple[str, ...]) -> CoordinationProtocol:
    """`cfg`'s protocol, once it is known to seat the `robots` one participant drives (a
    whole-team protocol: every robot of the team); ProtocolConfigError (--protocol, with the
    refusal's code) otherwise. What `seat` checks, said before anything starts."""
    from mhrc.run.config import ProtocolConfigError

    p = cfg.coordination()
    refused = p.refusal(cfg.team, robots=robots if p.whole_team else None, episode=cfg.robots)
    if refused is not None:
        raise ProtocolConfigError(f"--protocol: {refused}", refused.code)
    return p


def seat(
    cfg: EpisodeConfig, robots: tuple[str, ...], specs: Mapping[str, str | None] | None = None
) -> Mapping[str, Policy]:
    """robot -> its policy under `cfg`'s protocol, for the `robots` this participant drives
    (empty for the paper's protocol); ConfigError (--protocol) when the protocol refuses them.
    `specs`: each robot's model spec as served (a gguf: file's local server), default `cfg`'s;
    a protocol's LLM form uses the first robot's."""
    p = check_seating(cfg, robots)
    if p.build is None:
        return {}
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


async def close_seats(seats: Mapping[str, Policy]) -> None:
    """Await each seated policy's `aclose`, where it has one (the protocols' LLM forms close their
    model clients), once the episode is over."""
    for policy in seats.values():
        close = getattr(policy, "aclose", None)
        if close is not None:
            await close()


async def attach_seated(
    cfg: EpisodeConfig,
    robots: tuple[str, ...],
    connect: str,
    run: str | None,
    attach_timeout: float,
    security: Mapping[str, Credentials | None],
) -> EpisodeDone | None:
    """`mhrc agent --protocol NAME`: the agents of `robots` in this process, each with its own
    session and login (`security[robot]`), driving the policies `cfg`'s protocol seats for them
    (the seats of one planner under a whole-team protocol); the run is the credentials' run, or
    the only world alive. The first robot's end, as `attach_agent` returns it."""
    from mhrc.run.attach import find_run, local_models, run_agent

    logins = [c for c in security.values() if c is not None]
    if run is None and logins:
        run = logins[0].run
    if run is None:
        bus = await open_client(connect, attach_timeout)
        try:
            run = await find_run(bus)
        finally:
            await bus.close()
    own = cfg.robot_specs()
    async with local_models({r: own[r] for r in robots}, cfg.llm_seed) as specs:
        seats = seat(cfg, robots, specs)
        try:
            ends = await asyncio.gather(
                *(
                    run_agent(
                        r,
                        run,
                        connect,
                        llm=specs[r],
                        base_url=cfg.base_url,
                        client_options=cfg.client_options(own[r]),
                        attach_timeout=attach_timeout,
                        security=security.get(r),
                        policy=seats.get(r),
                        **cfg.policy_options(own[r]),
                    )
                    for r in robots
                )
            )
        finally:
            await close_seats(seats)
    return ends[0]
