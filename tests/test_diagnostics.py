"""Failure diagnostics (mhrc.analysis.diagnostics) over a hand-built trace and over real recorded episodes
(the heuristic team, and LLM agents against a scripted OpenAI-compatible server on loopback),
and the evaluation summaries that carry them: summary.md's table and summary.html."""

from __future__ import annotations

import asyncio
import csv
import io
import re
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import pytest
from json_rows import records
from test_metrics import _complete  # the protocol's required fields a hand-built message leaves out

from mhrc.analysis.diagnostics import diagnose, reject_kind
from mhrc.analysis.metrics import from_trace
from mhrc.core.protocol import EPISODE_OVER, LLM_ERROR_PREFIX
from mhrc.core.records import read_records
from mhrc.eval.engine import EvalSpec, evaluate
from mhrc.eval.means import summarize_diagnostics
from mhrc.eval.records import DIAG, EvalRow, upgrade_row
from mhrc.eval.rows import read_rows
from mhrc.eval.summaries import write_summaries
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.testing import ModelReply, ScriptedModelServer

# --------------------------------------------------------------------------- a hand-built trace

FURNITURE = [{"name": n, "kind": "table", "position": [0.0, 0.0, 0.0]} for n in ("table_0", "tray", "cabinet_0")]


def _put(kind: str, key: str = "world/event", **msg: Any) -> dict[str, Any]:
    return {"t": 0.0, "key": f"mhrc/r/{key}", "kind": "put", "msg": {"v": 2, "kind": kind, **_complete(kind, msg)}}


def _obs(
    robot: str, tick: int, objects: tuple[str, ...] = (), messages: tuple[dict[str, Any], ...] = ()
) -> dict[str, Any]:
    return {
        "robot": robot,
        "tick": tick,
        "status": {"name": robot, "kind": "k", "skills": []},
        "furniture": FURNITURE,
        "objects": [{"name": o, "position": [0.0, 0.0, 0.0], "on": "table_0"} for o in objects],
        "task_brief": "",
        "task_detail": "",
        "new_messages": list(messages),
    }


def _result(
    robot: str, tick: int, action: dict[str, Any], code: str = "ok", feedback: str = "", **obs: Any
) -> dict[str, Any]:
    outcome = {"succeeded": code == "ok", "code": code, "feedback": feedback, "details": {}, "sim_time": 0.5}
    return _put(
        "action_result",
        f"robot/{robot}/action/result",
        goal_id=f"{robot}{tick}",
        robot=robot,
        tick=tick,
        action=action,
        outcome=outcome,
        observation=_obs(robot, tick + 1, **obs),
        done=False,
    )


def _thought(robot: str, tick: int, error: str | None = None) -> dict[str, Any]:
    return _put(
        "thought",
        f"agent/{robot}/thought",
        robot=robot,
        tick=tick,
        policy="llm:m",
        prompt="p",
        reply="r",
        parse_error=error,
    )


WAIT = {"skill": "wait"}
GARAGE = {"skill": "navigate", "target": "garage", "stand_pose": 0}
TO_BOB = {"sender": "alice", "to": "bob", "content": "Bob, the mug is on table_0.", "tick": 0}
TO_ALICE = {"sender": "bob", "to": "alice", "content": "Thanks.", "tick": 2}


def hand_built() -> list[dict[str, Any]]:
    """Three ticks of three robots, holding exactly: a hallucinated name (garage, twice: the
    second a repeated failure), a capability violation (David picks), a parse failure (Bob, tick
    0), a lost LLM step (David, tick 2), a rejected action (stale tick), a chosen wait with a
    message pending (Bob, tick 1), two messages sent and read."""
    started: dict[str, Any] = {
        "run": "r",
        "task": "pack_objects",
        "scene": "kitchen",
        "seed": 0,
        "n_objects": 3,
        "robots": ["alice", "bob", "david"],
        "horizon": 10,
        "lower_bound": 2,
    }
    rows = [_put("episode_started", **started), _thought("bob", 0, "no command found: end the reply with one command")]
    rows += [
        _result("alice", 0, {"skill": "communicate", "content": TO_BOB["content"], "to": "bob"}, objects=("mug",)),
        _result("bob", 0, WAIT, messages=(TO_BOB,)),
        _result("david", 0, {"skill": "pick", "obj": "mug"}, "not_capable", "David cannot pick."),
        _put("message", "robot/bob/inbox/alice", **TO_BOB),
        _put(
            "action_ack",
            "robot/david/action/ack",
            goal_id="late",
            robot="david",
            accepted=False,
            reason="the request is for tick 0 but the world is at tick 1",
        ),
        _put("tick", tick=0),
        _thought("bob", 1),
        _result(
            "alice",
            1,
            GARAGE,
            "target_unknown",
            "There is no 'garage' in your scene graph; furniture: table_0.",
            objects=("mug",),
        ),
        _result("bob", 1, WAIT),
        _result("david", 1, {"skill": "navigate", "target": "cabinet_0", "stand_pose": 0}),
        _put("tick", tick=1),
        _thought("david", 2, LLM_ERROR_PREFIX + "m at http://x failed after 5 attempts: HTTP 503"),
        _result(
            "alice",
            2,
            GARAGE,
            "target_unknown",
            "There is no 'garage' in your scene graph; furniture: table_0.",
            messages=(TO_ALICE,),
        ),
        _result("bob", 2, {"skill": "communicate", "content": TO_ALICE["content"], "to": "alice"}),
        _result("david", 2, WAIT),
        _put("message", "robot/alice/inbox/bob", **TO_ALICE),
        _put("tick", tick=2),
    ]
    metrics = {
        "success": False,
        "placed": 1,
        "total": 3,
        "partial_success": 1 / 3,
        "temporal_steps": 3,
        "action_steps": 6,
        "action_steps_per_robot": {},
    }
    return rows + [_put("episode_done", run="r", reason="horizon", metrics=metrics)]


