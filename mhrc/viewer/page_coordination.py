"""The report's coordination: who led the team and what was allocated to whom, from the thoughts'
`coordination` (set by the protocols other than the paper's, docs/protocols.md). An episode of the
paper's protocol has none, and its page shows nothing of this: it renders as it always did.
"""

from __future__ import annotations

from dataclasses import dataclass

from mhrc.core.protocol import Coordination
from mhrc.viewer.model import EpisodeView
from mhrc.viewer.wording import html_text as _e


@dataclass(frozen=True)
class Change:
    """A robot's coordination from `tick` on, until its next change."""

    tick: int
    coordination: Coordination


def changes(view: EpisodeView) -> dict[str, list[Change]]:
    """Each robot's coordination where it changed (a new leader, a new job), in step order."""
    out: dict[str, list[Change]] = {}
    for robot in view.robots:
        seen: list[Change] = []
        for step in view.steps.get(robot, []):
            c = step.thought.coordination if step.thought is not None else None
            if c is not None and step.tick is not None and (not seen or seen[-1].coordination != c):
                seen.append(Change(step.tick, c))
        if seen:
            out[robot] = seen
    return out


def step_line(c: Coordination | None) -> str:
    """A step's line in its lane: the job it was working on and whom it followed."""
    if c is None:
        return ""
    parts = []
    if c.job:
        parts.append(f"job <code>{_e(c.job)}</code>" + (f" from {_e(c.by)}" if c.by else ""))
    if c.leader:
        parts.append(f"leader {_e(c.leader)}")
    return f'<div class="coordination dim">{" · ".join(parts) or "no job"}</div>'


def _leaders(found: dict[str, list[Change]]) -> str:
    """Who led, and from which tick, as the robots believed it (a re-election shows as a second row)."""
    since: dict[str, tuple[int, set[str]]] = {}
    for robot, seen in found.items():
        for ch in seen:
            leader = ch.coordination.leader
            if leader is None:
                continue
            tick, believers = since.get(leader, (ch.tick, set()))
            since[leader] = (min(tick, ch.tick), believers | {robot})
    if not since:
        return ""
    rows = "".join(
        f"<tr><td>{_e(leader)}</td><td>t{tick}</td><td>{_e(', '.join(sorted(believers)))}</td></tr>"
        for leader, (tick, believers) in sorted(since.items(), key=lambda kv: kv[1][0])
    )
    return f'<table class="leaders"><tr><th>leader</th><th>from</th><th>followed by</th></tr>{rows}</table>'


def section(view: EpisodeView) -> str:
    """The coordination section: the leaders, then each robot's jobs in order; empty without any."""
    found = changes(view)
    if not found:
        return ""
    rows = []
    for robot, seen in found.items():
        jobs = [ch for ch in seen if ch.coordination.job]
        cells = ", ".join(
            f"t{ch.tick} <code>{_e(ch.coordination.job)}</code>"
            + (f" ({_e(ch.coordination.by)})" if ch.coordination.by else "")
            for i, ch in enumerate(jobs)
            if i == 0 or jobs[i - 1].coordination.job != ch.coordination.job
        )
        rows.append(f'<tr data-robot="{_e(robot)}"><td>{_e(robot)}</td><td>{cells or "none"}</td></tr>')
    protocol = _e(view.header.protocol)
    return (
        f'<section id="coordination"><h2>Coordination ({protocol})</h2>{_leaders(found)}'
        f'<table class="jobs"><tr><th>robot</th><th>jobs allocated, in order</th></tr>{"".join(rows)}</table></section>'
    )
