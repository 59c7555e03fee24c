"""Real models' ways of failing, against scripted OpenAI-compatible servers on loopback: a server
that never stops writing, replies cut at max_tokens, reasoning blocks and fields, a 1 MB reply,
a server that refuses the JSON-schema response format, bad credentials, a server that is down,
and robots driven by different servers. Every episode is real (Zenoh on loopback, PyBullet)."""

from __future__ import annotations

import itertools
import json
import socket
import threading
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from mhrc.agents.llm import MAX_REPLY_CHARS, LLMFatalError, OpenAIChatClient, robot_specs, split_reasoning
from mhrc.agents.llm_policy import LLMUnreachable
from mhrc.analysis.metrics import from_trace
from mhrc.cli import main
from mhrc.core.protocol import ActionResult, EpisodeDone, Navigate, Thought
from mhrc.core.records import messages, read_records
from mhrc.run.config import ConfigError, EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.testing import ModelReply, ScriptedModelServer

WAIT = "Command: wait()"


def reply(
    text: str,
    *,
    finish: str = "stop",
    reasoning: str | None = None,
    field: str = "reasoning_content",
    usage: dict[str, Any] | None = None,
) -> ModelReply:
    return ModelReply(
        text,
        finish_reason=finish,
        reasoning=reasoning,
        reasoning_field=field,
        usage=usage or {"prompt_tokens": 10, "completion_tokens": 5},
    )


def robot_of(body: dict[str, Any]) -> str:
    return body["messages"][0]["content"].split()[2].rstrip(",").lower()  # "You are Alice, ..."


def thoughts(trace: Path) -> list[Thought]:
    return messages(read_records(trace), Thought)


def endless(body: dict[str, Any]) -> ModelReply:
    """Answers 200 and then writes one byte every 50 ms for as long as the client listens."""
    prefix = b'{"choices": [{"message": {"content": "'
    return ModelReply(
        headers={"Content-Length": str(10**9)},
        stream=itertools.chain([prefix], itertools.repeat(b"a")),
        stream_interval=0.05,
    )


async def against_endless(tmp_path: Path, **values: Any) -> tuple[EpisodeConfig, EpisodeDone, int]:
    """An LLM episode against a server that never stops writing: its config, its end, and the
    requests the server saw."""
    with ScriptedModelServer(endless) as server:
        cfg = EpisodeConfig.build(
            seed=0, llm="openai:m", base_url=server.url, trace=tmp_path / "t.jsonl", **values
        ).resolved()
        return cfg, await up_in_process(cfg), len(server.requests)


@pytest.mark.slow
async def test_an_endless_server_costs_each_step_at_most_its_deadline_and_the_row_counts_the_lost_steps(
    tmp_path: Path,
) -> None:
    """Every call hits the timeout, is retried once, then the robot waits: the episode reaches
    its horizon (it never stalls), and every lost step is counted as unreachable."""
    cfg, done, requests = await against_endless(tmp_path, horizon=2, llm_timeout=0.4, step_deadline=5.0)
    assert done.reason == "horizon" and done.metrics.temporal_steps == 2
    assert requests == 3 * 2 * 2  # 3 robots x 2 steps x (one call + one retry of its timeout)
    m = from_trace(read_records(cfg.trace))
    assert (m.llm_calls, m.llm_unreachable, m.parse_failures) == (6, 6, 0)
    assert all("retried at most 1 time" in t.parse_error for t in thoughts(cfg.trace))


async def test_the_step_deadline_bounds_all_attempts_of_one_step(tmp_path: Path) -> None:
    cfg, done, _ = await against_endless(
        tmp_path, horizon=1, llm_timeout=0.4, step_deadline=0.5
    )  # the retry would end past it
    assert done.metrics.temporal_steps == 1
    assert all("step deadline of 0.5 s" in t.parse_error for t in thoughts(cfg.trace))


