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
- `world_on_loopback(...)`: the world serving one episode on a free loopback port; attach
  agents with your policies, open sessions of your own, await the end.
- `run_episode(policies, ...)`: one whole episode, your policies for the robots you name, the
  configured policy (heuristic, or the model ``llm`` names) for the others; returns the final
  `EpisodeDone`, the trace and its metrics.

Installed with mhrc, this module is also a pytest plugin (entry point ``mhrc`` in
``pytest11``) providing the fixtures ``mhrc_world``, ``mhrc_model_server`` and
``mhrc_run_episode``; async tests need pytest-asyncio (``asyncio_mode = "auto"``)::

    from mhrc.testing import ScriptedPolicy

    async def test_my_policy(mhrc_run_episode):
        result = await mhrc_run_episode({"alice": MyPolicy()}, seed=0, horizon=20)
        assert result.metrics.success
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import tempfile
import threading
import time
import uuid
from collections.abc import AsyncIterator, Awaitable, Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, Literal, TypeAlias

from mhrc.agents.agent import RobotAgent
from mhrc.agents.heuristic import heuristic_policy
from mhrc.agents.parse import parse_command
from mhrc.agents.policy import Decision, Policy
from mhrc.core.bus import Bus
from mhrc.core.bus import open_client
from mhrc.run.attach import run_agent
from mhrc.run.config import EpisodeConfig
from mhrc.run.serve import serve_world
from mhrc.core.metrics import EpisodeMetrics, from_trace
from mhrc.core.protocol import Action, ActionResult, EpisodeDone, Observation, Wait
from mhrc.core.trace import read_trace

__all__ = [
    "AgentSpec",
    "EpisodeResult",
    "LoopbackWorld",
    "ModelCall",
    "ModelReply",
    "ScriptedModelServer",
    "ScriptedPolicy",
    "run_episode",
    "world_on_loopback",
]

DEFAULT_TIMEOUT = 300.0  # s: a bound on a whole episode, so that a regression fails instead of hanging
ATTACH_TIMEOUT = 30.0  # s: an agent's session and attach, while the world starts up

AgentSpec: TypeAlias = "Policy | Literal['heuristic'] | None"
"""What drives a robot: your `Policy`, ``"heuristic"`` (the built-in one), or None (in
`LoopbackWorld.agent`: as the episode's options configure the robot, heuristic or ``llm``; in
`run_episode`: no agent at all)."""


# --------------------------------------------------------------------------- a scripted policy


class ScriptedPolicy:
    """A `Policy` playing a fixed list of commands in the paper's syntax, in order.

    ``ScriptedPolicy(["navigate(table_0, 0)", "pick(apple)"])``: each command is parsed at once
    with the LLM robots' own parser (`mhrc.agents.parse.parse_command`; a ``Command:`` label is
    optional), so a typo fails here, not mid-episode. When the list is done the robot waits;
    with ``until``, it also waits while ``until(observation)`` is false, and plays its next
    command at the first observation that makes it true. Every `ActionResult` is kept in
    `results`, every observation planned on in `observations`.
    """

    def __init__(self, commands: Iterable[str], *, until: Callable[[Observation], bool] | None = None, name: str = "script") -> None:
        self.name = name
        self.commands = list(commands)
        self.actions: list[Action] = []
        for i, command in enumerate(self.commands):
            try:
                self.actions.append(parse_command(f"Command: {command}"))
            except ValueError as exc:
                raise ValueError(f"scripted command {i} ({command!r}): {exc}") from None
        self.until = until
        self.results: list[ActionResult] = []
        self.observations: list[Observation] = []

    @property
    def remaining(self) -> int:
        """Commands not played yet."""
        return len(self.actions)

    async def decide(self, obs: Observation) -> Decision:
        self.observations.append(obs)
        if not self.actions or (self.until is not None and not self.until(obs)):
            return Decision(action=Wait())
        return Decision(action=self.actions.pop(0))

    def record(self, result: ActionResult) -> None:
        self.results.append(result)


