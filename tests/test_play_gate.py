"""The play page opens only to its player (mhrc.play.gate): the page's real server (uvicorn on
loopback, one per module) answers plain HTTP and WebSocket clients. Without the secret, with a
rebound Host or a foreign Origin, a request gets 403 or 400 and a socket is refused at its
handshake, before it hears anything; every answer carries the security headers. The browser's
side of it (a page of another origin, the player's own page) is in test_play_browser.py."""

from __future__ import annotations

import asyncio
import socket
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import httpx
import pytest
import websocket  # websocket-client: a plain socket, no browser

from mhrc.play.app import bind, serving
from mhrc.play.gate import Gate
from mhrc.play.session import PlaySession


@dataclass
class Page:
    gate: Gate
    session: PlaySession

    @property
    def ws(self) -> str:
        return f"ws://{self.gate.host}:{self.gate.port}/ws"


def _unused_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def play_page() -> Iterator[Page]:
    """The page's server, its session pointed at a bus nobody serves (a socket let in tries to
    attach the robot and is told it failed; the gate's refusals never reach the session)."""
    sock = bind(0)
    gate = Gate("127.0.0.1", sock.getsockname()[1])
    started, stop = threading.Event(), threading.Event()
    box: dict[str, Any] = {}

    async def serve() -> None:
        session = PlaySession("david", run="gate-test", connect=f"tcp/127.0.0.1:{_unused_port()}", attach_timeout=0.5)
        session.reload_grace = 0.0
        box["session"] = session
        async with serving(session, sock, gate):
            started.set()
            while not stop.is_set():
                await asyncio.sleep(0.05)

    thread = threading.Thread(target=lambda: asyncio.run(serve()), daemon=True)
    thread.start()
    assert started.wait(30), "the page's server did not start"
    try:
        yield Page(gate, box["session"])
    finally:
        stop.set()
        thread.join(30)


def _get(page: Page, query: str = "", host: str | None = None) -> httpx.Response:
    headers = {"Host": host} if host else {}
    return httpx.get(f"{page.gate.origin}/{query}", headers=headers, timeout=10)


def _handshake(page: Page, query: str, origin: str | None, host: str | None = None) -> int | dict[str, Any]:
    """The status of a refused handshake, or the first message of a socket let in."""
    try:
        conn = websocket.create_connection(
            page.ws + query, origin=origin, host=host, timeout=10, suppress_origin=origin is None
        )
    except websocket.WebSocketBadStatusException as exc:
        return int(exc.status_code)
    try:
        import json

        return dict(json.loads(conn.recv()))
    finally:
        conn.close()


def test_the_page_needs_its_secret(play_page: Page) -> None:
    assert _get(play_page).status_code == 403
    assert _get(play_page, "?token=wrong").status_code == 403
    assert _get(play_page, f"?token={play_page.gate.token}x").status_code == 403
    refused = _get(play_page, "?token=")
    assert refused.status_code == 403 and "<html" not in refused.text and "david" not in refused.text
    mine = _get(play_page, f"?token={play_page.gate.token}")
    assert mine.status_code == 200 and 'data-panel="observation"' in mine.text


def test_a_rebound_host_is_refused(play_page: Page) -> None:
    """DNS rebinding: evil.example resolved to 127.0.0.1 reaches the port with its own Host."""
    for host in (
        "evil.example",
        f"evil.example:{play_page.gate.port}",
        f"127.0.0.1:{play_page.gate.port + 1}",
        "127.0.0.1",
    ):
        answer = _get(play_page, f"?token={play_page.gate.token}", host=host)
        assert answer.status_code == 400 and "observation" not in answer.text, host


def test_every_answer_forbids_framing_and_foreign_sources(play_page: Page) -> None:
    for answer in (
        _get(play_page, f"?token={play_page.gate.token}"),
        _get(play_page),
        _get(play_page, host="evil.example"),
    ):
        csp = answer.headers["content-security-policy"]
        assert "frame-ancestors 'none'" in csp and "default-src 'self'" in csp, csp
        assert "unsafe-inline" not in csp and answer.headers["x-frame-options"] == "DENY"
        assert answer.headers["referrer-policy"] == "no-referrer"


def test_a_socket_without_the_secret_is_refused_before_it_hears_anything(play_page: Page) -> None:
    own = play_page.gate.origin
    assert _handshake(play_page, "", own) == 403
    assert _handshake(play_page, "?token=wrong", own) == 403
    assert _handshake(play_page, f"?token={play_page.gate.token}", "http://127.0.0.1:9") == 403  # another origin
    assert _handshake(play_page, f"?token={play_page.gate.token}", "null") == 403  # a sandboxed frame, a file
    assert _handshake(play_page, f"?token={play_page.gate.token}", None) == 403  # no Origin at all
    assert _handshake(play_page, f"?token={play_page.gate.token}", own, host="evil.example") == 403
    assert play_page.session.attaches == 0 and not play_page.session.driven  # none of them counted as a driver


def test_the_players_socket_is_let_in(play_page: Page) -> None:
    first = _handshake(play_page, f"?token={play_page.gate.token}&tab=t1", play_page.gate.origin)
    assert isinstance(first, dict) and first["type"] == "hello" and first["robot"] == "david"


def test_a_launcher_file_is_private_and_holds_the_address(tmp_path: Any) -> None:
    from mhrc.play.gate import launcher

    gate = Gate("127.0.0.1", 4242)
    path = launcher(gate.url)
    try:
        assert path.stat().st_mode & 0o077 == 0 and gate.url in path.read_text()
    finally:
        path.unlink()
