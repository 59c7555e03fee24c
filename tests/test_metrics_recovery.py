"""Recovery scoring (issue 25, `mhrc.analysis.metrics`): per scenario event, the steps until the team
has one more target in place than when the event fired, on hand-built traces of each schedule;
and how `summarize` and the eval report carry it."""

from __future__ import annotations

import csv
import io
from typing import Any

import pytest
from json_rows import records
from test_metrics import _complete  # the protocol's required fields a hand-built message leaves out

from mhrc.analysis.metrics import EpisodeMetrics, from_trace
from mhrc.eval.means import summarize
from mhrc.eval.records import EvalRow, upgrade_row
from mhrc.eval.report import summary_csv, summary_markdown
from mhrc.eval.rows import SETTING, setting_of

STEP = 8.0  # async step_seconds of these traces


def _put(kind: str, **msg: Any) -> dict[str, Any]:
    return {"t": 0.0, "key": f"mhrc/r/{kind}", "kind": "put", "msg": {"v": 2, "kind": kind, **_complete(kind, msg)}}


def _event(index: int, tick: int, kind: str = "relocate", applied: bool = True) -> dict[str, Any]:
    return _put(
        "scenario_event",
        scenario="s",
        sha256="ab" * 32,
        index=index,
        event=kind,
        tick=tick,
        applied=applied,
        skipped=None if applied else "every target is in place or held",
        changed={},
        text="",
    )


def _started(scheduler: str = "lockstep") -> dict[str, Any]:
    return _put(
        "episode_started",
        run="r",
        task="pack_objects",
        scene="kitchen",
        seed=0,
        n_objects=3,
        robots=["alice", "bob"],
        horizon=50,
        scheduler=scheduler,
        step_seconds=STEP if scheduler == "async" else None,
    )


def _done(placed: int, total: int = 3, makespan: float = 0.0, **extra: Any) -> dict[str, Any]:
    metrics = {
        "success": placed == total,
        "placed": placed,
        "total": total,
        "partial_success": placed / total,
        "makespan": makespan,
    }
    return _put("episode_done", run="r", reason="success" if placed == total else "horizon", metrics=metrics, **extra)


def _ticks(
    placed: list[int], events: dict[int, list[dict[str, Any]]] | None = None, scheduler: str = "lockstep"
) -> list[dict[str, Any]]:
    """A lockstep (or sequential) trace: tick t closes with placed[t]; `events[T]` fire when tick T
    opens, published (as the world does) before tick T-1's tick event."""
    events = events or {}
    rows = [_started(scheduler), *events.get(0, [])]
    for t, n in enumerate(placed):
        rows += [*events.get(t + 1, []), _put("tick", tick=t, actions={}, outcomes={}, placed=n, total=3)]
    return rows + [_done(placed[-1])]


def _by_index(rows: list[dict[str, Any]]) -> dict[int, int | None]:
    return {e["index"]: e["ticks_to_recover"] for e in from_trace(records(rows)).recovery}


@pytest.mark.parametrize("scheduler", ["lockstep", "sequential"])
def test_progress_three_ticks_after_the_event_is_three(scheduler: str) -> None:
    """Event at tick 5 (one target in place after tick 4); ticks 5 and 6 place nothing, tick 7
    places the second: ticks 5, 6 and 7 ran from the event to the progress."""
    rows = _ticks([0, 1, 1, 1, 1, 1, 1, 2, 3], {5: [_event(0, 5)]}, scheduler)
    m = from_trace(records(rows))
    assert m.recovery == [{"index": 0, "kind": "relocate", "tick": 5, "applied": True, "ticks_to_recover": 3}]
    assert m.recovery_ticks == 3 and m.unrecovered == 0


def test_progress_in_the_first_tick_after_the_event_is_one() -> None:
    assert _by_index(_ticks([0, 1, 2, 3], {2: [_event(0, 2)]})) == {0: 1}


def test_an_event_at_tick_one_counts_from_what_tick_zero_left() -> None:
    assert _by_index(_ticks([0, 0, 1, 2, 3], {1: [_event(0, 1)]})) == {0: 2}


def test_no_progress_after_the_event_is_none() -> None:
    m = from_trace(records(_ticks([0, 1, 1, 1, 1], {2: [_event(0, 2, "breakdown")]})))
    assert [e["ticks_to_recover"] for e in m.recovery] == [None]
    assert m.recovery_ticks is None and m.unrecovered == 1


def test_a_skipped_event_has_no_recovery_value() -> None:
    """Progress follows it, but it changed nothing to recover from: no value, not unrecovered either."""
    m = from_trace(records(_ticks([0, 1, 1, 2, 3], {2: [_event(0, 2, "close", applied=False)]})))
    assert m.recovery == [{"index": 0, "kind": "close", "tick": 2, "applied": False, "ticks_to_recover": None}]
    assert m.recovery_ticks is None and m.unrecovered == 0


