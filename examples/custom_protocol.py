"""A coordination protocol of your own, registered and run (docs/protocols.md, "Writing a protocol").

`follow_the_finisher`: every robot decides with the paper's expert, and the team names the
finisher (the robot that can pick but not navigate: the arm) its leader, so each robot's thought
says whom it follows and the report's coordination section shows it. It is small on purpose: the
parts a protocol is made of are all here.

- `build(seating)` returns a `Policy` for each robot this participant drives (`seating.robots`);
  the team (`seating.team`) says who is who.
- A policy sees only what its robot's agent hands it: the robot's observation, the results of its
  own actions and the messages it received. It never reads the world's state.
- `Decision.coordination` is what the report and the Rerun recording show.

    python examples/custom_protocol.py [--scene bathroom] [--objects 3] [--out DIR]

It runs one episode in this process (real PyBullet, a real Zenoh bus on loopback), writes its
trace and report to DIR and prints the metrics.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
from collections.abc import Mapping
from pathlib import Path

from mhrc.agents.heuristic import heuristic_policy
from mhrc.agents.policy import Decision, Policy
from mhrc.agents.protocols import PROTOCOLS, CoordinationProtocol, Seating, register
from mhrc.core.protocol import ActionResult, Coordination, Observation


@dataclasses.dataclass
class Follower:
    """The paper's expert for one robot, its decisions labelled with the leader it follows."""

    robot: str
    leader: str
    expert: Policy
    name: str = "follow_the_finisher"

    async def decide(self, obs: Observation) -> Decision:
        decision = await self.expert.decide(obs)
        return dataclasses.replace(decision, coordination=Coordination(leader=self.leader))

    def record(self, result: ActionResult) -> None:
        self.expert.record(result)


def build(seating: Seating) -> Mapping[str, Policy]:
    """One follower for each robot this participant drives; the finisher is the team's arm."""
    kinds = seating.team.kinds
    finisher = next(r for r, kind in kinds.items() if kind == "tabletop_arm")
    return {r: Follower(r, finisher, heuristic_policy(r)) for r in seating.robots}


if "follow_the_finisher" not in PROTOCOLS:  # importing this file twice registers it once
    register(
        CoordinationProtocol("follow_the_finisher", "the paper's experts, the finisher named the leader", build=build)
    )


async def main(scene: str, objects: int, out: Path) -> None:
    from mhrc.run.config import EpisodeConfig
    from mhrc.run.inprocess import up_in_process
    from mhrc.viewer.load import load_trace
    from mhrc.viewer.model import build_view
    from mhrc.viewer.page import render_page

    out.mkdir(parents=True, exist_ok=True)
    cfg = EpisodeConfig.build(
        protocol="follow_the_finisher",
        task="pack_objects",
        scene=scene,
        n_objects=objects,
        seed=0,
        horizon=50,
        trace=out / "trace.jsonl",
    ).resolved()
    done = await up_in_process(cfg)
    report = out / "report.html"
    report.write_text(render_page(build_view(load_trace(out / "trace.jsonl"))), encoding="utf-8")
    m = done.metrics
    print(f"follow_the_finisher: success={m.success} placed={m.placed}/{m.total} TS={m.temporal_steps}")
    print(f"trace {out / 'trace.jsonl'}, report {report}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="bathroom")
    ap.add_argument("--objects", type=int, default=3)
    ap.add_argument("--out", type=Path, default=Path("runs/follow_the_finisher"))
    args = ap.parse_args()
    asyncio.run(main(args.scene, args.objects, args.out))
