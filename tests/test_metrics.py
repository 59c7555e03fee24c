"""Metric definitions on hand-built traces, the lower bound on hand-built episodes, and both
against real episodes."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest
from json_rows import records
from sweep import sweep

from mhrc.analysis.metrics import TraceError, from_trace, summarize
from mhrc.core.records import read_records
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.world.bound import SymbolicEpisode, SymbolicObject, lower_bound


def _put(kind: str, **msg: Any) -> dict[str, Any]:
    return {"t": 0.0, "key": f"mhrc/r/{kind}", "kind": "put", "msg": {"v": 1, "kind": kind, **_complete(kind, msg)}}


# What a message of each kind must hold (the protocol's required fields) that a test's message leaves out
REQUIRED: dict[str, dict[str, Any]] = {
    "action_result": {
        "goal_id": "g",
        "observation": {
            "robot": "r",
            "tick": 0,
            "status": {"name": "r", "kind": "k", "skills": []},
            "furniture": [],
            "objects": [],
            "task_brief": "",
            "task_detail": "",
        },
    },
    "tick": {"actions": {}, "outcomes": {}, "placed": 0, "total": 3},
}
METRICS = {"temporal_steps": 0, "action_steps": 0, "action_steps_per_robot": {}}


def _complete(kind: str, msg: dict[str, Any]) -> dict[str, Any]:
    """`msg` with the protocol's required fields it lacks filled in (the trace reader decodes every message)."""
    full = {**REQUIRED.get(kind, {}), **msg}
    if isinstance(full.get("outcome"), dict):
        full["outcome"] = {"feedback": "", **full["outcome"]}
    if isinstance(full.get("metrics"), dict):
        full["metrics"] = {**METRICS, **full["metrics"]}
    return full


def _result(robot: str, tick: int, skill: str, ok: bool = True, **action: Any) -> dict[str, Any]:
    return _put(
        "action_result",
        robot=robot,
        tick=tick,
        action={"skill": skill, **action},
        outcome={"succeeded": ok, "code": "ok" if ok else "too_far"},
    )


def _trace(success: bool = True) -> list[dict[str, Any]]:
    return [
        _put(
            "episode_started",
            run="r",
            task="pack_objects",
            scene="kitchen",
            seed=3,
            n_objects=3,
            robots=["alice", "bob"],
            horizon=50,
            lower_bound=7,
        ),
        _put(
            "thought",
            robot="bob",
            tick=0,
            policy="llm:x",
            prompt="p",
            reply="r",
            prompt_tokens=100,
            completion_tokens=20,
        ),
        _put("thought", robot="alice", tick=0, policy="heuristic", prompt=None, prompt_tokens=0),
        _result("bob", 0, "pick", ok=False, obj="apple"),
        _result("alice", 0, "communicate", content="hi", to="bob"),
        _put("tick", tick=0),
        _result("bob", 1, "wait"),
        _result("alice", 1, "navigate", target="table_0", stand_pose=0),
        _put("tick", tick=1),
        {"t": 0.0, "key": "mhrc/r/alive/robot/bob", "kind": "gone", "msg": None},
        _result("alice", 2, "pick", obj="apple"),
        _put("tick", tick=2),
        _put(
            "episode_done",
            run="r",
            reason="success" if success else "horizon",
            metrics={
                "success": success,
                "placed": 3 if success else 1,
                "total": 3,
                "partial_success": 1.0 if success else 1 / 3,
                "wall_time": 0.5,
            },
        ),
    ]


def test_metrics_of_a_hand_built_trace() -> None:
    m = from_trace(records(_trace()))
    assert (m.task, m.scene, m.seed, m.n_objects, m.reason) == ("pack_objects", "kitchen", 3, 3, "success")
    assert m.temporal_steps == 3  # three tick events
    assert m.action_steps == 4 and m.action_steps_per_robot == {"alice": 3, "bob": 1}  # wait excluded, failures counted
    assert m.failed_actions == {"pick": 1} and m.messages == 1
    assert (m.llm_calls, m.prompt_tokens, m.completion_tokens) == (1, 100, 20)  # the heuristic's thought is no call
    assert m.success and m.partial_success == 1.0 and m.lower_bound == 7 and m.wall_time == 0.5


def test_an_unfinished_trace_is_an_error() -> None:
    with pytest.raises(TraceError, match="did not finish"):
        from_trace(records(_trace()[:-1]))


