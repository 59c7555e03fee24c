"""What the play page's server tells the page over its WebSocket: one JSON object a message,
`type` naming it (page.js reads them); and what the page sends back, a form's submission.

The server writes these and only the page reads them, so they are TypedDicts: the dicts go to
the socket as they are. A submission comes from the page unchecked: it is a JSON object until
mhrc.play.forms.action_of reads it field by field.
"""

from __future__ import annotations

from typing import Literal, TypeAlias, TypedDict

from mhrc.core.jsontypes import JsonObject

Submission: TypeAlias = JsonObject  # a form's submission as the page sent it (its `type` removed), not yet checked


class Hello(TypedDict):
    type: Literal["hello"]
    robot: str
    run: str
    schedule: str | None  # None: the world's, not known here
    waits: bool  # lockstep and sequential wait for the person's decision
    started: bool


class HistoryEntry(TypedDict):
    step: int
    text: str


class FieldData(TypedDict):
    """One input of a form (mhrc.play.forms.Field)."""

    name: str
    kind: str  # choice | number | text
    choices: list[str]


class FormData(TypedDict):
    """One skill's form (mhrc.play.forms.SkillForm)."""

    skill: str
    fields: list[FieldData]
    disabled: str | None
    stand_poses: dict[str, int]


class View(TypedDict):
    """What the page shows of the robot now (mhrc.play.human.HumanPolicy.view)."""

    type: Literal["view"]
    tick: int
    deciding: bool
    waited: float  # seconds since the observation reached the person
    observation: JsonObject  # the Observation as sent on the bus
    text: dict[str, str]  # the observation in an agent's words, part by part
    histories: dict[str, list[HistoryEntry]]
    forms: list[FormData]
    last: Submission | None  # the person's last submission
    map: str  # the house's SVG
    map_scene: str


class Refused(TypedDict):
    type: Literal["refused"]
    code: str  # mhrc.play.forms.Refusal
    reason: str


class Accepted(TypedDict):
    type: Literal["accepted"]
    tick: int
    action: str  # its call


class Result(TypedDict):
    type: Literal["result"]
    tick: int
    action: str
    ok: bool
    feedback: str


class Done(TypedDict):
    type: Literal["done"]
    reason: str
    success: bool
    placed: int
    total: int
    temporal_steps: int


class Started(TypedDict):
    type: Literal["started"]


class Detached(TypedDict):
    type: Literal["detached"]
    robot: str
    reason: str


class Said(TypedDict):
    """The page is told why: its tab was reloaded (`replaced`), the episode failed (`error`), or
    another tab drives the robot (`refused_tab`)."""

    type: Literal["replaced", "error", "refused_tab"]
    reason: str


PageMessage: TypeAlias = Hello | View | Refused | Accepted | Result | Done | Started | Detached | Said
