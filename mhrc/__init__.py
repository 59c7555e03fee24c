"""mhrc: multi-heterogeneous robot collaboration with LLM agents over Zenoh.

Importing mhrc routes its structlog output to stderr at the level in MHRC_LOG_LEVEL
(default: warning); the CLI's --log-level and `mhrc.logs.configure` change it.
"""

import os as _os

from . import logs as _logs

_logs.configure(_os.environ.get("MHRC_LOG_LEVEL", "warning"))