def test_summary_means_and_both_action_step_readings() -> None:
    rows = [from_trace(records(_trace(True))).as_dict(), from_trace(records(_trace(False))).as_dict()]
    s = summarize(rows)
    assert s["episodes"] == 2 and s["succ"] == 0.5 and s["ps"] == pytest.approx((1 + 1 / 3) / 2, abs=1e-4)
    assert s["ts"] == 3 and s["as"] == 4 and s["as_per_robot"] == 2 and s["ts_bound"] == 7
    assert (
        s["as_ticks"] == 3
    )  # ticks 0, 1 and 2 each had a non-wait action (tick 1: alice's navigate beside bob's wait)
    old = [{k: v for k, v in r.items() if k != "active_ticks"} for r in rows]  # rows written before the reading existed
    assert summarize(old)["as_ticks"] is None


def test_the_three_action_step_readings_differ_as_the_paper_needs() -> None:
    """On a hand-built trace with a tick where only waits happen and a tick where two robots act:
    summed 3, per-robot mean 1.5, active ticks 2 (of TS 3): only the last can sit below TS
    the way every row of the paper's tables does while robots act in parallel."""
    rows = [
        _put(
            "episode_started",
            run="r",
            task="pack_objects",
            scene="kitchen",
            seed=0,
            n_objects=3,
            robots=["alice", "bob"],
            horizon=50,
        ),
        _result("alice", 0, "navigate", target="table_0", stand_pose=0),
        _result("bob", 0, "pick", obj="apple"),
        _put("tick", tick=0),
        _result("alice", 1, "wait"),
        _result("bob", 1, "wait"),
        _put("tick", tick=1),
        _result("bob", 2, "place", obj="apple", location="tray"),
        _put("tick", tick=2),
        _put(
            "episode_done",
            run="r",
            reason="horizon",
            metrics={"success": False, "placed": 1, "total": 3, "partial_success": 1 / 3},
        ),
    ]
    m = from_trace(records(rows))
    assert (m.temporal_steps, m.action_steps, m.action_steps / len(m.robots), m.active_ticks) == (3, 3, 1.5, 2)
    with pytest.raises(ValueError):
        summarize([])


def _obj(
    name: str, source: str = "table_0", inside: bool = False, on: bool = True, reach: bool = True
) -> SymbolicObject:
    return SymbolicObject(name, source, inside, on, reach)


@pytest.mark.parametrize(
    ("objects", "bound"),
    [
        ([_obj("a"), _obj("b"), _obj("c")], 3),  # Bob alone: 6 arm steps, two arms: 3 ticks at best
        ([_obj("a", reach=False)], 3),  # Alice drives to the table, picks, places
        ([_obj("a", "counter", on=False, reach=False)], 4),  # navigate, pick, navigate back, place
        (
            [
                _obj("a", "drawer", inside=True, on=False, reach=False),
                _obj("b", "drawer", inside=True, on=False, reach=False),
            ],
            9,
        ),  # one open
        (
            [
                _obj("a"),
                _obj("b", reach=False),
                _obj("c", "drawer", True, False, False),
                _obj("d", "sofa", on=False, reach=False),
            ],
            11,
        ),
        ([_obj(f"n{i}") for i in range(6)] + [_obj("f", reach=False)], 8),  # many near: both arms' work dominates
    ],
)
def test_lower_bound_of_hand_built_episodes(objects: list[SymbolicObject], bound: int) -> None:
    assert lower_bound(SymbolicEpisode(tuple(objects))) == bound


@pytest.mark.parametrize(
    ("task", "scene", "seed", "n"),
    sweep([("pack_objects", "kitchen", 4, 5), ("make_sandwich", "bathroom", 1, 4), ("sort_solids", "bedroom", 2, 6)]),
)
def test_real_episodes_agree_with_the_world_and_respect_the_bound(
    tmp_path: Path, task: str, scene: str, seed: int, n: int
) -> None:
    cfg = EpisodeConfig.build(task=task, scene=scene, seed=seed, n_objects=n, trace=tmp_path / "t.jsonl").resolved()
    done = asyncio.run(up_in_process(cfg))
    m = from_trace(read_records(tmp_path / "t.jsonl"))
    w = done.metrics
    assert (m.success, m.placed, m.temporal_steps, m.action_steps) == (
        w.success,
        w.placed,
        w.temporal_steps,
        w.action_steps,
    )
    assert (
        m.action_steps_per_robot == w.action_steps_per_robot
        and m.failed_actions == w.failed_actions
        and m.messages == w.messages
    )
    assert m.success and w.lower_bound is not None and m.lower_bound == w.lower_bound
    assert 0 < w.lower_bound <= m.temporal_steps
