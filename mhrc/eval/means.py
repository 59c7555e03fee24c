"""The means over an evaluation's episodes: of their metrics (`summarize`: Succ is then the
success rate) and of their failure diagnostics (`summarize_diagnostics`). Each episode's own
figures are mhrc.analysis's (`EpisodeMetrics`, `Diagnostics`); what is averaged together, and
which episodes are left out, is the caller's (mhrc.eval.summary).

A row written before a field existed: its metric counts as the field's default (0, or None for a
reading it lacks: `as_ticks` is then None); recovery_ticks and unrecovered are means over the
episodes that have a value (a static episode adds nothing to them); the team's work
(mhrc.analysis.teamwork) is unknown (None) when any row lacks it, and so are the diagnostics of a
row without them: left out and counted in `unknown`, never zero."""

from __future__ import annotations

import statistics
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

from mhrc.analysis.diagnostics import BREAKDOWNS, COUNTS, Diagnostics
from mhrc.analysis.metrics import EpisodeMetrics

__all__ = ["TEAMWORK_FIELDS", "summarize", "summarize_diagnostics"]


def summarize(rows: Sequence[EpisodeMetrics]) -> dict[str, Any]:
    """Means over episodes' metrics (module docstring). Leaving invalid episodes out is the
    caller's choice (mhrc.eval.summary)."""
    if not rows:
        raise ValueError("no episodes to summarize")

    def mean(value: Callable[[EpisodeMetrics], float], digits: int = 3) -> float:
        return round(statistics.fmean(float(value(m)) for m in rows), digits)

    bounds = [m.lower_bound for m in rows if m.lower_bound is not None]
    ticks = [m.active_ticks for m in rows]
    return {
        "episodes": len(rows),
        "succ": mean(lambda m: m.success, 4),
        "ps": mean(lambda m: m.partial_success, 4),
        "ts": mean(lambda m: m.temporal_steps),
        "ts_bound": round(statistics.fmean(bounds), 3) if bounds else None,
        "as": mean(lambda m: m.action_steps),
        "as_per_robot": mean(lambda m: m.action_steps / max(1, len(m.robots))),
        # the reading beside the paper's AS (mhrc.analysis.metrics); None when a row predates it
        "as_ticks": None if any(t is None for t in ticks) else round(statistics.fmean(float(t or 0) for t in ticks), 3),
        "messages": mean(lambda m: m.messages),
        "llm_calls": mean(lambda m: m.llm_calls),
        "prompt_tokens": mean(lambda m: m.prompt_tokens, 1),
        "completion_tokens": mean(lambda m: m.completion_tokens, 1),
        "parse_failures": mean(lambda m: m.parse_failures),
        "llm_unreachable": mean(lambda m: m.llm_unreachable),
        "rejected_actions": mean(lambda m: m.rejected_actions),
        "failed_actions": mean(lambda m: sum(m.failed_actions.values())),
        "wall_time": mean(lambda m: m.wall_time),
        "makespan": mean(lambda m: m.makespan),
        # scenario episodes only (a static episode, or a row written before the fields, adds nothing)
        "recovery_ticks": _mean_of_known([m.recovery_ticks for m in rows]),
        "unrecovered": _mean_of_known([m.unrecovered for m in rows]),
        # the team's work (mhrc.analysis.teamwork); None when a row predates the fields
        **_teamwork_means(rows),
    }


TEAMWORK_FIELDS = ("communication_steps", "redundant_navigations", "redundant_picks", "moves_per_robot")


def _teamwork_means(rows: Sequence[EpisodeMetrics]) -> dict[str, Any]:
    """comm_steps and other_steps (the rest of AS sum), redundant (navigations and picks, and each),
    moves (successful picks and places) per episode, and each robot's share of the moves: its moves
    over all robots' moves in these rows (an empty share when nothing was moved)."""
    if any(f not in m.model_fields_set for m in rows for f in TEAMWORK_FIELDS):  # a row written before them
        return dict.fromkeys(
            ("comm_steps", "other_steps", "redundant", "redundant_navigations", "redundant_picks", "moves", "share")
        )
    moves: Counter[str] = Counter()
    for m in rows:
        moves.update(m.moves_per_robot)
    robots = list(dict.fromkeys(name for m in rows for name in m.robots))
    total = sum(moves.values())

    def mean(value: Callable[[EpisodeMetrics], float]) -> float:
        return round(statistics.fmean(float(value(m)) for m in rows), 3)

    return {
        "comm_steps": mean(lambda m: m.communication_steps),
        "other_steps": mean(lambda m: m.action_steps - m.communication_steps),
        "redundant": mean(lambda m: m.redundant_navigations + m.redundant_picks),
        "redundant_navigations": mean(lambda m: m.redundant_navigations),
        "redundant_picks": mean(lambda m: m.redundant_picks),
        "moves": mean(lambda m: sum(m.moves_per_robot.values())),
        "share": {name: round(moves.get(name, 0) / total, 4) for name in robots} if total else {},
    }


def _mean_of_known(values: Sequence[float | None]) -> float | None:
    known = [float(v) for v in values if v is not None]
    return round(statistics.fmean(known), 3) if known else None


def summarize_diagnostics(rows: Sequence[Diagnostics | None]) -> dict[str, Any]:
    """Means and totals over episodes' diagnostics. An episode without them (None: written before
    they existed) is unknown, not zero: left out and counted in `unknown`, as is a count its row
    lacks; with none known, every mean and total is None."""
    known = [d for d in rows if d is not None]
    out: dict[str, Any] = {"episodes": len(rows), "known": len(known), "unknown": len(rows) - len(known)}
    means: dict[str, float | None] = {}
    totals: dict[str, int | None] = {}
    for name in COUNTS:
        values = [v for d in known if name in d.model_fields_set and (v := getattr(d, name)) is not None]
        means[name] = round(statistics.fmean(values), 3) if values else None
        totals[name] = int(sum(values)) if values else None
    out["mean"], out["total"] = means, totals
    for name in BREAKDOWNS:
        c: Counter[str] = Counter()
        for d in known:
            c.update(getattr(d, name))
        out[name] = dict(sorted(c.items())) if known else None
    return out
