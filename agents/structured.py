"""Structured decisions: a per-step JSON Schema that makes every reply a valid action by construction.

In `--structured` mode the request carries a schema built from the robot's own skills and the
names in its own scene graph, so a server that enforces it (OpenAI strict mode, vLLM, llama.cpp,
LM Studio, Ollama) can only return a skill the robot has, with names the robot knows. The schema
keeps to the subset those servers share: no `$ref`, `oneOf`, `format` or `pattern`, and no empty
enum (a skill without a name to act on is left out instead). The reply is `{"analysis": ...,
"command": {"skill": ..., args}}`, analysis first so that the model reasons before it commits.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable

from pydantic import ValidationError

from mhrc.core.jsontypes import JsonObject  # a JSON Schema or a part of one, a reply
from mhrc.core.protocol import Action, Observation
from mhrc.core.protocol.actions import CALLS, ArgKind, build

from .parse import ReplyFormatError

MAX_ANALYSIS = 2000  # characters: room for the paper's analysis and reasoning, a bound for small local models
MAX_MESSAGE = 500  # characters of a `communicate` content
MAX_STEP = 1.0  # metres: the bound on each of move's dx and dy

STRUCTURED_INSTRUCTIONS = (
    'Answer with one JSON object and nothing else: {"analysis": "...", "command": {"skill": "...", ...}}. '
    'In "analysis", think step by step and write the analysis and the reasoning the response format above asks for. '
    'In "command", give the one skill to run now: "skill" names it '
    "and the other fields are its arguments, for example "
    '{"skill": "navigate", "furniture": "table_1", "stand_pose": 0}, {"skill": "pick", "object": "apple"}, '
    '{"skill": "place", "object": "apple", "location": "table_0"}, '
    '{"skill": "communicate", "content": "Hello, Bob.", "to": "bob"} or {"skill": "wait"}. '
    'Use only names from your scene graph. This JSON object replaces the "Command:" line.'
)


def _names(values: Iterable[str]) -> JsonObject:
    return {"type": "string", "enum": sorted(set(values))}


def _number(low: float, high: float, kind: str = "number") -> JsonObject:
    return {"type": kind, "minimum": low, "maximum": high}


def arguments(skill: str) -> dict[str, str]:
    """`skill`'s arguments in call order, as a structured command names them -> the action model's field."""
    return {a.name: a.field for a in CALLS[skill].ARGS}


def _arguments(obs: Observation, recipients: list[str]) -> dict[str, dict[str, JsonObject] | None]:
    """Each declared skill's argument schemas, from this robot's own scene graph; None where a name
    enum would be empty."""
    stand = [f for f in obs.furniture if f.stand_poses]
    most = max((len(f.stand_poses) for f in stand), default=0) - 1
    # the goal fixtures on Bob's table have a place pose but no stand pose; only the robot given the
    # task's object list finishes the task, so only it may place on them
    places = [f.name for f in obs.furniture if f.place_pose is not None and (f.stand_poses or obs.targets)]
    known = [o.name for o in obs.objects] + ([obs.status.holding] if obs.status.holding else [])
    names: dict[ArgKind, list[str]] = {
        ArgKind.STAND: [f.name for f in stand],
        ArgKind.OPENABLE: [f.name for f in obs.furniture if f.openable],
        ArgKind.PICKABLE: [o.name for o in obs.objects if o.held_by is None],
        ArgKind.OBJECT: known,
        ArgKind.PLACE: places,
        ArgKind.TEAMMATE: recipients,
    }
    fixed: dict[ArgKind, JsonObject] = {
        ArgKind.STAND_POSE: _number(0, most, "integer"),
        ArgKind.OFFSET: _number(-MAX_STEP, MAX_STEP),
        ArgKind.TEXT: {"type": "string", "minLength": 1, "maxLength": MAX_MESSAGE},
    }
    out: dict[str, dict[str, JsonObject] | None] = {}
    for skill, model in CALLS.items():
        if any(a.kind in names and not names[a.kind] for a in model.ARGS):
            out[skill] = None
        else:
            out[skill] = {a.name: _names(names[a.kind]) if a.kind in names else fixed[a.kind] for a in model.ARGS}
    return out


def _variant(skill: str, args: dict[str, JsonObject]) -> JsonObject:
    props: JsonObject = {"skill": {"type": "string", "const": skill}, **args}
    return {"type": "object", "properties": props, "required": list(props), "additionalProperties": False}


COMMAND_TOKENS = 150  # tokens a command object takes at most (skill, names, a 500-character message aside)


def analysis_bound(max_tokens: int | None) -> int:
    """Characters the analysis may take so that, at no less than one character a token, the
    command still fits in a reply of `max_tokens`: the reply parses by construction."""
    if max_tokens is None:
        return MAX_ANALYSIS
    return max(0, min(MAX_ANALYSIS, max_tokens - COMMAND_TOKENS))


def decision_schema(
    obs: Observation, teammates: Iterable[str] | None = None, *, max_analysis: int = MAX_ANALYSIS
) -> JsonObject:
    """The JSON Schema of one decision of `obs.robot`: its analysis (at most `max_analysis`
    characters), then one command among its own skills with names from its own scene graph.
    `teammates` are the robots it may message (by default every teammate in the observation).
    The same observation gives the same schema."""
    recipients = sorted({t.lower() for t in (obs.teammates if teammates is None else teammates)} - {obs.robot})
    args = _arguments(obs, recipients)
    variants = [
        _variant(skill, a)
        for skill in CALLS
        if (skill in obs.status.skills or skill == "wait") and (a := args[skill]) is not None
    ]
    return {
        "type": "object",
        "properties": {
            "analysis": {"type": "string", "maxLength": max_analysis},
            "command": {"anyOf": variants},
        },
        "required": ["analysis", "command"],
        "additionalProperties": False,
    }


def schema_hash(schema: JsonObject) -> str:
    """A short stable id of a schema for the trace: equal schemas, equal ids, whatever the key order."""
    canonical = json.dumps(schema, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return hashlib.sha256(canonical.encode()).hexdigest()[:16]


def response_format(schema: JsonObject, provider: str) -> JsonObject:
    """The request-body fields that ask `provider` to enforce `schema` (Ollama takes the bare schema)."""
    if provider == "ollama":
        return {"format": schema}
    return {
        "response_format": {
            "type": "json_schema",
            "json_schema": {"name": "decision", "strict": True, "schema": schema},
        }
    }


def _json_object(text: str) -> JsonObject:
    """The outermost {...} of a reply, so code fences and text around it do not matter."""
    start, end = text.find("{"), text.rfind("}")
    if start < 0 or end < start:
        raise ReplyFormatError(
            'no JSON object found: answer with {"analysis": "...", "command": {"skill": "...", ...}}'
        )
    try:
        value = json.loads(text[start : end + 1])
    except json.JSONDecodeError as exc:
        raise ReplyFormatError(
            f"the reply is not valid JSON ({exc.msg} at character {exc.pos}): answer with one JSON object"
        ) from None
    if not isinstance(value, dict):
        raise ReplyFormatError("the reply must be one JSON object")
    return value


def parse_structured(text: str) -> tuple[Action, str]:
    """The action and the analysis (empty if the reply has none) of a structured reply, or
    ReplyFormatError saying what is wrong."""
    reply = _json_object(text)
    analysis = reply.get("analysis", "")
    if not isinstance(analysis, str):
        raise ReplyFormatError('"analysis" must be a string')
    command = reply.get("command")
    if not isinstance(command, dict):
        raise ReplyFormatError('the reply has no "command" object: give "command": {"skill": "...", ...}')
    skill = command.get("skill")
    if not isinstance(skill, str) or skill.strip().lower() not in CALLS:
        what = "no skill" if skill is None else f"unknown skill {skill!r}"
        raise ReplyFormatError(f'the command names {what}: "skill" must be one of {", ".join(CALLS)}')
    skill = skill.strip().lower()
    params = arguments(skill)
    given = set(command) - {"skill"}
    missing, extra = [n for n in params if n not in given], sorted(given - set(params))
    if missing or extra:
        takes = ", ".join(params) or "no arguments"
        problems = ([f"missing {', '.join(missing)}"] if missing else []) + (
            [f"unexpected {', '.join(extra)}"] if extra else []
        )
        raise ReplyFormatError(f"{skill} takes {takes}: {'; '.join(problems)}")
    fields: dict[str, object] = {field: command[name] for name, field in params.items()}
    for arg in CALLS[skill].ARGS:
        if arg.kind is ArgKind.TEAMMATE and isinstance(name := fields[arg.field], str):
            fields[arg.field] = name.strip().lower()  # as parse_command reads a recipient
    try:
        action = build(skill, fields)  # the same models parse_command builds
    except ValidationError as exc:
        names = {field: name for name, field in params.items()}
        errors = "; ".join(f"{names.get(str(e['loc'][-1]), e['loc'][-1])}: {e['msg']}" for e in exc.errors()[:3])
        raise ReplyFormatError(f"{skill} got bad arguments: {errors}") from None
    return action, analysis


# --------------------------------------------------------------------------- a planner's round


def round_schema(observations: Iterable[Observation], *, max_analysis: int = MAX_ANALYSIS) -> JsonObject:
    """The JSON Schema of a planner's round (a whole-team protocol, `centralized`): its analysis,
    then one command for each robot, each among that robot's own skills with names from that
    robot's own scene graph (`decision_schema`'s command). Robots in the observations' order."""
    commands: JsonObject = {}
    for obs in observations:
        one = decision_schema(obs, max_analysis=0)["properties"]
        assert isinstance(one, dict)
        commands[obs.robot] = one["command"]
    return {
        "type": "object",
        "properties": {
            "analysis": {"type": "string", "maxLength": max_analysis},
            "commands": {
                "type": "object",
                "properties": commands,
                "required": list(commands),
                "additionalProperties": False,
            },
        },
        "required": ["analysis", "commands"],
        "additionalProperties": False,
    }


def parse_round_structured(text: str, robots: Iterable[str]) -> tuple[dict[str, Action], dict[str, str]]:
    """A structured round's commands by robot, and for each robot whose command is missing or
    cannot be read, why (the others' commands still stand). ReplyFormatError when the reply is no
    JSON object with a "commands" object at all."""
    reply = _json_object(text)
    commands = reply.get("commands")
    if not isinstance(commands, dict):
        raise ReplyFormatError('the reply has no "commands" object: give "commands": {"<robot>": {"skill": ...}}')
    got: dict[str, Action] = {}
    problems: dict[str, str] = {}
    for robot in robots:
        command = commands.get(robot)
        if command is None:
            problems[robot] = "no command was given for it"
            continue
        try:
            got[robot] = parse_structured(json.dumps({"command": command}))[0]
        except ReplyFormatError as exc:
            problems[robot] = str(exc)
    return got, problems