def test_several_events_each_from_its_own_tick_and_count() -> None:
    """Events at 2 (1 in place), 3 and 6 (2 in place); one skipped at 4: values 2, 1 and none (no
    third target after tick 6); the mean is over the two that recovered."""
    placed = [1, 1, 1, 2, 2, 2, 2, 2]
    events = {
        2: [_event(0, 2, "relocate")],
        3: [_event(1, 3, "close")],
        4: [_event(2, 4, "close", applied=False)],
        6: [_event(3, 6, "new_target")],
    }
    m = from_trace(records(_ticks(placed, events)))
    assert [(e["index"], e["kind"], e["applied"], e["ticks_to_recover"]) for e in m.recovery] == [
        (0, "relocate", True, 2),
        (1, "close", True, 1),
        (2, "close", False, None),
        (3, "new_target", True, None),
    ]
    assert m.recovery_ticks == 1.5 and m.unrecovered == 1


def test_a_static_episode_has_no_recovery() -> None:
    m = from_trace(records(_ticks([1, 2, 3])))
    assert m.recovery == [] and m.recovery_ticks is None and m.unrecovered is None


# --------------------------------------------------------------------------- async


def _snapshot(goals: list[str], where: dict[str, str], held: str | None = None) -> dict[str, Any]:
    objects = {
        n: {"x": 0.0, "y": 0.0, "z": 0.7, "on": on, "inside": False, "held_by": held if n == "mug" else None}
        for n, on in where.items()
    }
    return _put("snapshot", tick=0, goals=goals, robots={}, objects=objects, open={})


def _action(goal: str, robot: str, started: float, ended: float) -> dict[str, Any]:
    return _put(
        "action_result",
        goal_id=goal,
        robot=robot,
        tick=0,
        action={"skill": "place", "obj": "x", "location": "tray"},
        outcome={"succeeded": True, "code": "ok"},
        started=started,
        ended=ended,
    )


def _async_trace(
    events_at: list[dict[str, Any]], mug_placed_at: float | None, mug_held: bool = False
) -> list[dict[str, Any]]:
    """phone in the tray from the start; a relocate at tick 3 (24 s); bob puts the mug in the tray
    in an action ending at `mug_placed_at` (None: never). Goals from episode_done (the tray)."""
    start = {"phone": "tray", "mug": "table_3", "book": "table_1"}
    rows = [_started("async"), _snapshot([], start)]
    rows += [_action("g1", "alice", 0.0, 20.0), _snapshot(["g1"], start)]
    rows += events_at
    rows += [
        _action("g2", "alice", 26.0, 30.0),
        _snapshot(["g2"], start | {"mug": "table_4"}, held="alice" if mug_held else None),
    ]
    if mug_placed_at is not None:
        rows += [
            _action("g3", "bob", 40.0, mug_placed_at),
            _snapshot(["g3"], start | {"mug": "tray"}, held="bob" if mug_held else None),
        ]
    tray = {"phone": "tray", "mug": "tray", "book": "tray"}
    return rows + [_done(2 if mug_placed_at is not None else 1, makespan=400.0, targets=list(tray), goals=tray)]


def test_async_counts_in_steps_from_the_events_simulated_time() -> None:
    """The event fires at 3 x 8 s = 24 s; the mug lands in the tray at the end of an action ending
    at 45 s: (45 - 24) / 8 = 2.6, rounded up as TS is: 3 steps."""
    m = from_trace(records(_async_trace([_event(0, 3)], mug_placed_at=45.0)))
    assert m.scheduler == "async" and [e["ticks_to_recover"] for e in m.recovery] == [3]
    assert m.recovery_ticks == 3


def test_async_without_progress_and_a_held_object_is_not_in_place() -> None:
    assert _by_index(_async_trace([_event(0, 3)], mug_placed_at=None)) == {0: None}
    assert _by_index(_async_trace([_event(0, 3)], mug_placed_at=45.0, mug_held=True)) == {
        0: None
    }  # on the tray's spot but in a gripper


def test_async_counts_each_event_from_the_targets_in_place_when_it_fired() -> None:
    late = _async_trace([], mug_placed_at=45.0)
    late.insert(-1, _event(1, 5))  # after the mug was placed: nothing more lands, so no recovery
    early = _async_trace([_event(0, 3)], mug_placed_at=45.0)
    early.insert(-1, _event(1, 5))
    assert _by_index(late) == {1: None}
    assert _by_index(early) == {0: 3, 1: None}


# --------------------------------------------------------------------------- summaries and the report


