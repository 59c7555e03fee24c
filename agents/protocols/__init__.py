"""Coordination protocols: how a team decides, by name (docs/protocols.md).

`PROTOCOLS` is the registry, in listing order; `protocol(name)` looks one up (ProtocolRefused
with `Refusal.UNKNOWN_PROTOCOL` for a name nobody registered), `register` adds one. The paper's
protocol, `mhrc`, is the default: every robot its own agent, messages as actions.

The centralized and leader protocols' modules (their planners, their LLM forms, the LLM policy's
vocabulary) are imported when one of them builds its policies, not with the registry: the paper's
protocol, which builds none, imports neither.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from types import ModuleType
from typing import TYPE_CHECKING

from mhrc.core.protocol.events import DEFAULT_PROTOCOL

from ..policy import Policy
from .base import CoordinationProtocol, ProtocolRefused, Refusal, Seating

__all__ = [
    "DEFAULT_PROTOCOL",
    "PROTOCOLS",
    "CoordinationProtocol",
    "ProtocolRefused",
    "Refusal",
    "Seating",
    "leader_talk",
    "protocol",
    "register",
]

if TYPE_CHECKING:
    from . import leader_talk

PROTOCOLS: dict[str, CoordinationProtocol] = {}


def __getattr__(name: str) -> ModuleType:
    """`leader_talk`, the leader protocol's sentences, imported on first use (its patterns are
    compiled on import, a tenth of the registry's import for a protocol that speaks none)."""
    if name == "leader_talk":
        return importlib.import_module(f"{__name__}.leader_talk")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def register(p: CoordinationProtocol) -> CoordinationProtocol:
    """Add `p` to the registry (a name registered twice is a mistake: ValueError)."""
    if p.name in PROTOCOLS:
        raise ValueError(f"protocol {p.name!r} is registered already")
    PROTOCOLS[p.name] = p
    return p


def protocol(name: str) -> CoordinationProtocol:
    """The protocol called `name`; ProtocolRefused (UNKNOWN_PROTOCOL) naming the known ones."""
    try:
        return PROTOCOLS[name]
    except KeyError:
        raise ProtocolRefused(
            Refusal.UNKNOWN_PROTOCOL, f"unknown protocol {name!r}: the protocols are {', '.join(PROTOCOLS)}"
        ) from None


def build_centralized(seating: Seating) -> Mapping[str, Policy]:
    """The centralized protocol's policies (centralized_llm.build_centralized), its modules imported now."""
    from .centralized_llm import build_centralized as build

    return build(seating)


def build_leader(seating: Seating) -> Mapping[str, Policy]:
    """The leader protocol's policies (leader_llm.build_leader), its modules imported now."""
    from .leader_llm import build_leader as build

    return build(seating)


register(
    CoordinationProtocol(
        DEFAULT_PROTOCOL,
        "the paper's: one agent per robot, each deciding alone; messages are actions (they cost a step)",
        forms=("heuristic", "llm"),
    )
)
register(
    CoordinationProtocol(
        "centralized",
        "one planner decides every robot's next action from all their observations; allocation by assignment",
        build=build_centralized,
        forms=("heuristic", "llm"),
        whole_team=True,
    )
)
register(
    CoordinationProtocol(
        "leader",
        "DynaHMRC's loop: self-descriptions and bids by message, an elected leader allocates by auction, robots report",
        build=build_leader,
        forms=("heuristic", "llm"),
        spoken=True,
    )
)
