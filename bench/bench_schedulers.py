"""The three schedules side by side (docs/architecture.md, "Time"): the same episodes, the same robots' minds,
the same loopback OpenAI-compatible server, measured in one run.

The server's latency differs per robot and per call: Bob 0.5 s, Alice 1.5 s, David 1.0 s, each
call drawn uniformly within +-50 % (seeded). Its replies are heuristic-scripted: each robot's
policy is the project's LLM policy (prompt built, HTTP call made, reply parsed by the paper's
parser), and the reply the server sends back is the command the heuristic policy chose on the
same observation, so the team plays well and the episodes end in success; what differs between
the schedules is only when the robots may plan and act.

Per schedule and episode: the world's wall time, the LLM calls (counted at the server), Succ,
TS, the makespan in simulated seconds and the actions per robot; then the ratios of the mean
wall times (sequential / lockstep, lockstep / async).

    python bench/bench_schedulers.py [--tasks pack_objects,sort_solids,make_sandwich] [--seeds 0] [--out FILE]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import random
import statistics
import tempfile
import threading
import time
from collections import Counter
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from report import emit

from mhrc.agents.agent import RobotAgent
from mhrc.agents.heuristic import heuristic_policy
from mhrc.agents.llm import OpenAIChatClient
from mhrc.agents.llm_policy import LLMPolicy
from mhrc.agents.policy import Decision
from mhrc.analysis.metrics import from_trace
from mhrc.core.bus import Bus, open_client
from mhrc.core.protocol import ActionResult, EpisodeDone, Observation
from mhrc.core.records import read_records
from mhrc.run.config import EpisodeConfig
from mhrc.run.serve import serve_world

LATENCY = {"bob": 0.5, "alice": 1.5, "david": 1.0}  # s per call, before jitter
JITTER = 0.5  # each call's latency is drawn uniformly in [1 - JITTER, 1 + JITTER] x the robot's
SCHEDULES = ("sequential", "lockstep", "async")


class ScriptedServer(ThreadingHTTPServer):
    """Answers each chat request with the reply its body carries, after the robot's latency."""

    def __init__(self, seed: int) -> None:
        super().__init__(("127.0.0.1", 0), _Handler)
        self.rng = random.Random(seed)
        self.lock = threading.Lock()
        self.calls: Counter[str] = Counter()
        self.slept: dict[str, list[float]] = {r: [] for r in LATENCY}

    def latency(self, robot: str) -> float:
        with self.lock:
            self.calls[robot] += 1
            t = LATENCY[robot] * self.rng.uniform(1 - JITTER, 1 + JITTER)
            self.slept[robot].append(t)
            return t


class _Handler(BaseHTTPRequestHandler):
    server: ScriptedServer

    def do_POST(self) -> None:  # noqa: N802
        body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
        script = body["mhrc_bench"]
        time.sleep(self.server.latency(script["robot"]))
        payload = json.dumps(
            {
                "choices": [{"message": {"role": "assistant", "content": script["reply"]}, "finish_reason": "stop"}],
                "usage": {"prompt_tokens": len(json.dumps(body["messages"])) // 4, "completion_tokens": 12},
            }
        ).encode()
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(payload)))
        self.end_headers()
        self.wfile.write(payload)

    def log_message(self, *args: object) -> None:
        pass


class HeuristicScripted:
    """The LLM policy of `robot`, whose model is told what to answer: the heuristic's command."""

    def __init__(self, robot: str, client: OpenAIChatClient) -> None:
        self.robot, self.name = robot, "llm (heuristic-scripted replies)"
        self.client = client
        self.heuristic = heuristic_policy(robot)
        self.llm = LLMPolicy(robot, client)
        self.mismatches = 0

    async def decide(self, obs: Observation) -> Decision:
        choice = await self.heuristic.decide(obs)
        self.client.extra_body = {"mhrc_bench": {"robot": self.robot, "reply": f"Command: {choice.action.call()}"}}
        decision = await self.llm.decide(obs)
        self.mismatches += decision.action != choice.action
        return decision

    def record(self, result: ActionResult) -> None:
        self.heuristic.record(result)
        self.llm.record(result)


