"""The team comparison of a summary (issue 33): when the rows hold more than one team, summary.md
(and the page that shows it) gains a table of each team beside the others, per task and setting,
with the paper's Succ, TS and AS, DynaHMRC's communication steps beside the other action steps,
the redundant actions and each robot's share of the moves (mhrc.analysis.teamwork); summary.html
plots them against team size when the teams differ in size (mhrc.eval.html). Read from the one
`mhrc.eval.summary.Summary`: no statistic is computed again."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mhrc.eval.rows import SETTING, order_key, setting_label
from mhrc.eval.summary import Summary

__all__ = ["TEAM", "TeamCell", "team_cells", "team_comparison", "team_count", "without_team"]

TEAM = SETTING.index("team")

TEAM_NOTE = (
    "Each team beside the others, per task and setting (the setting without its team). AS is the steps with a "
    "non-wait action of any robot, as in the tables above; communication steps are the communicate actions and "
    "other steps every other non-wait action (together AS sum), DynaHMRC's two cost figures; redundant counts a "
    "navigate to furniture a teammate had reached before, after which the robot neither picked nor placed, and a "
    "pick of an object a teammate held; share is each robot's part of the successful picks and places "
    "(mhrc.analysis.teamwork). Means per episode; '-' where rows were written before these metrics."
)


def without_team(setting: tuple[Any, ...]) -> tuple[Any, ...]:
    """A setting with its team left out: what the teams compared in one table share."""
    return setting[:TEAM] + (None,) + setting[TEAM + 1 :]


@dataclass(frozen=True)
class TeamCell:
    """One team's cell of the comparison: its setting and task, who it is, and its statistics."""

    setting: tuple[Any, ...]
    task: str
    name: str  # the team's name (the paper's is `paper`)
    kinds: dict[str, str | None]  # robot -> kind, in execution order (None: a row that does not say)
    stats: dict[str, Any]  # mhrc.eval.rows.cell_stats

    @property
    def size(self) -> int:
        return len(self.kinds)

    @property
    def robots(self) -> str:
        return ", ".join(f"{r} ({k})" for r, k in self.kinds.items())


def team_count(summary: Summary) -> int:
    """How many teams the summary's valid rows ran (the paper's, however an ablation cut it, is one)."""
    return len({setting[TEAM] for setting, _ in summary.cells})


def team_cells(summary: Summary) -> list[TeamCell]:
    """Every (setting, task) cell as a TeamCell, ordered by the setting without its team, the task,
    then the team's size and name."""
    out = []
    for (setting, task), rows in summary.cells.items():
        first = rows[0].metrics
        kinds: dict[str, str | None] = dict(first.team_kinds or dict.fromkeys(first.robots))
        out.append(TeamCell(setting, task, first.team, kinds, summary.stats[(setting, task)]))
    return sorted(out, key=lambda c: (order_key(without_team(c.setting)), c.task, c.size, c.name))


def _num(value: Any, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _share(share: dict[str, float] | None) -> str:
    if share is None:
        return "-"
    return ", ".join(f"{r} {v:.2f}" for r, v in share.items()) or "nothing moved"


def team_comparison(summary: Summary) -> list[str]:
    """The "Team comparison" section of summary.md, or nothing when the rows hold one team."""
    if team_count(summary) < 2:
        return []
    head = (
        "| setting | task | team | robots | episodes | Succ | TS | AS | communication steps | other steps | "
        "redundant (navigate / pick) | share of moves |"
    )
    lines = ["## Team comparison", "", TEAM_NOTE, "", head, "| --- |" + " --- |" * (head.count("|") - 2)]
    for c in team_cells(summary):
        s = c.stats
        redundant = (
            "-"
            if s.get("redundant") is None
            else f"{s['redundant']:.2f} ({s['redundant_navigations']:.2f} / {s['redundant_picks']:.2f})"
        )
        lines.append(
            f"| {setting_label(without_team(c.setting))} | {c.task} | {c.name} | {c.robots} | {s['episodes']} | "
            f"{s['succ']:.2f} | {s['ts']:.1f} | {_num(s.get('as_ticks'), 1)} | {_num(s.get('comm_steps'), 1)} | "
            f"{_num(s.get('other_steps'), 1)} | {redundant} | {_share(s.get('share'))} |"
        )
    return lines + [""]
