"""Structured decisions: schemas from real observations, their validity for the servers that
enforce them, and replies that parse into the same actions as the free-text commands."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import jsonschema
import pytest

from mhrc.agents.parse import ReplyFormatError, parse_command
from mhrc.agents.structured import (
    STRUCTURED_INSTRUCTIONS,
    arguments,
    decision_schema,
    parse_round_structured,
    parse_structured,
    response_format,
    round_schema,
    schema_hash,
)
from mhrc.core.protocol import Communicate, Navigate, Observation, Pick, Wait
from mhrc.world.sim import Sim

FORBIDDEN = {"$ref", "$defs", "definitions", "oneOf", "allOf", "not", "format", "pattern", "patternProperties"}


@pytest.fixture(scope="module")
def sim() -> Iterator[Sim]:
    s = Sim(task="pack_objects", scene="kitchen", seed=0, n_objects=4, robots=("alice", "bob", "david"))
    try:
        yield s
    finally:
        s.close()


@pytest.fixture(scope="module")
def start(sim: Sim) -> dict[str, Observation]:
    """Every robot's observation at tick 0: Alice and David know no object yet, Bob what lies on table_0."""
    return {r: sim.observe(r, 0) for r in sim.robots}


@pytest.fixture(scope="module")
def later(sim: Sim, start: dict[str, Observation]) -> dict[str, Observation]:
    """After Alice has looked at table_0 and Bob has picked the target within his reach."""
    assert sim.execute("alice", Navigate(target="table_0", stand_pose=0)).succeeded
    bob = start["bob"]
    ab, reach = bob.status.arm_base, bob.status.reach
    assert ab is not None and reach is not None
    near = next(o.name for o in bob.objects if math.hypot(o.position[0] - ab[0], o.position[1] - ab[1]) <= reach)
    assert sim.execute("bob", Pick(obj=near)).succeeded
    return {r: sim.observe(r, 1) for r in sim.robots}


@pytest.fixture(scope="module")
def observations(start: dict[str, Observation], later: dict[str, Observation]) -> list[Observation]:
    return list(start.values()) + list(later.values())


