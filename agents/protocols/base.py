"""What a coordination protocol is: a name, one line saying how the team decides, the teams it
can run (a typed refusal when it cannot), and how it builds the policies of the robots one
participant drives.

A protocol decides nothing about the world, the robots, the tasks or the metrics: it only chooses
which `Policy` each robot's agent (`agents/agent.py`) drives, and whether those policies share
anything (the seats of one planner). Every policy still sees only its robots' observations,
results and messages, never the world's state.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

from mhrc.core.team import TeamSpec

from ..crew import KIND_PROMPTS
from ..policy import Policy

__all__ = ["CoordinationProtocol", "ProtocolRefused", "Refusal", "Seating"]


class Refusal(StrEnum):
    """Why a protocol cannot run an episode (ProtocolRefused.code)."""

    UNKNOWN_PROTOCOL = "unknown_protocol"  # no protocol of that name is registered
    NO_LLM_FORM = "no_llm_form"  # the protocol has no LLM form (yet): it runs with its heuristic form only
    UNFIT_TEAM = "unfit_team"  # the team has a robot the protocol cannot seat (a kind without a part)
    NOT_ALL_ROBOTS = "not_all_robots"  # the protocol must drive every robot of the team from one participant


class ProtocolRefused(ValueError):
    """A protocol that cannot run this episode: `code` for programs, the message for people."""

    def __init__(self, code: Refusal, message: str) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class Seating:
    """What a protocol builds policies for: the team, the robots this participant drives (in the
    team's order) and the world's schedule (a planner that waits for every robot's observation of a
    tick may do so only in lockstep: docs/architecture.md, "Time")."""

    team: TeamSpec
    robots: tuple[str, ...]
    schedule: str = "lockstep"
    model: str | None = None  # the LLM form's model spec (None: the heuristic form)
    base_url: str | None = None
    client_options: Mapping[str, Any] = field(default_factory=dict)
    structured: bool = False  # the LLM form asks for JSON decisions (--structured), where it can


Build = Callable[[Seating], Mapping[str, Policy]]


@dataclass(frozen=True)
class CoordinationProtocol:
    """One way for a team to decide. `build` None: each robot's own agent with its own policy,
    built as it always was (the paper's protocol); otherwise the policies of `Seating.robots`.
    `whole_team`: one participant must drive every robot of the team (a central planner).
    `spoken`: every robot takes its part in fixed sentences of the protocol's own (the leader
    protocol's bids, elections and reports): a person at `mhrc play`'s page, who writes free text,
    cannot take a robot's place."""

    name: str
    summary: str
    build: Build | None = None
    forms: tuple[str, ...] = ("heuristic",)
    whole_team: bool = False
    spoken: bool = False

    def line(self) -> str:
        """One line for a listing (`mhrc protocols`)."""
        return f"{self.name:<12} {self.summary} [{', '.join(self.forms)}]"

    def refusal(
        self,
        team: TeamSpec,
        *,
        llm: bool = False,
        robots: tuple[str, ...] | None = None,
        episode: tuple[str, ...] | None = None,
    ) -> ProtocolRefused | None:
        """Why this protocol cannot run `team` (with an LLM when `llm`, driving `robots` from one
        participant when given), or None when it can. `episode`: the team's robots in the episode,
        when an ablation leaves some out (no_mobile), default the whole team."""
        if llm and "llm" not in self.forms:
            return ProtocolRefused(
                Refusal.NO_LLM_FORM,
                f"protocol {self.name!r} has no LLM form yet: run it without --llm (its heuristic form)",
            )
        unknown = sorted({k for k in team.kinds.values() if k not in KIND_PROMPTS})
        if self.build is not None and unknown:
            return ProtocolRefused(
                Refusal.UNFIT_TEAM,
                f"protocol {self.name!r} cannot seat robots of kind(s) {', '.join(unknown)} (team {team.name})",
            )
        if self.whole_team and robots is not None:
            missing = [r for r in (episode if episode is not None else team.names) if r not in robots]
            if missing:
                return ProtocolRefused(
                    Refusal.NOT_ALL_ROBOTS,
                    f"protocol {self.name!r} drives the whole team from one participant: it was not given "
                    f"{', '.join(missing)} (give it every robot's credentials)",
                )
        return None
