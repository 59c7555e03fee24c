"""The rows of `mhrc eval` (`episodes.jsonl`, read and upgraded by mhrc.eval.records): their setting
(what may be averaged together), validity, grouping, and 95% bootstrap intervals over a cell of them."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
import structlog

from mhrc.analysis.metrics import summarize
from mhrc.core.upgrade import paper_team
from mhrc.eval.paper import PAPER_HORIZON, PAPER_SCHEDULE
from mhrc.eval.records import OLD_MEANING, old_noise
from mhrc.eval.records import merge_runs as merge_runs  # where callers have always found them
from mhrc.eval.records import read_rows as read_rows

log = structlog.get_logger("mhrc.eval.rows")

RESAMPLES = 2000  # bootstrap resamples per confidence interval


CI_SEED = 0  # every interval is drawn with this seed: the same rows give the same intervals


CI_LEVEL = 0.95


CI_METRICS = {
    "succ": "success",
    "ps": "partial_success",
    "ts": "temporal_steps",
    "as_ticks": "active_ticks",
    "as": "action_steps",
}


# noise: the world's motion noise, on (the calibration) or off (--noise off, or the exact_motion aid; mhrc.core.fidelity);
# mode: free (the paper's) or structured replies; schedule: the world's time policy (world/schedulers);
# team: None for the paper's team (or as much of it as an ablation runs), else NAME@DIGEST (the team's name and
# TeamSpec.digest(): two teams of one name are two settings); the summaries never average across teams;
# scenario: the --events scenario as NAME@SHA12 (its name and the first 12 hex digits of the file's sha256, as
# `mhrc scenarios` lists it: two files of one name are two settings), None for a static episode
SETTING = ("method", "ablation", "fidelity", "noise", "history_cap", "horizon", "mode", "schedule", "team", "scenario")


def team_setting(row: dict[str, Any]) -> str | None:
    """A row's team as its setting holds it: None for the paper's (a row without a team ran it),
    else NAME@DIGEST."""
    name = row.get("team")
    if name is None:
        return None
    digest = str(row.get("team_digest") or "")
    if name == "paper" and digest == paper_team(row.get("robots")).digest:
        return None
    return f"{name}@{digest}"


def setting_of(row: dict[str, Any]) -> tuple[Any, ...]:
    """What a row's numbers depend on besides the episode; rows written before a field existed get its old meaning."""
    values = {
        k: row.get(k, OLD_MEANING.get(k)) for k in SETTING
    }  # rows read from a file are upgraded already (read_row)
    values["team"] = team_setting(row)
    if values["noise"] is None:
        values["noise"] = old_noise(row.get("aids"))
    if values["scenario"] is not None and row.get("scenario_sha256"):
        values["scenario"] = f"{values['scenario']}@{str(row['scenario_sha256'])[:12]}"
    return tuple(values[k] for k in SETTING)


def is_valid(row: dict[str, Any]) -> bool:
    return row.get("valid", True) is not False


def order_key(key: Iterable[Any]) -> tuple[str, ...]:
    return tuple("" if x is None else str(x) for x in key)


def setting_label(setting: tuple[Any, ...], *, ablation: bool = True) -> str:
    method, abl, fidelity, noise, cap, horizon, mode, schedule, team, scenario = setting
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
    return " · ".join(parts)


def bootstrap_ci(
    values: Sequence[float], *, resamples: int = RESAMPLES, seed: int = CI_SEED, level: float = CI_LEVEL
) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of the mean: `resamples` resamples with
    replacement, drawn with `seed` (the same values always give the same interval)."""
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


def cell_stats(rows: list[dict[str, Any]], *, resamples: int = RESAMPLES, seed: int = CI_SEED) -> dict[str, Any]:
    """`summarize` plus a bootstrap interval (`<metric>_ci`) for Succ, PS, TS and AS."""
    s = summarize(rows)
    for name, field in CI_METRICS.items():
        if s.get(name) is None:  # a reading older rows do not have
            s[f"{name}_ci"] = None
            continue
        s[f"{name}_ci"] = bootstrap_ci([float(r[field]) for r in rows], resamples=resamples, seed=seed)
    return s


def group(rows: list[dict[str, Any]], *keys: str) -> dict[tuple[Any, ...], list[dict[str, Any]]]:
    buckets: dict[tuple[Any, ...], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        buckets[tuple(setting_of(r)[SETTING.index(k)] if k in SETTING else r[k] for k in keys)].append(r)
    return dict(sorted(buckets.items(), key=lambda kv: order_key(kv[0])))


def by_setting_task(rows: list[dict[str, Any]]) -> dict[tuple[tuple[Any, ...], str], list[dict[str, Any]]]:
    out: dict[tuple[tuple[Any, ...], str], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        out[(setting_of(r), r["task"])].append(r)
    return dict(sorted(out.items(), key=lambda kv: (order_key(kv[0][0]), kv[0][1])))
