"""Coordination protocols' model cost by team size (issue 45, DynaHMRC's argument as numbers):
for each protocol with an LLM form and each team size from 2 to 8, the model calls per tick and
the prompt tokens per call, against the scripted model server (fixed replies: every robot waits),
on real PyBullet and a real Zenoh bus, in one run.

The teams are the first N robots of the shipped `full_house` (alice, bob, carol, frank, david,
erin, lucy, mia: two robots are the smallest team that can finish a task). Every robot waits, so
the episode runs to its horizon and every tick is a decision round; what grows with the team is
what the prompts show (the robots, their scene graphs, their messages). Tokens are estimated as
the client estimates them for servers that report no usage (four characters a token,
`mhrc.agents.llm.estimate_tokens`), from the prompt text the model was sent.

    python bench/bench_protocol_scaling.py [--sizes 2-8] [--protocols mhrc,centralized,...]
                                           [--horizon 4] [--schedule lockstep]
                                           [--out bench/results/protocol_scaling.json]
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from report import emit, int_range

from mhrc.agents.llm import estimate_tokens
from mhrc.agents.protocols import PROTOCOLS
from mhrc.core.team import TeamSpec
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.testing import ScriptedModelServer
from mhrc.world.teams import SHIPPED

TEAM = SHIPPED["full_house"]
EPISODE = {"task": "pack_objects", "scene": "kitchen", "seed": 0, "n_objects": 3}


def _prompt(body: dict[str, Any]) -> str:
    return "\n\n".join(str(m.get("content", "")) for m in body.get("messages", []))


def _reply(protocol: str, robots: list[str]) -> str:
    """Every robot waits, in the protocol's own reply format."""
    if protocol == "centralized":
        return "\n".join(f"{r}: wait()" for r in robots)
    return "Analysis: nothing to do yet.\nCommand: wait()"


async def _one(protocol: str, size: int, horizon: int, schedule: str) -> dict[str, Any]:
    robots = [r.name for r in TEAM.robots[:size]]
    team = TeamSpec(name=f"full_house_{size}", robots=TEAM.robots[:size])
    server = ScriptedModelServer(lambda body: _reply(protocol, robots), when_done=None)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            cfg = EpisodeConfig.build(
                protocol=protocol,
                team=team,
                horizon=horizon,
                schedule=schedule,
                llm="openai:scripted",
                base_url=server.url,
                trace=Path(tmp) / "t.jsonl",
                **EPISODE,
            )
            started = time.perf_counter()
            done = await asyncio.wait_for(up_in_process(cfg.resolved()), 600)
            wall = time.perf_counter() - started
    finally:
        server.close()
    tokens = [estimate_tokens(_prompt(body)) for body in server.requests]
    ticks = horizon
    return {
        "protocol": protocol,
        "team_size": size,
        "robots": robots,
        "ticks": ticks,
        "reason": done.reason,
        "calls": len(server.requests),
        "calls_per_tick": round(len(server.requests) / ticks, 3),
        "prompt_tokens_per_call": round(statistics.mean(tokens), 1) if tokens else None,
        "prompt_tokens_max": max(tokens) if tokens else None,
        "prompt_tokens_per_tick": round(sum(tokens) / ticks, 1),
        "wall_s": round(wall, 2),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="2-8", help="team sizes (2 to 8): '2-8', '3,8'")
    llm = [name for name, p in PROTOCOLS.items() if "llm" in p.forms]
    ap.add_argument("--protocols", default=",".join(llm), help=f"protocols with an LLM form (default: {','.join(llm)})")
    ap.add_argument("--horizon", type=int, default=4, help="ticks per episode (every robot waits, so all of them run)")
    ap.add_argument("--schedule", default="lockstep", choices=("lockstep", "sequential", "async"))
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    sizes = int_range(args.sizes)
    if not all(2 <= n <= len(TEAM.robots) for n in sizes):
        ap.error(f"--sizes: team sizes run from 2 to {len(TEAM.robots)}")
    protocols = args.protocols.split(",")
    unknown = [p for p in protocols if p not in llm]
    if unknown:
        ap.error(f"--protocols: {', '.join(unknown)} has no LLM form; the protocols with one: {', '.join(llm)}")
    rows = []
    for protocol in protocols:
        for size in sizes:
            rows.append(asyncio.run(_one(protocol, size, args.horizon, args.schedule)))
            print(
                f"{protocol} x{size}: {rows[-1]['calls_per_tick']} calls/tick, "
                f"{rows[-1]['prompt_tokens_per_call']} prompt tokens/call",
                flush=True,
            )
    emit(
        {
            "benchmark": "protocol_scaling",
            "episode": EPISODE,
            "schedule": args.schedule,
            "horizon": args.horizon,
            "team": "the first N robots of full_house",
            "tokens": "estimated, four characters a token (mhrc.agents.llm.estimate_tokens)",
            "rows": rows,
        },
        args.out,
    )


if __name__ == "__main__":
    main()