def test_a_hand_built_trace_gives_exactly_what_it_holds() -> None:
    d = diagnose(records(hand_built())).as_dict()
    assert d == {
        "llm_steps": 3,
        "parse_failures": 1,
        "llm_unreachable": 1,
        "hallucinations": 2,
        "hallucinated_names": {"garage": 2},
        "not_capable": 1,
        "rejected": 1,
        "rejected_by_reason": {"stale_tick": 1},
        "failed": 3,
        "failed_by_code": {"not_capable": 1, "target_unknown": 2},
        "failed_by_skill": {"navigate": {"target_unknown": 2}, "pick": {"not_capable": 1}},
        "repeated_failures": 1,
        "waits": 1,
        "waits_with_pending": 1,  # Bob's tick-0 and David's tick-2 waits were forced, not chosen
        "messages_sent": 2,
        "messages_read": 2,
        "steps_above_bound": 1,  # 3 ticks, bound 2
    }
    m = from_trace(records(hand_built()))  # the same trace, the metrics' own counts
    assert (m.parse_failures, m.llm_unreachable, m.rejected_actions, m.messages) == (1, 1, 1, 2)
    assert m.failed_actions == {"navigate": 2, "pick": 1}


def test_without_the_planning_observation_the_worlds_verdict_decides() -> None:
    """A robot's first step plans on its attach reply, which the trace does not hold: an unknown
    name is then what the world said it did not know, not an object another robot holds."""
    started: dict[str, Any] = {
        "run": "r",
        "task": "pack_objects",
        "scene": "kitchen",
        "seed": 0,
        "n_objects": 3,
        "robots": ["alice", "bob"],
        "horizon": 5,
    }
    rows = [
        _put("episode_started", **started),
        _result(
            "alice",
            0,
            {"skill": "pick", "obj": "ghost"},
            "object_unknown",
            "There is no 'ghost' in your scene graph; objects you know: mug.",
            objects=("mug",),
        ),
        _result(
            "bob",
            0,
            {"skill": "pick", "obj": "mug"},
            "object_unknown",
            "mug is held by alice; you cannot pick it now.",
            objects=("mug",),
        ),
        _result(
            "bob",
            1,
            {"skill": "place", "obj": "mug", "location": "moon"},
            "location_unknown",
            "There is no place called 'moon'; places: tray.",
        ),
        _result(
            "alice",
            1,
            {"skill": "place", "obj": "mug", "location": "sofa"},
            "location_unknown",
            "Objects cannot be placed on or into sofa.",
        ),
    ]
    # bob's and alice's tick-1 actions planned on observations the trace holds: neither "moon" nor "sofa" is in them
    d = diagnose(records(rows))
    assert (d.hallucinations, d.hallucinated_names, d.steps_above_bound) == (
        3,
        {"ghost": 1, "moon": 1, "sofa": 1},
        None,
    )
    assert d.failed_by_code == {"location_unknown": 2, "object_unknown": 2} and d.repeated_failures == 0


@pytest.mark.parametrize(
    "reason, kind",
    [
        ("the request is for tick 3 but the world is at tick 4", "stale_tick"),
        ("bob already submitted an action for tick 4", "busy"),
        ("alice is still busy with navigate(table_0, 0): send the next action after its result", "busy"),
        ("it is alice's turn in tick 2: bob waits for its own", "out_of_turn"),
        (EPISODE_OVER, "episode_over"),
        ("malformed action request: action: Field required", "malformed"),
        ("robot bob is not attached: attach first", "not_attached"),
        ("something new", "other"),
    ],
)
def test_rejections_recorded_without_a_code_are_grouped_by_their_text(reason: str, kind: str) -> None:
    assert reject_kind(reason) == kind