async def episode(cfg: EpisodeConfig, url: str) -> tuple[EpisodeDone, int]:
    """The world and the three agents, each on its own bus session; (final event, mismatches)."""
    world = asyncio.create_task(serve_world(cfg), name="world")
    buses: list[Bus] = []
    clients: list[OpenAIChatClient] = []
    policies: list[HeuristicScripted] = []
    agents = []
    try:
        for robot in cfg.robots:
            clients.append(OpenAIChatClient("scripted", url, timeout=60.0))
            policies.append(HeuristicScripted(robot, clients[-1]))
            buses.append(await open_client(cfg.endpoint, 30.0))
            agents.append(asyncio.create_task(RobotAgent(buses[-1], policies[-1], run=cfg.run, robot=robot).run()))
        done = await world
        await asyncio.gather(*agents)
        return done, sum(p.mismatches for p in policies)
    finally:
        for task in [world, *agents]:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        for bus in buses:
            await bus.close()
        for client in clients:
            await client.aclose()


def run(task: str, seed: int, schedule: str, server: ScriptedServer, n_objects: int) -> dict[str, Any]:
    url = f"http://127.0.0.1:{server.server_address[1]}/v1"
    before = Counter(server.calls)
    with tempfile.TemporaryDirectory() as tmp:
        trace = Path(tmp) / "t.jsonl"
        cfg = EpisodeConfig.build(task=task, seed=seed, n_objects=n_objects, schedule=schedule, trace=trace).resolved()
        done, mismatches = asyncio.run(episode(cfg, url))
        m = from_trace(read_records(trace))
    calls = server.calls - before
    return {
        "task": task,
        "seed": seed,
        "schedule": schedule,
        "reason": done.reason,
        "success": m.success,
        "ts": m.temporal_steps,
        "wall_s": round(m.wall_time, 2),
        "llm_calls": sum(calls.values()),
        "llm_calls_per_robot": dict(calls),
        "makespan_s": m.makespan,
        "actions_per_robot": m.actions_per_robot,
        "busy_s": m.busy,
        "reply_mismatches": mismatches,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tasks", default="pack_objects,sort_solids,make_sandwich")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--objects", type=int, default=4)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    server = ScriptedServer(seed=0)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    rows = []
    try:
        for task in args.tasks.split(","):
            for seed in (int(s) for s in args.seeds.split(",")):
                for schedule in SCHEDULES:  # interleaved: a drift of the machine touches all three alike
                    rows.append(run(task, seed, schedule, server, args.objects))
                    r = rows[-1]
                    print(
                        f"{task} seed {seed} {schedule:<10} {r['reason']:<8} TS {r['ts']:>3} wall {r['wall_s']:>7.2f} s  calls {r['llm_calls']}",
                        flush=True,
                    )
    finally:
        server.shutdown()
        server.server_close()
    per = {}
    for s in SCHEDULES:
        mine = [r for r in rows if r["schedule"] == s]
        per[s] = {
            "episodes": len(mine),
            "succ": statistics.fmean(r["success"] for r in mine),
            "ts": statistics.fmean(r["ts"] for r in mine),
            "wall_s": round(statistics.fmean(r["wall_s"] for r in mine), 2),
            "llm_calls": statistics.fmean(r["llm_calls"] for r in mine),
            "makespan_s": round(statistics.fmean(r["makespan_s"] for r in mine), 1),
        }
    slept = {
        r: {
            "calls": len(v),
            "mean_s": round(statistics.fmean(v), 3),
            "min_s": round(min(v), 3),
            "max_s": round(max(v), 3),
        }
        for r, v in server.slept.items()
        if v
    }
    emit(
        {
            "bench": "schedulers",
            "latency_s": LATENCY,
            "jitter": JITTER,
            "measured_latency": slept,
            "objects": args.objects,
            "summary": per,
            "lockstep_speedup_over_sequential": round(per["sequential"]["wall_s"] / per["lockstep"]["wall_s"], 2),
            "async_speedup_over_lockstep": round(per["lockstep"]["wall_s"] / per["async"]["wall_s"], 2),
            "episodes": rows,
            "note": "wall_s is the world's measure of each episode; every schedule ran the same episodes against the same server",
        },
        args.out,
    )


if __name__ == "__main__":
    from mhrc.core import logs

    logs.configure()
    main()
