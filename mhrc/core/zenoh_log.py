"""Zenoh's own log, read back by the world: refused logins said on the world's side too.

A login refused by the world's router (a wrong password, an unknown user, a client without
credentials) or a TLS handshake the client gave up (it does not trust the world's certificate)
happens inside zenoh's transport, where no Python code of ours runs: zenoh says so only in its
Rust log, which writes straight to file descriptor 1 (tracing's default, stdout). The agent's side learns the cause from
`mhrc.core.refusal.why_refused`; this module gives the world's side the same, as one warning per cause
(throttled, so a flood of bad logins costs a count per interval, not a line per attempt):

    refused a login  cause='a wrong password: the client's credentials are altered, or of another run'

`watch_refusals` turns zenoh's log on for just the lines that matter and points descriptor 1 at a
pipe read by a thread: a known line becomes the world's warning (on stderr), the per-connection
noise is dropped and anything else (a user's RUST_LOG, a C library's printf) is passed through
unchanged to the real stdout. Python's own `sys.stdout` is re-pointed at the real stdout first,
so the process's own output never goes through the pipe.
"""

from __future__ import annotations

import io
import os
import re
import sys
import threading
from collections.abc import Callable

from mhrc.core.logs import Throttle, get_logger

log = get_logger("mhrc.world")

# zenoh's log for the world: the accept side of the transport (logins) and TLS link warnings
# (alerts the client sent), nothing else; RUST_LOG, when set, replaces it (zenoh reads it first)
FILTER = "off,zenoh_transport::unicast::establishment::accept=debug,zenoh_link_tls::unicast=warn"

_ALERTS = {
    "UnknownCA": "the client does not trust the world's certificate: its credentials are of another run (another CA)",
    "CertificateExpired": "the client found the world's certificate expired: issue new credentials (mhrc credentials)",
    "BadCertificate": "the client rejected the world's certificate: it does not name the host the client connected to",
}
_CAUSES: tuple[tuple[re.Pattern[str], str], ...] = (
    (
        re.compile(r"UsrPwd extension - Recv OpenSyn\. Invalid password"),
        "a wrong password: the client's credentials are altered, or of another run",
    ),
    (re.compile(r"UsrPwd extension - Recv OpenSyn\. Invalid user"), "an unknown user: not a participant of this run"),
    (
        re.compile(r"UsrPwd extension - Recv InitSyn\. Expected extension"),
        "no login: a client without credentials (or with --insecure) on the secured bus",
    ),
    # a plain tcp client's first bytes (zenoh's length prefix, then its InitSyn) read as a TLS
    # record header: its first byte is most often no record type (InvalidContentType), but a
    # length whose low byte is 20-24 passes as one and fails on the version (UnknownProtocolVersion)
    (
        re.compile(r"received corrupt message of type (InvalidContentType|UnknownProtocolVersion)"),
        "a client spoke plain tcp to the secured world: it must connect to tls/ with its credentials",
    ),
)
_ALERT = re.compile(r"received fatal alert: (\w+)")
_NOISE = (
    "Cannot monitor expiration",
    "New transport link accepted",
    "Accepted TLS connection",
    "tls handshake eof",  # a client that closed before the handshake: a port probe (mhrc up's wait for the world, why_refused)
)
# one line of zenoh's own log: time, level, thread, target, message
_LINE = re.compile(r"^\S+\s+(TRACE|DEBUG|INFO|WARN|ERROR)\s+.*?\b(zenoh[\w:]*):\s?(.*)$")
_HINT = re.compile(r"\s*Hint: increase the system open file limit\.?")
_ANSI = re.compile(r"\x1b\[[0-9;]*m")

_installed = False


def classify(line: str) -> str | None:
    """The cause a line of zenoh's log reports (a refused login or a rejected certificate), or
    None for any other line."""
    text = _ANSI.sub("", line)
    for pattern, cause in _CAUSES:
        if pattern.search(text):
            return cause
    alert = _ALERT.search(text)
    if alert is not None:
        name = alert.group(1)
        return _ALERTS.get(name, f"the client ended the TLS handshake ({name}): it rejected the world's certificate")
    return None


def is_noise(line: str) -> bool:
    """A per-connection line of zenoh's log that says nothing wrong."""
    return any(n in line for n in _NOISE)


def translate(line: str) -> tuple[str, str] | None:
    """(level, message) of a line of zenoh's own log that is neither a known cause nor noise,
    in our words: no colours, no timestamp, no misleading "increase the open file limit" hint
    (zenoh adds it to every TLS accept error). Debug lines (the login watch's own level) are
    dropped: ("", ""). None: not a zenoh log line (a user's RUST_LOG, a C library's printf)."""
    m = _LINE.match(_ANSI.sub("", line).strip())
    if m is None:
        return None
    level, target, message = m.groups()
    if level in ("TRACE", "DEBUG", "INFO"):
        return "", ""
    return level.lower(), f"{_HINT.sub('', message).strip()} ({target})"


def watch_refusals(on_refusal: Callable[[str], None] | None = None) -> bool:
    """Report every login the world's router refuses (`on_refusal(cause)`; default: a throttled
    warning). Call once, before the world's session opens; later calls do nothing. Returns
    whether the watch is on (False where descriptor 1 cannot be redirected)."""
    global _installed
    if _installed:
        return True
    import zenoh

    report = on_refusal or _warner()
    try:
        sys.stdout.flush()
        real = os.dup(1)
        r, w = os.pipe()
    except (OSError, AttributeError, ValueError):
        return False
    # Python writes to the real stdout from now on; only native writes to fd 1 reach the pipe
    sys.stdout = io.TextIOWrapper(
        io.FileIO(real, "w", closefd=False), encoding="utf-8", errors="backslashreplace", line_buffering=True
    )
    os.dup2(w, 1)
    os.close(w)
    threading.Thread(target=_pump, args=(r, real, report), name="mhrc-zenoh-log", daemon=True).start()
    zenoh.init_log_from_env_or(FILTER)
    _installed = True
    return True


def _warner() -> Callable[[str], None]:
    throttle = Throttle()

    def warn(cause: str) -> None:
        due, held = throttle.due(cause)
        if due:
            log.warning("refused a login", cause=cause, **({"also_refused": held} if held else {}))

    return warn


def _pump(fd: int, real: int, report: Callable[[str], None]) -> None:
    raw_log = bool(os.environ.get("RUST_LOG"))  # the user asked for zenoh's own log: theirs, unchanged
    throttle = Throttle()
    with os.fdopen(fd, "rb") as pipe:
        for raw in pipe:
            line = raw.decode("utf-8", errors="replace")
            try:
                cause = classify(line)
                if cause is not None:
                    report(cause)
                    continue
                if is_noise(line):
                    continue
                said = None if raw_log else translate(line)
                if said is None:
                    os.write(real, raw)
                elif said[0]:
                    due, held = throttle.due(said[1])
                    if due:
                        log.warning("zenoh says", message=said[1], **({"also": held} if held else {}))
            except Exception:  # noqa: BLE001 - the pump must outlive any one bad line
                continue
