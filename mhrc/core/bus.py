"""Zenoh sessions bridged to asyncio.

zenoh-python has no asyncio API: its callbacks run on zenoh threads. Every callback here
copies the sample and hands it to the event loop (a batch at a time: `_Inbox`), then returns;
all user handlers run on the loop. Blocking zenoh calls (`open`, `close`) run in
`asyncio.to_thread`; a query's replies come to a callback and hold no thread while the query is
outstanding; a put (congestion control BLOCK) runs on the loop. A
`Bus` owns its session, every entity it declared and the tasks its handlers started, keeps a
reference to each task until it ends (the loop holds tasks weakly) and logs a handler's
exception; `close()` (use `async with`) closes them all."""

from __future__ import annotations

import asyncio
import collections
import contextlib
import json
import socket
import threading
import time
import weakref
from collections.abc import Awaitable, Callable, Coroutine, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import zenoh
from pydantic import BaseModel

from mhrc.core.endpoints import BusError, BusRefused, listen_error, split_endpoint
from mhrc.core.logs import get_logger
from mhrc.core.polling import poll
from mhrc.core.protocol import encode
from mhrc.core.refusal import why_refused
from mhrc.core.uncancelled import to_the_end

if TYPE_CHECKING:
    from mhrc.core.security import Credentials

log = get_logger("mhrc.core.bus")


DEFAULT_LEASE_MS = 2000


@dataclass(frozen=True)
class Sample:
    key: str
    payload: bytes
    is_put: bool = True


Handler = Callable[[Sample], Any]


QueryHandler = Callable[[str, dict[str, str], bytes], Awaitable[BaseModel | None]]


def make_config(
    *,
    mode: str = "peer",
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    lease_ms: int = DEFAULT_LEASE_MS,
    security: Credentials | None = None,
) -> zenoh.Config:
    """A Zenoh config with multicast scouting off and explicit endpoints only; with `security`,
    TLS and user/password authentication (and, for a router, the run's access control)."""
    if mode not in ("peer", "client", "router"):
        raise BusError(f"zenoh mode must be peer, client or router, not {mode!r}")
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "true")
    # zenoh's open waits `scouting/delay` (500 ms by default) for what scouting finds before it
    # returns; with multicast off there is nothing to wait for, and every world (a router) paid it:
    # half a second of each evaluation episode and of each `mhrc up` before its first tick
    conf.insert_json5("scouting/delay", "0")
    conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    conf.insert_json5("transport/link/tx/lease", str(lease_ms))
    conf.insert_json5("transport/link/tx/keep_alive", "4")
    # zenoh's shared-memory transport maps a 16 MB pool per session for messages over 3 KB and
    # never unmaps it when the session closes: an eval worker grew ~16 MB an episode (bench/bench_memory.py)
    conf.insert_json5("transport/shared_memory/enabled", "false")
    if security is not None:
        from mhrc.core.security import apply  # here: the open bus never needs it (nor cryptography)

        apply(conf, security, router=mode == "router")
    return conf


def _direct(callback: Callable[[Any], None]) -> zenoh.handlers.Callback[Any]:
    """`callback` run on the zenoh thread that delivers the sample (or inside the put, for this
    session's own), not handed to a Python thread of its own first. zenoh-python's default
    (`indirect=True`) gives every subscriber, queryable and query a Python thread that the
    sample wakes: a thread switch and a handoff of the GIL per sample per subscriber, and about
    25 Python threads an episode contending for the GIL (bench/bench_llm_client.py). Our
    callbacks only copy the sample and hand it to the loop (or append a line to the trace), and
    zenoh-python lets go of the GIL in every call that waits (put, get, undeclare, close)."""
    return zenoh.handlers.Callback(callback, indirect=False)


