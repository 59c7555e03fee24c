"""The metrics of a team's work (mhrc.analysis.teamwork, through mhrc.analysis.metrics.from_trace) on
hand-built traces, the team recorded in a trace (and read from one older than the field), and
summaries of them: each metric is asserted where a wrong definition would give another number."""

from __future__ import annotations

from typing import Any

import pytest
from json_rows import records
from test_metrics import _put, _result

from mhrc.analysis.metrics import EpisodeMetrics, from_trace
from mhrc.core.protocol import EpisodeStarted
from mhrc.core.records import messages
from mhrc.core.team import PAPER_TEAM
from mhrc.core.upgrade import paper_team
from mhrc.eval.means import summarize

PAPER_METRICS = (
    "success",
    "placed",
    "total",
    "partial_success",
    "temporal_steps",
    "action_steps",
    "action_steps_per_robot",
    "active_ticks",
    "messages",
    "failed_actions",
)


def _started(robots: list[str], team: dict[str, Any] | None = None) -> dict[str, Any]:
    extra = {"team": team} if team is not None else {}
    return _put(
        "episode_started",
        run="r",
        task="pack_objects",
        scene="kitchen",
        seed=0,
        n_objects=3,
        robots=robots,
        horizon=50,
        **extra,
    )


def _done(placed: int = 1) -> dict[str, Any]:
    return _put(
        "episode_done",
        run="r",
        reason="horizon",
        metrics={"success": False, "placed": placed, "total": 3, "partial_success": placed / 3},
    )


def _episode(*results: dict[str, Any], robots: tuple[str, ...] = ("alice", "bob", "david")) -> list[dict[str, Any]]:
    """A lockstep trace: the results given, a tick event after each tick's results."""
    lines = [_started(list(robots))]
    ticks = sorted({r["msg"]["tick"] for r in results})
    for t in ticks:
        lines += [r for r in results if r["msg"]["tick"] == t]
        lines.append(_put("tick", tick=t))
    return lines + [_done()]


def _at(line: dict[str, Any], started: float, ended: float) -> dict[str, Any]:
    """A result with its times on the world's clock."""
    line["msg"].update(started=started, ended=ended)
    return line


def nav(robot: str, tick: int, target: str, ok: bool = True) -> dict[str, Any]:
    return _result(robot, tick, "navigate", ok=ok, target=target, stand_pose=0)


def pick(robot: str, tick: int, obj: str, ok: bool = True) -> dict[str, Any]:
    return _result(robot, tick, "pick", ok=ok, obj=obj)


def place(robot: str, tick: int, obj: str, where: str = "table_0", ok: bool = True) -> dict[str, Any]:
    return _result(robot, tick, "place", ok=ok, obj=obj, location=where)


def say(robot: str, tick: int, to: str, ok: bool = True) -> dict[str, Any]:
    return _result(robot, tick, "communicate", ok=ok, content="hi", to=to)


# --------------------------------------------------------------------------- the team in the trace


def test_the_team_is_read_from_the_trace() -> None:
    team = {"name": "drone_scout", "digest": "abcdef012345", "kinds": {"alice": "mobile_manipulator", "lucy": "drone"}}
    m = from_trace(records([_started(["alice", "lucy"], team), _done()]))
    assert (m.team, m.team_digest, m.team_kinds) == ("drone_scout", "abcdef012345", team["kinds"])


def test_a_trace_older_than_the_field_ran_the_paper_team() -> None:
    m = from_trace(records([_started(["alice", "bob", "david"]), _done()]))
    assert (m.team, m.team_digest) == ("paper", PAPER_TEAM.digest())
    assert m.team_kinds == {"alice": "mobile_manipulator", "bob": "tabletop_arm", "david": "mobile_base"}
    # the no_mobile ablation ran Alice and Bob: the paper's team without David, as today's world records it
    m = from_trace(records([_started(["alice", "bob"]), _done()]))
    assert (m.team, m.team_digest) == ("paper", PAPER_TEAM.without({"david"}).digest())
    assert list(m.team_kinds) == ["alice", "bob"] and m.team_digest != PAPER_TEAM.digest()
    # the upgrade is the one place: the decoded event holds the team
    (started,) = messages(records([_started(["alice", "bob", "david"])]), EpisodeStarted)
    assert started.team == paper_team(["alice", "bob", "david"])


