"""JSON Schemas of every bus payload (`mhrc schema`), for agents written in any language.

One schema per top-level message (every `Message` subclass of `mhrc.core.protocol`) and one for the
world-event union (`WorldEvent`, what `mhrc/<run>/world/event` carries, discriminated by
`kind`), each with the key it travels on and who sends it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TypedDict

from pydantic import BaseModel

from mhrc.core import protocol
from mhrc.core.jsontypes import JsonObject
from mhrc.core.protocol import PROTOCOL_VERSION, WORLD_EVENT_ADAPTER, Message

SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"
JsonSchema = JsonObject  # one JSON Schema document (pydantic's model_json_schema)

# payload -> (key under mhrc/<run>/, direction); <rid> is the robot, <to>/<from> the receiver and sender
KEYS: dict[str, tuple[str, str]] = {
    "AttachRequest": ("robot/<rid>/attach", "agent -> world: the payload of a zenoh get (query)"),
    "AttachReply": ("robot/<rid>/attach", "world -> agent: the reply to that get"),
    "ActionRequest": ("robot/<rid>/action/request", "agent -> world (put)"),
    "ActionAck": ("robot/<rid>/action/ack", "world -> agent (put)"),
    "ActionResult": ("robot/<rid>/action/result", "world -> agent (put)"),
    "Turn": ("robot/<rid>/turn", "world -> agent (put): sequential schedule, after an attach reply with wait_turn"),
    "RobotMessage": (
        "robot/<to>/inbox/<from>",
        "world -> observers (put): a delivered communicate; agents read it in Observation.new_messages",
    ),
    "Thought": ("agent/<rid>/thought", "agent -> observers (put), optional"),
    "Generating": (
        "agent/<rid>/generating",
        "agent -> observers (put), optional: a long model call's progress, every few seconds; not recorded",
    ),
    "WorldState": ("world/state", "world -> anyone: the reply to a zenoh get"),
    "WorldEvent": ("world/event", "world -> all (put): one of the event kinds, discriminated by `kind`"),
}
WORLD_EVENT_KINDS = (
    "EpisodeStarted",
    "TickClosed",
    "RobotAttached",
    "RobotDetached",
    "EpisodeDone",
    "Snapshot",
    "ScenarioEvent",
)


def message_models() -> list[type[Message]]:
    """Every top-level payload model of mhrc.core.protocol, in definition order."""
    found: list[type[Message]] = []
    for value in vars(protocol).values():
        if (
            isinstance(value, type)
            and issubclass(value, Message)
            and value is not Message
            and value.__module__.startswith(protocol.__name__ + ".")
        ):
            found.append(value)
    return found


def _schema_of(name: str, schema: JsonSchema) -> JsonSchema:
    key, direction = KEYS.get(name) or (
        ("world/event", "world -> all (put), as part of WorldEvent") if name in WORLD_EVENT_KINDS else ("", "")
    )
    out: JsonSchema = {"$schema": SCHEMA_DIALECT, "$id": f"mhrc/v{PROTOCOL_VERSION}/{name}.json"}
    out.update(schema)
    out.setdefault("title", name)
    if key:
        out["x-mhrc-key"] = f"mhrc/<run>/{key}"
        out["x-mhrc-direction"] = direction
    return out


def schemas() -> dict[str, JsonSchema]:
    """name -> JSON Schema of every bus payload, plus `WorldEvent` (the union on world/event)."""
    out: dict[str, JsonSchema] = {}
    for model in message_models():
        out[model.__name__] = _schema_of(model.__name__, _model_schema(model))
    event = WORLD_EVENT_ADAPTER.json_schema(mode="validation")
    event["title"] = "WorldEvent"
    out["WorldEvent"] = _schema_of("WorldEvent", event)
    return out


def _model_schema(model: type[BaseModel]) -> JsonSchema:
    return model.model_json_schema(mode="validation")


class Payload(TypedDict):
    """One payload in the index: its schema's file, its key and who sends it."""

    file: str
    key: str
    direction: str


class SchemaIndex(TypedDict):
    """`index.json`: the protocol's versions and every payload's file, key and direction."""

    protocol_version: int
    supported_versions: list[int]
    encoding: str
    payloads: dict[str, Payload]


class SchemaDocument(SchemaIndex):
    """`mhrc schema` as one document: the index and every schema."""

    schemas: dict[str, JsonSchema]


def index(all_schemas: dict[str, JsonSchema]) -> SchemaIndex:
    return {
        "protocol_version": PROTOCOL_VERSION,
        "supported_versions": list(protocol.SUPPORTED_VERSIONS),
        "encoding": "UTF-8 JSON, one message per zenoh sample; unknown fields are rejected",
        "payloads": {
            name: {
                "file": f"{name}.json",
                "key": str(s.get("x-mhrc-key", "")),
                "direction": str(s.get("x-mhrc-direction", "")),
            }
            for name, s in all_schemas.items()
        },
    }


def document() -> SchemaDocument:
    """Everything as one JSON document: the index and every schema."""
    all_schemas = schemas()
    return {**index(all_schemas), "schemas": all_schemas}


def write(out: Path) -> list[Path]:
    """Write one `<Name>.json` per payload and `index.json` into `out`; return the paths written."""
    out.mkdir(parents=True, exist_ok=True)
    all_schemas = schemas()
    written = []
    for name, schema in all_schemas.items():
        path = out / f"{name}.json"
        path.write_text(json.dumps(schema, indent=2) + "\n", encoding="utf-8")
        written.append(path)
    path = out / "index.json"
    path.write_text(json.dumps(index(all_schemas), indent=2) + "\n", encoding="utf-8")
    written.append(path)
    return written