class _Inbox:
    """Calls handed from zenoh's threads to one event loop, which is woken once per batch: each
    `call_soon_threadsafe` writes to the loop's self-pipe (a system call and a wake-up of the
    loop), and a worker's loop gets some twelve samples a model call from up to 144 sessions.
    The calls run in the order they came."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self._calls: collections.deque[tuple[Callable[..., None], tuple[Any, ...]]] = collections.deque()
        self._lock = threading.Lock()
        self._armed = False  # a drain is scheduled on the loop and has not begun

    def put(self, fn: Callable[..., None], *args: Any) -> None:
        """Run `fn(*args)` on the loop, after the calls put before it (dropped once the loop closed)."""
        with self._lock:
            self._calls.append((fn, args))
            if self._armed:
                return
            self._armed = True
        if asyncio._get_running_loop() is self._loop:  # put on the loop itself (a share's put delivers in place):
            self._loop.call_soon(self._drain)  # the loop is awake, no need to write to its self-pipe
            return
        with contextlib.suppress(RuntimeError):  # the loop closed while zenoh still delivers
            self._loop.call_soon_threadsafe(self._drain)

    def _drain(self) -> None:
        with self._lock:
            calls, self._calls = self._calls, collections.deque()
            self._armed = False
        for fn, args in calls:
            fn(*args)


_INBOXES: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, _Inbox] = weakref.WeakKeyDictionary()


def _inbox(loop: asyncio.AbstractEventLoop) -> _Inbox:
    """The loop's one inbox, shared by every Bus on it (called on the loop)."""
    inbox = _INBOXES.get(loop)
    if inbox is None:
        inbox = _INBOXES[loop] = _Inbox(loop)
    return inbox


LISTEN_WAIT = 10.0  # s: how long a router's listeners may take to accept connections once its session is open


def _until_listening(listen: Sequence[str], timeout: float) -> None:
    """Return once every tcp/tls endpoint of `listen` with a port accepts a TCP connection. With
    `scouting/delay` 0 (make_config) zenoh's open returns without waiting, and its listeners are
    started on its own runtime: a client that came at once was refused (a world "ready" that no
    agent could reach). BusError when one does not listen within `timeout` seconds."""
    deadline = time.monotonic() + timeout
    for ep in listen:
        proto, host, port = split_endpoint(ep)
        if proto not in ("tcp", "tls") or not port:
            continue
        while True:
            try:
                with socket.create_connection((host, port), timeout=0.2):
                    break
            except OSError as exc:
                if time.monotonic() > deadline:
                    raise BusError(f"zenoh opened but does not listen on {ep} after {timeout:.0f} s ({exc})") from None
                time.sleep(0.01)


# Closed sessions, kept until the process exits. A zenoh Session is freed with the GIL held, and
# freeing a router's waits (up to 10 s) for a task of zenoh's `net` runtime to end; if that
# runtime's one worker is itself waiting for the GIL (delivering a liveliness subscriber's
# history to a Python callback), the two wait on each other until zenoh gives up. A closed Bus
# caught in a reference cycle is freed by Python's cyclic collector, on whichever thread
# allocates at that moment: about one episode in fifty run one after another on a loop stalled
# 10 to 40 s (gdb showed the collector in Session's drop and `net-1` waiting for the GIL). Kept
# here, no session is freed while others run; a closed one holds about 16 kB.
_CLOSED: list[zenoh.Session] = []


def _close_session(session: zenoh.Session) -> None:
    """Close `session` and keep it (_CLOSED); blocks: call it off the loop."""
    session.close()
    _CLOSED.append(session)


class _Users:
    """How many Buses use one zenoh session: the last to close closes it (Bus.share)."""

    def __init__(self) -> None:
        self.count = 1
        self.lock = threading.Lock()

    def join(self) -> None:
        with self.lock:
            self.count += 1

    def leave(self) -> bool:
        """One user fewer; whether it was the last."""
        with self.lock:
            self.count -= 1
            return self.count == 0


