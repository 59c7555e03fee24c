"""`LoopbackHTTP`: a real ASGI server (uvicorn running a Starlette app) on 127.0.0.1, in a thread
with its own event loop, that writes whatever answer its handler describes, well-formed or not.

`ScriptedModelServer` is its one user: the script decides what to answer, this module puts it on
the wire. A well-formed answer goes out through plain ASGI ``send`` calls, which uvicorn's h11
protocol frames (a ``Content-Length``, or chunked encoding for a stream on a kept-alive
connection). The answers a server gone bad gives are kept possible as follows:

- a ``Content-Length`` that lies (longer than the body): the body is sent as ASGI body chunks
  with ``more_body`` set, and the connection is then closed, as a server that dies mid-body does
  (h11 refuses to end a message shorter than its length, so the message is never ended). A
  length shorter than the body: the body is cut to it (h11 refuses to write more), which is what
  any client honouring the header reads anyway.
- `drop` (no byte of answer) and a stream cut short (`stall` at close, the client gone, the
  server closed): ASGI cannot close a connection without a response, so the app closes the
  connection's transport itself. Each connection is seen through a subclass of uvicorn's
  `H11Protocol` that registers it (its number, its transport) under the client address that
  also names it in the request's scope.
- HTTP/1.0: uvicorn always answers with an ``HTTP/1.1`` status line (the old hand-written server
  spoke HTTP/1.0 unless kept alive). One connection per request, which is what HTTP/1.0 meant
  here, is kept by answering ``Connection: close``; a client speaking HTTP/1.0 still gets a body
  delimited by the end of the connection, never chunked.

uvicorn and starlette are dependencies of mhrc itself, not of the ``test`` extra: `mhrc.testing`
is public and installed with mhrc, so ``from mhrc.testing import ScriptedModelServer`` must work
in any installation. They are still imported only when a server is built (`mhrc.testing` and its
pytest plugin load names on first use), so a pytest session that asks for no model server does
not pay for them.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import threading
from collections.abc import Awaitable, Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import uvicorn
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import Response
from starlette.routing import Route
from starlette.types import Message, Receive, Scope, Send
from uvicorn.protocols.http.h11_impl import H11Protocol

__all__ = ["Answer", "Incoming", "LoopbackHTTP", "RequestHeaders"]

_METHODS = ["GET", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"]  # HEAD comes with GET


@dataclass
class Answer:
    """What to write: `status`, `headers` (replacing the server's ``Content-Type``; a
    ``Content-Length`` of their own may lie), then `payload`, or with `stream` its chunks
    `interval` seconds apart; `stall` holds the connection silent after them until the server
    closes; `drop` closes the connection without a byte."""

    status: int
    headers: Mapping[str, str] = field(default_factory=dict)
    payload: bytes = b""
    stream: Iterable[bytes] | None = None
    interval: float = 0.0
    stall: bool = False
    drop: bool = False


class RequestHeaders(dict[str, str]):
    """A request's headers, named as HTTP spells them (``Content-Type``) and looked up in any case.

    ASGI hands header names over lowercased; the old server kept the client's spelling, and its
    users look headers up as ``headers["Authorization"]``."""

    def __init__(self, raw: Iterable[tuple[bytes, bytes]]) -> None:
        super().__init__((_title(name.decode("latin-1")), value.decode("latin-1")) for name, value in raw)

    def __getitem__(self, name: str) -> str:
        return super().__getitem__(_title(name))

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and super().__contains__(_title(name))

    def get(self, name: str, default: Any = None) -> Any:  # type: ignore[override]
        return super().get(_title(name), default)


def _title(name: str) -> str:
    return "-".join(part.capitalize() for part in name.split("-"))


@dataclass(frozen=True)
class Incoming:
    """A POST with a JSON body: the body, its headers, its path (with the query) and the number
    of the TCP connection it came on (1, 2, ... in the order they were opened)."""

    body: Any
    headers: RequestHeaders
    path: str
    connection: int


Handler = Callable[[Incoming], Awaitable[Answer]]


@dataclass
class _Link:
    number: int
    transport: asyncio.Transport


class _Server(uvicorn.Server):
    """uvicorn's server, telling the thread that built it when it listens (or failed to)."""

    def __init__(self, config: uvicorn.Config) -> None:
        super().__init__(config)
        self.ready = threading.Event()

    async def startup(self, sockets: Any = None) -> None:
        try:
            await super().startup(sockets)
        finally:
            self.ready.set()


