"""mhrc: multi-heterogeneous robot collaboration with LLM agents over Zenoh.

Importing mhrc leaves a structlog configuration alone; only when there is none does it route
structlog to stderr at warning level (structlog's own default prints every level, debug
included, on stdout: a library prints nothing unless asked). The `mhrc` command (and each process
it starts) uses MHRC_LOG_LEVEL or --log-level; a library user calls `mhrc.core.logs.configure`
for more, or configures structlog as they like.
"""

import structlog as _structlog

if not _structlog.is_configured():
    from mhrc.core import logs as _logs

    _logs.configure("warning")