def _variants(schema: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {v["properties"]["skill"]["const"]: v for v in schema["properties"]["command"]["anyOf"]}


def _enum(schema: dict[str, Any], skill: str, arg: str) -> list[str]:
    return list(_variants(schema)[skill]["properties"][arg]["enum"])


def _walk(node: Any, path: str = "#") -> Iterator[tuple[str, dict[str, Any]]]:
    if isinstance(node, dict):
        yield path, node
        for k, v in node.items():
            yield from _walk(v, f"{path}/{k}")
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _walk(v, f"{path}/{i}")


def _sample(skill: str, variant: dict[str, Any]) -> dict[str, Any]:
    """An instance of one command variant: the first name of each enum, the lowest number, a message."""
    out: dict[str, Any] = {"skill": skill}
    for arg, spec in variant["properties"].items():
        if arg == "skill":
            continue
        if "enum" in spec:
            out[arg] = spec["enum"][0]
        elif spec["type"] in ("integer", "number"):
            out[arg] = spec["maximum"] if spec["type"] == "integer" else -0.25
        else:
            out[arg] = "Please bring the mug to table_0, thanks."
    return out


def _free_text(c: dict[str, Any]) -> str:
    """The same command as the paper's prompts write it."""
    args = {
        "navigate": lambda: f"{c['furniture']}, {c['stand_pose']}",
        "move": lambda: f"{c['dx']}, {c['dy']}",
        "open": lambda: c["furniture"],
        "pick": lambda: c["object"],
        "place": lambda: f"{c['object']}, {c['location']}",
        "communicate": lambda: f'"{c["content"]}", {c["to"].capitalize()}',
        "wait": lambda: "",
    }[c["skill"]]()
    return f"Reasoning: that is the next step.\nCommand: {c['skill']}({args})"


# --------------------------------------------------------------------------- the schema


def test_schema_is_valid_json_schema(observations: list[Observation]) -> None:
    for obs in observations:
        jsonschema.Draft202012Validator.check_schema(decision_schema(obs))


def test_schema_keeps_to_the_subset_every_server_accepts(observations: list[Observation]) -> None:
    for obs in observations:
        schema = decision_schema(obs)
        assert list(schema["properties"]) == ["analysis", "command"] and schema["required"] == ["analysis", "command"]
        for path, node in _walk(schema):
            if path.endswith("/properties"):
                continue  # argument names, not keywords
            assert not FORBIDDEN & set(node), f"{obs.robot}: {path} uses {FORBIDDEN & set(node)}"
            if "enum" in node:
                assert node["enum"], f"{obs.robot}: empty enum at {path}"
                assert node["enum"] == sorted(set(node["enum"])), f"{obs.robot}: unsorted enum at {path}"
            if node.get("type") == "object":  # strict mode: closed objects, every property required
                assert node["additionalProperties"] is False and node["required"] == list(node["properties"]), path
        for skill, variant in _variants(schema).items():
            assert list(variant["properties"]) == ["skill", *arguments(skill)]


def test_enums_are_the_names_in_the_robots_own_scene_graph(observations: list[Observation]) -> None:
    for obs in observations:
        schema, variants = decision_schema(obs), _variants(decision_schema(obs))
        known = {o.name for o in obs.objects}
        if "navigate" in variants:
            assert _enum(schema, "navigate", "furniture") == sorted(f.name for f in obs.furniture if f.stand_poses)
            most = max(len(f.stand_poses) for f in obs.furniture) - 1
            assert variants["navigate"]["properties"]["stand_pose"] == {
                "type": "integer",
                "minimum": 0,
                "maximum": most,
            }
        if "open" in variants:
            assert _enum(schema, "open", "furniture") == sorted(f.name for f in obs.furniture if f.openable)
        if "pick" in variants:
            assert _enum(schema, "pick", "object") == sorted(o.name for o in obs.objects if o.held_by is None)
        if "place" in variants:
            assert set(_enum(schema, "place", "object")) == known | (
                {obs.status.holding} if obs.status.holding else set()
            )
            assert set(_enum(schema, "place", "location")) <= {
                f.name for f in obs.furniture if f.place_pose is not None
            }
        assert _enum(schema, "communicate", "to") == sorted(obs.teammates)


def test_alice_at_the_start_knows_no_object_so_cannot_pick_or_place(start: dict[str, Observation]) -> None:
    assert start["alice"].objects == []
    assert list(_variants(decision_schema(start["alice"]))) == ["navigate", "move", "open", "communicate", "wait"]
    assert list(_variants(decision_schema(start["david"]))) == ["navigate", "communicate", "wait"]


def test_alice_names_only_the_objects_she_has_seen(sim: Sim, later: dict[str, Observation]) -> None:
    alice = later["alice"]
    seen = {o.name for o in alice.objects}
    unseen = set(sim.objects) - seen
    assert seen and unseen, "the episode should leave Alice knowing some objects but not all"
    schema = decision_schema(alice)
    for skill in ("pick", "place"):
        assert not unseen & set(_enum(schema, skill, "object"))
    # the goal fixtures are Bob's to place on: Alice hands over on table_0
    assert "tray" not in _enum(schema, "place", "location") and "table_0" in _enum(schema, "place", "location")


def test_bob_is_a_fixed_arm_and_david_has_no_arm(observations: list[Observation]) -> None:
    for obs in observations:
        skills = set(_variants(decision_schema(obs)))
        assert skills <= set(obs.status.skills) | {"wait"}
        if obs.robot == "bob":
            assert not {"navigate", "move", "open"} & skills
        if obs.robot == "david":
            assert not {"pick", "place", "open", "move"} & skills


def test_bob_names_no_target_he_has_not_seen_and_may_place_on_the_tray(start: dict[str, Observation]) -> None:
    bob = start["bob"]
    schema = decision_schema(bob)
    unseen = set(bob.targets) - {o.name for o in bob.objects}
    assert unseen and not unseen & set(_enum(schema, "pick", "object"))
    assert "tray" in _enum(schema, "place", "location")


def test_a_held_object_is_placed_not_picked(later: dict[str, Observation]) -> None:
    bob = later["bob"]
    assert bob.status.holding is not None
    schema = decision_schema(bob)
    assert bob.status.holding in _enum(schema, "place", "object")
    assert bob.status.holding not in _enum(schema, "pick", "object")


def test_teammates_limit_the_recipients(start: dict[str, Observation]) -> None:
    alice = start["alice"]
    assert _enum(decision_schema(alice, teammates=["Bob"]), "communicate", "to") == ["bob"]
    assert "communicate" not in _variants(decision_schema(alice, teammates=[]))
    assert "wait" in _variants(decision_schema(alice, teammates=[]))


def test_same_observation_same_schema_bytes_and_hash(start: dict[str, Observation]) -> None:
    alice = start["alice"]
    a, b = decision_schema(alice), decision_schema(alice.model_copy(deep=True))
    assert json.dumps(a) == json.dumps(b)
    assert schema_hash(a) == schema_hash(b) and re.fullmatch(r"[0-9a-f]{16}", schema_hash(a))
    assert schema_hash(dict(reversed(list(a.items())))) == schema_hash(a)  # canonical: key order does not matter
    assert len({schema_hash(decision_schema(o)) for o in start.values()}) == 3


def test_response_format_per_provider(start: dict[str, Observation]) -> None:
    schema = decision_schema(start["bob"])
    assert response_format(schema, "ollama") == {"format": schema}
    for provider in ("openai", "vllm", "llamacpp", "lmstudio", ""):
        rf = response_format(schema, provider)["response_format"]
        assert rf == {"type": "json_schema", "json_schema": {"name": "decision", "strict": True, "schema": schema}}


# --------------------------------------------------------------------------- replies


def test_every_skill_round_trips_to_the_free_text_action(observations: list[Observation]) -> None:
    for obs in observations:
        schema = decision_schema(obs)
        validator = jsonschema.Draft202012Validator(schema)
        for skill, variant in _variants(schema).items():
            command = _sample(skill, variant)
            reply = {"analysis": f"{obs.robot} thinks about {skill}.", "command": command}
            validator.validate(reply)
            action, analysis = parse_structured(json.dumps(reply))
            assert action == parse_command(_free_text(command)), skill
            assert analysis == reply["analysis"]


def test_replies_in_fences_or_among_text_still_parse() -> None:
    body = '{"analysis": "Bob needs it.", "command": {"skill": "pick", "object": "mug"}}'
    for text in (f"```json\n{body}\n```", f"  \n{body}\n\n", f"Here is my decision: {body} I hope it helps."):
        assert parse_structured(text) == (Pick(obj="mug"), "Bob needs it.")
    spoken = (
        '{"analysis": "", "command": {"skill": "communicate", "content": "On sofa I found nothing.", "to": " Alice "}}'
    )
    assert parse_structured(spoken)[0] == Communicate(content="On sofa I found nothing.", to="alice")
    assert parse_structured('{"command": {"skill": "WAIT"}}') == (Wait(), "")


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("I will pick the mug.", "no JSON object"),
        ('{"analysis": "x", "command": {"skill": "pick", "object": "mug"}', "not valid JSON"),
        ('{"analysis": "x", "command": {"skill": "pick" "object": "mug"}}', "not valid JSON"),
        ('{"analysis": "x"}', 'no "command"'),
        ('{"analysis": "x", "command": "pick(mug)"}', 'no "command"'),
        ('{"analysis": 3, "command": {"skill": "wait"}}', "analysis"),
        ('{"analysis": "x", "command": {"object": "mug"}}', "no skill"),
        ('{"analysis": "x", "command": {"skill": "fly", "to": "moon"}}', "unknown skill 'fly'"),
        ('{"analysis": "x", "command": {"skill": "place", "object": "mug"}}', "missing location"),
        ('{"analysis": "x", "command": {"skill": "pick", "object": "mug", "location": "tray"}}', "unexpected location"),
        (
            '{"analysis": "x", "command": {"skill": "navigate", "furniture": "sofa", "stand_pose": -1}}',
            "stand_pose: Input should be greater",
        ),
        (
            '{"analysis": "x", "command": {"skill": "open", "furniture": 7}}',
            "furniture: Input should be a valid string",
        ),
        ('{"analysis": "x", "command": {"skill": "communicate", "content": "", "to": "bob"}}', "content:"),
        ('{"analysis": "x", "command": {"skill": "move", "dx": "far", "dy": 0}}', "dx:"),
    ],
)
def test_bad_replies_say_what_is_wrong(text: str, reason: str) -> None:
    with pytest.raises(ReplyFormatError, match=re.escape(reason)):
        parse_structured(text)


