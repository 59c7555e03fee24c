"""What a person may do now: one form per skill of the robot, its arguments as choices from what
the robot knows (its own Observation, nothing else), a skill that cannot work now disabled with
the reason; and a form's submission checked against them, refused with a code and a sentence.

The forms follow each skill's declared call form (mhrc.core.protocol.actions: its arguments, in
order, free text last); the choices and the reason a form is disabled come from each argument's
kind. The inputs are named as the protocol's fields (`target`, `stand_pose`, `object`,
`location`, `dx`, `dy`, `content`, `to`); `object` is the protocol's `obj` of pick and place.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum

from pydantic import ValidationError

from mhrc.core.protocol import Action, ObjectView, Observation
from mhrc.core.protocol.actions import CALLS, Arg, ArgKind, build
from mhrc.core.protocol.base import MAX_MOVE, _reason

from .messages import FieldData, FormData, Submission

MAX_SUBMISSION_BYTES = 16_384  # a form's JSON: a message of the protocol's 4,000 characters fits many times over
INPUT = {"obj": "object"}  # the protocol's field -> its input's name, where they differ


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


def _gone(o: ObjectView) -> bool:
    return bool(o.last_seen_on and not (o.on or o.held_by))


def _input(arg: Arg) -> str:
    return INPUT.get(arg.field, arg.field)


def _choices(kind: ArgKind, obs: Observation) -> tuple[list[str], str | None]:
    """An argument's choices in `obs` and why a form with it cannot work now (None: it can)."""
    s = obs.status
    if kind is ArgKind.STAND:
        stand = [f.name for f in obs.furniture if f.stand_poses]
        return stand, None if stand else "you know of no furniture with a stand pose"
    if kind is ArgKind.STAND_POSE:
        return [str(i) for i in range(max((len(f.stand_poses) for f in obs.furniture), default=0))], None
    if kind is ArgKind.OPENABLE:
        closed = [f.name for f in obs.furniture if f.openable and f.is_open is False and f.stand_poses]
        return closed, None if closed else "nothing you know of is closed"
    if kind is ArgKind.PICKABLE:
        pickable = [o.name for o in obs.objects if not o.held_by and not _gone(o)]
        if s.holding:
            return pickable, f"your gripper holds {s.holding}: place it first"
        return pickable, None if pickable else "you know of no object to pick"
    if kind is ArgKind.OBJECT:
        return ([s.holding], None) if s.holding else ([], "your gripper is empty: pick something first")
    if kind is ArgKind.PLACE:
        return [x.name for x in obs.furniture], None
    mates = sorted(r for r in obs.teammates if r != obs.robot)  # TEAMMATE
    return mates, None if mates else "no teammate is attached to hear you"


FREE = {ArgKind.OFFSET: "number", ArgKind.TEXT: "text"}  # the kinds a person types, not chooses


def forms(obs: Observation) -> list[SkillForm]:
    """The forms of the skills `obs.status` lists, in the protocol's order."""
    out: list[SkillForm] = []
    for skill, model in CALLS.items():
        if skill not in obs.status.skills:
            continue
        form = SkillForm(skill, [])
        for arg in sorted(model.ARGS, key=lambda a: a.kind is ArgKind.TEXT):  # free text last
            if arg.kind in FREE:
                form.fields.append(Field(_input(arg), FREE[arg.kind]))
                continue
            choices, why = _choices(arg.kind, obs)
            form.fields.append(Field(_input(arg), "choice", choices))
            form.disabled = form.disabled or why
            if arg.kind is ArgKind.STAND:
                form.stand_poses = {f.name: len(f.stand_poses) for f in obs.furniture if f.stand_poses}
        out.append(form)
    return out


def as_json(forms_: list[SkillForm]) -> list[FormData]:
    return [
        FormData(
            skill=f.skill,
            fields=[FieldData(name=x.name, kind=x.kind, choices=list(x.choices)) for x in f.fields],
            disabled=f.disabled,
            stand_poses=dict(f.stand_poses),
        )
        for f in forms_
    ]


def action_of(submission: Submission, obs: Observation) -> Action:
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
    extra = sorted(set(submission) - {"tick", "skill", *(f.name for f in form.fields)})
    if extra:
        raise Refused(Refusal.MALFORMED, f"{skill} takes no {', '.join(x[:64] for x in extra)}")
    fields = {_input(a): a.field for a in CALLS[form.skill].ARGS}
    wire: dict[str, str | int | float] = {}  # the action's fields
    for fld in form.fields:
        value = submission.get(fld.name)
        if not isinstance(value, str | int | float) or isinstance(value, bool):
            raise Refused(Refusal.MALFORMED, f"{skill}: {fld.name} is missing")
        if fld.kind == "choice":
            value = str(value)
            choices = fld.choices
            if fld.name == "stand_pose":  # the chosen target's own stand poses
                choices = [str(i) for i in range(form.stand_poses.get(str(submission.get("target")), 0))]
            if value not in choices:
                raise Refused(
                    Refusal.NOT_A_CHOICE,
                    f"{skill}: {fld.name} {value[:64]!r} is not one of the choices ({', '.join(choices) or 'none'})",
                )
            wire[fields[fld.name]] = int(value) if fld.name == "stand_pose" else value
        elif fld.kind == "number":
            try:
                number = float(value)
            except ValueError:
                raise Refused(Refusal.MALFORMED, f"{skill}: {fld.name} is not a number") from None
            if not math.isfinite(number) or abs(number) > MAX_MOVE:
                raise Refused(Refusal.MALFORMED, f"{skill}: {fld.name} must be a number within ±{MAX_MOVE:g} m")
            wire[fields[fld.name]] = number
        else:
            wire[fields[fld.name]] = str(value)
    try:
        return build(form.skill, wire)
    except ValidationError as exc:  # the protocol's own bounds, as the world checks them (a message too long)
        raise Refused(Refusal.MALFORMED, f"malformed action request: {_reason(exc, form.skill)}") from None
