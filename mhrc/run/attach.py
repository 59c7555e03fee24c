"""An agent's side of an episode: attach one robot's policy (heuristic, an LLM, a replay) to a
world, and serve the in-process gguf: models its robots need."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator, Callable
from typing import TYPE_CHECKING, Unpack

from mhrc.core.bus import Bus
from mhrc.core.logs import get_logger
from mhrc.core.polling import poll
from mhrc.core.protocol import EpisodeDone

if TYPE_CHECKING:
    from mhrc.agents.llm.openai_client import ClientOptions
    from mhrc.agents.llm_policy import PolicyOptions
    from mhrc.core.security import Credentials

from mhrc.agents.agent import RobotAgent
from mhrc.agents.heuristic import heuristic_policy
from mhrc.agents.policy import Policy
from mhrc.core.bus import open_client
from mhrc.core.deadlines import ATTACH_TIMEOUT
from mhrc.run.config import ConfigError

log = get_logger("mhrc.run.attach")


async def run_agent(
    robot: str,
    run: str,
    connect: str,
    *,
    llm: str | None = None,
    base_url: str | None = None,
    client_options: ClientOptions | None = None,
    attach_timeout: float = ATTACH_TIMEOUT,
    security: Credentials | None = None,
    on_error: Callable[[BaseException], None] | None = None,
    policy: Policy | None = None,
    session_of: Bus | None = None,
    **policy_options: Unpack[PolicyOptions],
) -> EpisodeDone | None:
    """Attach an agent for `robot` to the world at `connect` and play until the episode ends:
    `policy` when given (a coordination protocol's: mhrc.agents.protocols), else the heuristic
    policy, or with `llm` (one robot's spec) an LLMPolicy on that model. A
    `gguf:PATH` spec gets a one-slot local server of its own for as long as the agent runs.
    `on_error` hears an error that ends the agent while its session is still open: before the
    world sees the robot vanish. With `session_of` (a Bus of this process that logs in as this
    agent would), the agent shares its session (Bus.share) instead of connecting to `connect`."""

    if security is not None:
        from mhrc.core.security import check_for

        check_for(security, run=run, user=robot)
    async with contextlib.AsyncExitStack() as stack:
        if policy is not None:
            pass
        elif llm is None:
            policy = heuristic_policy(robot)
        else:  # a model's policy: its modules (and httpx) are imported only for it
            from mhrc.agents.llm import make_client
            from mhrc.agents.llm_policy import LLMPolicy
            from mhrc.agents.replay import ReplayClient

            if llm.startswith("replay:"):
                policy = LLMPolicy(robot, ReplayClient(llm.removeprefix("replay:"), robot), **policy_options)  # type: ignore[assignment]
            else:
                if llm.startswith("gguf:"):
                    served = await stack.enter_async_context(
                        local_models({robot: llm}, (client_options or {}).get("seed"))
                    )
                    llm = served[robot] or llm  # the spec of the server now serving the file
                client = make_client(llm, base_url=base_url, **(client_options or {}))
                stack.push_async_callback(client.aclose)
                policy = LLMPolicy(robot, client, **policy_options)  # type: ignore[assignment]
        bus = (
            session_of.share()
            if session_of is not None
            else await open_client(connect, attach_timeout, security=security)
        )
        try:
            agent = RobotAgent(
                bus,
                policy,
                run=run,
                robot=robot,
                attach_timeout=attach_timeout,
                endpoint=connect,  # type: ignore[arg-type]
                security=security,
            )
            return await agent.run()
        except Exception as exc:
            if on_error is not None:
                on_error(exc)
            raise
        finally:
            await bus.close()


@contextlib.asynccontextmanager
async def local_models(specs: dict[str, str | None], seed: int | None = None) -> AsyncIterator[dict[str, str | None]]:
    """Serve every `gguf:PATH` spec in-process (mhrc.agents.llm.local): one llama.cpp server per
    model file with one slot per robot on it, so the robots decode in parallel; yields the specs
    with each gguf one replaced by `llamacpp:MODEL@URL` of its server. The servers stop on exit."""
    paths = sorted({s.removeprefix("gguf:") for s in specs.values() if s and s.startswith("gguf:")})
    if not paths:
        yield specs
        return

    from mhrc.agents.llm.local import LocalModelServer

    async with contextlib.AsyncExitStack() as stack:
        served: dict[str, str] = {}
        for path in paths:
            slots = sum(1 for s in specs.values() if s == f"gguf:{path}")
            server = await stack.enter_async_context(LocalModelServer(path, slots=slots, seed=seed))
            served[path] = f"llamacpp:{server.model}@{server.base_url}"
            log.info("local model serving", path=path, slots=slots, url=server.base_url)
        yield {r: served[s.removeprefix("gguf:")] if s and s.startswith("gguf:") else s for r, s in specs.items()}


async def find_run(bus: Bus, timeout: float = 5.0) -> str:
    """The run id of the only world alive on this bus (raises if there is none or several).

    Asks again for a while: a freshly connected session may not see the tokens at once."""

    async def worlds() -> list[str] | None:
        return sorted({key.split("/")[1] for key in await bus.alive("mhrc/*/alive/world", timeout=1.0)}) or None

    runs = await poll(worlds, timeout=timeout, every=0.3) or []
    if len(runs) != 1:
        found = ", ".join(runs) if runs else "none"
        raise ConfigError(f"pass --run: expected exactly one world on the bus, found {found}")
    return runs[0]


async def attach_agent(
    robot: str,
    connect: str,
    run: str | None,
    attach_timeout: float = ATTACH_TIMEOUT,
    llm: str | None = None,
    base_url: str | None = None,
    client_options: ClientOptions | None = None,
    security: Credentials | None = None,
    **policy_options: Unpack[PolicyOptions],
) -> EpisodeDone | None:
    """`mhrc agent`: find the run if not given (the credentials' run, or the only world alive),
    then play `robot` (heuristic policy, or `llm`)."""
    if run is None and security is not None:
        run = security.run
    if run is None:
        bus = await open_client(connect, attach_timeout)
        try:
            run = await find_run(bus)
        finally:
            await bus.close()
    return await run_agent(
        robot,
        run,
        connect,
        llm=llm,
        base_url=base_url,
        client_options=client_options,
        attach_timeout=attach_timeout,
        security=security,
        **policy_options,
    )
