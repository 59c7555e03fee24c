"""Test your own agent or policy the way mhrc tests its own: a public harness and a pytest plugin.

Everything here runs on loopback (127.0.0.1) with Zenoh's multicast scouting off, and closes
every session, task and server it opened, whatever happens:

- `ScriptedPolicy`: a robot that plays a fixed list of commands in the paper's syntax
  (``"navigate(table_0, 0)"``), answering ``wait()`` when the list is done or while a condition
  on its observation is false.
- `ScriptedModelServer`: an OpenAI-compatible chat-completions server (a real threaded HTTP
  server) answering from a script, with per-call latency, errors, reasoning fields and
  trickling or endless bodies, recording every request (and which ones overlapped); point an
  LLM robot at it with ``llm="openai:test", base_url=server.url``.
- `PolicyHarness(policy)`: a policy's unit test in memory, with nothing started (no bus, no
  world): hand it observations (`observation("bob", objects={"phone": "table_0"})` builds a
  plausible one), say how each action went (`outcome("no_path", ...)`), read its decisions.
- `world_on_loopback(...)`: the world serving one episode on a free loopback port; attach
  agents with your policies, open sessions of your own, await the end.
- `run_episode(policies, ...)`: one whole episode, your policies for the robots you name, the
  configured policy (heuristic, or the model ``llm`` names) for the others; returns the final
  `EpisodeDone`, the trace and its metrics.

Installed with mhrc, its `mhrc.testing.plugin` is also a pytest plugin (entry point ``mhrc`` in
``pytest11``) providing the fixtures ``mhrc_world``, ``mhrc_model_server`` and
``mhrc_run_episode``; async tests need pytest-asyncio (``asyncio_mode = "auto"``)::

    from mhrc.testing import ScriptedPolicy

    async def test_my_policy(mhrc_run_episode):
        result = await mhrc_run_episode({"alice": MyPolicy()}, seed=0, horizon=20)
        assert result.metrics.success
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the same names, imported on first use (below) so that the plugin stays cheap
    from mhrc.testing.model_server import ModelCall, ModelReply, ScriptedModelServer
    from mhrc.testing.policy import ScriptedPolicy
    from mhrc.testing.policy_harness import PolicyHarness, Step, observation, outcome
    from mhrc.testing.world import AgentSpec, EpisodeResult, LoopbackWorld, run_episode, world_on_loopback

__all__ = [
    "AgentSpec",
    "EpisodeResult",
    "LoopbackWorld",
    "ModelCall",
    "ModelReply",
    "PolicyHarness",
    "ScriptedModelServer",
    "ScriptedPolicy",
    "Step",
    "observation",
    "outcome",
    "run_episode",
    "world_on_loopback",
]

# where each name lives: the public ones, then helpers importable from here as before the split
_HOME = {
    "ScriptedPolicy": "policy",
    "PolicyHarness": "policy_harness",
    "Step": "policy_harness",
    "observation": "policy_harness",
    "outcome": "policy_harness",
    "ModelCall": "model_server",
    "ModelReply": "model_server",
    "ScriptedModelServer": "model_server",
    "AgentSpec": "world",
    "EpisodeResult": "world",
    "LoopbackWorld": "world",
    "run_episode": "world",
    "world_on_loopback": "world",
    "Reply": "model_server",
    "Script": "model_server",
    "WHEN_DONE": "model_server",
    "DEFAULT_TIMEOUT": "world",
    "ATTACH_TIMEOUT": "world",
}


def __getattr__(name: str) -> Any:
    """Import a public name's module when the name is first used: pytest loads
    `mhrc.testing.plugin` in every session, and that must not cost PyBullet and Zenoh."""
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_HOME[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_HOME})