@pytest.mark.parametrize(
    ("code", "kind"),
    [
        ("stale_tick", "stale_tick"),
        ("tick_taken", "busy"),
        ("busy", "busy"),
        ("not_your_turn", "out_of_turn"),
        ("episode_over", "episode_over"),
        ("malformed", "malformed"),
        ("not_attached", "not_attached"),
        ("other_agent", "not_attached"),
        ("wrong_key", "not_attached"),
        ("no_such_robot", "not_attached"),
    ],
)
def test_a_rejections_code_decides_its_kind_whatever_its_text(code: str, kind: str) -> None:
    from mhrc.analysis.diagnostics import KIND_OF_CODE
    from mhrc.core.protocol import RejectCode

    assert set(KIND_OF_CODE) == {c.value for c in RejectCode}  # every code the world sends has its kind
    assert reject_kind("a sentence a later world may word differently", code) == kind


# --------------------------------------------------------------------------- real recorded episodes


def _scripted(body: dict[str, Any]) -> ModelReply:
    """Bob's first reply has no command; David tries to pick (he has no arm); Alice navigates
    twice to furniture that does not exist, then messages Bob; everything else waits."""
    system = body["messages"][0]["content"]
    step = ScriptedModelServer.step_of(body)
    robot = system.split()[2].rstrip(",").lower()  # "You are Bob, ..."
    script = {
        ("bob", 0): "Let me think about the tray first.",
        ("david", 0): "Command: pick(mug)",
        ("alice", 0): "Command: navigate(garage, 0)",
        ("alice", 1): "Command: navigate(garage, 0)",
        ("alice", 2): 'Command: communicate("Bob, where is the tray?", bob)',
    }
    text = script.get((robot, step), "Analysis: nothing to do.\nCommand: wait()")
    return ModelReply(text, usage={"prompt_tokens": 50, "completion_tokens": 9})


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("recorded")
    heuristic, llm = out / "heuristic.jsonl", out / "llm.jsonl"
    asyncio.run(up_in_process(EpisodeConfig.build(seed=0, horizon=50, trace=heuristic).resolved()))
    server = ScriptedModelServer(_scripted, when_done=None)
    try:
        cfg = EpisodeConfig.build(
            seed=0,
            horizon=5,
            trace=llm,
            llm="openai:test-model",
            base_url=server.url,
            llm_timeout=5.0,
            schedule="sequential",
        )
        asyncio.run(up_in_process(cfg.resolved()))
    finally:
        server.close()
    return {"heuristic": heuristic, "llm": llm}


def _consistent(rows: list[dict[str, Any]]) -> tuple[Any, Any]:
    d, m = diagnose(rows), from_trace(rows)
    assert (d.parse_failures, d.llm_unreachable, d.rejected, d.messages_sent) == (
        m.parse_failures,
        m.llm_unreachable,
        m.rejected_actions,
        m.messages,
    )
    assert {s: sum(c.values()) for s, c in d.failed_by_skill.items()} == m.failed_actions and d.failed == sum(
        m.failed_actions.values()
    )
    assert d.llm_steps == m.llm_calls and d.messages_read <= d.messages_sent
    excess = m.temporal_steps - m.lower_bound if m.lower_bound is not None else None
    # below the bound the episode was cut off by its horizon: no excess to tell, never a negative one
    assert excess is not None and d.steps_above_bound == (excess if excess >= 0 else None)
    return d, m


def test_a_heuristic_episode_has_no_llm_failures_and_no_hallucinations(recorded: dict[str, Path]) -> None:
    d, m = _consistent(read_records(recorded["heuristic"]))
    assert m.success and d.steps_above_bound is not None and d.steps_above_bound >= 0
    assert (d.parse_failures, d.hallucinations, d.not_capable, d.rejected, d.repeated_failures) == (0, 0, 0, 0, 0)
    assert d.messages_sent == d.messages_read > 0  # every report David sends reaches Alice


def test_a_scripted_llm_episode_shows_its_bad_replies(recorded: dict[str, Path]) -> None:
    d, m = _consistent(read_records(recorded["llm"]))
    assert d.parse_failures == m.parse_failures == 1
    assert d.hallucinated_names == {"garage": 2, "mug": 1}  # David's pick names a mug his own scene graph does not hold
    assert (d.hallucinations, d.not_capable, d.repeated_failures) == (3, 1, 1)
    assert d.failed_by_code == {"not_capable": 1, "target_unknown": 2}
    assert (d.messages_sent, d.messages_read) == (1, 1)
    assert d.waits_with_pending == 2  # Bob waits in ticks 3 and 4 with Alice's question unanswered


# --------------------------------------------------------------------------- summaries


