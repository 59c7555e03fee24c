"""The page's server: a Starlette app (the page at `/`, its WebSocket at `/ws`) served by uvicorn
on 127.0.0.1, in the event loop of the episode's participants, behind the gate (mhrc.play.gate)
that lets only the player in."""

from __future__ import annotations

import asyncio
import contextlib
import socket
from collections.abc import Iterator
from typing import Any

import uvicorn
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import HTMLResponse, Response
from starlette.routing import Route, WebSocketRoute
from starlette.websockets import WebSocket, WebSocketDisconnect

from mhrc.core.logs import get_logger

from .gate import Gate, GateMiddleware, policy
from .messages import PageMessage
from .page import CSS, JS, page_html
from .session import REPLACED, PlaySession, SecondDriver

log = get_logger("mhrc.play")

SECOND_DRIVER = 4409  # the WebSocket close code of a page refused because another drives the robot


class PortInUse(OSError):
    """The page's port is taken."""


def make_app(session: PlaySession, gate: Gate) -> GateMiddleware:
    """The page and its WebSocket, reachable only through `gate`."""
    html = page_html(session.robot)

    async def index(request: Request) -> HTMLResponse:
        return HTMLResponse(html, headers={"Cache-Control": "no-store"})

    async def ws(websocket: WebSocket) -> None:
        await websocket.accept()
        outbox: asyncio.Queue[PageMessage] = asyncio.Queue()
        page = object()
        tab = websocket.query_params.get("tab", "")  # the page's tab (kept across its reloads)
        try:
            session.open(page, outbox.put_nowait, tab=tab)
        except SecondDriver as exc:
            await websocket.send_json({"type": "refused_tab", "reason": str(exc)})
            await websocket.close(code=SECOND_DRIVER)
            return

        async def pump() -> None:
            while True:
                message = await outbox.get()
                await websocket.send_json(message)
                if message["type"] == REPLACED:  # the same tab, reloaded, drives on a new socket
                    await websocket.close()
                    return

        sender = asyncio.create_task(pump())
        try:
            while True:
                msg = await websocket.receive()
                if msg["type"] == "websocket.disconnect":
                    break
                session.submit(page, msg.get("text") or msg.get("bytes") or b"")
        except WebSocketDisconnect:
            pass
        finally:
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await sender
            await session.close(page)

    async def no_icon(request: Request) -> Response:
        return Response(status_code=204)  # the page has no icon: said, so a browser's console stays quiet

    app = Starlette(routes=[Route("/", index), Route("/favicon.ico", no_icon), WebSocketRoute("/ws", ws)])
    return GateMiddleware(app, gate, policy(JS, CSS))


def bind(port: int, host: str = "127.0.0.1") -> socket.socket:
    """The page's listening socket, bound before anything starts; PortInUse if taken."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise PortInUse(
            f"--port: {host}:{port} is in use ({exc.strerror}); pick another port, or 0 for a free one"
        ) from None
    sock.listen(16)
    return sock


class _Server(uvicorn.Server):
    """uvicorn inside the command's loop: the command's own signal handling stays (Ctrl-C ends the episode)."""

    @contextlib.contextmanager
    def capture_signals(self) -> Iterator[None]:
        yield


@contextlib.asynccontextmanager
async def serving(session: PlaySession, sock: socket.socket, gate: Gate) -> Any:
    """Serve the page on `sock`, behind `gate`, for as long as the block runs."""
    config = uvicorn.Config(
        make_app(session, gate), ws="wsproto", lifespan="off", log_level="warning", access_log=False
    )
    server = _Server(config)
    task = asyncio.create_task(server.serve(sockets=[sock]), name="play-page")
    try:
        while not server.started and not task.done():
            await asyncio.sleep(0.02)
        if task.done():
            task.result()
        yield server
    finally:
        server.should_exit = True
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await asyncio.wait_for(task, 5.0)
        sock.close()