def test_the_instructions_examples_are_valid_commands() -> None:
    examples = [e for e in re.findall(r'\{"skill": [^{}]*\}', STRUCTURED_INSTRUCTIONS) if "..." not in e]
    assert {json.loads(e)["skill"] for e in examples} >= {"navigate", "pick", "place", "communicate", "wait"}
    for e in examples:
        parse_structured(json.dumps({"analysis": "", "command": json.loads(e)}))
    assert '"analysis"' in STRUCTURED_INSTRUCTIONS and '"command"' in STRUCTURED_INSTRUCTIONS


# --------------------------------------------------------------------------- llama.cpp


async def _ask(client: httpx.AsyncClient, url: str, schema: dict[str, Any]) -> httpx.Response:
    """The first token of a constrained reply: enough for the server to compile the schema."""
    body = {"messages": [{"role": "user", "content": "Decide your next step."}], "max_tokens": 1, "temperature": 0.0}
    return await client.post(f"{url}/chat/completions", json=body | response_format(schema, "llamacpp"))


@pytest.mark.slow
async def test_llama_cpp_server_compiles_every_robots_schema(gemma: Path, observations: list[Observation]) -> None:
    """llama.cpp's server (in-process, over HTTP on loopback) compiles each robot's schema for real."""
    from mhrc.agents.llm.local import LocalModelServer

    async with LocalModelServer(gemma, slots=1, n_ctx_per_slot=2048) as srv, httpx.AsyncClient(timeout=60) as client:
        bad = await _ask(
            client,
            srv.base_url,
            {"type": "object", "properties": {"a": {"type": "string", "enum": []}}, "required": ["a"]},
        )
        assert bad.status_code >= 400 and "enum" in bad.text  # the check has teeth: an empty enum is refused
        for obs in observations:
            reply = await _ask(client, srv.base_url, decision_schema(obs))
            assert reply.status_code == 200, reply.text
            assert reply.json()["choices"][0]["message"]["content"].startswith("{")


