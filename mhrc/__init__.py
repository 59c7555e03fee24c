"""mhrc: multi-heterogeneous robot collaboration with LLM agents over Zenoh.

Importing mhrc imports nothing else. Every module of mhrc that logs gets its logger from
`mhrc.core.logs`, which leaves a structlog configuration alone; only when there is none does it
route structlog to stderr at MHRC_LOG_LEVEL's level, else warning (structlog's own default prints
every level, debug included, on stdout: a library prints nothing unless asked), and it imports
structlog only when a line is first due. The `mhrc`
command (and each process it starts) uses MHRC_LOG_LEVEL or --log-level; a library user calls
`mhrc.core.logs.configure` for more, or configures structlog as they like.
"""