def _row(m: Any, *, scenario: str | None, sha: str | None = None, key: str = "pack_objects/kitchen/3/0") -> EvalRow:
    return upgrade_row(
        {
            **m.as_dict(),
            "seed": int(key.rsplit("/", 1)[1]),
            "key": key,
            "method": "heuristic",
            "ablation": "none",
            "fidelity": "paper",
            "horizon": 50,
            "schedule": "sequential",
            "mode": "free",
            "history_cap": None,
            "aids": [],
            "scenario": scenario,
            "scenario_sha256": sha,
        }
    )


def test_summarize_averages_recovery_over_the_episodes_that_have_one() -> None:
    three = from_trace(records(_ticks([0, 1, 1, 1, 1, 1, 1, 2, 3], {5: [_event(0, 5)]})))  # 3
    one = from_trace(records(_ticks([0, 1, 2, 3], {2: [_event(0, 2)]})))  # 1
    never = from_trace(records(_ticks([0, 1, 1, 1, 1], {2: [_event(0, 2)]})))  # no value, one unrecovered
    static = from_trace(records(_ticks([1, 2, 3])))
    rows = [three, one, never, static]
    s = summarize(rows)
    assert s["recovery_ticks"] == 2.0  # (3 + 1) / 2: neither the unrecovered nor the static episode adds a value
    assert s["unrecovered"] == pytest.approx(1 / 3, abs=1e-3)  # over the three scenario episodes
    assert summarize([static])["recovery_ticks"] is None and summarize([static])["unrecovered"] is None
    old = [
        EpisodeMetrics.model_validate(
            {k: v for k, v in r.as_dict().items() if k not in ("recovery", "recovery_ticks", "unrecovered")}
        )
        for r in rows
    ]
    assert summarize(old)["recovery_ticks"] is None  # rows written before the fields


def test_the_report_shows_recovery_only_where_a_scenario_ran_and_never_mixes_two() -> None:
    sha_a, sha_b = "a" * 64, "b" * 64
    scen = from_trace(records(_ticks([0, 1, 1, 1, 1, 1, 1, 2, 3], {5: [_event(0, 5)]})))
    static = from_trace(records(_ticks([1, 2, 3])))
    rows = [
        _row(static, scenario=None),
        _row(scen, scenario="relocate", sha=sha_a),
        _row(scen, scenario="relocate", sha=sha_b),
    ]
    # two files of one name are two settings, labelled as `mhrc scenarios` lists them
    scenario = SETTING.index("scenario")
    assert [setting_of(r)[scenario] for r in rows] == [None, "relocate@aaaaaaaaaaaa", "relocate@bbbbbbbbbbbb"]
    md = summary_markdown(rows, resamples=50)
    per_setting = md.split("## Per setting")[1].split("## Failure diagnostics")[0]
    sections = {s.splitlines()[0]: s for s in per_setting.split("### ")[1:]}
    assert set(sections) == {
        "heuristic · ablation none · paper",
        "heuristic · ablation none · paper · scenario relocate@aaaaaaaaaaaa",
        "heuristic · ablation none · paper · scenario relocate@bbbbbbbbbbbb",
    }
    for title, text in sections.items():
        head = next(line for line in text.splitlines() if line.startswith("| task |"))
        row = next(line for line in text.splitlines() if line.startswith("| pack_objects |"))
        if "scenario" in title:
            assert "recovery (steps)" in head and "| 3.0 (0.00 unrecovered) |" in row
        else:
            assert "recovery" not in head and head.count("|") == row.count("|")
    table = list(csv.DictReader(io.StringIO(summary_csv(rows, resamples=50))))
    assert [(r["scenario"], r["recovery_ticks"], r["unrecovered"]) for r in table] == [
        ("", "", ""),
        ("relocate@aaaaaaaaaaaa", "3.0", "0.0"),
        ("relocate@bbbbbbbbbbbb", "3.0", "0.0"),
    ]


def test_the_html_summary_lists_each_episodes_recovery_only_where_a_scenario_ran() -> None:
    from mhrc.eval.html import html_summary

    scen = from_trace(
        records(_ticks([0, 1, 1, 1, 1, 1, 1, 2, 3], {5: [_event(0, 5), _event(1, 5, "close", applied=False)]}))
    )
    static = from_trace(records(_ticks([1, 2, 3])))
    page = html_summary(
        [_row(static, scenario=None), _row(scen, scenario="relocate", sha="a" * 64, key="pack_objects/kitchen/3/1")],
        [None, None],
        resamples=50,
    )
    episodes = page.split("<h2>Episodes</h2>")[1]
    assert "<th>recovery (steps)</th>" in episodes and "<td>relocate@5: 3, close@5: skipped</td>" in episodes
    assert (
        "recovery"
        not in html_summary([_row(static, scenario=None)], [None], resamples=50).split("<h2>Episodes</h2>")[1]
    )
