"""The rows of `mhrc eval` (`episodes.jsonl`, read and upgraded by mhrc.eval.records): their setting
(what may be averaged together), validity, grouping, and 95% bootstrap intervals over a cell of them."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from mhrc.analysis.metrics import EpisodeMetrics
from mhrc.core.logs import get_logger
from mhrc.core.protocol.events import DEFAULT_PROTOCOL
from mhrc.core.upgrade import paper_team
from mhrc.eval.means import summarize
from mhrc.eval.paper import PAPER_HORIZON, PAPER_SCHEDULE
from mhrc.eval.records import EvalRow, Settings
from mhrc.eval.records import merge_runs as merge_runs  # where callers have always found them
from mhrc.eval.records import read_rows as read_rows

log = get_logger("mhrc.eval.rows")

RESAMPLES = 2000  # bootstrap resamples per confidence interval


CI_SEED = 0  # every interval is drawn with this seed: the same rows give the same intervals


CI_LEVEL = 0.95


# each interval's metric, read from a row's metrics
CI_METRICS: dict[str, Callable[[EvalRow], float | None]] = {
    "succ": lambda r: float(r.metrics.success),
    "ps": lambda r: r.metrics.partial_success,
    "ts": lambda r: r.metrics.temporal_steps,
    "as_ticks": lambda r: r.metrics.active_ticks,
    "as": lambda r: r.metrics.action_steps,
}


# noise: the world's motion noise, on (the calibration) or off (--noise off, or the exact_motion aid; mhrc.core.fidelity);
# mode: free (the paper's) or structured replies; schedule: the world's time policy (world/schedulers);
# team: None for the paper's team (or as much of it as an ablation runs), else NAME@DIGEST (the team's name and
# TeamSpec.digest(): two teams of one name are two settings); the summaries never average across teams;
# scenario: the --events scenario as NAME@SHA12 (its name and the first 12 hex digits of the file's sha256, as
# `mhrc scenarios` lists it: two files of one name are two settings), None for a static episode;
# protocol: the coordination protocol (mhrc.agents.protocols), None for the paper's (mhrc): never averaged across
SETTING = (
    "method",
    "ablation",
    "fidelity",
    "noise",
    "history_cap",
    "horizon",
    "mode",
    "schedule",
    "team",
    "scenario",
    "protocol",
)
Setting = tuple[Any, ...]  # a row's values of SETTING, in its order


def setting_defaults() -> dict[str, Any]:
    """Each SETTING field's value in a row written without it: its model's default (team and protocol: the
    paper's, None)."""
    fields = {**Settings.model_fields, **EpisodeMetrics.model_fields}
    return {k: None if k in ("team", "protocol") or fields[k].is_required() else fields[k].default for k in SETTING}


def team_setting(row: EvalRow) -> str | None:
    """A row's team as its setting holds it: None for the paper's, else NAME@DIGEST."""
    m = row.metrics
    if m.team == "paper" and m.team_digest == paper_team(m.robots).digest:
        return None
    return f"{m.team}@{m.team_digest}"


def setting_of(row: EvalRow) -> Setting:
    """What a row's numbers depend on besides the episode (a row read from a file has every field's
    old meaning already: mhrc.eval.records.upgrade_row)."""
    s, m = row.settings, row.metrics
    scenario = s.scenario
    if scenario is not None and s.scenario_sha256:
        scenario = f"{scenario}@{s.scenario_sha256[:12]}"
    return (
        s.method,
        s.ablation,
        m.fidelity,
        m.noise,
        s.history_cap,
        m.horizon,
        s.mode,
        s.schedule,
        team_setting(row),
        scenario,
        None if s.protocol == DEFAULT_PROTOCOL else s.protocol,
    )


def is_valid(row: EvalRow) -> bool:
    return row.metrics.valid


def order_key(key: Iterable[Any]) -> tuple[str, ...]:
    return tuple("" if x is None else str(x) for x in key)


def setting_label(setting: Setting, *, ablation: bool = True) -> str:
    method, abl, fidelity, noise, cap, horizon, mode, schedule, team, scenario, protocol = setting
    parts = (
        [method] + ([f"ablation {abl}"] if ablation else []) + [fidelity] + (["noise off"] if noise == "off" else [])
    )
    parts += ["structured decisions"] if mode == "structured" else []
    if schedule != PAPER_SCHEDULE:
        parts.append(f"{schedule} schedule")
    if cap is not None:
        parts.append(f"history cap {cap}")
    if horizon is not None and horizon != PAPER_HORIZON:
        parts.append(f"horizon {horizon}")
    if team is not None:
        parts.append(f"team {team}")
    if scenario is not None:
        parts.append(f"scenario {scenario}")
    if protocol is not None:
        parts.append(f"protocol {protocol}")
    return " · ".join(parts)


def bootstrap_ci(
    values: Sequence[float], *, resamples: int = RESAMPLES, seed: int = CI_SEED, level: float = CI_LEVEL
) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of the mean: `resamples` resamples with
    replacement, drawn with `seed` (the same values always give the same interval)."""
    import numpy as np  # here: a refused `mhrc eval` command line, which imports this module, needs no numerics

    x = np.asarray([float(v) for v in values], dtype=float)
    if x.size == 0:
        raise ValueError("no values to bootstrap")
    if resamples < 1 or not 0 < level < 1:
        raise ValueError("need resamples >= 1 and 0 < level < 1")
    rng = np.random.default_rng(seed)
    means = x[rng.integers(0, x.size, size=(resamples, x.size))].mean(axis=1)
    alpha = (1 - level) / 2
    lo, hi = np.percentile(means, [100 * alpha, 100 * (1 - alpha)])
    return float(lo), float(hi)


def cell_stats(rows: list[EvalRow], *, resamples: int = RESAMPLES, seed: int = CI_SEED) -> dict[str, Any]:
    """`summarize` plus a bootstrap interval (`<metric>_ci`) for Succ, PS, TS and AS."""
    s = summarize([r.metrics for r in rows])
    for name, value in CI_METRICS.items():
        values = [value(r) for r in rows]
        if s.get(name) is None or any(v is None for v in values):  # a reading older rows do not have
            s[f"{name}_ci"] = None
            continue
        s[f"{name}_ci"] = bootstrap_ci([float(v or 0.0) for v in values], resamples=resamples, seed=seed)
    return s


# what rows are grouped by besides their setting's fields
BY: dict[str, Callable[[EvalRow], Any]] = {
    "task": lambda r: r.metrics.task,
    "scene": lambda r: r.metrics.scene,
    "n_objects": lambda r: r.metrics.n_objects,
}


def group(rows: list[EvalRow], *keys: str) -> dict[tuple[Any, ...], list[EvalRow]]:
    """Rows by the values of `keys` (SETTING's fields, or BY's), in the order every table lists them."""
    buckets: dict[tuple[Any, ...], list[EvalRow]] = defaultdict(list)
    for r in rows:
        setting = setting_of(r)
        buckets[tuple(setting[SETTING.index(k)] if k in SETTING else BY[k](r) for k in keys)].append(r)
    return dict(sorted(buckets.items(), key=lambda kv: order_key(kv[0])))


def by_setting_task(rows: list[EvalRow]) -> dict[tuple[Setting, str], list[EvalRow]]:
    out: dict[tuple[Setting, str], list[EvalRow]] = defaultdict(list)
    for r in rows:
        out[(setting_of(r), r.metrics.task)].append(r)
    return dict(sorted(out.items(), key=lambda kv: (order_key(kv[0][0]), kv[0][1])))
