"""Where a participant listens or connects: Zenoh endpoints (`tcp/HOST:PORT`, `tls/...`), free
ports, and the bus's errors (`BusError`, `BusRefused`, `ListenError`), said in one sentence each."""

from __future__ import annotations

import socket
from collections.abc import Sequence


class BusError(RuntimeError):
    """The bus could not be opened or used."""


class BusRefused(BusError):
    """The world is there but refused this session (certificate, credentials); `final`: retrying cannot help."""

    def __init__(self, message: str, final: bool = True) -> None:
        super().__init__(message)
        self.final = final


class ListenError(BusError):
    """This process cannot listen where it was told to (port taken, no permission)."""


def listen_error(listen: Sequence[str], detail: str) -> BusError:
    """Zenoh's error for a listener that could not be created, said in one sentence with what to do."""
    where = ", ".join(listen)
    port = where.rsplit(":", 1)[-1]
    if "Address already in use" in detail:
        return ListenError(
            f"cannot listen on {where}: port {port} is already in use (another mhrc world, or another program): "
            "choose another --port, or leave --port out for a free one"
        )
    if "Permission denied" in detail:
        return ListenError(
            f"cannot listen on {where}: port {port} needs privileges this process lacks: choose a port above 1023"
        )
    if "Cannot assign requested address" in detail or "Can not assign" in detail:
        return ListenError(
            f"cannot listen on {where}: no network interface of this host has that address: check --host"
        )
    return ListenError(f"cannot listen on {where}: {detail.split(' at /')[0]}")


def check_listen(host: str, port: int, proto: str = "tcp") -> None:
    """Raise ListenError if this process could not listen on host:port now (taken, no permission);
    `proto` (tcp, tls) only names the endpoint in the message."""
    import errno

    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM) as s:
        # as the world's listener binds (Zenoh sets it): connections of a run just ended, in TIME_WAIT,
        # do not make the port look taken; a socket listening there still does
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as exc:
            detail = (
                "Address already in use"
                if exc.errno == errno.EADDRINUSE
                else "Permission denied"
                if exc.errno == errno.EACCES
                else str(exc)
            )
            raise listen_error([f"{proto}/{host}:{port}"], detail) from None


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that is free on `host` right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def split_endpoint(ep: str) -> tuple[str, str, int | None]:
    """(protocol, host, port) of a Zenoh endpoint such as `tcp/127.0.0.1:7447`; a bare
    `HOST:PORT` means tcp. Port None where the endpoint has none we can read."""
    proto, sep, rest = ep.partition("/")
    if not sep:
        proto, rest = "tcp", ep
    rest = rest.split("#", 1)[0].split("?", 1)[0]
    host, colon, port = rest.rpartition(":")
    if not colon or not port.isdigit():
        return proto, rest, None
    return proto, host.strip("[]"), int(port)


def endpoint(host: str, port: int, tls: bool = False) -> str:
    return f"{'tls' if tls else 'tcp'}/{host}:{port}"
