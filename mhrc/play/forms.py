"""What a person may do now: one form per skill of the robot, its arguments as choices from what
the robot knows (its own Observation, nothing else), a skill that cannot work now disabled with
the reason; and a form's submission checked against them, refused with a code and a sentence.

The inputs are named as the protocol's fields (`target`, `stand_pose`, `object`, `location`,
`dx`, `dy`, `content`, `to`); `object` is the protocol's `obj` of pick and place.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from enum import Enum
from typing import Any

from mhrc.core.protocol import SKILLS, Action, Observation, ProtocolError, parse_action
from mhrc.core.protocol.base import MAX_MOVE

MAX_SUBMISSION_BYTES = 16_384  # a form's JSON: a message of the protocol's 4,000 characters fits many times over
FIELDS = {
    "navigate": ("target", "stand_pose"),
    "move": ("dx", "dy"),
    "open": ("target",),
    "pick": ("object",),
    "place": ("object", "location"),
    "communicate": ("to", "content"),
    "wait": (),
}
WIRE = {"object": "obj"}  # an input's name -> the protocol's field, where they differ


class Refusal(str, Enum):
    """Why the page's server refused a submission (the page shows the sentence beside it)."""

    MALFORMED = "malformed"  # not a form's JSON, too long, a field the protocol refuses (a message too long)
    STALE_TICK = "stale_tick"  # planned on another tick than the robot's of now
    NOT_DECIDING = "not_deciding"  # the robot is not waiting for a decision now (its action is under way)
    NOT_CAPABLE = "not_capable"  # the robot has no such skill
    UNAVAILABLE = "unavailable"  # the skill cannot work now (the form is disabled)
    NOT_A_CHOICE = "not_a_choice"  # an argument that is not one of the form's choices


@dataclass(frozen=True)
class Refused(Exception):
    code: Refusal
    reason: str


@dataclass
class Field:
    name: str
    kind: str  # choice | number | text
    choices: list[str] = field(default_factory=list)


@dataclass
class SkillForm:
    skill: str
    fields: list[Field]
    disabled: str | None = None  # why the skill cannot work now
    stand_poses: dict[str, int] = field(default_factory=dict)  # navigate: target -> how many stand poses


def _gone(o: Any) -> bool:
    return bool(o.last_seen_on and not (o.on or o.held_by))


def forms(obs: Observation) -> list[SkillForm]:
    """The forms of the skills `obs.status` lists, in the protocol's order."""
    s = obs.status
    targets = {f.name: len(f.stand_poses) for f in obs.furniture if f.stand_poses}
    closed = [f.name for f in obs.furniture if f.openable and f.is_open is False and f.stand_poses]
    pickable = [o.name for o in obs.objects if not o.held_by and not _gone(o)]
    mates = sorted(r for r in obs.teammates if r != obs.robot)
    out: list[SkillForm] = []
    for skill in SKILLS:
        if skill not in s.skills:
            continue
        if skill == "navigate":
            f = SkillForm(skill, [Field("target", "choice", list(targets)), Field("stand_pose", "choice")])
            f.fields[1].choices = [str(i) for i in range(max(targets.values(), default=0))]
            f.stand_poses = targets
            f.disabled = None if targets else "you know of no furniture with a stand pose"
        elif skill == "move":
            f = SkillForm(skill, [Field("dx", "number"), Field("dy", "number")])
        elif skill == "open":
            f = SkillForm(skill, [Field("target", "choice", closed)])
            f.disabled = None if closed else "nothing you know of is closed"
        elif skill == "pick":
            f = SkillForm(skill, [Field("object", "choice", pickable)])
            if s.holding:
                f.disabled = f"your gripper holds {s.holding}: place it first"
            elif not pickable:
                f.disabled = "you know of no object to pick"
        elif skill == "place":
            f = SkillForm(
                skill,
                [
                    Field("object", "choice", [s.holding] if s.holding else []),
                    Field("location", "choice", [x.name for x in obs.furniture]),
                ],
            )
            f.disabled = None if s.holding else "your gripper is empty: pick something first"
        elif skill == "communicate":
            f = SkillForm(skill, [Field("to", "choice", mates), Field("content", "text")])
            f.disabled = None if mates else "no teammate is attached to hear you"
        else:
            f = SkillForm(skill, [])
        out.append(f)
    return out


def as_json(forms_: list[SkillForm]) -> list[dict[str, Any]]:
    return [asdict(f) for f in forms_]


def action_of(submission: dict[str, Any], obs: Observation) -> Action:
    """The action a form's submission asks for, planned on `obs`; Refused when it cannot be sent."""
    tick = submission.get("tick")
    if not isinstance(tick, int) or isinstance(tick, bool):
        raise Refused(Refusal.MALFORMED, "the submission names no tick (an integer)")
    if tick != obs.tick:
        raise Refused(
            Refusal.STALE_TICK,
            f"the request is for tick {tick} but {obs.robot} is at tick {obs.tick}: choose again on what you see now",
        )
    skill = submission.get("skill")
    form = next((f for f in forms(obs) if f.skill == skill), None)
    if form is None:
        raise Refused(
            Refusal.NOT_CAPABLE,
            f"{obs.robot} has no skill {str(skill)[:64]!r} (skills: {', '.join(obs.status.skills)})",
        )
    if form.disabled:
        raise Refused(Refusal.UNAVAILABLE, f"{skill} cannot work now: {form.disabled}")
    extra = sorted(set(submission) - {"tick", "skill", *FIELDS[form.skill]})
    if extra:
        raise Refused(Refusal.MALFORMED, f"{skill} takes no {', '.join(x[:64] for x in extra)}")
    wire: dict[str, Any] = {"skill": skill}
    for fld in form.fields:
        value = submission.get(fld.name)
        if not isinstance(value, str | int | float) or isinstance(value, bool):
            raise Refused(Refusal.MALFORMED, f"{skill}: {fld.name} is missing")
        if fld.kind == "choice":
            value = str(value)
            choices = fld.choices
            if fld.name == "stand_pose":
                choices = [str(i) for i in range(form.stand_poses.get(str(submission.get("target")), 0))]
            if value not in choices:
                raise Refused(
                    Refusal.NOT_A_CHOICE,
                    f"{skill}: {fld.name} {value[:64]!r} is not one of the choices ({', '.join(choices) or 'none'})",
                )
            wire[WIRE.get(fld.name, fld.name)] = int(value) if fld.name == "stand_pose" else value
        elif fld.kind == "number":
            try:
                number = float(value)
            except ValueError:
                raise Refused(Refusal.MALFORMED, f"{skill}: {fld.name} is not a number") from None
            if not math.isfinite(number) or abs(number) > MAX_MOVE:
                raise Refused(Refusal.MALFORMED, f"{skill}: {fld.name} must be a number within ±{MAX_MOVE:g} m")
            wire[fld.name] = number
        else:
            wire[fld.name] = str(value)
    try:
        return parse_action(wire)
    except ProtocolError as exc:  # the protocol's own bounds, as the world checks them (a message too long)
        raise Refused(Refusal.MALFORMED, f"malformed action request: {exc}") from None
