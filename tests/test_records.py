"""The typed trace reader (mhrc.core.records): lines decoded once, older lines upgraded, codes derived once."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from test_metrics import _trace

from mhrc.core import records
from mhrc.core.protocol import LLM_ERROR_PREFIX, ActionAck, EpisodeStarted, RejectCode, Thought
from mhrc.core.protocol.thoughts import ReplyFailure
from mhrc.core.records import LineError, LineKind, NotCopied, TraceLineError, decode_row, parse_line, read_records
from mhrc.core.upgrade import UNRECORDED


def _line(msg: Any, key: str = "mhrc/r/world/event", kind: str = "put", t: float = 0.5) -> dict[str, Any]:
    return {"t": t, "key": key, "kind": kind, "msg": msg}


def _write(path: Path, lines: list[Any]) -> Path:
    path.write_text(
        "".join((line if isinstance(line, str) else json.dumps(line)) + "\n" for line in lines), encoding="utf-8"
    )
    return path


STARTED = {"v": 1, "kind": "episode_started", "run": "r", "task": "pack_objects", "scene": "kitchen", "seed": 0, "n_objects": 3,
           "robots": ["alice"], "horizon": 5}  # fmt: skip  # as a world wrote it before fidelity and noise were recorded


def test_a_trace_reads_as_typed_records(tmp_path: Path) -> None:
    thought = Thought(
        robot="bob",
        tick=0,
        policy="llm:m",
        prompt="p",
        parse_error=LLM_ERROR_PREFIX + "m failed after 5 attempts",
        failure=ReplyFailure.MODEL_UNREACHABLE,
    ).model_dump(mode="json")
    path = _write(
        tmp_path / "t.jsonl",
        [
            _line(STARTED),
            _line(thought, "mhrc/r/agent/bob/thought", t=1.0),
            "",
            _line(None, "mhrc/r/alive/robot/bob", "alive"),
            _line({"raw": "x"}, "mhrc/r/robot/bob/action/request"),
        ],
    )
    lines = read_records(path)
    assert [line.number for line in lines] == [1, 2, 4, 5]  # the blank line 3 is skipped, still counted
    assert isinstance(lines[0].msg, EpisodeStarted) and isinstance(lines[1].msg, Thought)
    assert (
        lines[1].failure is ReplyFailure.MODEL_UNREACHABLE and lines[2].kind is LineKind.ALIVE and lines[2].msg is None
    )
    assert lines[3].msg is None and lines[3].problem is None and lines[3].named is None  # names no model
    assert lines[0].named == "episode_started" and lines[1].named == "thought"


def test_older_lines_are_upgraded_on_read() -> None:
    started = decode_row(_line(STARTED), 1).msg
    assert isinstance(started, EpisodeStarted) and started.fidelity == UNRECORDED and started.noise.setting == "on"
    exact = decode_row(_line({**STARTED, "aids": ["exact_motion"]}), 1).msg
    assert isinstance(exact, EpisodeStarted) and exact.noise.setting == "off"  # it ran without noise
    old_ack = {
        "v": 1,
        "kind": "action_ack",
        "goal_id": "g",
        "robot": "bob",
        "accepted": False,
        "reason": "the request is for tick 2, the world is at tick 3",
    }
    ack = decode_row(_line(old_ack, "mhrc/r/robot/bob/action/ack"), 1).msg
    assert isinstance(ack, ActionAck) and ack.code is RejectCode.STALE_TICK  # the code its reason stood for
    junk = decode_row(
        _line(
            {"count": 4, "bytes": 900, "reason": "rejected: Bob is still busy"}, "mhrc/r/robot/bob/action/ack", "junk"
        ),
        1,
    ).junk
    assert junk is not None and (junk.count, junk.code, junk.excerpt) == (4, RejectCode.BUSY, None)


def test_a_name_longer_than_todays_bound_reads_as_recorded() -> None:
    """An older world executed a pick of a 1,000-character name; today's bound is for admission, not reading."""
    name = "x" * 1000
    request = {
        "v": 2,
        "kind": "action_request",
        "goal_id": "g1",
        "robot": "bob",
        "agent_id": "a" * 300,
        "tick": 0,
        "action": {"skill": "pick", "obj": name},
    }
    line = decode_row(_line(request, "mhrc/r/robot/bob/action/request"), 7)
    assert line.problem is None and line.msg is not None and line.msg.model_dump(mode="json") == request


@pytest.mark.parametrize(
    ("text", "code", "where"),
    [
        ('{"t": 0.1, "key": "mhrc/r/world/event", "kind": "put", "msg": {', LineError.NOT_JSON, "line 3"),
        ('["not", "a", "line"]', LineError.NOT_A_LINE, "line 3"),
        ('{"t": "soon", "key": "mhrc/r/world/event", "kind": "put", "msg": null}', LineError.NOT_A_LINE, "line 3"),
        # an integer no float holds (an OverflowError before)
        (
            '{"t": 1' + "0" * 400 + ', "key": "mhrc/r/world/event", "kind": "put", "msg": null}',
            LineError.NOT_A_LINE,
            "line 3",
        ),
        ('{"t": 0.1, "key": "mhrc/r/world/event", "kind": "shout", "msg": null}', LineError.UNKNOWN_KIND, "line 3"),
    ],
)
def test_a_malformed_line_is_a_typed_error_naming_its_line(
    tmp_path: Path, text: str, code: LineError, where: str
) -> None:
    path = _write(tmp_path / "t.jsonl", [_line(STARTED), _line(None, "mhrc/r/alive/world", "alive"), text])
    with pytest.raises(TraceLineError) as caught:
        read_records(path)
    assert caught.value.code is code and caught.value.line == 3 and caught.value.path == path
    assert f"{path}, {where} is not a trace line ({code.value})" in str(caught.value)
    assert isinstance(caught.value, ValueError)  # callers that catch ValueError, as for bad JSON before, still do


