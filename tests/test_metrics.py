"""Metric definitions on hand-built traces, the lower bound on hand-built episodes, and both
against real episodes."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest
from json_rows import records
from sweep import sweep

from mhrc.analysis.metrics import EpisodeMetrics, TraceError, from_trace
from mhrc.core.records import read_records
from mhrc.eval.means import summarize
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
    rows = [from_trace(records(_trace(True))), from_trace(records(_trace(False)))]
    s = summarize(rows)
    assert s["episodes"] == 2 and s["succ"] == 0.5 and s["ps"] == pytest.approx((1 + 1 / 3) / 2, abs=1e-4)
    assert s["ts"] == 3 and s["as"] == 4 and s["as_per_robot"] == 2 and s["ts_bound"] == 7
    assert (
        s["as_ticks"] == 3
    )  # ticks 0, 1 and 2 each had a non-wait action (tick 1: alice's navigate beside bob's wait)
    old = [  # rows written before the reading existed
        EpisodeMetrics.model_validate({k: v for k, v in r.as_dict().items() if k != "active_ticks"}) for r in rows
    ]
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
        ([_obj("a"), _obj("b"), _obj("c")], 6),  # only Bob places on the goal: a pick and a place each
        ([_obj("a", reach=False)], 4),  # Alice drives to the table, picks, places; Bob picks it then, places
        ([_obj("a", "counter", on=False, reach=False)], 5),  # navigate, pick, navigate back, place; Bob's place
        (
            [
                _obj("a", "drawer", inside=True, on=False, reach=False),
                _obj("b", "drawer", inside=True, on=False, reach=False),
            ],
            10,
        ),  # one open
        (
            [
                _obj("a"),
                _obj("b", reach=False),
                _obj("c", "drawer", True, False, False),
                _obj("d", "sofa", on=False, reach=False),
            ],
            12,
        ),
        ([_obj(f"n{i}") for i in range(6)] + [_obj("f", reach=False)], 14),  # many near: Bob's work dominates
    ],
)
def test_lower_bound_of_hand_built_episodes(objects: list[SymbolicObject], bound: int) -> None:
    assert lower_bound(SymbolicEpisode(tuple(objects))) == bound


def test_more_fetchers_never_lift_the_bound_below_the_finishers_own_work() -> None:
    """`mhrc up --team full_house --objects 6 --seed 1` said "no team can need fewer than 7": the
    bound let every arm place on a goal. Only the finisher may (world/skills/manipulation.py), so
    six targets cost him 12 steps whatever the number of fetchers."""
    six = (
        _obj("near"),
        _obj("far", reach=False),
        _obj("c", "drawer", True, False, False),
        *(_obj(f"away{i}", "sofa", on=False, reach=False) for i in range(3)),
    )
    assert [lower_bound(SymbolicEpisode(six, fetchers=f)) for f in (1, 2, 3, 8)] == [20, 12, 12, 12]
    assert lower_bound(SymbolicEpisode(six, fetchers=3, finishers=2)) == 8  # two finishers share it: 19/3 steps, +1
    # a target fetched from a closed container, by one fetcher: navigate, open, pick, navigate, place (5), Bob's place
    assert lower_bound(SymbolicEpisode((_obj("c", "drawer", True, False, False),))) == 6
    # with two, the other opens earlier in the same tick of the sequential schedule: the chain is a tick shorter
    assert lower_bound(SymbolicEpisode((_obj("c", "drawer", True, False, False),), fetchers=2)) == 5


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


@pytest.mark.parametrize(
    "team",
    sweep(["paper", "full_house", "no_mobile", "two_fetchers", "drone_scout", "scout_and_drone", "large"]),
)
async def test_no_shipped_team_solves_an_episode_in_fewer_steps_than_the_bound(team: str) -> None:
    """The bound's relaxation lets a robot act in the tick a teammate before it acted (the
    sequential schedule's rule, the loosest tick schedule), so it must hold for every shipped
    team's heuristic run under it; six objects, where the finisher's own work (12 steps) is
    what bounds a team of many fetchers."""
    from mhrc.testing import run_episode
    from mhrc.world.teams import SHIPPED

    ep = await run_episode(
        team=SHIPPED[team], task="pack_objects", scene="kitchen", seed=1, n_objects=6, horizon=80, schedule="sequential"
    )
    m = ep.done.metrics
    assert m.success and m.lower_bound is not None, (ep.done.reason, m)
    assert 12 <= m.lower_bound <= m.temporal_steps
