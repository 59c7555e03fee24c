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
    assert parse_action({"skill": "navigate", "target": "table_1", "stand_pose": 1}) == Navigate(target="table_1", stand_pose=1)
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