def test_a_message_that_does_not_fit_its_model_is_kept_with_the_reason() -> None:
    line = decode_row(_line({"v": 2, "kind": "thought", "robot": "bob"}, "mhrc/r/agent/bob/thought"), 9)
    assert line.msg is None and line.failure is None and line.problem is not None and "tick" in line.problem


@pytest.mark.parametrize(
    ("parse_error", "finish_reason", "code"),
    [
        (None, "stop", None),
        ("", "stop", None),
        (LLM_ERROR_PREFIX + "no answer within the step deadline of 6 s", None, ReplyFailure.MODEL_UNREACHABLE),
        (
            LLM_ERROR_PREFIX + "m at http://x failed after 5 attempts: HTTP 503",
            "length",
            ReplyFailure.MODEL_UNREACHABLE,
        ),
        (
            "your reply was cut at the token limit before it gave a command; think more briefly",
            "length",
            ReplyFailure.CUT_OFF,
        ),
        ("no command found: give one command, such as Command: pick(apple)", "stop", ReplyFailure.UNREADABLE),
    ],
)
def test_an_older_thoughts_failure_is_upgraded_to_its_code(
    parse_error: str | None, finish_reason: str | None, code: ReplyFailure | None
) -> None:
    """A thought recorded before thoughts carried `failure` reads with the code its texts stand for
    (mhrc.core.upgrade); one that carries it reads as it says, whatever its texts."""
    old = Thought(robot="bob", tick=0, policy="llm:m", prompt="p", parse_error=parse_error, finish_reason=finish_reason)
    row = old.model_dump(mode="json")
    del row["failure"]  # as a world of before issue 44 wrote it
    line = decode_row(_line(row, "mhrc/r/agent/bob/thought"), 1)
    assert isinstance(line.msg, Thought) and line.msg.failure is code and line.failure is code
    assert code is None or code.unparsed == (code is not ReplyFailure.MODEL_UNREACHABLE)
    today = old.model_copy(update={"failure": ReplyFailure.UNREADABLE}).model_dump(mode="json")
    assert decode_row(_line(today, "mhrc/r/agent/bob/thought"), 1).failure is ReplyFailure.UNREADABLE


def test_a_junk_line_keeps_the_recorders_own_code() -> None:
    """A `thoughts_ahead` count has no excerpt; upgrading it read its code from the reason as a
    rejection's and lost it (the flood test saw None)."""
    row = {"count": 3, "bytes": 10, "reason": "more than 8 thoughts", "code": "thoughts_ahead"}
    line = decode_row({"t": 0.0, "key": "mhrc/r/agent/alice/thought", "kind": "junk", "msg": row}, 1)
    assert line.junk is not None and line.junk.code is NotCopied.THOUGHTS_AHEAD and line.junk.excerpt is None
    old = decode_row(
        {
            "t": 0.0,
            "key": "mhrc/r/robot/alice/action/request",
            "kind": "junk",
            "msg": {**row, "code": None, "reason": "malformed: x"},
        },
        2,
    )
    assert old.junk is not None and old.junk.code is RejectCode.MALFORMED


def test_a_put_of_todays_shape_reads_in_one_pass_as_the_long_way_reads_it() -> None:
    """parse_line validates a put of today's shape from its text in one pass (records._put); it makes the
    TraceLine decode_row makes of the line's JSON, and leaves every line `upgrade` would change (and any
    other) to the long way."""
    ack = {
        "v": 2,
        "kind": "action_ack",
        "goal_id": "g",
        "robot": "bob",
        "accepted": False,
        "reason": "Bob is still busy",
    }
    thought = {"v": 2, "kind": "thought", "robot": "bob", "tick": 0, "policy": "llm:m", "parse_error": "no action"}
    today = [_line(m, "mhrc/r/robot/bob/x") for m in (ack | {"code": "busy"}, thought | {"failure": "unreadable"})]
    today += [line for line in _trace() if line["kind"] == "put" and line["msg"]["kind"] != "episode_started"]
    long_name = {"v": 2, "kind": "action_request", "goal_id": "g", "robot": "bob", "agent_id": "a",
                 "tick": 0, "action": {"skill": "pick", "obj": "x" * 1000}}  # fmt: skip
    pose = {"x": 10**400, "y": 0.0, "yaw": 0.0}  # no float: model_validate refuses it, pydantic's JSON parser reads inf
    huge = {"v": 2, "kind": "snapshot", "tick": 0, "goals": [], "robots": {"bob": pose}, "objects": {}, "open": {}}
    older = [_line(m, "mhrc/r/robot/bob/x") for m in (STARTED, ack, thought, long_name, huge)]
    others = [_line(None, "mhrc/r/alive/robot/bob", "alive"), _line({"kind": "tick", "tick": "x"}), _line(ack, t=True)]
    for n, line in enumerate(today + older + others, 1):
        text = json.dumps(line)
        fast = records._put(text, n)
        assert (fast is not None) == (line in today), line
        try:
            long_way = decode_row(json.loads(text), n)
        except TraceLineError as exc:
            with pytest.raises(TraceLineError, match=exc.code.value):
                parse_line(text, n)
        else:
            assert parse_line(text, n) == long_way and (fast is None or fast == long_way)
    assert parse_line(json.dumps(_line(ack, "k")), 1).msg.code is RejectCode.BUSY  # type: ignore[union-attr]  # upgraded