def test_a_planners_round_schema_gives_each_robot_its_own_commands_and_reads_them_back_one_by_one(
    start: dict[str, Observation],
) -> None:
    """`centralized` with --structured: one command per robot, each from that robot's own schema;
    a robot's bad command is that robot's problem, the others' commands stand."""
    schema = round_schema(start.values())
    jsonschema.Draft202012Validator.check_schema(schema)
    commands = schema["properties"]["commands"]
    assert commands["required"] == ["alice", "bob", "david"] and commands["additionalProperties"] is False
    for robot, obs in start.items():  # the same command schema a robot's own decision has
        assert commands["properties"][robot] == decision_schema(obs)["properties"]["command"]
    for path, node in _walk(schema):
        if not path.endswith("/properties"):
            assert not FORBIDDEN & set(node), path
    reply = {
        "analysis": "alice looks at the table",
        "commands": {"alice": {"skill": "navigate", "furniture": "table_1", "stand_pose": 0}, "bob": {"skill": "fly"}},
    }
    got, problems = parse_round_structured(json.dumps(reply), ("alice", "bob", "david"))
    assert got == {"alice": Navigate(target="table_1", stand_pose=0)}
    assert set(problems) == {"bob", "david"} and "fly" in problems["bob"]
    with pytest.raises(ReplyFormatError, match="commands"):
        parse_round_structured('{"analysis": "x"}', ("alice",))
