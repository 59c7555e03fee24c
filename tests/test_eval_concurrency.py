"""`mhrc eval` with a worker that runs several episodes at once (`--concurrency`): real worker
processes (mhrc.eval.pool), real Zenoh buses on loopback, real worlds, and LLM agents against a scripted
OpenAI-compatible server on loopback (`mhrc.testing.ScriptedModelServer`)."""

from __future__ import annotations

import asyncio
import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from mhrc.eval.engine import EvalSpec, evaluate
from mhrc.run.config import ConfigError
from mhrc.testing import ScriptedModelServer

LATENCY = 0.3  # s the scripted model takes per reply: long enough for episodes to overlap at the server


def _rows(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in (path / "episodes.jsonl").read_text().splitlines()]


class SlowModel:
    """A model that always waits, answering after LATENCY seconds; the server records the order in
    which its requests start and end (`ModelCall.started`, `ended`), and each request tells the
    episode it came from: Bob's prompt lists the episode's objects, and every episode of the grid
    has another number of them."""

    def __init__(self) -> None:
        self.server = ScriptedModelServer(lambda body: "Analysis: nothing to do yet.\nCommand: wait()", latency=LATENCY)
        self.url = self.server.url

    @staticmethod
    def episode_of(body: dict[str, Any]) -> int:
        """The number of objects in Bob's list; 0 for Alice's and David's prompts."""
        listed = re.search(r" The list: (.*?)\. Nothing that is not on the list", body["messages"][-1]["content"])
        return len(listed.group(1).split(", ")) if listed else 0

    def overlapping(self) -> set[frozenset[int]]:
        """Pairs of episodes one of whose requests started before a request of the other ended
        and ended after it started (from the recorded order alone, no clock)."""
        spans = [(self.episode_of(c.request), c.started, c.ended) for c in self.server.calls if c.ended is not None]
        spans = [span for span in spans if span[0]]
        return {frozenset((a, b)) for a, s1, e1 in spans for b, s2, e2 in spans if a != b and s1 < e2 and s2 < e1}

    def close(self) -> None:
        self.server.close()


@pytest.mark.slow
def test_one_worker_runs_llm_episodes_at_once_and_writes_each_row_once(tmp_path: Path) -> None:
    model = SlowModel()
    spec = EvalSpec(
        tasks=("pack_objects",),
        scenes=("kitchen",),
        objects=(3, 4, 5, 6),
        horizon=3,
        llm="m",
        base_url=model.url,
        llm_timeout=20.0,
    )
    try:
        rows = [r.flat() for r in asyncio.run(evaluate(spec, tmp_path / "ev", workers=1, concurrency=4))]
    finally:
        model.close()
    keys = [r["key"] for r in _rows(tmp_path / "ev")]
    assert sorted(keys) == [f"pack_objects/kitchen/{n}/0" for n in (3, 4, 5, 6)] and len(rows) == 4  # each once
    assert len({r["worker"] for r in rows}) == 1  # one worker ran them all
    for r in rows:
        assert (r["temporal_steps"], r["llm_calls"], r["llm_unreachable"], r["valid"]) == (3, 9, 0, True)
    assert not (tmp_path / "ev" / "errors.jsonl").exists()
    assert len(model.server.requests) == 4 * 9  # no request was retried or sent twice
    # the episodes' model calls overlapped: a call of one episode was in flight while another's was
    assert model.overlapping(), [(c.started, c.ended, model.episode_of(c.request)) for c in model.server.calls]
    assert model.server.max_in_flight > 3  # one episode alone never has more than its three robots' calls in flight


@pytest.mark.slow
def test_heuristic_episodes_run_at_once_give_the_same_metrics_as_one_at_a_time(tmp_path: Path) -> None:
    """Each episode has its own PyBullet client and arm planner; the process-wide OMPL generator
    is re-seeded under a lock before every plan (world/arm.py), so sharing a process changes nothing."""
    spec = EvalSpec(tasks=("pack_objects", "sort_solids"), scenes=("kitchen",), objects=(4,))
    one = [r.flat() for r in asyncio.run(evaluate(spec, tmp_path / "one", workers=1))]
    many = [r.flat() for r in asyncio.run(evaluate(spec, tmp_path / "many", workers=1, concurrency=2))]

    def stable(rows: list[dict[str, object]]) -> dict[object, dict[str, object]]:
        return {r["key"]: {k: v for k, v in r.items() if k not in ("wall_time", "worker")} for r in rows}

    assert len(many) == 2 and all(r["success"] for r in many)
    assert stable(many) == stable(one)


def test_concurrency_below_one_fails_before_anything_starts(tmp_path: Path) -> None:
    spec = EvalSpec(tasks=("pack_objects",), scenes=("kitchen",), objects=(3,))
    with pytest.raises(ConfigError, match=re.escape("--concurrency: must be at least 1 (got 0)")):
        asyncio.run(evaluate(spec, tmp_path / "x", concurrency=0))
    assert not (tmp_path / "x").exists()
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "mhrc",
            "eval",
            "--tasks",
            "pack_objects",
            "--concurrency",
            "0",
            "--out",
            str(tmp_path / "x"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2 and "--concurrency" in out.stderr, out.stderr
    assert not (tmp_path / "x").exists()
