"""The LLM clients' public surface: import from here, whichever module holds the name.

- `mhrc.agents.llm.completion`: what a model answers (`Completion`), how a call fails (`LLMError`
  and its kinds), the `LLMClient` protocol every policy needs, reasoning split off a reply;
- `mhrc.agents.llm.openai_client`: `OpenAIChatClient`, an OpenAI-compatible server over httpx:
  streamed, timed to the first token and between chunks, retried, bounded (its names are
  imported from here on first use, so that a run without a model loads no HTTP client);
- `mhrc.agents.llm.reply`: a reply's body (whole or streamed) read into a `Completion`;
- `mhrc.agents.llm.model_spec`: `--llm` specs (`openai:gpt-4o`, `alice=SPEC,bob=SPEC`, `SPEC@URL`)
  checked and turned into clients, and how many episodes keep a server busy;
- `mhrc.agents.llm.scripted_client`: `ScriptedClient`, a model answering from a list, in process;
- `mhrc.agents.llm.packaged`: the test extra's Gemma 3 270M GGUF, built in $MHRC_MODEL_DIR (not
  imported here: `python -m mhrc.agents.llm.packaged` prints its path).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .completion import (
    DEFAULT_IDLE_TIMEOUT,
    DEFAULT_MAX_TOKENS,
    DEFAULT_TEMPERATURE,
    DEFAULT_TIMEOUT,
    MAX_REPLY_CHARS,
    THINK,
    Completion,
    LLMClient,
    LLMError,
    LLMFatalError,
    LLMSilent,
    LLMTimeout,
    Messages,
    bounded,
    estimate_tokens,
    prompt_text,
    split_reasoning,
)
from .model_spec import (
    GENERIC_KEY_ENV,
    PROVIDER_EPISODES,
    PROVIDERS,
    ROBOT_SPEC,
    LLMSpecError,
    check_spec,
    episodes_at_once,
    make_client,
    robot_specs,
    server_slots,
    split_url,
)

if TYPE_CHECKING:
    from .openai_client import MAX_STREAM_CHARS, MAX_STREAM_CHUNKS, OpenAIChatClient, retry_after
    from .scripted_client import Reply, ScriptedClient

_OPENAI_CLIENT = ("MAX_STREAM_CHARS", "MAX_STREAM_CHUNKS", "OpenAIChatClient", "retry_after")
_SCRIPTED_CLIENT = ("Reply", "ScriptedClient")


def __getattr__(name: str) -> Any:
    """The clients' names, imported on first use: the OpenAI client's (httpx with them), so that a
    heuristic run, which imports this package for its errors and spec checks, never loads an HTTP
    client; the scripted client's (asyncio with it), so that a command line checked against the
    configuration loads no event loop before it is accepted."""
    if name in _OPENAI_CLIENT:
        from . import openai_client

        return getattr(openai_client, name)
    if name in _SCRIPTED_CLIENT:
        from . import scripted_client

        return getattr(scripted_client, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "DEFAULT_IDLE_TIMEOUT",
    "DEFAULT_MAX_TOKENS",
    "DEFAULT_TEMPERATURE",
    "DEFAULT_TIMEOUT",
    "GENERIC_KEY_ENV",
    "MAX_REPLY_CHARS",
    "MAX_STREAM_CHARS",
    "MAX_STREAM_CHUNKS",
    "PROVIDERS",
    "PROVIDER_EPISODES",
    "ROBOT_SPEC",
    "THINK",
    "Completion",
    "LLMClient",
    "LLMError",
    "LLMFatalError",
    "LLMSilent",
    "LLMSpecError",
    "LLMTimeout",
    "Messages",
    "OpenAIChatClient",
    "Reply",
    "ScriptedClient",
    "bounded",
    "check_spec",
    "episodes_at_once",
    "estimate_tokens",
    "make_client",
    "prompt_text",
    "retry_after",
    "robot_specs",
    "server_slots",
    "split_reasoning",
    "split_url",
]
