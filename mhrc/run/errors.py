"""A run's configuration errors, apart from mhrc.run.config (which imports the bus and the model
clients), so that a command can catch them before anything heavy is loaded; and a process of
`mhrc up --processes` that failed, apart from mhrc.run.processes, which a run in one process
never imports."""

from __future__ import annotations


class ConfigError(ValueError):
    """A configuration value that cannot work; the message names the field."""


class ModelServerDown(ConfigError):
    """Nothing listens where a robot's model server should be (connection refused): no step could
    ever be planned, so the run does not start."""


class ProcessFailed(RuntimeError):
    """A process of `mhrc up --processes` failed the run: the world's ended before the episode
    did, or an agent's before the episode started (the world would wait for its robot forever).
    With a positive exit code the process has said why on stderr itself; a negative one is the
    signal that killed it."""

    def __init__(self, who: str, returncode: int, before: str | None) -> None:
        self.who = who
        self.returncode = returncode
        how = f"was killed by signal {-returncode}" if returncode < 0 else f"exited with code {returncode}"
        super().__init__(
            f"{who} {how} " + ("after the episode ended" if before is None else f"before the episode {before}")
        )