async def test_every_request_carries_max_tokens_and_seed_and_a_cut_reply_is_parsed_or_explained(
    mhrc_model_server, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    """Bob's first reply is cut at max_tokens before any command: it becomes feedback saying so.
    Alice's is cut too but holds a command: it runs. Then a 1 MB reply: bounded in the trace and
    in the next prompt."""
    script = {
        "bob": [
            reply("Analysis: I should think about the tray and then about the", finish="length"),
            reply("x" * 1_000_000),
        ],
        "alice": [reply("Command: navigate(table_1, 0)\nAnalysis: this will", finish="length")],
    }
    server = mhrc_model_server(script, when_done=WAIT)
    cfg = EpisodeConfig.build(
        seed=0, horizon=3, llm="openai:m", base_url=server.url, max_tokens=77, llm_seed=5, trace=tmp_path / "t.jsonl"
    ).resolved()
    await up_in_process(cfg)
    assert server.requests and all(b["max_tokens"] == 77 and b["seed"] == 5 for b in server.requests)
    ts = thoughts(cfg.trace)
    bob = [t for t in ts if t.robot == "bob"]
    alice = [t for t in ts if t.robot == "alice"]
    assert bob[0].finish_reason == "length" and "cut at the token limit" in bob[0].parse_error
    assert (
        "- (latest) step 0: Your command could not be read, so you waited." in bob[1].prompt
    )  # came back as the paper's feedback
    assert "token limit" not in bob[1].prompt  # the reason and advice are the feedback_advice aid's
    assert (
        alice[0].finish_reason == "length"
        and alice[0].parse_error is None
        and alice[0].action == "navigate(table_1, 0)"
    )
    # the 1 MB reply: at most MAX_REPLY_CHARS (and a note) in the trace, a short reason in the next prompt
    assert len(bob[1].reply) < MAX_REPLY_CHARS + 100 and "more characters cut by mhrc" in bob[1].reply
    assert len(bob[1].parse_error) <= 300 and len(bob[2].prompt) < len(bob[1].prompt) + 1000
    assert cfg.trace.stat().st_size < 2_000_000


async def test_reasoning_never_reaches_the_parser_and_is_recorded_apart(mhrc_model_server, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """A <think> block full of commands (as DeepSeek-R1 or Qwen3 write them inline) and a
    reasoning_content / reasoning field (vLLM, llama.cpp, Ollama): the command after the
    thinking is the one that runs; the thoughts and their tokens are recorded separately."""
    think = "<think>Maybe pick(apple)? Or navigate(sofa, 0). Command: wait()</think>\nAnalysis: go.\nCommand: navigate(table_1, 0)"
    script = {
        "alice": [reply(think)],
        "bob": [
            reply(
                "Command: wait()",
                reasoning="I could pick(phone) now.",
                usage={
                    "prompt_tokens": 9,
                    "completion_tokens": 30,
                    "completion_tokens_details": {"reasoning_tokens": 21},
                },
            )
        ],
        "david": [reply("Command: navigate(sofa, 0)", reasoning="Command: wait() is tempting", field="reasoning")],
    }
    server = mhrc_model_server(script, when_done=WAIT)
    cfg = EpisodeConfig.build(
        seed=0, horizon=1, llm="openai:m", base_url=server.url, trace=tmp_path / "t.jsonl"
    ).resolved()
    await up_in_process(cfg)
    by = {t.robot: t for t in thoughts(cfg.trace)}
    assert by["alice"].action == "navigate(table_1, 0)" and by["alice"].reasoning.startswith("Maybe pick(apple)")
    assert "<think>" not in by["alice"].reply and by["alice"].reasoning_tokens > 0
    assert (
        by["bob"].action == "wait()"
        and by["bob"].reasoning == "I could pick(phone) now."
        and by["bob"].reasoning_tokens == 21
    )
    assert by["david"].action == "navigate(sofa, 0)" and by["david"].reasoning == "Command: wait() is tempting"


def test_an_unclosed_think_block_is_all_reasoning() -> None:
    assert split_reasoning("<think>pick(apple) then navigate(") == ("", "pick(apple) then navigate(")
    assert split_reasoning("Command: wait()") == ("Command: wait()", None)
    assert split_reasoning("plan pick(x)</think>\nCommand: wait()") == (
        "\nCommand: wait()",
        "plan pick(x)",
    )  # opened by the template


@pytest.mark.parametrize(
    ("status", "body", "match"),
    [
        (401, b'{"error": "invalid api key"}', "refused the credentials"),
        (404, b'{"error": "model not found"}', "no model 'nope'"),
    ],
)
async def test_bad_credentials_or_a_missing_model_stop_the_episode_at_the_first_step(
    mhrc_model_server, tmp_path: Path, status: int, body: bytes, match: str
) -> None:  # type: ignore[no-untyped-def]
    server = mhrc_model_server(lambda _b: ModelReply(status=status, body=body))
    cfg = EpisodeConfig.build(
        seed=0, horizon=50, llm="openai:nope", base_url=server.url, trace=tmp_path / "t.jsonl"
    ).resolved()
    with pytest.raises(LLMFatalError, match=match):
        await up_in_process(cfg)
    assert len(server.requests) <= 3  # one call per robot, none retried, no second step


async def test_a_server_that_refuses_the_response_format_stops_a_structured_run_naming_the_option(
    mhrc_model_server, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    def respond(body: dict[str, Any]) -> ModelReply | str:
        if "response_format" in body:
            return ModelReply(status=400, body=b'{"error": {"message": "response_format is not supported"}}')
        return WAIT

    server = mhrc_model_server(respond)
    cfg = EpisodeConfig.build(
        seed=0, horizon=50, llm="openai:m", base_url=server.url, structured=True, trace=tmp_path / "t.jsonl"
    ).resolved()
    with pytest.raises(LLMFatalError, match="--structured"):
        await up_in_process(cfg)
    assert len(server.requests) <= 3


@pytest.mark.slow
async def test_a_server_down_for_the_whole_first_step_stops_the_run(tmp_path: Path) -> None:
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cfg = EpisodeConfig.build(
        seed=0, horizon=50, llm="openai:m", base_url=f"http://127.0.0.1:{port}/v1", trace=tmp_path / "t.jsonl"
    ).resolved()
    with pytest.raises(LLMUnreachable, match="never answered during its first step"):
        await up_in_process(cfg)


async def test_a_server_that_goes_down_later_only_costs_steps(mhrc_model_server, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    calls: dict[str, int] = {}
    lock = threading.Lock()

    def respond(body: dict[str, Any]) -> ModelReply | str:
        with lock:
            n = calls[robot_of(body)] = calls.get(robot_of(body), 0) + 1
        return WAIT if n == 1 else ModelReply(status=503, headers={"Retry-After": "0"}, body=b"down")

    server = mhrc_model_server(respond)
    cfg = EpisodeConfig.build(
        seed=0, horizon=3, llm="openai:m", base_url=server.url, trace=tmp_path / "t.jsonl"
    ).resolved()
    done = await up_in_process(cfg)
    assert done.reason == "horizon" and from_trace(read_records(cfg.trace)).llm_unreachable == 6


async def test_each_robot_reaches_its_own_server_and_the_rest_play_the_heuristic(
    mhrc_model_server, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    a = mhrc_model_server(lambda _b: WAIT)
    b = mhrc_model_server(lambda _b: WAIT)
    spec = f"alice=openai:model-a@{a.url},bob=vllm:model-b@{b.url}"
    cfg = EpisodeConfig.build(seed=0, horizon=2, llm=spec, trace=tmp_path / "t.jsonl").resolved()
    await up_in_process(cfg)
    assert (
        a.requests
        and {robot_of(body) for body in a.requests} == {"alice"}
        and {body["model"] for body in a.requests} == {"model-a"}
    )
    assert (
        b.requests
        and {robot_of(body) for body in b.requests} == {"bob"}
        and {body["model"] for body in b.requests} == {"model-b"}
    )
    policies = {t.robot: t.policy for t in thoughts(cfg.trace)}
    assert policies == {"alice": "llm:model-a", "bob": "llm:model-b", "david": "heuristic"}


def test_per_robot_specs_are_parsed_and_checked() -> None:
    robots = ("alice", "bob", "david")
    assert robot_specs("ollama:q", robots) == dict.fromkeys(robots, "ollama:q")
    assert robot_specs("ollama:q,bob=openai:gpt-4o", robots) == {
        "alice": "ollama:q",
        "bob": "openai:gpt-4o",
        "david": "ollama:q",
    }
    assert robot_specs("david=llamacpp:m@http://127.0.0.1:9/v1", robots)["david"] == "llamacpp:m@http://127.0.0.1:9/v1"
    with pytest.raises(ValueError, match="names robot 'david', which is not in this episode"):
        robot_specs("david=ollama:q", ("alice", "bob"))
    with pytest.raises(ValueError, match="two default specs"):
        robot_specs("ollama:a,ollama:b", robots)


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["--max-tokens", "0"], "--max-tokens"),
        (["--llm", "ollama:q", "--step-deadline", "0"], "--step-deadline"),
        (["--llm", "david=ollama:q", "--ablation", "no_mobile"], "not in this episode"),
        (["--llm", "gguf:/nonexistent/model.gguf"], "does not exist"),
    ],
)
def test_bad_model_options_fail_before_anything_starts(args: list[str], match: str, tmp_path: Path) -> None:
    result = CliRunner().invoke(main, ["up", "--trace", str(tmp_path / "t.jsonl"), *args])
    assert result.exit_code == 2 and match in result.output, result.output
    assert not (tmp_path / "t.jsonl").exists()


def test_a_file_that_is_not_gguf_is_refused_before_anything_starts(tmp_path: Path) -> None:
    fake = tmp_path / "model.gguf"
    fake.write_text("not a model")
    with pytest.raises(ConfigError, match="not a GGUF file"):
        EpisodeConfig.build(llm=f"gguf:{fake}")


async def test_the_client_sends_the_schema_in_the_form_each_server_takes(mhrc_model_server) -> None:  # type: ignore[no-untyped-def]
    server = mhrc_model_server(lambda _b: '{"analysis": "", "command": {"skill": "wait"}}')
    schema = {"type": "object", "properties": {"x": {"type": "string"}}}
    for provider, field in (("openai", "response_format"), ("ollama", "format")):
        async with OpenAIChatClient("m", server.url, provider=provider) as client:
            await client.complete([{"role": "user", "content": "hi"}], schema=schema)
        body = server.requests[-1]
        assert field in body
        assert (body["format"] if field == "format" else body["response_format"]["json_schema"]["schema"]) == schema


async def test_a_structured_episode_sends_each_robots_schema_and_runs_what_the_json_names(
    mhrc_model_server, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    """The scripted server answers with the first command its request's schema allows (for
    Alice: navigate to the first furniture in the enum); the world runs exactly that."""

    def respond(body: dict[str, Any]) -> str:
        schema = body["response_format"]["json_schema"]["schema"]
        first = schema["properties"]["command"]["anyOf"][0]["properties"]
        command = {
            k: (v["const"] if "const" in v else v["enum"][0] if "enum" in v else v.get("minimum", 0))
            for k, v in first.items()
        }
        if command["skill"] in ("move", "communicate"):
            command = {"skill": "wait"}
        return json.dumps({"analysis": "first option", "command": command})

    server = mhrc_model_server(respond)
    cfg = EpisodeConfig.build(
        seed=0, horizon=2, llm="openai:m", base_url=server.url, structured=True, trace=tmp_path / "t.jsonl"
    ).resolved()
    await up_in_process(cfg)
    ts = thoughts(cfg.trace)
    assert ts and all(t.schema_hash and t.parse_error is None for t in ts)
    assert all('"command": {"skill"' in t.prompt for t in ts)  # the JSON instructions replace "Command:"
    alice = [t for t in ts if t.robot == "alice"]
    first_furniture = json.loads(alice[0].reply)["command"]["furniture"]
    assert alice[0].action == f"navigate({first_furniture}, 0)"
    results = [r for r in messages(read_records(cfg.trace), ActionResult) if r.robot == "alice"]
    assert results[0].action == Navigate(target=first_furniture, stand_pose=0)
    hashes = {t.schema_hash for t in ts}
    assert len(hashes) >= 2  # each robot's own schema (different skills, different names)


async def test_the_console_says_when_a_reply_did_not_parse(mhrc_model_server, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """Not just `wait() ok You waited.`: the reason the robot waited, on the line before."""
    import io

    from rich.console import Console

    from mhrc.run.console import ProgressPrinter

    server = mhrc_model_server(lambda body: "I will think about [bold]it[/bold]." if robot_of(body) == "bob" else WAIT)
    out = io.StringIO()
    printer = ProgressPrinter(Console(file=out, width=200, highlight=False))
    cfg = EpisodeConfig.build(
        seed=0, horizon=1, llm="openai:m", base_url=server.url, trace=tmp_path / "t.jsonl"
    ).resolved()
    await up_in_process(cfg, observe=printer.attach)
    text = out.getvalue()
    assert "bob reply did not parse: no command found" in text and "it waits" in text
    assert "alice reply did not parse" not in text


def test_a_process_agent_gets_every_model_option_of_the_episode() -> None:
    """`--processes` starts `mhrc agent` command lines: the same options mean the same there."""
    from mhrc.run.processes import agent_command

    cfg = EpisodeConfig.build(
        llm="openai:m",
        base_url="http://127.0.0.1:9/v1",
        max_tokens=99,
        llm_seed=4,
        structured=True,
        step_deadline=7.5,
        llm_timeout=3.0,
        llm_idle_timeout=4.0,
        stream=False,
    ).resolved()
    cmd = agent_command("bob", cfg, "openai:m")
    ctx = main.make_context("mhrc", cmd[3:])  # after `python -m mhrc`
    sub = main.get_command(ctx, cmd[3])
    assert sub is not None
    params = sub.make_context("agent", cmd[4:]).params
    agent_cfg = EpisodeConfig.build(
        **{k: v for k, v in params.items() if k in EpisodeConfig.model_fields and v is not None}
    )
    assert agent_cfg.client_options() == cfg.client_options()
    assert (cfg.client_options()["stream"], cfg.client_options()["idle_timeout"]) == (False, 4.0)
    assert agent_cfg.policy_options() == cfg.policy_options()


def test_a_local_model_gets_a_longer_default_timeout_than_a_server(gemma: Path) -> None:
    """A CPU takes minutes for a long reply (bench/results/local_model.json); a server does not."""
    cfg = EpisodeConfig.build(llm=f"alice=gguf:{gemma},openai:m@http://127.0.0.1:9/v1")
    specs = cfg.robot_specs()
    assert (
        cfg.client_options(specs["alice"])["timeout"] == 600.0 and cfg.client_options(specs["bob"])["timeout"] == 120.0
    )
    assert (
        cfg.policy_options(specs["alice"])["step_deadline"] is None
    )  # slow is not down: the call's own timeouts bound it
    assert EpisodeConfig.build(llm=f"gguf:{gemma}", llm_timeout=5.0).client_options(f"gguf:{gemma}")["timeout"] == 5.0


async def test_a_workers_default_concurrency_is_sized_to_the_model_server(mhrc_model_server) -> None:  # type: ignore[no-untyped-def]
    from mhrc.agents.llm import episodes_at_once

    plain = mhrc_model_server(lambda _b: WAIT)  # answers chat, not llama.cpp's /props
    assert await episodes_at_once([None, None, None]) == 1  # the heuristic is CPU-bound
    assert await episodes_at_once(["gguf:/m.gguf"] * 3) == 1  # each episode would load its own model
    assert await episodes_at_once([f"openai:m@{plain.url}"] * 3) == 12
    assert await episodes_at_once(["ollama:q"] * 3, base_url=plain.url) == 1


@pytest.mark.slow
async def test_a_llama_cpp_servers_slots_size_the_default_concurrency(gemma: Path) -> None:
    from mhrc.agents.llm import episodes_at_once
    from mhrc.agents.llm.local import LocalModelServer

    async with LocalModelServer(gemma, slots=6, n_ctx_per_slot=512) as srv:
        assert await episodes_at_once([f"llamacpp:m@{srv.base_url}"] * 3) == 2  # 6 slots, 3 robots an episode