class LoopbackHTTP:
    """uvicorn serving a Starlette app on 127.0.0.1 (a free port, `port`), in a daemon thread with
    its own event loop. Each POST with a JSON body goes to `handle` (a coroutine on that loop),
    and the `Answer` it returns is written; a body that is not JSON gets a 400, any other method
    a 404 (GET) or 501. With `keep_alive` connections stay open between requests; without, every
    answer closes its connection. `close()` cuts `pause`s and streams short and stops the server.
    """

    def __init__(self, handle: Handler, *, keep_alive: bool = False, name: str = "mhrc-loopback-http") -> None:
        self._handle = handle
        self._keep_alive = keep_alive
        self._name = name
        self._links: dict[tuple[str, int], _Link] = {}
        self._opened = itertools.count(1)
        self._streaming: set[asyncio.Transport] = set()
        self._closing = threading.Event()
        self._stop = asyncio.Event()  # bound to the server's loop on first use, there
        self._loop: asyncio.AbstractEventLoop | None = None
        links, opened = self._links, self._opened

        class Counted(H11Protocol):
            def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
                super().connection_made(transport)
                if self.client is not None:
                    links[self.client] = _Link(next(opened), transport)

            def connection_lost(self, exc: Exception | None) -> None:
                if self.client is not None:
                    links.pop(self.client, None)
                super().connection_lost(exc)
                self.flow.resume_writing()  # a send waiting for the socket to drain returns (into a closed connection)

        app = Starlette(routes=[Route("/{path:path}", self._endpoint, methods=_METHODS)])
        config = uvicorn.Config(
            app,
            host="127.0.0.1",
            port=0,
            http=Counted,
            ws="none",
            lifespan="off",
            log_config=None,
            access_log=False,
            timeout_keep_alive=3600,
            timeout_graceful_shutdown=5,
        )
        self._server = _Server(config)
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()
        self._server.ready.wait(30.0)
        if not self._server.started:
            self.close()
            raise RuntimeError("the loopback HTTP server did not start on 127.0.0.1 (see uvicorn's log)")
        self.port = int(self._server.servers[0].sockets[0].getsockname()[1])

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._server.serve())
        finally:
            self._server.ready.set()
            loop.close()

    @property
    def closing(self) -> bool:
        return self._closing.is_set()

    async def pause(self, seconds: float) -> bool:
        """Wait `seconds` on the server's loop, or less if the server closes meanwhile (then True)."""
        if seconds > 0 and not self._stop.is_set():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stop.wait(), seconds)
        return self._stop.is_set()

    async def off_loop(self, fn: Callable[..., Any], *args: Any) -> Any:
        """`fn(*args)` in a daemon thread of its own, so that it may block (a script waiting on a
        barrier) without holding up the other requests; a thread still blocked when the server
        closes is left to end with the process, as the old server's request threads were."""
        loop = asyncio.get_running_loop()
        done: asyncio.Future[Any] = loop.create_future()

        def settle(ok: bool, value: Any) -> None:
            if not done.done():
                done.set_result(value) if ok else done.set_exception(value)

        def run() -> None:
            try:
                value, ok = fn(*args), True
            except BaseException as exc:  # noqa: BLE001  (handed to the awaiting request)
                value, ok = exc, False
            with contextlib.suppress(RuntimeError):  # the loop is gone: the server was closed
                loop.call_soon_threadsafe(settle, ok, value)

        threading.Thread(target=run, name=f"{self._name}-call", daemon=True).start()
        return await done

    async def _endpoint(self, request: Request) -> Response:
        if request.method == "POST":
            raw = await request.body()
            try:
                body = json.loads(raw or b"{}")
            except ValueError:
                return _Written(self, Answer(400, payload=b'{"error": "the request body is not JSON"}'))
            path = request.scope["raw_path"].decode("latin-1")
            if query := request.scope.get("query_string"):
                path += "?" + query.decode("latin-1")
            link = self._links.get(tuple(request.scope["client"] or ()))
            incoming = Incoming(body, RequestHeaders(request.scope["headers"]), path, link.number if link else 0)
            return _Written(self, await self._handle(incoming))
        if request.method in ("GET", "HEAD"):
            return _Written(self, Answer(404, payload=b'{"error": "only POST /v1/chat/completions is served"}'))
        return _Written(self, Answer(501, payload=b'{"error": "unsupported method"}'))

    async def write(self, answer: Answer, scope: Scope, receive: Receive, send: Send) -> None:
        """Put `answer` on the wire, faults included (see the module's docstring)."""
        link = self._links.get(tuple(scope["client"] or ()))
        if answer.drop:
            if link is not None:
                link.transport.close()
            await _hung_up(receive)  # then uvicorn sees a connection gone, not a missing response
            return
        names = {k.lower() for k in answer.headers}
        declared = _length(answer.headers)
        headers = [] if "content-type" in names else [(b"content-type", b"application/json")]
        headers += [(k.encode("latin-1"), v.encode("latin-1")) for k, v in answer.headers.items()]
        if answer.stream is None and declared is None:
            headers.append((b"content-length", str(len(answer.payload)).encode()))
        if not self._keep_alive or declared is not None:  # one connection a request; a length may lie
            headers.append((b"connection", b"close"))
        await send({"type": "http.response.start", "status": answer.status, "headers": headers})
        if answer.stream is None:
            body = answer.payload if declared is None else answer.payload[:declared]
            whole = declared is None or len(body) == declared
            await send({"type": "http.response.body", "body": body, "more_body": not whole})
            if not whole and link is not None:
                link.transport.close()  # a length that lies: the body ends with the connection
                await _hung_up(receive)
            return
        await self._write_stream(answer, declared, link, receive, send)

    async def _write_stream(
        self, answer: Answer, declared: int | None, link: _Link | None, receive: Receive, send: Send
    ) -> None:
        assert answer.stream is not None
        gone = asyncio.ensure_future(_hung_up(receive))
        if link is not None:
            self._streaming.add(link.transport)
        sent, finished = 0, False
        try:
            for i, chunk in enumerate(answer.stream):
                if (
                    self._stop.is_set()
                    or gone.done()
                    or (i and answer.interval > 0 and await self.pause(answer.interval))
                ):
                    break
                if declared is not None:
                    chunk = chunk[: max(0, declared - sent)]
                if chunk:
                    await send({"type": "http.response.body", "body": chunk, "more_body": True})
                    sent += len(chunk)
                await asyncio.sleep(0)  # an endless stream with no interval still lets the loop run
            else:
                if answer.stall:
                    stop = asyncio.ensure_future(self._stop.wait())
                    try:
                        await asyncio.wait([gone, stop], return_when=asyncio.FIRST_COMPLETED)
                    finally:
                        stop.cancel()
                elif declared is None or sent == declared:
                    await send({"type": "http.response.body", "body": b"", "more_body": False})
                    finished = True
            if not finished and link is not None:
                link.transport.abort()  # cut short: the body has no proper end
                await gone
        finally:
            gone.cancel()
            if link is not None:
                self._streaming.discard(link.transport)

    def _stop_on_loop(self) -> None:
        self._stop.set()
        for transport in list(self._streaming):  # a stream whose client stopped reading waits on the socket
            transport.abort()
        self._server.should_exit = True

    def close(self) -> None:
        """Cut pauses and streams short, stop serving and free the port (idempotent)."""
        if self._closing.is_set():
            return
        self._closing.set()
        if self._loop is not None and self._thread.is_alive():
            with contextlib.suppress(RuntimeError):
                self._loop.call_soon_threadsafe(self._stop_on_loop)
        self._thread.join(timeout=10.0)


class _Written(Response):
    """A Starlette response whose writing is `LoopbackHTTP.write`'s (raw ASGI sends)."""

    def __init__(self, http: LoopbackHTTP, answer: Answer) -> None:
        super().__init__(status_code=answer.status)
        self._http, self._answer = http, answer

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        await self._http.write(self._answer, scope, receive, send)


async def _hung_up(receive: Receive) -> None:
    """Return when the client's side of the connection is gone (the request body was read)."""
    message: Message = {}
    while message.get("type") != "http.disconnect":
        message = await receive()


def _length(headers: Mapping[str, str]) -> int | None:
    for name, value in headers.items():
        if name.lower() == "content-length":
            return int(value)
    return None
