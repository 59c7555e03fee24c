"""Who may reach the play page: only its player, as Jupyter's server lets only its user in.

- A per-run secret (`secrets.token_urlsafe`) is in the address `mhrc play` prints and opens, as
  the query parameter `token`; the page and its WebSocket both require it (the page's script
  passes it on to `/ws`). No cookie carries it: a cookie of 127.0.0.1 is sent to every port of
  127.0.0.1, so another local server the browser visits would receive it.
- The WebSocket's `Origin` must be the page's own (`http://127.0.0.1:PORT`): a page of another
  origin cannot open it, even knowing the secret (cross-site WebSocket hijacking).
- The `Host` header must be the bound address and port: a name rebound to 127.0.0.1 (DNS
  rebinding, `Host: evil.example`) gets 400, as Starlette's `TrustedHostMiddleware` answers.
- Every answer carries a Content-Security-Policy (`frame-ancestors 'none'`: no page frames this
  one; the page's own inline script and style by hash, nothing else runs), `no-referrer` and
  `nosniff`.

An HTTP request refused gets 403 (400 for a wrong Host) and nothing of the page; a WebSocket
refused is closed before it is accepted (the browser sees the handshake fail with 403) and hears
nothing. The secret is compared in constant time and never logged: a refusal is logged with its
code, not its request line.
"""

from __future__ import annotations

import base64
import hashlib
import html
import os
import secrets
import tempfile
from collections.abc import Awaitable, Callable, MutableMapping
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs

from mhrc.core.logs import get_logger

log = get_logger("mhrc.play")

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

OPEN_PATHS = frozenset({"/favicon.ico"})  # answered without the secret: an empty 204, nothing of the page
REFUSED_SOCKET = 1008  # policy violation: the close code of a WebSocket refused before accept


class Denial(str, Enum):
    """Why the gate refused a request (logged; the requester gets only the status)."""

    HOST = "host"  # a Host header other than the bound address and port (DNS rebinding)
    TOKEN = "token"  # no secret, or a wrong one
    ORIGIN = "origin"  # a WebSocket whose Origin is not the page's own


def new_token() -> str:
    """A fresh per-run secret for the page's address."""
    return secrets.token_urlsafe(32)


def launcher(url: str) -> Path:
    """A file only its owner can read (mode 0600) that sends the browser on to `url`. The browser
    is opened on it rather than on the address, so the secret is in no command line another local
    user can read (/proc/PID/cmdline), as Jupyter opens its own. The caller removes it."""
    fd, name = tempfile.mkstemp(prefix="mhrc-play-", suffix=".html")
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(
            f'<!doctype html><meta charset="utf-8"><meta http-equiv="refresh" content="0;url={html.escape(url)}">'
            f'<title>mhrc play</title><p><a href="{html.escape(url)}">open the play page</a></p>\n'
        )
    return Path(name)


def csp_hash(source: str) -> str:
    """A CSP source expression allowing exactly this inline script or style."""
    return "'sha256-" + base64.b64encode(hashlib.sha256(source.encode("utf-8")).digest()).decode("ascii") + "'"


def policy(script: str, style: str) -> str:
    """The page's Content-Security-Policy: its own inline script and style, its own WebSocket."""
    return "; ".join(
        (
            "default-src 'self'",
            f"script-src {csp_hash(script)}",
            f"style-src {csp_hash(style)}",
            "connect-src 'self'",
            "img-src 'self'",
            "object-src 'none'",
            "base-uri 'none'",
            "form-action 'none'",
            "frame-ancestors 'none'",
        )
    )


@dataclass(frozen=True)
class Gate:
    """The page's secret and the one address it answers on."""

    host: str
    port: int
    token: str = field(default_factory=new_token, repr=False)

    @property
    def origin(self) -> str:
        return f"http://{self.host}:{self.port}"

    @property
    def url(self) -> str:
        """The address `mhrc play` prints and opens (it holds the secret)."""
        return f"{self.origin}/?token={self.token}"

    def denial(self, scope: Scope) -> Denial | None:
        """Why this request may not reach the page (None: it may)."""
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        if headers.get("host") != f"{self.host}:{self.port}":
            return Denial.HOST
        if scope["type"] == "http" and scope.get("path") in OPEN_PATHS:
            return None
        given = parse_qs(scope.get("query_string", b"").decode("latin-1")).get("token", [""])
        if len(given) != 1 or not secrets.compare_digest(given[0].encode(), self.token.encode()):
            return Denial.TOKEN
        if scope["type"] == "websocket" and headers.get("origin") != self.origin:
            return Denial.ORIGIN
        return None


class GateMiddleware:
    """The gate in front of the page's app, and the security headers on every answer."""

    def __init__(self, app: ASGIApp, gate: Gate, csp: str) -> None:
        self.app, self.gate = app, gate
        self.headers = [
            (b"content-security-policy", csp.encode()),
            (b"x-frame-options", b"DENY"),
            (b"x-content-type-options", b"nosniff"),
            (b"referrer-policy", b"no-referrer"),
            (b"cache-control", b"no-store"),
        ]

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        denial = self.gate.denial(scope)
        if denial is not None:
            log.warning("play page: request refused", code=denial.value, kind=scope["type"])
            if scope["type"] == "websocket":
                await receive()  # websocket.connect
                await send({"type": "websocket.close", "code": REFUSED_SOCKET})  # before accept: the handshake fails
            else:
                await self._refuse_http(send, 400 if denial is Denial.HOST else 403)
            return

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                names = {k.lower() for k, _ in message.get("headers", [])}
                message["headers"] = [*message.get("headers", []), *(h for h in self.headers if h[0] not in names)]
            await send(message)

        await self.app(scope, receive, with_headers)

    async def _refuse_http(self, send: Send, status: int) -> None:
        body = b"Invalid host header" if status == 400 else b"Forbidden: open the address mhrc play printed"
        await send(
            {
                "type": "http.response.start",
                "status": status,
                "headers": [(b"content-type", b"text/plain; charset=utf-8"), *self.headers],
            }
        )
        await send({"type": "http.response.body", "body": body})