# --------------------------------------------------------------------------- a scripted model server


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
    after the status and headers (no ``Content-Length`` unless `headers` give one; the end of the
    body is the end of the connection, or with `keep_alive` a chunked body whose end keeps the
    connection open for the next request): a server that trickles or never stops writing. The
    stream ends when the iterable does, the client hangs up, or the server is closed. A
    generator is consumed by the one call it answers: return a fresh reply from a callable
    script to stream to every call.
    """

    text: str | None = None
    status: int = 200
    headers: Mapping[str, str] = field(default_factory=dict)
    body: Any = None
    latency: float | None = None
    finish_reason: str = "stop"
    reasoning: str | None = None
    reasoning_field: str = "reasoning_content"
    usage: Mapping[str, Any] | bool = True
    stream: Iterable[bytes] | None = None
    stream_interval: float = 0.0


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

    request: dict[str, Any]
    headers: dict[str, str]
    path: str
    robot: str | None
    started: int
    ended: int | None = None
    connection: int = 0
    latency: float = 0.0
    reply: ModelReply | None = None


Reply: TypeAlias = "str | ModelReply"
Script: TypeAlias = "Sequence[Reply] | Mapping[str, Sequence[Reply]] | Callable[[dict[str, Any]], Reply]"

WHEN_DONE = "Analysis: the script is over.\nCommand: wait()"


@dataclass
class _Answer:
    status: int
    headers: Mapping[str, str]
    payload: bytes
    delay: float
    reply: ModelReply | None = None
    stream: Iterable[bytes] | None = None
    interval: float = 0.0


class ScriptedModelServer:
    """An OpenAI-compatible chat-completions server on 127.0.0.1 answering from a script.

    `script` is a list of replies, answered in the order the requests arrive; or a mapping from
    robot name to its own list (the robot read from the request's system prompt, "You are
    Alice, ..."), so concurrent robots do not race for one list; or a callable on the request's
    JSON returning the reply (called from the server's threads, one per request: guard any
    state it shares). A reply is a `str` (the assistant's text) or a `ModelReply`. After a list
    runs out the server answers `when_done` (a wait command), or with `when_done=None` HTTP 500.
    `latency` (seconds, or a callable on the request JSON) delays each answer; the server is
    threaded, so concurrent requests are answered concurrently. `close()` cuts short the
    latencies and streams still running. With `keep_alive` the server speaks HTTP/1.1 and keeps
    connections open between requests, as production servers do, so that a client's
    connection pool is exercised (the default is HTTP/1.0: one connection a request).

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
        latency: float | Callable[[dict[str, Any]], float] = 0.0,
        when_done: Reply | None = WHEN_DONE,
        keep_alive: bool = False,
    ) -> None:
        self.script = script
        self.latency = latency
        self.when_done = when_done
        self.requests: list[dict[str, Any]] = []
        self.headers: list[dict[str, str]] = []
        self.paths: list[str] = []
        self.calls: list[ModelCall] = []
        self.in_flight = 0
        self.max_in_flight = 0
        self._seq = 0
        self._connections = 0
        self._lock = threading.Lock()
        self._closing = threading.Event()
        self._queues: dict[str | None, list[Reply]] = {}
        if isinstance(script, Mapping):
            self._queues = {robot: list(replies) for robot, replies in script.items()}
        elif not callable(script):
            self._queues = {None: list(script)}
        server = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1" if keep_alive else "HTTP/1.0"

            def setup(self) -> None:
                super().setup()
                with server._lock:
                    server._connections += 1
                    self.connection_no = server._connections

            def do_POST(self) -> None:  # noqa: N802
                raw = self.rfile.read(int(self.headers.get("Content-Length") or 0))
                try:
                    body = json.loads(raw or b"{}")
                except ValueError:
                    self._send(_Answer(400, {}, b'{"error": "the request body is not JSON"}', 0.0))
                    return
                call = server._begin(body, dict(self.headers), self.path, self.connection_no)
                answer = server._answer(body)
                if answer.delay > 0:
                    server._closing.wait(answer.delay)
                server._end(call, answer)
                self._send(answer)

            def do_GET(self) -> None:  # noqa: N802
                self._send(_Answer(404, {}, b'{"error": "only POST /v1/chat/completions is served"}', 0.0))

            def _send(self, answer: _Answer) -> None:
                names = {k.lower() for k in answer.headers}
                try:
                    self.send_response(answer.status)
                    if "content-type" not in names:
                        self.send_header("Content-Type", "application/json")
                    for k, v in answer.headers.items():
                        self.send_header(k, v)
                    # a stream on a kept-alive connection is chunked, so that its end leaves the connection open
                    chunked = answer.stream is not None and "content-length" not in names and self.protocol_version != "HTTP/1.0"
                    if chunked:
                        self.send_header("Transfer-Encoding", "chunked")
                    elif answer.stream is not None or "content-length" in names:
                        self.close_connection = True  # the body may not be what a length says
                        if self.protocol_version != "HTTP/1.0":
                            self.send_header("Connection", "close")
                    if answer.stream is None and "content-length" not in names:
                        self.send_header("Content-Length", str(len(answer.payload)))
                    self.end_headers()
                    if answer.stream is None:
                        self.wfile.write(answer.payload)
                        return
                    for i, chunk in enumerate(answer.stream):
                        if server._closing.is_set() or (i and answer.interval > 0 and server._closing.wait(answer.interval)):
                            self.close_connection = True  # cut short: the body has no proper end
                            break
                        self.wfile.write(b"%x\r\n%s\r\n" % (len(chunk), chunk) if chunked and chunk else chunk)
                        self.wfile.flush()
                    else:
                        if chunked:
                            self.wfile.write(b"0\r\n\r\n")
                            self.wfile.flush()
                except OSError:  # the client gave up (its timeout): what a timeout should do
                    self.close_connection = True

            def log_message(self, *args: object) -> None:
                pass

        self._httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self._httpd.daemon_threads = True
        self.port = int(self._httpd.server_address[1])
        self.url = f"http://127.0.0.1:{self.port}/v1"
        self._thread = threading.Thread(
            target=self._httpd.serve_forever, kwargs={"poll_interval": 0.05}, name="mhrc-scripted-model", daemon=True
        )
        self._thread.start()
        self._closed = False

    @staticmethod
    def robot_of(request: Mapping[str, Any]) -> str | None:
        """The robot a request comes from, read from its system prompt ("You are Alice, ...")."""
        messages = request.get("messages") or []
        text = str(messages[0].get("content") or "") if messages else ""
        if not text.startswith("You are "):
            return None
        return text.removeprefix("You are ").split(",")[0].split()[0].strip(".").lower() or None

    def requests_of(self, robot: str) -> list[dict[str, Any]]:
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

    def _begin(self, body: dict[str, Any], headers: dict[str, str], path: str, connection: int = 0) -> ModelCall:
        with self._lock:
            self.requests.append(body)
            self.headers.append(headers)
            self.paths.append(path)
            self._seq += 1
            robot = self.robot_of(body) if isinstance(body, Mapping) else None
            call = ModelCall(request=body, headers=headers, path=path, robot=robot, started=self._seq, connection=connection)
            self.calls.append(call)
            self.in_flight += 1
            self.max_in_flight = max(self.max_in_flight, self.in_flight)
            return call

    def _end(self, call: ModelCall, answer: _Answer) -> None:
        with self._lock:
            self.in_flight -= 1
            self._seq += 1
            call.ended, call.latency, call.reply = self._seq, answer.delay, answer.reply

    def _next(self, body: dict[str, Any]) -> Reply | None:
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

    def _answer(self, body: dict[str, Any]) -> _Answer:
        try:
            reply = self._next(body)
        except Exception as exc:  # a bug in the test's script: answer it, visibly
            return _Answer(500, {}, json.dumps({"error": f"the script raised {exc!r}"}).encode(), 0.0)
        if reply is None:
            return _Answer(500, {}, b'{"error": "the script is exhausted"}', 0.0)
        if isinstance(reply, str):
            reply = ModelReply(text=reply)
        delay = reply.latency if reply.latency is not None else (self.latency(body) if callable(self.latency) else self.latency)
        answer = _Answer(reply.status, reply.headers, b"", delay, reply, reply.stream, reply.stream_interval)
        if reply.stream is not None:
            return answer
        if reply.body is not None:
            answer.payload = reply.body if isinstance(reply.body, bytes) else json.dumps(reply.body).encode()
            return answer
        if reply.text is None:  # an error status with no content
            answer.payload = json.dumps({"error": f"scripted HTTP {reply.status}"}).encode()
            return answer
        message: dict[str, Any] = {"role": "assistant", "content": reply.text}
        if reply.reasoning is not None:
            message[reply.reasoning_field] = reply.reasoning
        completion: dict[str, Any] = {
            "id": f"chatcmpl-{uuid.uuid4().hex[:12]}",
            "object": "chat.completion",
            "created": int(time.time()),
            "model": body.get("model", "scripted"),
            "choices": [{"index": 0, "message": message, "finish_reason": reply.finish_reason}],
        }
        if reply.usage is True:
            prompt = sum(len(str(m.get("content") or "")) for m in body.get("messages") or [])
            completion["usage"] = {"prompt_tokens": max(1, prompt // 4), "completion_tokens": max(1, len(reply.text) // 4)}
        elif reply.usage is not False:
            completion["usage"] = dict(reply.usage)
        answer.payload = json.dumps(completion).encode()
        return answer

    def close(self) -> None:
        """Stop serving and free the port (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._closing.set()  # ends the latencies and streams still running
        self._httpd.shutdown()
        self._httpd.server_close()
        self._thread.join(timeout=5.0)

    def __enter__(self) -> ScriptedModelServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --------------------------------------------------------------------------- a world on loopback


def _default_trace() -> Path:
    return Path(tempfile.mkdtemp(prefix="mhrc-episode-")) / "trace.jsonl"


class LoopbackWorld:
    """The handle `world_on_loopback` yields: one episode's world, serving on 127.0.0.1."""

    def __init__(self, config: EpisodeConfig, world: asyncio.Task[EpisodeDone]) -> None:
        self.config = config
        self.world = world
        self.agents: dict[str, asyncio.Task[EpisodeDone | None]] = {}
        self._buses: list[Bus] = []

    @property
    def endpoint(self) -> str:
        """The world's Zenoh endpoint (``tcp/127.0.0.1:PORT``), for `open_client` or ``mhrc agent --connect``."""
        return self.config.endpoint

    @property
    def run(self) -> str:
        """The run id: every key of the episode is under ``mhrc/<run>/``."""
        return self.config.run

    @property
    def trace(self) -> Path:
        """The trace file the world writes (complete once `done()` returned)."""
        assert self.config.trace is not None
        return self.config.trace

    async def client(self, timeout: float = ATTACH_TIMEOUT) -> Bus:
        """A client session of your own on the world's bus, closed when the world's context exits."""
        bus = await open_client(self.endpoint, timeout)
        self._buses.append(bus)
        return bus

    async def agent(self, robot: str, policy: AgentSpec = None, *, attach_timeout: float = ATTACH_TIMEOUT) -> asyncio.Task[EpisodeDone | None]:
        """Start an agent for `robot` on its own session, driven by `policy` (a `Policy`,
        ``"heuristic"``, or None: as the episode's options configure the robot, heuristic or
        the model ``llm`` names). Returns its task, which ends with the episode (its result:
        the `EpisodeDone` the agent saw); it is cancelled, and its session closed, on exit.
        Cancelling the task is a crash as the world sees it (its liveliness goes); a new agent
        for the same robot may then be started, as a replacement."""
        if robot not in self.config.robots:
            raise ValueError(f"robot {robot!r} is not in this episode: {', '.join(self.config.robots)}")
        if robot in self.agents and not self.agents[robot].done():
            raise ValueError(f"an agent for {robot} is running; cancel its task first to replace it")
        cfg = self.config
        if policy is None:
            spec = cfg.robot_specs()[robot]
            coro: Awaitable[EpisodeDone | None] = run_agent(
                robot, cfg.run, cfg.endpoint, llm=spec, base_url=cfg.base_url, client_options=cfg.client_options(spec),
                attach_timeout=attach_timeout, **cfg.policy_options(spec),
            )  # fmt: skip
        else:
            chosen: Policy = heuristic_policy(robot) if policy == "heuristic" else policy  # type: ignore[assignment]
            coro = self._drive(robot, chosen, attach_timeout)
        task: asyncio.Task[EpisodeDone | None] = asyncio.ensure_future(coro)
        task.set_name(f"agent-{robot}")
        self.agents[robot] = task
        return task

    async def _drive(self, robot: str, policy: Policy, attach_timeout: float) -> EpisodeDone | None:
        bus = await open_client(self.endpoint, attach_timeout)
        try:
            return await RobotAgent(bus, policy, run=self.run, robot=robot, attach_timeout=attach_timeout).run()
        finally:
            await bus.close()

    async def done(self, timeout: float | None = DEFAULT_TIMEOUT) -> EpisodeDone:
        """The episode's final event, once the world has ended it (its trace is then complete).
        Raises TimeoutError after `timeout` seconds (the world keeps running)."""
        return await asyncio.wait_for(asyncio.shield(self.world), timeout)

    async def _close(self) -> None:
        tasks = [*self.agents.values(), self.world]
        for task in tasks:
            if not task.done():
                task.cancel()
        for task in tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        for bus in self._buses:
            with contextlib.suppress(Exception):
                await bus.close()
        self._buses.clear()


@contextlib.asynccontextmanager
async def world_on_loopback(**options: Any) -> AsyncIterator[LoopbackWorld]:
    """Serve one episode's world on a free port of 127.0.0.1 (a Zenoh router, multicast
    scouting off) as a task of this event loop, and yield its `LoopbackWorld`.

    `options` are `EpisodeConfig`'s fields (``task``, ``scene``, ``seed``, ``n_objects``,
    ``horizon``, ``schedule``, ``start_timeout``, ``trace``, ``llm``, ``base_url``, ...),
    checked as ``mhrc up`` checks them (`mhrc.run.config.ConfigError` names the bad one); the host
    is always 127.0.0.1, and without ``trace`` the trace goes to a fresh temporary directory.
    The world waits for every robot of the episode to attach (``start_timeout`` starts it with
    whoever came). On exit the agents and the world are cancelled if still running and every
    session opened through the handle is closed.
    """
    if options.get("host", "127.0.0.1") != "127.0.0.1":
        raise ValueError("world_on_loopback serves on 127.0.0.1 only")
    options["host"] = "127.0.0.1"
    if options.get("trace") is None:
        options["trace"] = _default_trace()
    cfg = EpisodeConfig.build(**options).resolved()
    world = LoopbackWorld(cfg, asyncio.create_task(serve_world(cfg), name=f"world-{cfg.run}"))
    try:
        yield world
    finally:
        await world._close()


# --------------------------------------------------------------------------- one whole episode


@dataclass
class EpisodeResult:
    """What `run_episode` returns: the world's final event, the trace and the metrics from it."""

    done: EpisodeDone
    trace: Path
    rows: list[dict[str, Any]]
    metrics: EpisodeMetrics
    config: EpisodeConfig

    def messages(self, kind: str, robot: str | None = None) -> list[dict[str, Any]]:
        """The decoded messages of one kind in the trace (``action_result``, ``thought``,
        ``action_request``, ``episode_started``, ...), optionally of one robot, in order."""
        out = []
        for row in self.rows:
            msg = row.get("msg")
            if row.get("kind") == "put" and isinstance(msg, dict) and msg.get("kind") == kind:
                if robot is None or msg.get("robot") == robot:
                    out.append(msg)
        return out

    def results(self, robot: str | None = None) -> list[dict[str, Any]]:
        """Every action result in the trace (or one robot's), in order."""
        return self.messages("action_result", robot)

    def thoughts(self, robot: str | None = None) -> list[dict[str, Any]]:
        """Every published thought (prompt, reply, parse error, action), or one robot's."""
        return self.messages("thought", robot)


async def run_episode(
    policies: Mapping[str, AgentSpec] | None = None, *, timeout: float = DEFAULT_TIMEOUT, **options: Any
) -> EpisodeResult:
    """Run one episode on loopback and return its `EpisodeResult`.

    `policies` maps a robot to your `Policy`, ``"heuristic"``, or None to leave it out (no
    agent attaches: pass ``start_timeout`` so the world starts without it). Robots not named
    play as `options` configure them: the heuristic policy, or the model ``llm`` names for them
    (``llm="bob=openai:test", base_url=server.url``). `options` are `world_on_loopback`'s.
    Each agent has its own Zenoh session. An agent that fails (your policy raised, the world
    refused it, a model that cannot answer at all) fails the call at once with its error; the
    whole episode is bounded by `timeout` seconds (TimeoutError). Everything is closed on return.
    """
    policies = dict(policies or {})
    async with asyncio.timeout(timeout), world_on_loopback(**options) as world:
        unknown = sorted(set(policies) - set(world.config.robots))
        if unknown:
            raise ValueError(f"no such robot in this episode: {', '.join(unknown)} (robots: {', '.join(world.config.robots)})")
        for robot in world.config.robots:
            if robot in policies and policies[robot] is None:
                continue
            await world.agent(robot, policies.get(robot))
        pending: set[asyncio.Future[Any]] = {world.world, *world.agents.values()}
        while world.world in pending:
            finished, pending = await asyncio.wait(pending, return_when=asyncio.FIRST_COMPLETED)
            for task in finished:
                error = None if task is world.world else task.exception()
                if error is not None:
                    raise error
        done = world.world.result()
        for task in world.agents.values():  # they end on the world's episode_done
            await task
        trace = world.trace
        rows = read_trace(trace)
        return EpisodeResult(done=done, trace=trace, rows=rows, metrics=from_trace(rows), config=world.config)


# --------------------------------------------------------------------------- the pytest plugin

try:
    import pytest
except ImportError:  # pragma: no cover - the harness works without pytest, the fixtures need it
    pytest = None  # type: ignore[assignment]

if pytest is not None:

    @pytest.fixture
    def mhrc_world(tmp_path: Path) -> Callable[..., contextlib.AbstractAsyncContextManager[LoopbackWorld]]:
        """A factory of `world_on_loopback`: ``async with mhrc_world(seed=0, horizon=5) as world``;
        each world's trace goes to the test's tmp_path unless you pass ``trace``."""
        count = itertools.count()

        def make(**options: Any) -> contextlib.AbstractAsyncContextManager[LoopbackWorld]:
            options.setdefault("trace", tmp_path / f"mhrc-world-{next(count)}" / "trace.jsonl")
            return world_on_loopback(**options)

        return make

    @pytest.fixture
    def mhrc_model_server() -> Iterator[Callable[..., ScriptedModelServer]]:
        """A factory of `ScriptedModelServer` (same arguments); every server it made is closed
        at teardown."""
        servers: list[ScriptedModelServer] = []

        def make(script: Script, **kwargs: Any) -> ScriptedModelServer:
            servers.append(ScriptedModelServer(script, **kwargs))
            return servers[-1]

        yield make
        for server in servers:
            server.close()

    @pytest.fixture
    def mhrc_run_episode(tmp_path: Path) -> Callable[..., Awaitable[EpisodeResult]]:
        """`run_episode`, with each episode's trace in the test's tmp_path unless you pass ``trace``:
        ``result = await mhrc_run_episode({"alice": MyPolicy()}, seed=0)``."""
        count = itertools.count()

        async def run(policies: Mapping[str, AgentSpec] | None = None, **options: Any) -> EpisodeResult:
            options.setdefault("trace", tmp_path / f"mhrc-episode-{next(count)}" / "trace.jsonl")
            return await run_episode(policies, **options)

        return run
