"""mhrc: multi-heterogeneous robot collaboration with LLM agents over Zenoh.

Importing mhrc configures nothing: the `mhrc` command (and each process it starts) routes
structlog to stderr at MHRC_LOG_LEVEL or --log-level; a library user calls
`mhrc.core.logs.configure` to do the same.
"""
