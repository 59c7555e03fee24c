"""structlog set-up: human-readable lines on stderr, context (run, robot, tick) bound by callers."""

from __future__ import annotations

import logging
import os
import sys
import time
from typing import Any

import structlog
from structlog.typing import EventDict, WrappedLogger

from mhrc.core.printable import printable

LEVELS = ("debug", "info", "warning", "error")
_level = "warning"  # the level configured last


def configure(level: str = "warning") -> None:
    """Route structlog to stderr at `level` (debug, info, warning, error)."""
    global _level
    if level not in LEVELS:
        raise ValueError(f"log level must be one of {', '.join(LEVELS)}, not {level!r}")
    _level = level
    structlog.configure(
        processors=[
            level_now,
            structlog.contextvars.merge_contextvars,
            structlog.processors.add_log_level,
            structlog.processors.TimeStamper(fmt="%H:%M:%S", utc=False),
            inert_values,  # before the traceback is formatted: its line breaks stay
            structlog.processors.format_exc_info,
            structlog.dev.ConsoleRenderer(colors=False),
        ],
        wrapper_class=structlog.make_filtering_bound_logger(getattr(logging, level.upper())),
        logger_factory=structlog.PrintLoggerFactory(file=sys.stderr),
        cache_logger_on_first_use=False,
    )


_SEVERITY = {"debug": 10, "info": 20, "warning": 30, "warn": 30, "error": 40, "exception": 40, "critical": 50}


def level_now(logger: WrappedLogger, name: str, event: EventDict) -> EventDict:
    """Drop an event below the level configured now. A logger bound before a later `configure`
    (a service's `log.bind(run=...)`) keeps the level and processors of its binding; `hush` must
    quiet it too, so the level is read here, at every call."""
    if _SEVERITY.get(name, 50) < _SEVERITY[_level]:
        raise structlog.DropEvent
    return event


def inert_values(logger: WrappedLogger, name: str, event: EventDict) -> EventDict:
    """Every text of a log line without control characters (mhrc.core.printable): a participant's
    agent id, goal or a reason quoting its payload cannot drive the operator's terminal."""
    return {k: printable(v) if isinstance(v, str) else v for k, v in event.items()}


def hush() -> None:
    """A run being stopped (Ctrl-C, SIGTERM): at the default level, no more warnings about the
    other participants leaving, which they do because of the same stop; errors still show, and a
    --log-level below warning is kept as asked."""
    global _level
    if _level == "warning":
        _level = "error"  # first: level_now reads it at every call, so nothing below error gets out from here on
        configure("error")


class Throttle:
    """At most one log line per `interval` seconds per key: `due(key)` says whether to log now
    and how many occurrences were held back since the last line (so a flood of junk costs a
    count per interval, not a line per message)."""

    def __init__(self, interval: float = 5.0) -> None:
        self.interval = interval
        self._last: dict[str, float] = {}
        self._held: dict[str, int] = {}

    def due(self, key: str) -> tuple[bool, int]:
        now = time.monotonic()
        last = self._last.get(key)
        if last is not None and now - last < self.interval:
            self._held[key] = self._held.get(key, 0) + 1
            return False, 0
        self._last[key] = now
        return True, self._held.pop(key, 0)


def get_logger(name: str) -> Any:
    """structlog's logger for an mhrc module. Importing this module gives structlog mhrc's set-up
    when nobody configured it (stderr, the level of MHRC_LOG_LEVEL, else warning): a library
    prints nothing unless asked, and the `mhrc` command's modules import only what they use."""
    return structlog.get_logger(name)


if not structlog.is_configured():
    configure(_env if (_env := os.environ.get("MHRC_LOG_LEVEL", "warning")) in LEVELS else "warning")
