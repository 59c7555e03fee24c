"""Bus tools: `mhrc bus list`, `mhrc bus echo` and `mhrc doctor`.

Each opens one short-lived Zenoh client session to the endpoint it is given (multicast
scouting off, that endpoint only) and closes it in `finally`. Before Zenoh is asked at all, a
TCP endpoint is probed with a plain connect, so "nothing listens there" and "something listens
but it is not zenoh" are told apart in one clear line each (`BusToolError`), never a traceback.

- presence comes from liveliness tokens (docs/architecture.md, "The bus"): `mhrc/<run>/alive/world` and
  `mhrc/<run>/alive/robot/<rid>`;
- every message `echo` shows is decoded with `mhrc.core.protocol` by its `kind`; a payload that is
  not JSON or not a valid message is shown as such (mhrc.cli.message_lines);
- the protocol version a world speaks is the `v` field of its `world/state` answer (every
  message carries one).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from mhrc.cli.message_lines import clip, describe_sample
from mhrc.core.bus import Bus, Sample, make_config
from mhrc.core.endpoints import split_endpoint
from mhrc.core.keys import ROOT, Keys
from mhrc.core.polling import poll
from mhrc.core.printable import printable
from mhrc.core.protocol import PROTOCOL_VERSION, SUPPORTED_VERSIONS, ProtocolError, WorldState, decode
from mhrc.core.refusal import speaks_tls, why_refused
from mhrc.core.security import OBSERVER, WORLD

OPEN_TIMEOUT_MS = (
    2000  # a zenoh handshake over loopback takes milliseconds; a silent non-zenoh listener would hold 10 s
)
PROBE_TIMEOUT = 2.0  # s for the plain TCP connect
STATE_TIMEOUT = 3.0  # s for a world's state answer

Write = Callable[[str], None]


class BusToolError(RuntimeError):
    """The endpoint cannot be used; the message is one line that says why."""


# --------------------------------------------------------------------------- connecting


def normalize_endpoint(ep: str) -> str:
    """`HOST:PORT` -> `tcp/HOST:PORT`; anything with a protocol stays as it is."""
    if "/" in ep:
        return ep
    proto, host, port = split_endpoint(ep)
    if port is None:
        raise BusToolError(f"{ep}: not an endpoint; expected e.g. tcp/127.0.0.1:7447")
    return f"{proto}/{host}:{port}"


def probe_tcp(host: str, port: int, timeout: float = PROBE_TIMEOUT) -> str | None:
    """None if something accepts TCP connections on host:port, else why not (one phrase)."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        return f"cannot resolve host {host!r} ({exc.strerror})"
    reason = "no address to connect to"
    for family, kind, proto, _, addr in infos:
        with socket.socket(family, kind, proto) as s:
            s.settimeout(timeout)
            try:
                s.connect(addr)
                return None
            except ConnectionRefusedError:
                reason = "nothing listens there (connection refused)"
            except TimeoutError:
                reason = f"no answer to a TCP connect within {timeout:.0f} s (host down or port filtered)"
            except OSError as exc:
                reason = f"cannot connect: {exc.strerror or exc}"
    return reason


@dataclass
class Connection:
    """An open tool session: the Bus, plus the Zenoh session's view of whom it reached."""

    endpoint: str
    bus: Bus
    session: zenoh.Session
    run: str | None = None  # the run of the credentials the session logged in with
    user: str | None = None  # and their user (world, a robot, observer)

    @property
    def token_patterns(self) -> list[str]:
        """Where to look for liveliness tokens: everything, and for a secured run's login the
        keys its access control lets it query (a query of `mhrc/**` would be denied there)."""
        if self.run is None:
            return [f"{ROOT}/**"]
        return [f"{ROOT}/**", f"{ROOT}/{self.run}/alive/**", f"{ROOT}/*/alive/world"]

    def remote(self) -> str:
        """`zenoh router <zid>` / `zenoh peer <zid>`: what answered at the endpoint."""
        try:
            routers = [str(z) for z in self.session.info.routers_zid()]
            peers = [str(z) for z in self.session.info.peers_zid()]
        except Exception:  # informational only
            return "zenoh"
        if routers:
            return "zenoh router " + ", ".join(routers)
        if peers:
            return "zenoh peer " + ", ".join(peers)
        return "zenoh"