def test_the_team_does_not_change_the_papers_metrics() -> None:
    results = (
        nav("alice", 0, "cabinet"),
        say("david", 0, "alice"),
        pick("alice", 1, "apple"),
        _result("bob", 1, "wait"),
    )
    old = from_trace(records(_episode(*results))).as_dict()
    lines = _episode(*results)
    lines[0] = _started(["alice", "bob", "david"], {"name": "x", "digest": "d", "kinds": {"alice": "k"}})
    new = from_trace(records(lines)).as_dict()
    assert {k: new[k] for k in PAPER_METRICS} == {k: old[k] for k in PAPER_METRICS}
    assert (old["active_ticks"], old["action_steps"], old["temporal_steps"]) == (2, 3, 2)


# --------------------------------------------------------------------------- who did the work


def test_per_robot_messages_moves_and_communication_steps() -> None:
    m = from_trace(
        records(
            _episode(
                say("david", 0, "alice"),
                pick("alice", 0, "apple"),
                say("david", 1, "bob", ok=False),  # not delivered: a communication step, not a message
                place("alice", 1, "apple"),
                pick("bob", 2, "apple"),
                pick("bob", 3, "pear", ok=False),  # a failed pick moves nothing
                place("bob", 4, "apple", "tray"),
                say("alice", 4, "bob"),
                _result("david", 4, "wait"),
            )
        )
    )
    assert m.messages_per_robot == {"alice": 1, "bob": 0, "david": 1} and m.messages == 2
    assert m.moves_per_robot == {"alice": 2, "bob": 2, "david": 0}
    assert m.communication_steps == 3 and m.action_steps == 8
    assert (m.redundant_navigations, m.redundant_picks) == (0, 0)


# --------------------------------------------------------------------------- redundant navigations


@pytest.mark.parametrize(
    ("results", "redundant"),
    [
        pytest.param(
            (
                nav("david", 0, "cabinet"),
                nav("alice", 1, "cabinet"),
                nav("alice", 2, "fridge"),
                pick("alice", 3, "pear"),
            ),
            1,
            id="looked-again",
        ),
        pytest.param((nav("david", 0, "cabinet"), nav("alice", 1, "cabinet")), 1, id="looked-again-then-the-end"),
        pytest.param(
            (
                nav("david", 0, "cabinet"),
                nav("alice", 1, "cabinet"),
                _result("alice", 2, "move", dx=1.0, dy=0.0),
                pick("alice", 3, "apple"),  # picked elsewhere: the look at the cabinet was still for nothing
            ),
            1,
            id="looked-again-then-moved-away",
        ),
        pytest.param(
            (nav("david", 0, "cabinet"), nav("alice", 1, "cabinet"), pick("alice", 2, "apple", ok=False)),
            0,
            id="came-to-pick",
        ),
        pytest.param(
            (
                nav("david", 0, "cabinet"),
                nav("alice", 1, "cabinet"),
                say("alice", 2, "bob"),
                place("alice", 3, "apple"),
            ),
            0,
            id="came-to-place",
        ),
        pytest.param((nav("david", 1, "cabinet"), nav("alice", 1, "cabinet")), 0, id="same-tick-lockstep"),
        pytest.param(
            (nav("david", 0, "cabinet", ok=False), nav("alice", 1, "cabinet")), 0, id="teammate-never-got-there"
        ),
        pytest.param((nav("david", 0, "cabinet"), nav("alice", 1, "cabinet", ok=False)), 0, id="did-not-get-there"),
        pytest.param((nav("alice", 0, "cabinet"), nav("alice", 1, "cabinet")), 0, id="own-second-visit"),
        pytest.param((nav("david", 0, "cabinet"), nav("alice", 1, "fridge")), 0, id="elsewhere"),
        pytest.param(
            (
                nav("david", 0, "cabinet"),
                nav("alice", 1, "cabinet"),
                nav("david", 2, "fridge"),
                nav("alice", 3, "fridge"),
            ),
            2,
            id="twice",
        ),
    ],
)
def test_redundant_navigations(results: tuple[dict[str, Any], ...], redundant: int) -> None:
    m = from_trace(records(_episode(*results)))
    assert (m.redundant_navigations, m.redundant_picks) == (redundant, 0)
    assert m.redundant_per_robot == {"alice": redundant, "bob": 0, "david": 0}


