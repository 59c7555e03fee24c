"""The options an environment is made with: a subset of `mhrc up`'s episode options, checked by
the same `EpisodeConfig` before anything is built; a bad one is a ValueError naming it."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

from mhrc.core.protocol.events import DEFAULT_PROTOCOL
from mhrc.core.team import TeamSpec
from mhrc.run.config import EpisodeConfig, ProtocolConfigError
from mhrc.run.teams import resolve_team

# env option -> EpisodeConfig field (the CLI's --objects is n_objects there)
OPTIONS = {
    "task": "task",
    "scene": "scene",
    "objects": "n_objects",
    "seed": "seed",
    "horizon": "horizon",
    "team": "team",
    "aids": "aids",
    "noise": "noise",
    "events": "events",
    "ablation": "ablation",
    "history_cap": "history_cap",
    "prompts": "prompts",
    "structured": "structured",
    "protocol": "protocol",
}
RENDER_MODES = ("rgb_array",)


class EnvOptionError(ValueError):
    """An option the environment cannot be made with; the message names it."""


class EnvProtocolError(EnvOptionError):
    """`protocol=` names a coordination protocol the environment cannot seat: `code` says why
    (mhrc.agents.protocols.Refusal's codes, or `CALLER_DECIDES`)."""

    def __init__(self, message: str, code: str) -> None:
        super().__init__(message)
        self.code = code


# in the environment the caller gives every robot's command: it is the team's coordination, so a protocol whose
# policies would decide for the robots (a planner, an elected leader) has no robot left to seat
CALLER_DECIDES = "caller_decides"


def episode_config(options: Mapping[str, object]) -> EpisodeConfig:
    """The episode the options describe (EnvOptionError naming a bad or unknown one): the caller's
    values, unchecked until EpisodeConfig checks them."""
    unknown = sorted(set(options) - set(OPTIONS))
    if unknown:
        raise EnvOptionError(
            f"unknown option(s) {', '.join(map(repr, unknown))}: the environment takes {', '.join(OPTIONS)}"
        )
    values = {OPTIONS[k]: v for k, v in options.items()}
    team = values.get("team")
    if team is not None and not isinstance(team, TeamSpec):
        values["team"] = resolve_team(str(team))  # a shipped team's name, a file, or robots inline
    for path in ("events", "prompts"):
        value = values.get(path)
        if isinstance(value, str | os.PathLike):  # anything else is EpisodeConfig's to refuse, naming it
            values[path] = Path(value)
    try:
        cfg = EpisodeConfig.build(run="env", **values)
    except ProtocolConfigError as exc:
        raise EnvProtocolError(str(exc).replace("--protocol", "protocol", 1), exc.code) from None
    except ValueError as exc:
        raise EnvOptionError(str(exc)) from None
    if cfg.coordination().build is not None:
        raise EnvProtocolError(
            f"protocol {cfg.protocol!r}: in the environment the caller decides every robot's command, so no robot is "
            f"left for its policies; the environment runs the paper's protocol ({DEFAULT_PROTOCOL}) only (docs/protocols.md)",
            CALLER_DECIDES,
        )
    return cfg


def check_render_mode(mode: str | None) -> str | None:
    if mode is not None and mode not in RENDER_MODES:
        raise EnvOptionError(f"render_mode {mode!r}: the environment renders {', '.join(RENDER_MODES)} or nothing")
    return mode
