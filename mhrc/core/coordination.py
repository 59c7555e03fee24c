"""The coordination protocol a run uses unless told otherwise, as a name: the wire's episode
events carry it, the configuration defaults to it, and neither the wire's models nor the
protocols' registry (mhrc.agents.protocols) need importing to read it."""

from __future__ import annotations

DEFAULT_PROTOCOL = "mhrc"  # the paper's coordination: one agent per robot, messages as actions (mhrc.agents.protocols)
