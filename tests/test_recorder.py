"""The trace recorder on a real bus: what it writes, in which order."""

from __future__ import annotations

from pathlib import Path

from waits import until

from mhrc.core.bus import Bus
from mhrc.core.endpoints import endpoint, free_port
from mhrc.core.keys import Keys
from mhrc.core.protocol import ActionAck, ActionRequest, Wait
from mhrc.core.records import read_records
from mhrc.core.trace import Recorder


def _request(goal: str) -> ActionRequest:
    return ActionRequest(goal_id=goal, robot="alice", agent_id="alice-1", tick=0, action=Wait())


async def test_an_answer_that_comes_before_its_request_is_written_after_it(tmp_path: Path) -> None:
    """Each subscriber has its own thread: the world may handle a request and ack it before the
    recorder's thread is given the request, so under load the ack can come first (a 3-worker
    run's viewer test counted 27 steps in the first half of a trace that held 25 requests:
    theirs were written at the end). Each request is written before its answers, at the time of
    its first answer; an answer whose request never comes is written at the end."""
    run = "rec-order"
    k = Keys(run)
    bus = await Bus.open(mode="router", listen=[endpoint("127.0.0.1", free_port())])
    recorder = Recorder(bus, run, tmp_path / "t.jsonl").start()
    try:
        ack = k.action_ack("alice")
        bus.put(ack, ActionAck(goal_id="late", robot="alice", accepted=True))  # the race: answers first
        bus.put(ack, ActionAck(goal_id="late-rejected", robot="alice", accepted=False, reason="not your turn"))
        bus.put(k.action_request("alice"), _request("in-order"))
        bus.put(ack, ActionAck(goal_id="in-order", robot="alice", accepted=True))
        bus.put(k.action_request("alice"), _request("late"))
        bus.put(k.action_request("alice"), _request("late-rejected"))
        bus.put(ack, ActionAck(goal_id="orphan", robot="alice", accepted=True))  # its request never comes
        bus.put(f"{k.base}/end", b'{"kind": "end"}')  # the subscriber's thread takes the samples in the order put:
        # once this line is written, every sample before it was handled
        await until(lambda: recorder.count >= 7, "the recorder's 7 lines", 15, every=0.05)
    finally:
        recorder.close()
        await bus.close()
    rows = read_records(tmp_path / "t.jsonl")  # the `end` line names no protocol kind: its key's last part
    order = [
        (r.msg.kind if r.msg is not None else r.key.rsplit("/", 1)[-1], getattr(r.msg, "goal_id", None)) for r in rows
    ]
    assert order == [
        ("action_request", "in-order"),
        ("action_ack", "in-order"),
        ("action_request", "late"),
        ("action_ack", "late"),
        ("action_request", "late-rejected"),
        ("action_ack", "late-rejected"),
        ("end", None),
        ("action_ack", "orphan"),
    ], order
    for goal in ("late", "late-rejected"):
        request, answer = (r.t for r in rows if getattr(r.msg, "goal_id", None) == goal)
        assert request == answer, f"the {goal} request takes the time of its answer"


async def test_a_payload_is_copied_as_it_came_when_ascii_and_on_one_line_and_written_again_otherwise(
    tmp_path: Path,
) -> None:
    """The recorder parses every payload (its checks read it) and copies an ASCII one on one line
    as it came instead of encoding it again; a payload with a line end between its tokens, or
    with characters beyond ASCII (U+2028 ends a line for str.splitlines), is written again by
    json.dumps, escaped. Either way the file is ASCII, one line per message, and every `msg`
    reads as the payload does."""
    import json

    run = "rec-copy"
    k = Keys(run)
    sent = {
        "ours": ActionAck(goal_id="g", robot="alice", accepted=True).model_dump_json().encode(),
        "spaced": b'{"kind": "x", "n": [1, 2.5, 1e-5]}',
        "lines": b'{\n"kind": "x",\r\n"n": 1}',
        "beyond": '{"kind":"x","text":"caf\u00e9 \u2028 done"}'.encode(),
        "escaped": b'{"kind":"x","text":"\\u00e9 \\ud800"}',  # an unpaired surrogate: Python's parser takes it
        "scalar": b"12",
    }
    bus = await Bus.open(mode="router", listen=[endpoint("127.0.0.1", free_port())])
    recorder = Recorder(bus, run, tmp_path / "t.jsonl").start()
    try:
        for name, payload in sent.items():
            bus.put(f"{k.base}/test/{name}", payload)
        await until(lambda: recorder.count >= len(sent), "every line", 15, every=0.05)
    finally:
        recorder.close()
        await bus.close()
    raw = (tmp_path / "t.jsonl").read_bytes()
    assert raw.isascii()
    lines = raw.decode().splitlines()
    assert len(lines) == len(sent)
    got = {line["key"].rsplit("/", 1)[-1]: line for line in map(json.loads, lines)}
    for name, payload in sent.items():
        assert got[name]["msg"] == json.loads(payload), name
    copied = {name for name, text in zip(got, lines) if text.endswith(',"msg":' + sent[name].decode("utf-8") + "}")}
    assert copied == {"ours", "spaced", "escaped", "scalar"}, copied
