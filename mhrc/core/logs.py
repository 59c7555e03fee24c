"""structlog set-up: human-readable lines on stderr, context (run, robot, tick) bound by callers.

structlog itself is imported when a line is first due: a logger from `get_logger` drops a line
below the configured level without it, so a run that logs nothing (a clean `mhrc up` at the default
level) never imports structlog, rich's tracebacks and pygments behind it (a tenth of a second of
every command's start). While structlog has a configuration that is not this module's (a library
user's), every line goes to it, whatever the level here.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from mhrc.core.printable import printable

if TYPE_CHECKING:
    from structlog.typing import EventDict, WrappedLogger

LEVELS = ("debug", "info", "warning", "error")
_level = "warning"  # the level configured last
# a set-up owed to structlog once imported: True asked by configure, False only if it has none, None owed nothing
_pending: bool | None = None
_installed: list[Any] | None = None  # the processors of mhrc's set-up, once installed


def configure(level: str = "warning") -> None:
    """Route structlog to stderr at `level` (debug, info, warning, error): now if structlog is
    imported, else when a line is first due."""
    global _level, _pending
    if level not in LEVELS:
        raise ValueError(f"log level must be one of {', '.join(LEVELS)}, not {level!r}")
    _level = level
    if "structlog" in sys.modules:
        _install(level)
    else:
        _pending = True


def _install(level: str) -> None:
    global _installed, _pending
    import logging

    import structlog

    _pending = None
    _installed = [
        level_now,
        structlog.contextvars.merge_contextvars,
        structlog.processors.add_log_level,
        structlog.processors.TimeStamper(fmt="%H:%M:%S", utc=False),
        inert_values,  # before the traceback is formatted: its line breaks stay
        structlog.processors.format_exc_info,
        structlog.dev.ConsoleRenderer(colors=False),
    ]
    structlog.configure(
        processors=_installed,
        wrapper_class=structlog.make_filtering_bound_logger(getattr(logging, level.upper())),
        logger_factory=structlog.PrintLoggerFactory(file=sys.stderr),
        cache_logger_on_first_use=False,
    )


def _ready() -> Any:
    """structlog, imported, with the set-up this module still owes it."""
    import structlog

    if _pending or (_pending is False and not structlog.is_configured()):
        _install(_level)
    return structlog


def _ours() -> bool:
    """Whether mhrc's set-up is the one in force, or will be (structlog not imported yet, or with no
    configuration when mhrc's import-time set-up is still owed)."""
    structlog = sys.modules.get("structlog")
    if structlog is None or _pending:
        return True
    if not structlog.is_configured():
        return _pending is False
    return structlog.get_config()["processors"] is _installed


_SEVERITY = {"debug": 10, "info": 20, "warning": 30, "warn": 30, "error": 40, "exception": 40, "critical": 50}


def level_now(logger: WrappedLogger, name: str, event: EventDict) -> EventDict:
    """Drop an event below the level configured now. A logger bound before a later `configure`
    (a service's `log.bind(run=...)`) keeps the level and processors of its binding; `hush` must
    quiet it too, so the level is read here, at every call."""
    if _SEVERITY.get(name, 50) < _SEVERITY[_level]:
        import structlog

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


def _at(method: str) -> Callable[..., Any]:
    """A Logger's method for one level (structlog's of that name, once a line is due)."""

    def log(self: Logger, event: Any = None, *args: Any, **kw: Any) -> Any:
        return self._emit(method, event, args, kw)

    log.__name__ = log.__qualname__ = method
    return log


class Logger:
    """An mhrc module's logger: structlog's, once a line is due (see the module's docstring).
    `bind` adds context (bound in structlog when the first line is due, with the set-up then)."""

    __slots__ = ("_name", "_context", "_real")

    def __init__(self, name: str, context: dict[str, Any] | None = None) -> None:
        self._name = name
        self._context = context or {}
        self._real: Any = None

    def bind(self, **context: Any) -> Logger:
        return Logger(self._name, {**self._context, **context})

    def _logger(self) -> Any:
        structlog = _ready()
        if self._real is None:
            base = structlog.get_logger(self._name)
            self._real = base.bind(**self._context) if self._context else base
        return self._real

    def _emit(self, method: str, event: Any, args: tuple[Any, ...], kw: dict[str, Any]) -> Any:
        if _SEVERITY[method] < _SEVERITY[_level] and _ours():
            return None
        return getattr(self._logger(), method)(event, *args, **kw)

    debug = _at("debug")
    info = _at("info")
    warning = warn = _at("warning")
    error = _at("error")
    exception = _at("exception")
    critical = _at("critical")

    def __getattr__(self, name: str) -> Any:  # the rest of structlog's logger (new, unbind, ...), as structlog has it
        if name.startswith("_"):  # a slot not set yet (a copy being made): not structlog's
            raise AttributeError(name)
        return getattr(self._logger(), name)


def get_logger(name: str) -> Any:
    """The logger of an mhrc module. When nobody configured structlog, mhrc's set-up is installed
    with the first line due (stderr, the level of MHRC_LOG_LEVEL, else warning): a library prints
    nothing unless asked, and the `mhrc` command's modules import only what they use."""
    return Logger(name)


_from_env = _env if (_env := os.environ.get("MHRC_LOG_LEVEL", "warning")) in LEVELS else "warning"
if "structlog" not in sys.modules:
    _level, _pending = _from_env, False  # mhrc's set-up, if nobody has configured structlog by the first line due
elif not sys.modules["structlog"].is_configured():
    configure(_from_env)