def test_before_is_on_the_worlds_clock() -> None:
    """Sequential: David's turn of tick 1 ends at 3.0 and Alice's starts then, so David got there
    first; lockstep: both start at 2.0, so neither did."""
    sequential = _episode(_at(nav("david", 1, "cabinet"), 2.0, 3.0), _at(nav("alice", 1, "cabinet"), 3.0, 5.0))
    assert from_trace(records(sequential)).redundant_per_robot == {"alice": 1, "bob": 0, "david": 0}
    lockstep = _episode(_at(nav("david", 1, "cabinet"), 2.0, 3.0), _at(nav("alice", 1, "cabinet"), 2.0, 5.0))
    assert from_trace(records(lockstep)).redundant_navigations == 0
    # a later tick whose clock says it started before the other ended (async): not before
    overlapping = _episode(_at(nav("david", 0, "cabinet"), 0.0, 9.0), _at(nav("alice", 1, "cabinet"), 4.0, 6.0))
    assert from_trace(records(overlapping)).redundant_navigations == 0


# --------------------------------------------------------------------------- redundant picks


@pytest.mark.parametrize(
    ("results", "redundant"),
    [
        pytest.param((pick("alice", 0, "apple"), pick("carol", 1, "apple", ok=False)), 1, id="teammate-holds-it"),
        pytest.param(
            (pick("alice", 0, "apple"), place("alice", 1, "apple"), pick("carol", 2, "apple")), 0, id="put-down-first"
        ),
        pytest.param(
            (pick("alice", 0, "apple"), place("alice", 1, "apple"), pick("carol", 1, "apple", ok=False)),
            1,
            id="put-down-at-once",
        ),
        pytest.param((pick("alice", 0, "apple", ok=False), pick("carol", 1, "apple")), 0, id="teammate-missed-it"),
        pytest.param((pick("alice", 1, "apple"), pick("carol", 1, "apple", ok=False)), 0, id="same-tick-lockstep"),
        pytest.param((pick("alice", 0, "apple"), pick("carol", 1, "pear")), 0, id="another-object"),
        pytest.param(
            (pick("alice", 0, "apple"), place("alice", 1, "apple", ok=False), pick("carol", 2, "apple", ok=False)),
            1,
            id="a-failed-place-keeps-it-held",
        ),
        pytest.param(
            (
                pick("alice", 0, "apple"),
                place("alice", 1, "apple"),
                pick("alice", 2, "apple"),
                pick("carol", 3, "apple", ok=False),
            ),
            1,
            id="picked-up-again",
        ),
    ],
)
def test_redundant_picks(results: tuple[dict[str, Any], ...], redundant: int) -> None:
    m = from_trace(records(_episode(*results, robots=("alice", "bob", "carol"))))
    assert (m.redundant_picks, m.redundant_navigations) == (redundant, 0)
    assert m.redundant_per_robot == {"alice": 0, "bob": 0, "carol": redundant}


def test_own_pick_again_is_not_a_teammates() -> None:
    m = from_trace(records(_episode(pick("alice", 0, "apple"), pick("alice", 1, "apple", ok=False))))
    assert m.redundant_picks == 0


# --------------------------------------------------------------------------- over episodes


def test_summary_of_team_metrics() -> None:
    a = from_trace(
        records(
            _episode(
                say("david", 0, "alice"), pick("alice", 0, "apple"), place("alice", 1, "apple"), nav("david", 1, "x")
            )
        )
    )
    b = from_trace(
        records(
            _episode(
                nav("david", 0, "cabinet"), nav("alice", 1, "cabinet"), pick("bob", 1, "pear"), say("bob", 2, "alice")
            )
        )
    )
    s = summarize([a, b])
    assert s["comm_steps"] == 1.0 and s["other_steps"] == 3.0 and s["as"] == 4.0
    assert (s["redundant"], s["redundant_navigations"], s["redundant_picks"]) == (0.5, 0.5, 0.0)
    assert s["moves"] == 1.5
    assert s["share"] == {"alice": round(2 / 3, 4), "bob": round(1 / 3, 4), "david": 0.0}  # moves over all moves
    nothing = from_trace(records(_episode(nav("david", 0, "x"))))
    assert summarize([nothing])["share"] == {}
    older = EpisodeMetrics.model_validate(  # a row written before the fields
        {k: v for k, v in a.as_dict().items() if k != "moves_per_robot"}
    )
    assert summarize([older, b])["comm_steps"] is None and summarize([older])["share"] is None
    assert summarize([older, b])["succ"] == summarize([a, b])["succ"]
