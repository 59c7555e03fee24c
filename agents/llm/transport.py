"""httpx's requests sent over aiohttp's connections: the model client's default transport.

`OpenAIChatClient` speaks httpx (its requests, responses, streams, errors and timeouts), and
httpx's own transport (httpcore, h11, anyio) cost most of the client's CPU a call: 2-5 ms, where
the same requests over aiohttp take two thirds to a quarter of that (bench/bench_http_client.py,
issue 46). This transport keeps httpx above it (its requests, headers, decoding and errors) and
hands the connection's work to aiohttp:

- the request goes as httpx built it (every header, its body), aiohttp adds none of its own;
- the response's body is streamed as it arrives, undecoded (httpx decodes it);
- a body read to its end leaves its connection in the pool; one left before its end closes it,
  so a server sees its client go (llama.cpp stops decoding and frees the slot);
- the connect timeout is the request's (httpx's ``timeout`` extension); there is no other;
- aiohttp's failures are httpx's: ConnectError, ConnectTimeout, ReadError,
  RemoteProtocolError, or TransportError for the rest, as the client retries them;
- TLS is the caller's context (the client's one context for every client);
- no proxy: httpx reads the environment's proxies only for transports of its own, so a client
  whose environment names one keeps httpx's (openai_client._proxied).

The aiohttp session is opened on the first request (inside the event loop) and closed by
`aclose`. A transport dropped without `aclose` lets its connections go quietly when it is
collected, as httpx's do, instead of aiohttp's "Unclosed client session" on the loop's handler.
"""

from __future__ import annotations

import asyncio
import ssl
import weakref
from collections.abc import AsyncIterator

import aiohttp
import httpx

__all__ = ["AiohttpTransport"]

POOL = 100  # connections at most, as httpx's default pool (a client's calls are bounded by its max_concurrency)
KEEPALIVE = 5.0  # s an idle connection is kept, as httpx's default keepalive_expiry
MAX_HEADER = 65536  # bytes of a status or header line (aiohttp's 8190 by default; h11 took more)


class AiohttpTransport(httpx.AsyncBaseTransport):
    """An httpx transport over an aiohttp session (see the module docstring)."""

    def __init__(self, ssl_context: ssl.SSLContext | None = None) -> None:
        self._ssl: ssl.SSLContext | bool = ssl_context if ssl_context is not None else True
        self._session: aiohttp.ClientSession | None = None
        self._closed = False

    def _open(self) -> aiohttp.ClientSession:
        if self._closed:
            raise RuntimeError("the transport is closed")
        if self._session is None:
            connector = _Connector(ssl=self._ssl, limit=POOL, keepalive_timeout=KEEPALIVE)
            self._session = aiohttp.ClientSession(
                connector=connector,
                auto_decompress=False,  # httpx decodes, as the headers it sent asked
                cookie_jar=aiohttp.DummyCookieJar(),  # httpx keeps the cookies
                skip_auto_headers=("User-Agent", "Accept", "Accept-Encoding", "Content-Type"),
                timeout=aiohttp.ClientTimeout(total=None),
                trust_env=False,  # with a proxy in the environment, httpx's own transports carry the calls
                max_line_size=MAX_HEADER,
                max_field_size=MAX_HEADER,
            )
            weakref.finalize(self, _let_go, self._session)
        return self._session

    async def handle_async_request(self, request: httpx.Request) -> httpx.Response:
        session = self._open()
        connect = request.extensions.get("timeout", {}).get("connect")
        body = await request.aread()
        try:
            resp = await session.request(
                request.method,
                str(request.url),
                data=body or None,
                headers=[(k.decode("latin-1"), v.decode("latin-1")) for k, v in request.headers.raw],
                timeout=aiohttp.ClientTimeout(total=None, sock_connect=connect),
                allow_redirects=False,  # httpx follows redirects itself, if asked
                compress=None,
            )
        except aiohttp.ClientConnectorError as exc:
            raise httpx.ConnectError(str(exc), request=request) from exc
        except (aiohttp.ServerTimeoutError, asyncio.TimeoutError) as exc:
            raise httpx.ConnectTimeout(str(exc) or "connect timed out", request=request) from exc
        except aiohttp.ServerDisconnectedError as exc:
            raise httpx.RemoteProtocolError("Server disconnected without sending a response.", request=request) from exc
        except aiohttp.ClientResponseError as exc:  # an unreadable status line or headers
            raise httpx.RemoteProtocolError(str(exc), request=request) from exc
        except (aiohttp.ClientError, OSError) as exc:
            raise httpx.TransportError(str(exc) or type(exc).__name__, request=request) from exc
        return httpx.Response(
            resp.status,
            headers=list(resp.raw_headers),
            stream=_Body(resp, request),
            extensions={"http_version": b"HTTP/1.1", "reason_phrase": (resp.reason or "").encode("latin-1")},
        )

    async def aclose(self) -> None:
        self._closed = True
        if self._session is not None:
            await self._session.close()


class _Body(httpx.AsyncByteStream):
    """A response's body as aiohttp receives it; closing it before its end closes the connection."""

    def __init__(self, resp: aiohttp.ClientResponse, request: httpx.Request) -> None:
        self._resp = resp
        self._request = request

    async def __aiter__(self) -> AsyncIterator[bytes]:
        try:
            async for chunk in self._resp.content.iter_any():
                yield chunk
        except aiohttp.ClientPayloadError as exc:
            raise httpx.RemoteProtocolError(str(exc), request=self._request) from exc
        except (aiohttp.ClientError, OSError) as exc:
            raise httpx.ReadError(str(exc) or type(exc).__name__, request=self._request) from exc

    async def aclose(self) -> None:
        if self._resp.content.at_eof():
            self._resp.release()  # the whole body: the connection serves the next request
        else:
            self._resp.close()  # left before its end: the connection goes, and the server sees it


class _Connector(aiohttp.TCPConnector):
    """aiohttp's connector, but one collected unclosed says nothing on the loop's exception handler
    (aiohttp's "Unclosed connector"): its sockets close as they are collected, as httpx's do."""

    def __del__(self, _warnings: object = None) -> None:
        return


def _let_go(session: aiohttp.ClientSession) -> None:
    """A collected transport's session, never closed: detached from its connector (see
    _Connector), so that aiohttp reports no unclosed session either."""
    session.detach()
