"""Model specs: which server and model a `--llm` spec names, and how many episodes keep it busy.

A model spec names the provider and the model: `openai:gpt-4o`, `ollama:llama3.1:8b`,
`vllm:MODEL`, `lmstudio:MODEL`, `llamacpp:MODEL`. With an explicit `base_url` the request goes
to that server, and a spec without a known provider is the model name itself (`qwen2.5:7b`). The API
key comes from the provider's variable (OPENAI_API_KEY for openai), from `api_key_env` if
given, else from MHRC_API_KEY.

httpx, the local server and the OpenAI client are imported where a spec is turned into a client or a
server is asked: checking the names of a heuristic run's (no model) imports none of them.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from typing import TYPE_CHECKING, Unpack

if TYPE_CHECKING:
    from .openai_client import ClientOptions, OpenAIChatClient

# provider -> (default base URL, environment variable holding the API key, or None)
# `replay:TRACE` is not a provider: mhrc.agents.replay builds one client per robot from a trace.
PROVIDERS: dict[str, tuple[str, str | None]] = {
    "openai": ("https://api.openai.com/v1", "OPENAI_API_KEY"),
    "ollama": ("http://127.0.0.1:11434/v1", None),
    "vllm": ("http://127.0.0.1:8000/v1", None),
    "lmstudio": ("http://127.0.0.1:1234/v1", None),
    "llamacpp": ("http://127.0.0.1:8080/v1", None),
}
GENERIC_KEY_ENV = "MHRC_API_KEY"


class LLMSpecError(ValueError):
    """A model spec that names no usable server (unknown provider, missing API key)."""


ROBOT_SPEC = re.compile(r"^([a-z][a-z0-9_]*)=(.+)$")


def split_url(spec: str) -> tuple[str, str | None]:
    """`provider:model@http://host:port/v1` -> (provider:model, its own base URL)."""
    at = spec.rfind("@http")
    return (spec[:at], spec[at + 1 :]) if at > 0 else (spec, None)


def robot_specs(text: str, robots: Sequence[str]) -> dict[str, str | None]:
    """Which model drives which robot: `--llm SPEC` drives them all; `alice=SPEC,bob=SPEC` (any
    subset) drives those, a bare SPEC among them the rest, and without one the rest play the
    heuristic policy (None). A spec may end in `@URL` to name its own server. LLMSpecError names
    a robot that is not in the episode, or one given twice."""
    default: str | None = None
    chosen: dict[str, str] = {}
    for item in (i.strip() for i in text.split(",")):
        if not item:
            continue
        m = ROBOT_SPEC.match(item)
        if m is None:
            if default is not None:
                raise LLMSpecError(
                    f"--llm {text!r} gives two default specs ({default!r}, {item!r}); name the robot of each: alice=SPEC"
                )
            default = item
            continue
        robot, spec = m.groups()
        if robot not in robots:
            raise LLMSpecError(
                f"--llm {text!r} names robot {robot!r}, which is not in this episode (robots: {', '.join(robots)})"
            )
        if robot in chosen:
            raise LLMSpecError(f"--llm {text!r} gives robot {robot!r} two specs")
        chosen[robot] = spec
    if default is None and not chosen:
        raise LLMSpecError("--llm is empty: give a model spec such as openai:gpt-4o, or alice=SPEC,bob=SPEC")
    return {r: chosen.get(r, default) for r in robots}


def check_spec(spec: str, base_url: str | None = None, api_key_env: str | None = None) -> tuple[str, str, str | None]:
    """(model, base URL, API key) for a spec, or LLMSpecError (a ValueError) saying what to fix.

    A spec's own `@URL` wins over `base_url`. `gguf:PATH` is checked as a local model file (its
    URL is known once its server runs)."""
    spec, own_url = split_url(spec)
    base_url = own_url or base_url
    provider, sep, model = spec.partition(":")
    if provider == "replay":
        if not model or not os.path.isfile(model):
            raise LLMSpecError(f"replay trace {model!r} (from LLM spec {spec!r}) does not exist")
        return model, "", None
    if provider == "gguf":
        from .local import GGUFError, check_gguf

        try:
            return str(check_gguf(model)), "", None
        except GGUFError as exc:
            raise LLMSpecError(f"LLM spec {spec!r}: {exc}") from None
    if provider not in PROVIDERS:
        if base_url is None:
            hint = f"known providers: {', '.join(PROVIDERS)}; or pass a base URL for any OpenAI-compatible server"
            if not sep:
                raise LLMSpecError(f"LLM spec {spec!r} must look like provider:model, e.g. openai:gpt-4o; {hint}")
            raise LLMSpecError(f"unknown LLM provider {provider!r} in LLM spec {spec!r}; {hint}")
        provider, model = "", spec  # with a base URL, a spec without a known provider is the model name
    if not model:
        raise LLMSpecError(f"LLM spec {spec!r} names no model, e.g. {provider or 'openai'}:gpt-4o")
    default_url, key_env = PROVIDERS.get(provider, ("", None))
    key_env = api_key_env or key_env
    api_key = (os.environ.get(key_env) if key_env else None) or os.environ.get(GENERIC_KEY_ENV)
    if provider == "openai" and base_url is None and not api_key:
        raise LLMSpecError(
            f"LLM spec {spec!r}: set {key_env} (or {GENERIC_KEY_ENV}) to your API key, or pass a base URL for another server"
        )
    return model, base_url or default_url, api_key


def make_client(
    spec: str, base_url: str | None = None, *, api_key_env: str | None = None, **options: Unpack[ClientOptions]
) -> OpenAIChatClient:
    """An OpenAI-compatible client for a model spec; raises LLMSpecError before any request if unusable.

    `options` go to OpenAIChatClient: timeout (to the first token), idle_timeout, stream, retries,
    backoff, max_concurrency, max_tokens, extra_body.
    """
    from .openai_client import OpenAIChatClient

    model, url, api_key = check_spec(spec, base_url, api_key_env)
    if spec.startswith("replay:"):
        raise LLMSpecError(f"{spec!r} is a recorded trace: use mhrc.agents.replay.replay_clients for it")
    if spec.startswith("gguf:"):
        raise LLMSpecError(
            f"{spec!r} is a local model file: serve it with mhrc.agents.llm.local.LocalModelServer first"
        )
    provider = spec.partition(":")[0]
    return OpenAIChatClient(model, url, api_key=api_key, provider=provider if provider in PROVIDERS else "", **options)


# episodes a worker runs at once against a provider whose parallelism cannot be asked (with no
# answer from llama.cpp's /props): hosted APIs and vLLM batch many requests; Ollama and LM
# Studio serve few at once by default, and a queued request spends its timeout waiting
PROVIDER_EPISODES: dict[str, int] = {"openai": 12, "vllm": 12, "ollama": 1, "lmstudio": 1, "llamacpp": 1}


async def server_slots(base_url: str, timeout: float = 3.0) -> int | None:
    """How many requests the server decodes at once, where it says (llama.cpp's `/props`
    `total_slots`); None when it does not answer that."""
    import httpx

    root = base_url.rstrip("/").removesuffix("/v1")
    try:
        async with httpx.AsyncClient(timeout=timeout) as http:
            resp = await http.get(f"{root}/props")
        slots = resp.json().get("total_slots") if resp.status_code == 200 else None
    except (httpx.HTTPError, ValueError, AttributeError):
        return None
    return slots if isinstance(slots, int) and slots > 0 else None


async def episodes_at_once(specs: Sequence[str | None], base_url: str | None = None) -> int:
    """A worker's default --concurrency for episodes whose robots use `specs`: as many episodes
    as keep the model server's slots busy (one slot a robot), else the provider's usual
    parallelism; 1 for the heuristic (CPU-bound), replays and in-process GGUF models (each
    episode would load its own copy)."""
    llm = [s for s in specs if s is not None]
    if not llm or any(s.startswith(("gguf:", "replay:")) for s in llm):
        return 1
    spec, own = split_url(llm[0])
    url = own or base_url or PROVIDERS.get(spec.partition(":")[0], ("",))[0]
    slots = await server_slots(url) if url and url != PROVIDERS["openai"][0] else None
    if slots is not None:
        return max(1, slots // len(llm))
    return PROVIDER_EPISODES.get(spec.partition(":")[0], 4)