async def open_connection(
    ep: str, *, credentials: Path | None = None, open_timeout_ms: int = OPEN_TIMEOUT_MS
) -> Connection:
    """A client session to `ep` (with `credentials`, a participant's file of a secured run:
    TLS and its login; mhrc.core.security), or BusToolError saying clearly why there is none."""
    ep = normalize_endpoint(ep)
    proto, host, port = split_endpoint(ep)
    security = None
    if credentials is not None:
        from mhrc.core.security import SecurityError, load

        try:
            security = load(credentials)
        except SecurityError as exc:
            raise BusToolError(f"--credentials: {exc}") from None
    if proto in ("tcp", "tls") and port is not None:
        reason = await asyncio.to_thread(probe_tcp, host, port)
        if reason is not None:
            raise BusToolError(f"{ep}: {reason}")
    conf = make_config(mode="client", connect=[ep], security=security)
    conf.insert_json5("transport/unicast/open_timeout", str(open_timeout_ms))
    try:
        session = await asyncio.to_thread(zenoh.open, conf)
    except zenoh.ZError as exc:
        if (
            proto == "tcp"
            and security is None
            and port is not None
            and not await asyncio.to_thread(speaks_tls, host, port)
        ):
            raise BusToolError(
                f"{ep}: something accepts TCP connections there, but no zenoh handshake within {open_timeout_ms / 1000:.0f} s: "
                f"it is not zenoh (or a secured world: connect to tls/{host}:{port} with --credentials)"
            ) from None
        if proto in ("tcp", "tls"):
            raise BusToolError(f"{ep}: {await asyncio.to_thread(why_refused, ep, security)}") from None
        raise BusToolError(f"{ep}: no zenoh session could be opened: {str(exc).split(' at ')[0]}") from None
    bus = Bus(session, asyncio.get_running_loop())
    if security is None:
        return Connection(ep, bus, session)
    return Connection(ep, bus, session, security.run, security.user)


@contextlib.asynccontextmanager
async def connected(ep: str, credentials: Path | None = None) -> AsyncIterator[Connection]:
    conn = await open_connection(ep, credentials=credentials)
    try:
        yield conn
    finally:
        await conn.bus.close()


# --------------------------------------------------------------------------- presence


@dataclass
class Group:
    """The participants alive under one `mhrc/<run>/`: its world and robots."""

    id: str
    world: bool = False
    robots: list[str] = field(default_factory=list)
    other: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"run": self.id, "world": self.world, "robots": self.robots}
        if self.other:
            out["other"] = self.other
        return out

    def describe(self) -> str:
        text = f"run {self.id}: {'world alive' if self.world else 'no world'}; "
        text += f"robots attached: {', '.join(self.robots)}" if self.robots else "no robots attached"
        if self.other:
            text += f"; other tokens: {', '.join(self.other)}"
        return text


def group_tokens(keys: list[str]) -> list[Group]:
    """Liveliness keys -> one Group per run id, sorted. A run's tokens are `mhrc/<run>/alive/...`."""
    groups: dict[str, Group] = {}
    for key in sorted(set(keys)):
        parts = key.split("/")
        if len(parts) >= 4 and parts[0] == ROOT and parts[2] == "alive":
            gid, role = parts[1], parts[3:]
        else:
            groups.setdefault("", Group("")).other.append(key)
            continue
        g = groups.setdefault(gid, Group(gid))
        if role == ["world"]:
            g.world = True
        elif len(role) == 2 and role[0] == "robot":
            g.robots.append(role[1])
        else:
            g.other.append("/".join(role))
    return [groups[k] for k in sorted(groups)]


async def alive_tokens(bus: Bus, patterns: list[str] | None = None, *, settle: float = 1.5) -> list[str]:
    """Every liveliness token under `mhrc/` (or `patterns`); asks again for up to `settle`
    seconds while the answer is empty (a freshly connected session may not see them at once)."""

    async def tokens() -> list[str] | None:
        return (
            sorted({k for pattern in patterns or [f"{ROOT}/**"] for k in await bus.alive(pattern, timeout=1.0)}) or None
        )

    return await poll(tokens, timeout=settle, every=0.25) or []


async def bus_list(ep: str, *, as_json: bool = False, credentials: Path | None = None, write: Write = print) -> int:
    """`mhrc bus list`: the runs alive at `ep`, from liveliness. Exit code 0."""
    async with connected(ep, credentials) as conn:
        groups = group_tokens(await alive_tokens(conn.bus, conn.token_patterns))
    if as_json:
        write(json.dumps({"endpoint": conn.endpoint, "groups": [g.to_json() for g in groups]}))
        return 0
    if not groups:
        write(f"{conn.endpoint}: no mhrc participants alive")
    for g in groups:
        write(g.describe())
    return 0


# --------------------------------------------------------------------------- echo


def _clock(t: float) -> str:
    return time.strftime("%H:%M:%S", time.localtime(t)) + f".{int((t % 1) * 1000):03d}"


