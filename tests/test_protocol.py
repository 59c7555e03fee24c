from __future__ import annotations

import pytest

from mhrc.core.keys import InvalidId, Keys
from mhrc.core.protocol import (
    PROTOCOL_VERSION,
    ActionRequest,
    Navigate,
    Pick,
    ProtocolError,
    TickClosed,
    decode,
    decode_event,
    encode,
    parse_action,
)


def test_actions_are_a_discriminated_union() -> None:
    assert parse_action({"skill": "navigate", "target": "table_1", "stand_pose": 1}) == Navigate(
        target="table_1", stand_pose=1
    )
    assert parse_action({"skill": "pick", "obj": "apple"}) == Pick(obj="apple")
    with pytest.raises(ProtocolError, match="fly"):
        parse_action({"skill": "fly"})
    with pytest.raises(ProtocolError, match="stand_pose"):
        parse_action({"skill": "navigate", "target": "t", "stand_pose": -1})


def test_request_round_trip_and_version() -> None:
    req = ActionRequest(robot="alice", agent_id="a1", tick=3, action=Pick(obj="apple"))
    back = decode(encode(req), ActionRequest)
    assert back == req and back.v == PROTOCOL_VERSION == 2 and back.goal_id
    old = decode(b'{"v": 1, "robot": "alice", "agent_id": "a", "tick": 0, "action": {"skill": "wait"}}', ActionRequest)
    assert old.v == 1  # a version-1 message reads as it always did


@pytest.mark.parametrize(
    "payload, reason",
    [
        (b"not json", "Invalid JSON"),
        (b'{"v": 3, "robot": "alice", "agent_id": "a", "tick": 0, "action": {"skill": "wait"}}', "v"),
        (b'{"v": 1, "robot": "alice", "agent_id": "a", "tick": 0, "action": {"skill": "pick"}}', "action.pick.obj"),
        (b'{"v": 1, "robot": "alice", "agent_id": "a", "tick": -1, "action": {"skill": "wait"}}', "tick"),
        (b'{"v": 1, "robot": "alice", "agent_id": "a", "tick": 0, "action": {"skill": "wait"}, "x": 1}', "x"),
    ],
)
def test_malformed_payloads_are_rejected_with_a_reason(payload: bytes, reason: str) -> None:
    with pytest.raises(ProtocolError, match=reason.replace(".", r"\.")):
        decode(payload, ActionRequest)


def test_world_events_decode_by_kind() -> None:
    ev = TickClosed(tick=2, actions={"bob": "wait()"}, outcomes={"bob": True}, placed=1, total=3)
    assert decode_event(encode(ev)) == ev
    with pytest.raises(ProtocolError):
        decode_event(b'{"v": 1, "kind": "nonsense"}')


def test_keys_reject_ids_that_are_not_one_chunk() -> None:
    k = Keys("run-1")
    assert k.action_request("alice") == "mhrc/run-1/robot/alice/action/request"
    assert k.robot_of(k.inbox("bob", "alice")) == "bob"
    for bad in ("Alice", "a/b", "*", "", "a b"):
        with pytest.raises(InvalidId):
            k.action_request(bad)
    with pytest.raises(InvalidId):
        Keys("run/1")


# --------------------------------------------------------------------------- limits (issue 38; docs/protocol.md, "Limits")
def _req(**fields: object) -> bytes:
    import json

    return json.dumps(
        {"v": 2, "robot": "alice", "agent_id": "a", "tick": 0, "action": {"skill": "wait"}} | fields
    ).encode()


