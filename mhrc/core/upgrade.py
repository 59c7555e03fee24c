"""Traces written by older mhrc versions, brought to today's shape as they are read: the one place
that knows what changed (`upgrade`), so no reader of a trace guesses from missing fields or texts.

The line format (`t`, `key`, `kind`, `msg`) never changed, and no field of a message was renamed or
removed (every field added later has a default). What older traces lack, and what each is read as:

- an `action_ack` rejected without a `code` (before reject codes, issue 24): the code its reason's
  text stands for (`legacy_reject_code`), None for a reason no code covers;
- a `junk` line without a `code` (the recorder's counts before reject codes): the same, read from
  its reason (`rejected: ` and the ack's reason), and without an `excerpt`: none;
- an `episode_started` without `fidelity` (before fidelity was recorded): UNRECORDED, not the
  model's default `paper`;
- an `episode_started` without `noise` (before the motion noise was recorded): the calibration, or
  none under the exact_motion aid (mhrc.core.fidelity.recorded_noise);
- an `episode_started` without `team` (before teams were data, issue 33): the paper's team, those of
  Alice, Bob and David the episode ran (`paper_team`: the no_mobile ablation ran Alice and Bob), which
  is what today's world records for the same episode;
- a `thought` without `failure` (before a step's failure was a code on the wire, issue 44): the code
  its parse_error's text stands for (`legacy_failure`): a model that did not answer wrote
  LLM_ERROR_PREFIX first, a reply cut at the token limit finished with `length`, any other
  parse_error was a reply that did not parse; none without a parse_error.
"""

from __future__ import annotations

from typing import Any

from mhrc.core.fidelity import recorded_noise
from mhrc.core.protocol import EPISODE_OVER, LLM_ERROR_PREFIX, RejectCode, TeamRecord
from mhrc.core.protocol.thoughts import ReplyFailure
from mhrc.core.team import PAPER_TEAM

UNRECORDED = "unrecorded"  # the fidelity of a trace written before episodes recorded it
JUNK_REJECTED = "rejected: "  # how the recorder's junk lines start the reason of a counted rejection


def paper_team(robots: Any) -> TeamRecord:
    """The paper's team as an episode of `robots` ran it (the no_mobile ablation leaves David out):
    what an episode recorded before teams were data ran, and what today's world records for the
    paper's team. Names that are not the paper's robots are left out (no such episode existed)."""
    names = set(robots) if isinstance(robots, (list, tuple)) else set(PAPER_TEAM.names)
    team = PAPER_TEAM.without(set(PAPER_TEAM.names) - names)
    return TeamRecord(name=team.name, digest=team.digest(), kinds=team.kinds)


# what the world's rejection sentences of the time said, in the order they were told apart
LEGACY_REASONS: tuple[tuple[str, RejectCode], ...] = (
    ("the request is for tick", RejectCode.STALE_TICK),
    ("already submitted", RejectCode.TICK_TAKEN),
    ("still busy", RejectCode.BUSY),
    ("'s turn", RejectCode.NOT_YOUR_TURN),
    ("not attached", RejectCode.NOT_ATTACHED),
    ("attached to another agent", RejectCode.OTHER_AGENT),
    ("sent on the key of", RejectCode.WRONG_KEY),
    ("there is no robot", RejectCode.NO_SUCH_ROBOT),
)


def legacy_reject_code(reason: str) -> RejectCode | None:
    """The code of a rejection recorded before acks carried one, from the world's sentence of that
    time (world/admission.py), or None where no code says it."""
    r = reason.lower()
    if reason == EPISODE_OVER:
        return RejectCode.EPISODE_OVER
    if r.startswith("malformed"):
        return RejectCode.MALFORMED
    return next((code for words, code in LEGACY_REASONS if words in r), None)


def _code(value: Any, reason: str) -> str | None:
    """A recorded code if it is one of today's, else the one the reason's text stands for."""
    if isinstance(value, str) and value in RejectCode._value2member_map_:
        return value
    legacy = legacy_reject_code(reason)
    return legacy.value if legacy is not None else None


def legacy_failure(parse_error: object, finish_reason: object) -> ReplyFailure | None:
    """The failure of a thought recorded before thoughts carried one, from its texts (module docstring)."""
    if not parse_error or not isinstance(parse_error, str):
        return None
    if parse_error.startswith(LLM_ERROR_PREFIX):
        return ReplyFailure.MODEL_UNREACHABLE
    if finish_reason == "length":
        return ReplyFailure.CUT_OFF
    return ReplyFailure.UNREADABLE


def upgrade(kind: str, msg: Any) -> Any:
    """A line's `msg` (its JSON) in today's shape; `kind` is the line's. A new dict where something
    changed, the same object otherwise."""
    if not isinstance(msg, dict):
        return msg
    if kind == "junk":
        if msg.get("code") is None or "excerpt" not in msg:
            # a code the line carries is kept (a rejection's, or the recorder's own: thoughts_ahead);
            # only a line without one has it read from its reason
            code = msg.get("code")
            if code is None:
                code = _code(None, str(msg.get("reason", "")).removeprefix(JUNK_REJECTED))
            return {"excerpt": None, **msg, "code": code}
        return msg
    if kind != "put":
        return msg
    what = msg.get("kind")
    if what == "thought" and "failure" not in msg and msg.get("parse_error"):
        failure = legacy_failure(msg.get("parse_error"), msg.get("finish_reason"))
        return {**msg, "failure": failure.value if failure is not None else None}
    if what == "action_ack" and msg.get("accepted") is False and msg.get("code") is None:
        return {**msg, "code": _code(None, str(msg.get("reason", "")))}
    if what == "episode_started" and ("fidelity" not in msg or not isinstance(msg.get("noise"), dict)):
        msg = {**msg, "fidelity": msg.get("fidelity") or UNRECORDED, "noise": recorded_noise(msg).model_dump()}
    if what == "episode_started" and msg.get("team") is None:
        return {**msg, "team": paper_team(msg.get("robots")).model_dump()}
    return msg
