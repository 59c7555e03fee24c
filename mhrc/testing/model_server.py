"""`ScriptedModelServer`: an OpenAI-compatible chat-completions server on loopback answering
from a script, a real HTTP server (uvicorn and Starlette, `mhrc.testing.loopback_http`) standing
in for a model's judgement.

The script, the records of the calls and the completion bodies are here; how an answer goes on
the wire (faults included: a lying ``Content-Length``, a stall, a dropped connection) is the
transport's. uvicorn and starlette are dependencies of mhrc itself, since `mhrc.testing` is
public; they are imported when the first server is built, never by the pytest plugin's load.
"""

from __future__ import annotations

import json
import re
import threading
import time
import uuid
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeAlias

from mhrc.core.jsontypes import JsonObject, JsonValue
from mhrc.testing.loopback_http import Answer, Incoming, LoopbackHTTP

__all__ = ["ModelCall", "ModelReply", "Reply", "Script", "ScriptedModelServer", "WHEN_DONE"]

Request: TypeAlias = JsonObject  # a chat-completions request's JSON body, as the client sent it (unchecked)


@dataclass(frozen=True)
class ModelReply:
    """One scripted answer of `ScriptedModelServer`; a plain `str` in a script is ``ModelReply(text)``.

    `text` becomes the assistant message (with `reasoning` under `reasoning_field`:
    ``"reasoning_content"`` as vLLM and llama.cpp send it, or ``"reasoning"`` as Ollama does)
    and `finish_reason`; `usage` is the completion's ``usage`` object: True (the default)
    estimates it from the lengths of the prompt and the text, a mapping is sent as it is (e.g.
    with ``completion_tokens_details``), False leaves it out, as some servers do. `body`
    (JSON-able or bytes) replaces the whole response body, e.g. to send malformed JSON; `status`
    and `headers` for errors (``ModelReply(status=429, headers={"Retry-After": "0"})``);
    `headers` also override the server's own ``Content-Type`` and ``Content-Length`` (a
    ``Content-Length`` of your own may lie: the connection is closed after such a reply).
    `latency` (seconds) overrides the server's for this call.

    `stream` (an iterable of bytes, which may be endless, e.g. ``itertools.repeat(b"a")``)
    makes the body be written chunk by chunk, flushed each time, `stream_interval` seconds apart,
    after the status and headers (no ``Content-Length`` unless `headers` give one; chunked to an
    HTTP/1.1 client, whose connection is then closed, or with `keep_alive` kept open for the next
    request; to an HTTP/1.0 client the end of the body is the end of the connection): a server
    that trickles or never stops writing. The stream ends when the iterable does, the client
    hangs up, or the server is closed. Its chunks are taken on the server's event loop, between
    writes: pace a stream with `stream_interval`, not by blocking in a generator. A generator is
    consumed by the one call it answers: return a fresh reply from a callable script to stream
    to every call.

    Two faults of a server gone bad: `stall` writes the status, the headers and the `stream`'s
    chunks (or no body at all, without a `stream`), then nothing more, the connection held open
    until the server is closed (a stream stalled mid-reply); `drop`
    closes the connection after the latency without a byte of answer (a server that crashed
    while the request was being answered).
    """

    text: str | None = None
    status: int = 200
    headers: Mapping[str, str] = field(default_factory=dict)
    body: Any = None
    latency: float | None = None
    finish_reason: str = "stop"
    reasoning: str | None = None
    reasoning_field: str = "reasoning_content"
    usage: Mapping[str, JsonValue] | bool = True
    stream: Iterable[bytes] | None = None
    stream_interval: float = 0.0
    stall: bool = False
    drop: bool = False


@dataclass
class ModelCall:
    """One request `ScriptedModelServer` received, as kept in its `calls`.

    `request` (the JSON body), `headers`, `path` and `robot` (`ScriptedModelServer.robot_of`)
    are what came in; `reply` is the `ModelReply` the script gave (None when it raised or was
    exhausted) and `latency` the delay applied before answering. `started` and `ended` are
    positions in one count of every call's start and end (a call ends when its latency is over
    and its answer is about to be written; `ended` is None until then): two calls overlapped
    in time exactly when each started before the other ended, whatever the machine's speed.
    `connection` numbers the TCP connection the call came on (1, 2, ... in the order they were
    opened): calls on one connection reused it.
    """

    request: Request
    headers: dict[str, str]
    path: str
    robot: str | None
    started: int
    ended: int | None = None
    connection: int = 0
    latency: float = 0.0
    reply: ModelReply | None = None


