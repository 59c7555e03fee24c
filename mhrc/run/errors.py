"""A run's configuration errors, apart from mhrc.run.config (which imports the bus and the model
clients), so that a command can catch them before anything heavy is loaded."""

from __future__ import annotations


class ConfigError(ValueError):
    """A configuration value that cannot work; the message names the field."""


class ModelServerDown(ConfigError):
    """Nothing listens where a robot's model server should be (connection refused): no step could
    ever be planned, so the run does not start."""