async def bus_echo(
    ep: str,
    keyexpr: str,
    *,
    as_json: bool = False,
    count: int | None = None,
    timeout: float | None = None,
    credentials: Path | None = None,
    write: Write = print,
) -> int:
    """`mhrc bus echo`: print every message on `keyexpr` (one line each) until `count` messages
    or `timeout` seconds. Exit code 0, or 1 when the timeout came before `count` messages."""
    try:
        zenoh.KeyExpr(keyexpr)
    except zenoh.ZError as exc:
        raise BusToolError(f"{keyexpr!r} is not a key expression: {str(exc).split(' at ')[0]}") from None
    queue: asyncio.Queue[tuple[float, Sample]] = asyncio.Queue()
    async with connected(ep, credentials) as conn:
        conn.bus.subscribe(keyexpr, lambda s: queue.put_nowait((time.time(), s)))
        loop = asyncio.get_running_loop()
        deadline = None if timeout is None else loop.time() + timeout
        t0 = time.time()
        seen = 0
        while count is None or seen < count:
            wait = None if deadline is None else deadline - loop.time()
            if wait is not None and wait <= 0:
                break
            try:
                t, sample = await asyncio.wait_for(queue.get(), wait)
            except asyncio.TimeoutError:
                break
            seen += 1
            d = describe_sample(sample)
            if as_json:
                line: dict[str, Any] = {
                    "t": round(t - t0, 6),
                    "key": sample.key,
                    "kind": "put" if sample.is_put else "delete",
                    "msg": d.msg,
                }
                if d.error is not None:
                    line["error"] = d.error
                write(json.dumps(line, separators=(",", ":")))
            else:
                write(printable(f"{_clock(t)} {sample.key} {d.kind} {d.summary}").rstrip())
    return 0 if count is None or seen >= count else 1


# --------------------------------------------------------------------------- doctor


async def world_version(bus: Bus, run: str, timeout: float = STATE_TIMEOUT) -> tuple[bool, str]:
    """(healthy, description) of the world of `run`, from its state answer's `v`."""
    loop = asyncio.get_running_loop()
    t0 = loop.time()
    replies = await bus.get(Keys(run).world_state, timeout=timeout)
    if not replies:
        if loop.time() - t0 >= timeout * 0.9:
            return False, f"world alive, but its state query got no answer within {timeout:.0f} s"
        return False, "world alive, but nothing answers its state query (world/state)"
    raw = replies[0]
    try:
        data = json.loads(raw)
    except (ValueError, UnicodeDecodeError):
        return False, "world alive, but its state answer is not JSON"
    v = data.get("v") if isinstance(data, dict) else None
    ours = f"this mhrc speaks v{PROTOCOL_VERSION}, reads {', '.join(f'v{x}' for x in SUPPORTED_VERSIONS)}"
    if v is None:
        return False, f"world alive, but its state answer carries no protocol version ({ours})"
    if v not in SUPPORTED_VERSIONS:
        return (
            False,
            f"world speaks protocol v{v}, which this mhrc cannot read ({ours}): use the same mhrc version on both sides",
        )
    try:
        state = decode(raw, WorldState)
    except ProtocolError as exc:
        return False, f"world speaks protocol v{v}, but its state answer is not valid here: {clip(str(exc), 160)}"
    phase = "done" if state.done else "running" if state.started else "waiting for robots"
    attached = ", ".join(r for r in state.robots if r in state.attached) or "none"  # in the episode's robot order
    return True, (
        f"world speaks protocol v{v} ({ours}); {state.task} in {state.scene}, seed {state.seed}, {phase}, "
        f"tick {state.tick}/{state.horizon}, placed {state.placed}/{state.total}; robots attached: {attached}"
    )


async def doctor(ep: str, *, credentials: Path | None = None, write: Write = print) -> int:
    """`mhrc doctor`: is zenoh reachable at `ep`, which runs are alive, which protocol version
    each world speaks. Exit code 0 healthy, 1 not."""
    try:
        conn = await open_connection(ep, credentials=credentials)
    except BusToolError as exc:
        write(f"FAIL {exc}")
        return 1
    healthy = True
    try:
        write(f"ok   {conn.endpoint}: {conn.remote()} answers")
        groups = group_tokens(await alive_tokens(conn.bus, conn.token_patterns))
        if not groups:
            write("ok   no runs alive (nothing has declared an mhrc liveliness token)")
        for g in groups:
            if g.world and conn.user is not None and conn.user not in (OBSERVER, WORLD):
                write(
                    f"ok   run {g.id}: world alive (its state answers only the observer's login: "
                    f"--credentials .../observer.json, not {conn.user}'s)"
                )
            elif g.world:
                ok, text = await world_version(conn.bus, g.id)
                healthy &= ok
                write(f"{'ok  ' if ok else 'FAIL'} run {g.id}: {text}")
            elif g.robots:
                write(f"warn run {g.id}: robots {', '.join(g.robots)} alive, but no world")
            if g.other:
                write(f"warn {g.id or 'bus'}: tokens mhrc does not know: {', '.join(g.other)}")
    finally:
        await conn.bus.close()
    write("healthy" if healthy else "not healthy")
    return 0 if healthy else 1