class Bus:
    """One participant on a Zenoh session, with asyncio-friendly publish, subscribe, query and
    liveliness. A participant has a session of its own (`open`, `open_client`), or shares
    another's (`share`): participants of one process that log in alike."""

    def __init__(self, session: zenoh.Session, loop: asyncio.AbstractEventLoop, users: _Users | None = None) -> None:
        self._session = session
        self._loop = loop
        self._users = users or _Users()
        self._entities: list[Any] = []
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._tokens: dict[str, zenoh.LivelinessToken] = {}  # key -> this session's liveliness token on it
        self._tasks: set[asyncio.Task[Any]] = (
            set()
        )  # the handlers' tasks still running (the loop keeps only weak references)
        self._closed = False
        self.connected_to: tuple[str, ...] = ()  # the endpoints a client session was opened to

    # ------------------------------------------------------------------ lifecycle
    @classmethod
    async def open(
        cls,
        *,
        mode: str = "peer",
        listen: Sequence[str] = (),
        connect: Sequence[str] = (),
        lease_ms: int = DEFAULT_LEASE_MS,
        security: Credentials | None = None,
    ) -> Bus:
        """Open a session. With `security` (mhrc.core.security.Credentials) the links are TLS and
        the session logs in as the credentials' user; a client that the world refuses gets a
        BusRefused naming the cause (expired or foreign certificate, refused login)."""
        conf = make_config(mode=mode, listen=listen, connect=connect, lease_ms=lease_ms, security=security)
        try:
            session = await asyncio.to_thread(zenoh.open, conf)
        except zenoh.ZError as exc:
            where = ", ".join([*listen, *connect]) or "no endpoints"
            if mode == "client" and len(connect) == 1:
                why = await asyncio.to_thread(why_refused, connect[0], security)
                if why.final:  # retrying cannot help: a certificate, a missing login, the wrong transport
                    raise BusRefused(f"could not open a zenoh session ({where}): {why}") from None
                if why.login_refused:  # or a world still starting: open_client retries a little
                    raise BusRefused(f"could not open a zenoh session ({where}): {why}", final=False) from None
                raise BusError(f"could not open a zenoh session ({where}): {why}") from None
            if listen:
                raise listen_error(listen, str(exc)) from None
            raise BusError(f"could not open a zenoh session ({where}): {exc}") from None
        if mode == "router":
            try:
                await asyncio.to_thread(_until_listening, listen, LISTEN_WAIT)
            except BusError:
                await asyncio.to_thread(_close_session, session)
                raise
        bus = cls(session, asyncio.get_running_loop())
        bus.connected_to = tuple(connect)
        return bus

    async def close(self) -> None:
        """Undeclare everything and close the session; a cancellation meanwhile waits for the
        session to close (an open one keeps the process from exiting)."""
        if self._closed:
            return
        self._closed = True
        await to_the_end(asyncio.to_thread(self._close))

    def _close(self) -> None:
        for ent in reversed(self._entities):
            try:
                ent.undeclare()
            except Exception as exc:  # an entity of a dying session; keep closing the rest
                log.debug("undeclare failed", error=str(exc))
        for pub in self._publishers.values():
            try:
                pub.undeclare()
            except Exception as exc:
                log.debug("undeclare publisher failed", error=str(exc))
        self._entities.clear()
        self._publishers.clear()
        self._tokens.clear()
        if self._users.leave():
            _close_session(self._session)

    def share(self) -> Bus:
        """Another participant on this one's session, as a client of the same world would be:
        its own subscriptions, publishers, liveliness tokens and tasks, which its own `close`
        withdraws (so the others see its tokens go), and every message between the two delivered
        within the session, never through a socket: no zenoh link, no thread woken, no copy in
        the kernel. The session closes with the last Bus on it. For participants of one process
        that would log in with the same credentials (or none): the access control of a router
        sees one login for them all."""
        if self._closed:
            raise BusError("this bus is closed: nothing can share its session")
        self._users.join()
        bus = Bus(self._session, self._loop, self._users)
        bus.connected_to = self.connected_to
        return bus

    async def __aenter__(self) -> Bus:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    @property
    def zid(self) -> str:
        return str(self._session.zid())

    # ------------------------------------------------------------------ pub/sub
    def put(self, key: str, message: BaseModel | bytes) -> None:
        """Publish reliably (congestion control BLOCK) on `key`."""
        payload = message if isinstance(message, bytes) else encode(message)
        pub = self._publishers.get(key)
        if pub is None:
            pub = self._session.declare_publisher(
                key, congestion_control=zenoh.CongestionControl.BLOCK, reliability=zenoh.Reliability.RELIABLE
            )
            self._publishers[key] = pub
        pub.put(payload)

    def spawn(self, coro: Coroutine[Any, Any, Any], name: str) -> asyncio.Task[Any]:
        """Run `coro` as a task of this bus's loop (called on the loop): referenced until it ends,
        its exception logged, never lost."""
        task = self._loop.create_task(coro, name=name)
        self._tasks.add(task)
        task.add_done_callback(self._task_done)
        return task

    def _task_done(self, task: asyncio.Task[Any]) -> None:
        self._tasks.discard(task)
        if not task.cancelled() and (exc := task.exception()) is not None:
            log.error("bus handler failed", task=task.get_name(), error=str(exc), exc_info=exc)

    def _bridge(self, handler: Handler, on_thread: bool = False) -> Callable[[zenoh.Sample], None]:
        inbox = _inbox(self._loop)

        def on_sample(sample: zenoh.Sample) -> None:
            copy = Sample(str(sample.key_expr), sample.payload.to_bytes(), sample.kind == zenoh.SampleKind.PUT)
            if on_thread:
                self._run_handler(handler, copy)
                return
            inbox.put(self._run_handler, handler, copy)

        return on_sample

    def subscribe(self, key_expr: str, handler: Handler, *, on_thread: bool = False) -> None:
        """Call `handler(Sample)` on the event loop for every sample matching `key_expr`; with
        `on_thread`, on zenoh's thread at once (a quick, thread-safe handler that must not depend
        on the loop: the trace recorder, which keeps writing while the loop is busy or stopping)."""
        self._entities.append(self._session.declare_subscriber(key_expr, _direct(self._bridge(handler, on_thread))))

    # ------------------------------------------------------------------ queries
    def serve(self, key: str, handler: QueryHandler) -> None:
        """Answer `get`s on `key` with `await handler(key, parameters, payload)` (None: no reply)."""
        loop = self._loop

        async def answer(query: zenoh.Query) -> None:
            try:
                params = dict(query.parameters) if query.parameters is not None else {}  # type: ignore[call-overload]
                payload = query.payload.to_bytes() if query.payload is not None else b""
                reply = await handler(str(query.key_expr), params, payload)
                if reply is not None:
                    query.reply(
                        query.key_expr, encode(reply)
                    )  # the key asked, not the served pattern: ACL rules match it
            except Exception as exc:
                log.warning("query handler failed", key=key, error=str(exc))
                try:
                    query.reply_err(str(exc).encode())
                except Exception:
                    pass
            finally:
                query.drop()

        def on_query(query: zenoh.Query) -> None:
            try:
                loop.call_soon_threadsafe(lambda: self.spawn(answer(query), f"answer {key}"))
            except RuntimeError:
                query.drop()

        self._entities.append(self._session.declare_queryable(key, _direct(on_query), complete=True))

    async def get(self, selector: str, payload: BaseModel | bytes | None = None, timeout: float = 5.0) -> list[bytes]:
        """Query `selector`; return the payloads of the OK replies received within `timeout`."""
        data = None if payload is None else payload if isinstance(payload, bytes) else encode(payload)

        def keep(reply: zenoh.Reply, out: list[bytes]) -> None:
            if reply.ok is not None:
                out.append(reply.ok.payload.to_bytes())
            elif reply.err is not None:
                log.debug("query error reply", selector=selector, error=reply.err.payload.to_string())

        return await self._replies(
            lambda handler: self._session.get(selector, payload=data, timeout=timeout, handler=handler), keep
        )

    async def _replies(self, ask: Callable[[Any], object], keep: Callable[[zenoh.Reply, list[Any]], None]) -> list[Any]:
        """A query's replies, kept by `keep` as zenoh's threads deliver them; returned when zenoh
        drops the query's handler (the last reply came, or its timeout passed). No thread of
        this process waits for them meanwhile: a query costs nothing while it is outstanding."""
        loop = asyncio.get_running_loop()
        finished: asyncio.Future[None] = loop.create_future()
        out: list[Any] = []

        def settle() -> None:
            if not finished.done():
                finished.set_result(None)

        def finish() -> None:
            with contextlib.suppress(RuntimeError):  # the loop closed first: nobody waits any more
                loop.call_soon_threadsafe(settle)

        ask(zenoh.handlers.Callback(lambda reply: keep(reply, out), finish, indirect=False))
        await finished
        return list(out)

    # ------------------------------------------------------------------ liveliness
    def declare_token(self, key: str) -> None:
        token = self._session.liveliness().declare_token(key)
        self._entities.append(token)
        self._tokens[key] = token

    def undeclare_token(self, key: str) -> None:
        """Withdraw this session's token on `key` (declare_token's), if it holds one."""
        token = self._tokens.pop(key, None)
        if token is not None:
            self._entities.remove(token)
            token.undeclare()

    def watch_liveliness(self, key_expr: str, handler: Handler, *, on_thread: bool = False) -> None:
        """`handler(Sample)` with is_put True when a token appears, False when it vanishes
        (`on_thread` as in `subscribe`).

        Tokens alive at the time of the call are reported too (history)."""
        self._entities.append(
            self._session.liveliness().declare_subscriber(
                key_expr, _direct(self._bridge(handler, on_thread)), history=True
            )
        )

    async def alive(self, key_expr: str, timeout: float = 2.0) -> list[str]:
        """Keys of the liveliness tokens currently matching `key_expr`."""

        def keep(reply: zenoh.Reply, out: list[str]) -> None:
            if reply.ok is not None:
                out.append(str(reply.ok.key_expr))

        return await self._replies(
            lambda handler: self._session.liveliness().get(key_expr, timeout=timeout, handler=handler), keep
        )

    def _run_handler(self, handler: Handler, sample: Sample) -> None:
        try:
            result = handler(sample)
            if asyncio.iscoroutine(result):
                self.spawn(result, f"handle {sample.key}")
        except Exception as exc:
            if self._closed:  # the session closes under it (the run is being stopped): nothing is lost that mattered
                log.debug("bus handler ended by the closing session", key=sample.key, error=str(exc))
                return
            log.exception("bus handler failed", key=sample.key, error=str(exc))


async def open_client(connect: str, timeout: float, *, security: Credentials | None = None) -> Bus:
    """A client session to `connect` (logged in with `security`), retrying while the world is
    still starting up; a world that refuses the session (BusRefused) is not retried."""
    loop = asyncio.get_running_loop()
    refused_at: float | None = None
    failed: list[BusError] = []

    async def session() -> Bus | None:
        nonlocal refused_at
        try:
            return await Bus.open(mode="client", connect=[connect], security=security)
        except BusRefused as exc:
            refused_at = loop.time() if refused_at is None else refused_at
            if exc.final or loop.time() - refused_at > 3.0:
                raise
            failed.append(exc)
        except BusError as exc:
            failed.append(exc)
        return None

    bus = await poll(session, timeout=timeout, every=0.2)
    if bus is None:
        raise failed[-1]
    return bus