class _Page(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.tags: list[str] = []
        self.links: list[str] = []
        self.images: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append(tag)
        a = dict(attrs)
        if tag == "a" and a.get("href"):
            self.links.append(str(a["href"]))
        if tag == "img" and a.get("src"):
            self.images.append(str(a["src"]))


def _flat(key: str, trace: Path, **extra: Any) -> dict[str, Any]:
    """A row of episode `key` (its seed the key's) as episodes.jsonl holds it."""
    rows = read_records(trace)
    return {
        "key": key,
        "method": extra.pop("method", "heuristic"),
        "ablation": "none",
        "repeat": 0,
        "trial": 0,
        **from_trace(rows).as_dict(),
        "seed": int(key.rsplit("/", 1)[1]),
        "history_cap": None,
        "mode": "free",
        "schedule": "sequential",
        "trace": f"traces/{key.replace('/', '_')}.jsonl",
        **{DIAG + k: v for k, v in diagnose(rows).as_dict().items()},
        **extra,
    }


def _row(key: str, trace: Path, **extra: Any) -> EvalRow:
    return upgrade_row(_flat(key, trace, **extra))


def test_summaries_carry_the_diagnostics_and_the_page_links_every_episode(
    recorded: dict[str, Path], tmp_path: Path
) -> None:
    rows = [
        _row("pack_objects/kitchen/4/0", recorded["heuristic"]),
        _row("pack_objects/kitchen/4/1", recorded["llm"], method="openai:test-model"),
    ]
    old = upgrade_row(  # before diagnostics
        {k: v for k, v in _flat("pack_objects/kitchen/4/2", recorded["heuristic"]).items() if not k.startswith(DIAG)}
    )
    rows.append(old)
    assert old.diagnostics is None and rows[0].diagnostics is not None
    s = summarize_diagnostics([r.diagnostics for r in rows])
    assert (s["episodes"], s["known"], s["unknown"]) == (3, 2, 1)
    assert s["total"]["parse_failures"] == 1 and s["mean"]["parse_failures"] == 0.5  # the old row is unknown, not zero
    assert s["hallucinated_names"] == {"garage": 2, "mug": 1}
    assert summarize_diagnostics([r.diagnostics for r in rows[2:]])["mean"]["hallucinations"] is None

    write_summaries(rows, tmp_path)
    md = (tmp_path / "summary.md").read_text()
    assert "## Failure diagnostics" in md
    assert re.search(
        r"\| pack_objects \| 1 \(1\) \| 1\.00 \| 3\.00 \| 1\.00 \| 0\.00 \| 3\.00 \(target_unknown 2\.00, not_capable 1\.00\) \| 1\.00 \| 2\.00 / ",
        md,
    ), md
    assert (
        "| pack_objects | 2 (1) |" in md and "1 episode of this setting was recorded before diagnostics existed" in md
    )
    line = next(
        r
        for r in csv.DictReader(io.StringIO((tmp_path / "summary.csv").read_text()))
        if r["method"] == "openai:test-model"
    )
    assert (line["diag_episodes"], line["diag_hallucinations"], line["diag_repeated_failures"]) == ("1", "3.0", "1.0")

    page = (tmp_path / "summary.html").read_text()
    parser = _Page()
    parser.feed(page)
    parser.close()
    assert "table" in parser.tags and (
        "svg" in parser.tags or any(i.startswith("data:image/png;base64,") for i in parser.images)
    )
    assert (
        "Table I: methods" in page
        and "Failure diagnostics" in page
        and "Per setting, with 95% confidence intervals" in page
    )
    assert sorted(parser.links) == [
        "traces/pack_objects_kitchen_4_0.html",
        "traces/pack_objects_kitchen_4_1.html",
        "traces/pack_objects_kitchen_4_2.html",
    ]
    assert not re.search(r"(src|href)=\"(https?:|//)|<link|<script", page)  # self-contained: nothing to fetch


def test_an_evaluation_writes_diagnostics_on_every_row_and_an_html_summary(tmp_path: Path) -> None:
    spec = EvalSpec(tasks=("pack_objects",), scenes=("kitchen",), objects=(3,), trials=1)
    rows = asyncio.run(evaluate(spec, tmp_path / "ev", workers=1))
    assert rows == read_rows(tmp_path / "ev" / "episodes.jsonl") and len(rows) == 1
    r = rows[0].flat()  # as the file holds it
    assert (r["diag_parse_failures"], r["diag_hallucinations"], r["diag_rejected_by_reason"]) == (0, 0, {})
    m = rows[0].metrics
    assert m.lower_bound is not None
    assert r["diag_steps_above_bound"] == m.temporal_steps - m.lower_bound and r["diag_messages_sent"] == m.messages
    page = (tmp_path / "ev" / "summary.html").read_text()
    assert f'href="traces/{Path(str(rows[0].trace)).stem}.html"' in page
