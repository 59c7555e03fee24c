"""Why a client session to a world could not open (`why_refused`), told from the outside: a plain
TCP connect and TLS handshakes with the run's CA (`speaks_tls`, none verified when only asking
whether the server speaks TLS), each cause one `Diagnosis` a person can act on. The bus
(mhrc.core.bus), the agent and `mhrc doctor` / `mhrc bus` call it when a session will not open;
the world's side of the same is mhrc.core.zenoh_log.
"""

from __future__ import annotations

import socket
import ssl
from dataclasses import dataclass
from typing import TYPE_CHECKING

from mhrc.core.endpoints import split_endpoint

if TYPE_CHECKING:
    from mhrc.core.security import Credentials


@dataclass(frozen=True)
class Diagnosis:
    """Why a client session could not open (`cause`, one phrase for a person) and whether
    trying again can help (`final` False: nothing listens yet, or a login a world still
    starting may refuse for a moment)."""

    cause: str
    final: bool = False
    login_refused: bool = False  # the TLS link is sound and the world refused this login

    def __str__(self) -> str:
        return self.cause


def speaks_tls(host: str, port: int, timeout: float = 3.0) -> bool:
    """Whether the server at host:port completes a TLS handshake (a secured world), checked
    without trusting or verifying anything: only to tell a plain-tcp client what is wrong."""
    ctx = ssl.create_default_context()
    ctx.check_hostname = False
    ctx.verify_mode = ssl.CERT_NONE
    try:
        with (
            socket.create_connection((host, port), timeout=timeout) as raw,
            ctx.wrap_socket(raw, server_hostname=host) as tls,
        ):
            tls.do_handshake()
            return True
    except (OSError, ssl.SSLError):
        return False


def why_refused(endpoint: str, creds: Credentials | None, timeout: float = 3.0) -> Diagnosis:
    """Why a client session to `endpoint` could not open, as far as a plain TLS handshake with
    the run's CA can tell: nothing listening, a secured world reached on plain tcp (or the
    reverse), an expired or foreign certificate, or (the handshake succeeding) credentials the
    world refused."""
    proto, host, port = split_endpoint(endpoint)
    if port is None:
        return Diagnosis(f"bad endpoint {endpoint!r}", final=True)
    try:
        raw = socket.create_connection((host, port), timeout=timeout)
    except OSError as exc:
        return Diagnosis(f"nothing accepts connections on {host}:{port} ({exc.strerror or exc})")
    raw.close()
    if proto != "tls":
        if speaks_tls(host, port, timeout):
            login = "with this participant's --credentials FILE" if creds is None else "with the same --credentials"
            return Diagnosis(
                f"the world at {host}:{port} is secured (it speaks TLS): connect to tls/{host}:{port} {login}",
                final=True,
            )
        if creds is None:
            return Diagnosis(
                "the world refused an open connection: it probably requires credentials (--credentials or $MHRC_CREDENTIALS)"
            )
        return Diagnosis(f"credentials were given but the endpoint {endpoint} is not tls/", final=True)
    if creds is None:
        return Diagnosis(
            "the endpoint is tls/ (a secured world) but no credentials were given: pass --credentials FILE "
            "(or set $MHRC_CREDENTIALS)",
            final=True,
        )
    ctx = ssl.create_default_context(cafile=str(creds.ca))
    try:
        with (
            socket.create_connection((host, port), timeout=timeout) as raw2,
            ctx.wrap_socket(raw2, server_hostname=host) as tls,
        ):
            tls.do_handshake()
    except ssl.SSLCertVerificationError as exc:
        why = exc.verify_message or str(exc)
        if "expired" in why:
            return Diagnosis(
                f"the world's certificate has expired ({why}): issue new credentials (mhrc credentials, or a new mhrc up)",
                final=True,
            )
        if "issuer" in why or "self-signed" in why or "self signed" in why:
            return Diagnosis(
                f"the world's certificate is not signed by the CA of {creds.describe()} ({why}): "
                "a foreign certificate, or a world of another run",
                final=True,
            )
        return Diagnosis(f"the world's certificate was rejected: {why}", final=True)
    except ssl.SSLError as exc:
        return Diagnosis(
            f"the TLS handshake failed: {exc.reason or exc} (is the world listening on plain tcp? then drop tls/ and --credentials)",
            final=True,
        )
    except OSError as exc:
        return Diagnosis(f"the TLS handshake failed: {exc}")
    return Diagnosis(
        f"the TLS link is sound but the world refused the login of {creds.describe()}: "
        "a wrong password, or credentials of another run",
        login_refused=True,
    )