Reply: TypeAlias = "str | ModelReply"
Script: TypeAlias = "Sequence[Reply] | Mapping[str, Sequence[Reply]] | Callable[[Request], Reply]"


def _contents(request: Mapping[str, JsonValue]) -> list[str]:
    """The text of each of a request's messages, in order ("" for a message without content; none
    when the request has no list of messages)."""
    messages = request.get("messages")
    if not isinstance(messages, list):
        return []
    return [str(m.get("content") or "") if isinstance(m, Mapping) else "" for m in messages]


WHEN_DONE = "Analysis: the script is over.\nCommand: wait()"


@dataclass
class _Answer(Answer):
    """What to write, with the latency before it and the reply it came from."""

    delay: float = 0.0
    reply: ModelReply | None = None


class ScriptedModelServer:
    """An OpenAI-compatible chat-completions server on 127.0.0.1 answering from a script.

    `script` is a list of replies, answered in the order the requests arrive; or a mapping from
    robot name to its own list (the robot read from the request's system prompt, "You are
    Alice, ..."), so concurrent robots do not race for one list; or a callable on the request's
    JSON returning the reply (called from the server's threads, one per request: guard any
    state it shares). A reply is a `str` (the assistant's text) or a `ModelReply`. After a list
    runs out the server answers `when_done` (a wait command), or with `when_done=None` HTTP 500.
    `latency` (seconds, or a callable on the request JSON) delays each answer; requests are
    answered concurrently (each waits its latency on the server's event loop, each script call
    runs in a thread of its own). `close()` cuts short the latencies and streams still running.
    With `keep_alive` connections stay open between requests, as production servers keep them,
    so that a client's connection pool is exercised; the default closes each connection after
    its answer (``Connection: close``: one connection a request). The status line always says
    HTTP/1.1 (uvicorn's); a client speaking HTTP/1.0 is answered as one.

    Every request is recorded: `requests` (the JSON bodies, in arrival order), `headers` (the
    matching request headers) and `paths`, and `calls` (a `ModelCall` each: the request, the
    reply, its latency and the order of its start and end); `in_flight` counts the requests
    being answered and `max_in_flight` the most at once, e.g. to check a client's concurrency
    limit; `remaining()` counts the scripted replies not given yet. Use as a context manager,
    or call `close()`; the endpoint to give a client is `url` (``http://127.0.0.1:PORT/v1``).
    """

    def __init__(
        self,
        script: Script,
        *,
        latency: float | Callable[[Request], float] = 0.0,
        when_done: Reply | None = WHEN_DONE,
        keep_alive: bool = False,
    ) -> None:
        self.script = script
        self.latency = latency
        self.when_done = when_done
        self.requests: list[Request] = []
        self.headers: list[dict[str, str]] = []
        self.paths: list[str] = []
        self.calls: list[ModelCall] = []
        self.in_flight = 0
        self.max_in_flight = 0
        self._seq = 0
        self._lock = threading.Lock()
        self._queues: dict[str | None, list[Reply]] = {}
        if isinstance(script, Mapping):
            self._queues = {robot: list(replies) for robot, replies in script.items()}
        elif not callable(script):
            self._queues = {None: list(script)}
        self._http = LoopbackHTTP(self._serve, keep_alive=keep_alive, name="mhrc-scripted-model")
        self.port = self._http.port
        self.url = f"http://127.0.0.1:{self.port}/v1"
        self._closed = False

    @staticmethod
    def robot_of(request: Mapping[str, JsonValue]) -> str | None:
        """The robot a request comes from, read from its system prompt ("You are Alice, ...")."""
        contents = _contents(request)
        text = contents[0] if contents else ""
        if not text.startswith("You are "):
            return None
        return text.removeprefix("You are ").split(",")[0].split()[0].strip(".").lower() or None

    @staticmethod
    def step_of(request: Mapping[str, JsonValue]) -> int | None:
        """The step a request's prompt plans, read from its action history (the default prompts
        show no step number, as the paper's): 0 before the robot's first action, else one after
        its latest; None for a prompt without an action history (no_history, your own templates)."""
        contents = _contents(request)
        text = contents[-1] if contents else ""
        if "Your actions so far" not in text:
            return None
        actions = text.split("Your actions so far", 1)[1]
        latest = re.findall(r"\(latest\) step (\d+):", actions)
        return int(latest[-1]) + 1 if latest else 0

    def requests_of(self, robot: str) -> list[Request]:
        """The recorded requests of one robot, in arrival order."""
        with self._lock:
            return [r for r in self.requests if self.robot_of(r) == robot]

    def remaining(self, robot: str | None = None) -> int:
        """The scripted replies not given yet: of the list, of one robot's list, or (with a
        mapping and no `robot`) of all robots' lists; 0 for a callable script."""
        with self._lock:
            if robot is None:
                return sum(len(queue) for queue in self._queues.values())
            return len(self._queues.get(robot, []))

    async def _serve(self, incoming: Incoming) -> Answer:
        """One request, on the server's loop: record it, ask the script (in a thread of its own),
        wait the latency (cut short by `close()`), record its end."""
        call = self._begin(incoming.body, incoming.headers, incoming.path, incoming.connection)
        answer: _Answer = await self._http.off_loop(self._answer, incoming.body)
        await self._http.pause(answer.delay)
        self._end(call, answer)
        return answer

    def _begin(self, body: Request, headers: dict[str, str], path: str, connection: int = 0) -> ModelCall:
        with self._lock:
            self.requests.append(body)
            self.headers.append(headers)
            self.paths.append(path)
            self._seq += 1
            robot = self.robot_of(body) if isinstance(body, Mapping) else None
            call = ModelCall(
                request=body, headers=headers, path=path, robot=robot, started=self._seq, connection=connection
            )
            self.calls.append(call)
            self.in_flight += 1
            self.max_in_flight = max(self.max_in_flight, self.in_flight)
            return call

    def _end(self, call: ModelCall, answer: _Answer) -> None:
        with self._lock:
            self.in_flight -= 1
            self._seq += 1
            call.ended, call.latency, call.reply = self._seq, answer.delay, answer.reply

    def _next(self, body: Request) -> Reply | None:
        if isinstance(self.script, Mapping):
            key = self.robot_of(body)
        elif callable(self.script):
            return self.script(body)
        else:
            key = None
        with self._lock:
            queue = self._queues.get(key)
            if queue:
                return queue.pop(0)
        return self.when_done

    def _answer(self, body: Request) -> _Answer:
        try:
            reply = self._next(body)
        except Exception as exc:  # a bug in the test's script: answer it, visibly
            return _Answer(500, payload=json.dumps({"error": f"the script raised {exc!r}"}).encode())
        if reply is None:
            return _Answer(500, payload=b'{"error": "the script is exhausted"}')
        if isinstance(reply, str):
            reply = ModelReply(text=reply)
        delay = (
            reply.latency
            if reply.latency is not None
            else (self.latency(body) if callable(self.latency) else self.latency)
        )
        answer = _Answer(
            reply.status,
            reply.headers,
            stream=reply.stream,
            interval=reply.stream_interval,
            stall=reply.stall,
            drop=reply.drop,
            delay=delay,
            reply=reply,
        )
        if reply.stall and reply.stream is None:
            answer.stream = ()  # the headers, then silence
        if answer.stream is not None:
            return answer
        if reply.body is not None:
            answer.payload = reply.body if isinstance(reply.body, bytes) else json.dumps(reply.body).encode()
            return answer
        if reply.text is None:  # an error status with no content
            answer.payload = json.dumps({"error": f"scripted HTTP {reply.status}"}).encode()
            return answer
        message: dict[str, str] = {"role": "assistant", "content": reply.text}  # and the reasoning, if any
        if reply.reasoning is not None:
            message[reply.reasoning_field] = reply.reasoning
        completion: JsonObject = {
            "id": f"chatcmpl-{uuid.uuid4().hex[:12]}",
            "object": "chat.completion",
            "created": int(time.time()),
            "model": body.get("model", "scripted"),
            "choices": [{"index": 0, "message": message, "finish_reason": reply.finish_reason}],
        }
        if reply.usage is True:
            prompt = sum(len(c) for c in _contents(body))
            completion["usage"] = {
                "prompt_tokens": max(1, prompt // 4),
                "completion_tokens": max(1, len(reply.text) // 4),
            }
        elif reply.usage is not False:
            completion["usage"] = dict(reply.usage)
        answer.payload = json.dumps(completion).encode()
        return answer

    def close(self) -> None:
        """Stop serving and free the port (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._http.close()  # ends the latencies and streams still running

    def __enter__(self) -> ScriptedModelServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