@pytest.mark.parametrize(
    "payload, field",
    [
        (_req(agent_id="a" * 129), "agent_id"),
        (_req(robot="r" * 65), "robot"),
        (_req(action={"skill": "pick", "obj": "o" * 65}), "action.pick.obj"),
        (_req(action={"skill": "place", "obj": "o", "location": "l" * 65}), "action.place.location"),
        (_req(action={"skill": "navigate", "target": "t" * 65}), "action.navigate.target"),
        (_req(action={"skill": "navigate", "target": "t", "stand_pose": 2**31}), "action.navigate.stand_pose"),
        (_req(action={"skill": "communicate", "content": "hi", "to": "t" * 65}), "action.communicate.to"),
        (_req(tick=2**31), "tick"),
        (_req(goal_id="g" * 65), "goal_id"),
        (
            b'{"v": 2, "robot": "alice", "agent_id": "a", "tick": 0, "action": {"skill": "move", "dx": NaN, "dy": 0}}',
            "action.move.dx",
        ),
        (
            b'{"v": 2, "robot": "alice", "agent_id": "a", "tick": 0, "action": {"skill": "move", "dx": 0, "dy": -Infinity}}',
            "action.move.dy",
        ),
        (
            b'{"v": 2, "robot": "alice", "agent_id": "a", "tick": 0, "action": {"skill": "move", "dx": 1e999, "dy": 0}}',
            "action.move.dx",
        ),
        (
            b'{"v": 2, "robot": "alice", "agent_id": "a", "tick": 0, "action": {"skill": "move", "dx": 100.5, "dy": 0}}',
            "action.move.dx",
        ),
    ],
)
def test_fields_past_their_limits_are_malformed(payload: bytes, field: str) -> None:
    with pytest.raises(ProtocolError, match=field.replace(".", r"\.")):
        decode(payload, ActionRequest)


def test_the_longest_names_and_moves_within_the_limits_are_valid() -> None:
    from mhrc.core.protocol import Move, Navigate

    req = decode(
        _req(
            agent_id="a" * 128,
            goal_id="g" * 64,
            action={"skill": "navigate", "target": "t" * 64, "stand_pose": 2**31 - 1},
        ),
        ActionRequest,
    )
    assert req.action == Navigate(target="t" * 64, stand_pose=2**31 - 1)
    assert decode(_req(action={"skill": "move", "dx": -100, "dy": 100.0}), ActionRequest).action == Move(
        dx=-100, dy=100
    )


def test_size_and_nesting_are_bounded_before_python_recurses() -> None:
    """A payload past max_bytes is refused unread; one nested 100k deep is a ProtocolError from
    both parsers (Python's json raises RecursionError on it: `loads` turns that into one)."""
    from mhrc.core.protocol.base import MAX_REQUEST_BYTES, loads

    with pytest.raises(ProtocolError, match="more than the 65536"):
        decode(_req(agent_id="a" * MAX_REQUEST_BYTES), ActionRequest, max_bytes=MAX_REQUEST_BYTES)
    deep = b"[" * 100_000 + b"]" * 100_000
    with pytest.raises(ProtocolError, match="recursion limit"):
        decode(deep, ActionRequest)
    with pytest.raises(ProtocolError, match="RecursionError"):
        loads(deep)
    with pytest.raises(ProtocolError, match="not JSON"):
        loads(b"[1" + b"0" * 5000 + b"]")  # past Python's 4,300 digits


def test_loads_takes_what_pythons_parser_takes_and_reads_it_alike() -> None:
    """`loads` reads with pydantic's parser first; what that one refuses and Python's takes (an
    unpaired surrogate's escape, nesting past 200 levels) is still read, as json.loads reads it."""
    import json

    from mhrc.core.protocol.base import loads

    for doc in (
        b'{"a":[1,2.5,-0.0,1e400,null,true],"b":"\\u00e9"}',
        b'"\\ud800"',
        b"[" * 300 + b"]" * 300,
        b"NaN",
        b'{"a":1,"a":2}',
        '"caf\u00e9"'.encode(),
    ):
        got, want = loads(doc), json.loads(doc)
        assert json.dumps(got) == json.dumps(want), doc[:40]
    for bad in (b"", b"{", b"[1,]", b'"\x01"', b"\xff"):
        with pytest.raises(ProtocolError, match="not JSON"):
            loads(bad)


def test_a_reason_never_quotes_a_long_input_whole() -> None:
    with pytest.raises(ProtocolError) as exc:
        decode(_req(action={"skill": "x" * 100_000}), ActionRequest)
    assert len(str(exc.value)) < 1000
