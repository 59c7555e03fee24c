"""`--team`: a shipped team's name, a TOML or JSON file, or robots inline (mhrc.core.team), read
into a TeamSpec; `mhrc teams` lists the shipped ones (mhrc.world.teams.SHIPPED)."""

from __future__ import annotations

import json
from pathlib import Path

from mhrc.core.team import PAPER_TEAM, TeamError, TeamProblem, TeamSpec, checked, load_team_file, parse_inline

__all__ = ["resolve_team", "shipped_teams", "team_argument", "team_from_json"]


def shipped_teams() -> dict[str, TeamSpec]:
    """The shipped teams by name (reading them loads the world's robot kinds)."""
    from mhrc.world.teams import SHIPPED

    return SHIPPED


def resolve_team(text: str | None) -> TeamSpec:
    """The team `--team TEXT` names: a shipped team, a .toml or .json file, or name=kind,...;
    None: the paper's. TeamError (UNKNOWN_TEAM) naming the shipped teams for anything else."""
    if text is None or text == PAPER_TEAM.name:
        return PAPER_TEAM
    text = text.strip()
    if text.startswith("{"):  # a team as JSON (how mhrc up --processes hands the team to its children)
        return team_from_json(text)
    shipped = shipped_teams()
    if text in shipped:
        return shipped[text]
    path = Path(text)
    if path.suffix.lower() in (".toml", ".json") or _is_file(path):
        if not _is_file(path):
            raise TeamError(TeamProblem.BAD_FILE, f"--team {text}: no such file")
        return load_team_file(path)
    if "=" in text:
        return parse_inline(text)
    raise TeamError(
        TeamProblem.UNKNOWN_TEAM,
        f"--team {text!r}: not a shipped team ({', '.join(shipped)}; mhrc teams), "
        "a .toml or .json file, or robots inline (alice=mobile_manipulator,bob=tabletop_arm)",
    )


def _is_file(path: Path) -> bool:
    """Whether `path` is a file; False for text no file can have as its name (a name over the
    system's limit, as a long inline team is: Path.is_file raises OSError for it, or a NUL byte)."""
    try:
        return path.is_file()
    except (OSError, ValueError):
        return False


def team_argument(team: TeamSpec) -> str:
    """`team` as one `--team` argument for a child process: its shipped name when it is that
    team, else its JSON."""
    if team == PAPER_TEAM or shipped_teams().get(team.name) == team:
        return team.name
    return team.model_dump_json(exclude_none=True)


def team_from_json(text: str) -> TeamSpec:
    try:
        data = json.loads(text)
    except (ValueError, RecursionError) as exc:  # Python's parser raises RecursionError on a deep document
        raise TeamError(TeamProblem.BAD_FILE, f"--team: not JSON: {type(exc).__name__}: {str(exc)[:200]}") from None
    if not isinstance(data, dict):
        raise TeamError(TeamProblem.BAD_FILE, "--team: the JSON is not an object with robots")
    return checked(data, "--team")
