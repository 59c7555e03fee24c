"""Episodes against a real model: llama.cpp's own server (the xllamacpp wheel, in-process, HTTP on
loopback) serving the packaged Gemma 3 270M on the CPU. The model is tiny and plans badly, so
these tests check the plumbing, the formats and the limits, never whether a task gets solved."""

from __future__ import annotations

from pathlib import Path

import pytest

from mhrc.agents.llm.local import LocalModelServer
from mhrc.core.protocol import ActionResult, Observation, Thought
from mhrc.core.records import messages, read_records
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process

pytestmark = pytest.mark.slow
CTX = 6144  # tokens per slot: the paper's prompts are about 2,000-3,500 tokens at the start


def thoughts(trace: Path) -> list[Thought]:
    return messages(read_records(trace), Thought)


def observations(trace: Path) -> dict[tuple[str, int], Observation]:
    """Each robot's observation per tick, from the results (the state it planned on next)."""
    out = {}
    for msg in messages(read_records(trace), ActionResult):
        out[(msg.robot, msg.tick + 1)] = msg.observation
    return out


async def test_a_free_text_episode_at_the_defaults_gets_every_robot_its_models_own_reply(
    gemma: Path, tmp_path: Path
) -> None:
    """The paper's free text, every model option at its default (1024 tokens, the first-token and
    idle timeouts, no step deadline), three robots on three slots of this machine's CPU: each
    reply takes minutes of decoding, and every robot-step still gets the model's own reply
    (parsed or not), none "unavailable" (the old total timeout of 60 s cut them all)."""
    from mhrc.core.protocol import LLM_ERROR_PREFIX

    async with LocalModelServer(gemma, slots=3, n_ctx_per_slot=CTX, seed=7) as srv:
        cfg = EpisodeConfig.build(
            seed=0, horizon=1, llm=f"llamacpp:{srv.model}", base_url=srv.base_url, trace=tmp_path / "t.jsonl"
        ).resolved()
        done = await up_in_process(cfg)
    assert done.reason == "horizon" and done.metrics.temporal_steps == 1
    ts = thoughts(cfg.trace)
    assert len(ts) == 3 and not any((t.parse_error or "").startswith(LLM_ERROR_PREFIX) for t in ts), [
        t.parse_error for t in ts
    ]
    assert all(t.reply is not None and t.prompt_tokens > 500 and t.ttft is not None and t.ttft < t.latency for t in ts)
    # the server counted its tokens: none went past the default cap (the rambling base model reaches it)
    assert all(0 < t.completion_tokens <= 1024 for t in ts)
    assert all(t.finish_reason in ("stop", "length") for t in ts)
    for t in ts:  # whatever it wrote, the robot either acted or was told why not
        assert t.action and (t.parse_error is None or len(t.parse_error) <= 300)


async def test_a_structured_episode_against_llama_cpp_parses_every_reply_into_a_known_action(
    gemma: Path, tmp_path: Path
) -> None:
    """Grammar-constrained decoding from each step's schema: every reply of even a 270M base
    model is one valid action naming only what that robot's own scene graph holds."""
    async with LocalModelServer(gemma, slots=3, n_ctx_per_slot=CTX, seed=3) as srv:
        cfg = EpisodeConfig.build(
            seed=0,
            horizon=2,
            llm=f"llamacpp:{srv.model}",
            base_url=srv.base_url,
            structured=True,
            max_tokens=400,
            llm_seed=3,
            trace=tmp_path / "t.jsonl",  # the default timeouts: streamed, a slow grammar-constrained reply is not cut
        ).resolved()
        await up_in_process(cfg)
    ts = thoughts(cfg.trace)
    assert len(ts) == 6
    assert all(t.parse_error is None and t.schema_hash and t.completion_tokens <= 400 for t in ts), [
        t.parse_error for t in ts
    ]
    results = messages(read_records(cfg.trace), ActionResult)
    later = observations(cfg.trace)
    for r in results:  # every name in an action is one the robot knew when it chose it
        a = r.action.model_dump()
        if r.tick == 0:
            continue  # the start-of-episode observation is not in a result; tick 0 is covered by the schema test
        obs = later[(r.robot, r.tick)]
        known = (
            {f.name for f in obs.furniture}
            | {o.name for o in obs.objects}
            | {"tray", "cutting_board"}
            | {f"{c}_panel" for c in ("red", "green", "blue", "yellow")}
        )
        for field in ("target", "obj", "location"):
            if field in a:
                assert a[field] in known, (r.robot, a)


async def test_a_gguf_episode_needs_no_server_of_its_own(gemma: Path, tmp_path: Path) -> None:
    cfg = EpisodeConfig.build(
        seed=0, horizon=1, llm=f"gguf:{gemma}", max_tokens=24, trace=tmp_path / "t.jsonl"
    ).resolved()
    done = await up_in_process(cfg)
    assert done.metrics.temporal_steps == 1
    ts = thoughts(cfg.trace)
    assert {t.robot for t in ts} == {"alice", "bob", "david"}
    assert all(t.policy == f"llm:{gemma}" and 0 < t.completion_tokens <= 24 for t in ts)


@pytest.mark.parametrize("protocol", ["centralized", "leader"])
async def test_one_round_of_each_protocol_holds_its_format_on_a_real_server(
    gemma: Path, tmp_path: Path, protocol: str
) -> None:
    """Issue 45: a protocol's LLM form with --structured against llama.cpp's own server: the
    centralized planner's one reply names a command for every robot, each leader-protocol robot's
    reply is one action; every reply parses (the grammar holds the format), whatever it decides."""
    from mhrc.agents.structured import parse_round_structured

    async with LocalModelServer(gemma, slots=3, n_ctx_per_slot=CTX, seed=3) as srv:
        cfg = EpisodeConfig.build(
            protocol=protocol,
            seed=0,
            horizon=1,
            schedule="lockstep",
            llm=f"llamacpp:{srv.model}",
            base_url=srv.base_url,
            structured=True,
            max_tokens=600,
            llm_seed=3,
            trace=tmp_path / "t.jsonl",
        ).resolved()
        done = await up_in_process(cfg)
    assert done.metrics.temporal_steps == 1
    replied = [t for t in thoughts(cfg.trace) if t.reply is not None]
    assert len(replied) == (1 if protocol == "centralized" else 3)  # one call a round against one per robot
    assert all(t.schema_hash and t.parse_error is None and t.completion_tokens <= 600 for t in replied), [
        (t.parse_error, t.reply) for t in replied
    ]
    if protocol == "centralized":
        commands, problems = parse_round_structured(replied[0].reply or "", ("alice", "bob", "david"))
        assert set(commands) == {"alice", "bob", "david"} and not problems, problems
