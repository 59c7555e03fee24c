"""Summaries of `mhrc eval` results: tables shaped like the paper's, 95% bootstrap confidence
intervals, and the paper's own figures beside mhrc's where the configuration matches.

Rows are the `episodes.jsonl` rows of one or several evaluation directories. Only valid rows
(`mhrc.core.metrics`: not every LLM step lost to an unreachable model) enter a table; the summary
says how many were left out and which. Rows are grouped by their *setting*: method, ablation,
fidelity, history cap and horizon, so that a paper-fidelity number is never averaged with an
aided one (nor a capped prompt with a whole one).

The paper's figures are shown beside a setting's (per task) only when it is the paper's
configuration: paper fidelity, no history cap, horizon 50, the paper grid (3 scenes, each with
one episode per object count 3, 4, 5 and 6, or the same number of them per cell with
`--repeats`), and a method whose model is one the paper ran, with an ablation it reports.

Beside the metrics, a "Failure diagnostics" table per setting (`mhrc.core.diagnostics`: the rows'
`diag_*` columns); rows written before those columns existed are unknown there, never zero.
`write_summaries` writes summary.md, summary.csv and summary.html (`mhrc.eval.html`).
"""

from __future__ import annotations

import csv
import io
import json
import re
from collections import Counter, defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import structlog

from mhrc.core.diagnostics import summarize_diagnostics
from mhrc.run.episode import ConfigError
from mhrc.core.metrics import UNRECORDED, summarize

log = structlog.get_logger("mhrc.eval.report")

PAPER_OBJECTS = (3, 4, 5, 6)  # one episode per object count per scene
PAPER_SCENES = 3
PAPER_HORIZON = 50
RESAMPLES = 2000  # bootstrap resamples per confidence interval
CI_SEED = 0  # every interval is drawn with this seed: the same rows give the same intervals
CI_LEVEL = 0.95

# The MHRC paper's figures (Succ, PS, TS, AS per task), as /work/shared/PAPER.md transcribes
# them from the paper (seed/000_027b806dfa4f6e57.txt): Table I, "MHRC with each LLM" (ablation
# none), and Table II, "GPT-4o ablations" (w/o feedback, w/o history, w/o mobile robot; its
# "full" column repeats Table I's GPT-4o). Keys: (the paper's model, mhrc's ablation name).
Figures = tuple[float, float, float, float]
PAPER_FIGURES: dict[tuple[str, str], dict[str, Figures]] = {
    ("GPT-3.5-turbo", "none"): {
        "make_sandwich": (0.0, 0.14, 50.0, 41.22),
        "sort_solids": (0.0, 0.17, 50.0, 39.89),
        "pack_objects": (0.0, 0.25, 50.0, 37.67),
    },
    ("Llama-3.1-8B", "none"): {
        "make_sandwich": (0.0, 0.12, 50.0, 46.00),
        "sort_solids": (0.0, 0.14, 50.0, 44.33),
        "pack_objects": (0.0, 0.20, 50.0, 40.33),
    },
    ("GPT-4o", "none"): {
        "make_sandwich": (0.75, 0.81, 38.89, 31.11),
        "sort_solids": (0.83, 0.88, 34.56, 27.33),
        "pack_objects": (0.92, 0.96, 32.67, 25.00),
    },
    ("GPT-4o", "no_feedback"): {
        "make_sandwich": (0.0, 0.08, 50.0, 48.56),
        "sort_solids": (0.0, 0.10, 50.0, 46.22),
        "pack_objects": (0.0, 0.14, 50.0, 46.00),
    },
    ("GPT-4o", "no_history"): {
        "make_sandwich": (0.0, 0.48, 50.0, 46.89),
        "sort_solids": (0.0, 0.56, 50.0, 47.44),
        "pack_objects": (0.0, 0.61, 50.0, 48.33),
    },
    ("GPT-4o", "no_mobile"): {
        "make_sandwich": (0.69, 0.78, 44.67, 36.33),
        "sort_solids": (0.81, 0.84, 40.50, 31.17),
        "pack_objects": (0.92, 0.94, 37.00, 28.33),
    },
}
PAPER_ABLATION_NAMES = {"none": "", "no_feedback": "w/o feedback", "no_history": "w/o history", "no_mobile": "w/o mobile robot"}
# How a method's model spec is recognised as one the paper ran (lower-cased, matched loosely:
# openai:gpt-4o, azure:gpt-4o-2024-08-06, ollama:llama3.1:8b, vllm:meta-llama/Llama-3.1-8B-Instruct).
PAPER_MODELS: tuple[tuple[str, re.Pattern[str]], ...] = (
    ("GPT-4o", re.compile(r"gpt-?4o(?:-\d{4}-\d{2}-\d{2})?$")),
    ("GPT-3.5-turbo", re.compile(r"gpt-?3\.5-turbo(?:-\d{4})?$")),
    ("Llama-3.1-8B", re.compile(r"llama-?3\.1[-_:]?8b")),
)

COLUMNS = (
    "episodes", "succ", "ps", "ts", "ts_bound", "as_ticks", "as", "as_per_robot", "messages", "llm_calls", "prompt_tokens",
    "completion_tokens", "parse_failures", "llm_unreachable", "rejected_actions", "failed_actions", "wall_time",
)  # fmt: skip
CI_METRICS = {"succ": "success", "ps": "partial_success", "ts": "temporal_steps", "as_ticks": "active_ticks", "as": "action_steps"}
# mode: free (the paper's) or structured replies; schedule: the world's time policy (world/schedulers)
SETTING = ("method", "ablation", "fidelity", "history_cap", "horizon", "mode", "schedule")
PAPER_SCHEDULE = "sequential"  # Algorithm 1; rows written before the field ran lockstep
AS_NOTE = (
    "AS is the number of steps in which any robot did a non-wait action: the reading set beside the paper's AS, "
    "because the paper's AS is below its TS in every row of its tables (48.56 of 50 where episodes fail), which a "
    "sum over three robots cannot be and a per-robot mean reaches only if every robot acts in nearly every step. "
    "The other readings are columns: AS sum (actions of all robots, wait excluded) and AS/robot (that sum over the "
    "number of robots); rows written before AS existed show '-'. TS* is the mean lower bound on TS (world/bound.py)."
)


# --------------------------------------------------------------------------- reading


def read_rows(path: Path) -> list[dict[str, Any]]:
    """The rows of an episodes.jsonl (a torn last line, from an interrupted write, is skipped)."""
    if not path.exists():
        return []
    rows = []
    for i, line in enumerate(path.read_text(encoding="utf-8").splitlines()):
        if not line.strip():
            continue
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            log.warning("skipping a torn line of episodes.jsonl (an interrupted write)", line=i + 1)
    return rows


def merge_runs(dirs: list[Path]) -> list[dict[str, Any]]:
    """Every episode row of several evaluation directories (for `mhrc report`)."""
    rows = []
    for d in dirs:
        path = d / "episodes.jsonl"
        if not path.exists():
            raise ConfigError(f"{d}: no episodes.jsonl here; is it an `mhrc eval --out` directory?")
        rows += read_rows(path)
    return rows


def _setting(row: dict[str, Any]) -> tuple[Any, ...]:
    """What a row's numbers depend on besides the episode; rows written before a field existed get its old meaning."""
    defaults = {"fidelity": UNRECORDED, "history_cap": None, "horizon": None, "mode": "free", "schedule": "lockstep"}
    return tuple(row.get(k, defaults.get(k)) for k in SETTING)


def _valid(row: dict[str, Any]) -> bool:
    return row.get("valid", True) is not False


def _order(key: Iterable[Any]) -> tuple[str, ...]:
    return tuple("" if x is None else str(x) for x in key)


def setting_label(setting: tuple[Any, ...], *, ablation: bool = True) -> str:
    method, abl, fidelity, cap, horizon, mode, schedule = setting
    parts = [method] + ([f"ablation {abl}"] if ablation else []) + [fidelity] + (["structured decisions"] if mode == "structured" else [])
    if schedule != PAPER_SCHEDULE:
        parts.append(f"{schedule} schedule")
    if cap is not None:
        parts.append(f"history cap {cap}")
    if horizon is not None and horizon != PAPER_HORIZON:
        parts.append(f"horizon {horizon}")
    return " · ".join(parts)


# --------------------------------------------------------------------------- statistics


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


# --------------------------------------------------------------------------- the paper


def paper_model(method: str) -> str | None:
    """The paper's name of the model a method runs (GPT-4o, GPT-3.5-turbo, Llama-3.1-8B), or None."""
    spec = method.strip().lower()
    if spec.startswith("replay:"):
        return None
    return next((name for name, pattern in PAPER_MODELS if pattern.search(spec)), None)


@dataclass(frozen=True)
class PaperMatch:
    model: str
    ablation: str
    figures: Figures | None  # None: the configuration does not match, `why` says how
    why: str = ""

    @property
    def title(self) -> str:
        extra = PAPER_ABLATION_NAMES.get(self.ablation, self.ablation)
        return f"paper {self.model}" + (f" {extra}" if extra else "")

    @property
    def table(self) -> str:
        return "Table I" if self.ablation == "none" else "Table II"


def grid_problem(rows: list[dict[str, Any]]) -> str | None:
    """Why these rows (one setting, one task) are not the paper grid, or None if they are."""
    cells = Counter((r["scene"], r["n_objects"]) for r in rows)
    scenes = sorted({s for s, _ in cells})
    if len(scenes) != PAPER_SCENES:
        return f"{len(scenes)} scene(s), the paper has {PAPER_SCENES}"
    for scene in scenes:
        counts = sorted({n for s, n in cells if s == scene})
        if counts != list(PAPER_OBJECTS):
            return f"scene {scene} has object counts {', '.join(map(str, counts))}, the paper {', '.join(map(str, PAPER_OBJECTS))}"
    if len(set(cells.values())) != 1:
        return "unequal numbers of episodes per scene and object count"
    return None


def paper_match(setting: tuple[Any, ...], task: str, rows: list[dict[str, Any]]) -> PaperMatch | None:
    """The paper's figures for this setting and task when the configuration matches; a
    PaperMatch without figures (and the reason) when only the model matches; None otherwise."""
    method, ablation, fidelity, cap, horizon, mode, schedule = setting
    model = paper_model(str(method))
    if model is None:
        return None
    figures = PAPER_FIGURES.get((model, ablation), {}).get(task)
    if figures is None:
        return PaperMatch(model, ablation, None, f"the paper reports no {task} figures for {model} with ablation {ablation}")
    why = ""
    if fidelity != "paper":
        why = f"fidelity {fidelity}, not paper"
    elif mode != "free":
        why = f"{mode} decisions (the paper's model answers in free text)"
    elif cap is not None:
        why = f"history cap {cap} (the paper keeps whole histories)"
    elif horizon != PAPER_HORIZON:
        why = f"horizon {horizon}, the paper's is {PAPER_HORIZON}"
    elif schedule != PAPER_SCHEDULE:
        why = f"the {schedule} schedule (the paper's robots act one after another: --schedule {PAPER_SCHEDULE})"
    else:
        why = grid_problem(rows) or ""
        if why:
            why = "not the paper grid: " + why
    return PaperMatch(model, ablation, None if why else figures, why)


def _paper_cell(f: Figures) -> str:
    return f"{f[0]:.2f} / {f[1]:.2f} / {f[2]:.2f} / {f[3]:.2f}"


# --------------------------------------------------------------------------- tables


def group(rows: list[dict[str, Any]], *keys: str) -> dict[tuple[Any, ...], list[dict[str, Any]]]:
    buckets: dict[tuple[Any, ...], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        buckets[tuple(_setting(r)[SETTING.index(k)] if k in SETTING else r[k] for k in keys)].append(r)
    return dict(sorted(buckets.items(), key=lambda kv: _order(kv[0])))


def _by_setting_task(rows: list[dict[str, Any]]) -> dict[tuple[tuple[Any, ...], str], list[dict[str, Any]]]:
    out: dict[tuple[tuple[Any, ...], str], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        out[(_setting(r), r["task"])].append(r)
    return dict(sorted(out.items(), key=lambda kv: (_order(kv[0][0]), kv[0][1])))


def _cell(s: dict[str, Any]) -> str:
    bound = f" ({s['ts_bound']:.1f})" if s.get("ts_bound") is not None else ""
    steps = "-" if s.get("as_ticks") is None else f"{s['as_ticks']:.1f}"
    return f"{s['succ']:.2f} / {s['ps']:.2f} / {s['ts']:.1f}{bound} / {steps} (sum {s['as']:.1f}, per robot {s['as_per_robot']:.1f})"


def _ci(s: dict[str, Any], name: str, digits: int) -> str:
    if s.get(f"{name}_ci") is None:
        return "-"
    lo, hi = s[f"{name}_ci"]
    return f"{s[name]:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def invalid_note(rows: list[dict[str, Any]]) -> list[str]:
    bad = [r for r in rows if not _valid(r)]
    if not bad:
        return []
    lines = [f"{len(bad)} invalid episode(s) left out of every table below:"]
    for r in sorted(bad, key=lambda r: (_order(_setting(r)), r["key"])):
        lines.append(f"- {r['key']} ({setting_label(_setting(r))}): {r.get('invalid_reason') or 'invalid'}")
    return lines + [""]


def summary_markdown(rows: list[dict[str, Any]], *, resamples: int = RESAMPLES, seed: int = CI_SEED) -> str:
    """Table I (settings without ablation) and Table II (ablations per method), the paper's
    figures beside matching settings, then per setting each task with 95% bootstrap intervals,
    the LLM failures and costs, and the breakdown by scene and by object count."""
    valid = [r for r in rows if _valid(r)]
    n_bad = len(rows) - len(valid)
    lines = ["# Evaluation summary", ""]
    lines.append(f"{len(rows)} episodes, {len(valid)} valid" + (f", {n_bad} invalid" if n_bad else "") + ".")
    lines += ["", *invalid_note(rows)]
    if not valid:
        return "\n".join(lines + ["No valid episodes to summarize.", ""])
    lines += [
        "Each cell: Succ / PS / TS (TS*) / AS (AS sum, AS per robot); paper cells: Succ / PS / TS / AS. "
        "Settings are method · ablation · fidelity (and history cap or horizon when not the paper's).",
        "",
        AS_NOTE,
        "",
    ]
    cells = {k: cell_stats(v, resamples=resamples, seed=seed) for k, v in _by_setting_task(valid).items()}
    matches = {k: paper_match(k[0], k[1], v) for k, v in _by_setting_task(valid).items()}
    tasks = sorted({r["task"] for r in valid})

    def paper_of(setting: tuple[Any, ...], task: str) -> PaperMatch | None:
        m = matches.get((setting, task))
        return m if m is not None and m.figures is not None else None

    def matrix(title: str, columns: list[tuple[tuple[Any, ...], str]]) -> list[str]:
        """One column per setting; beside it, the paper's column when some task matches."""
        head: list[str] = []
        cols: list[tuple[bool, tuple[Any, ...]]] = []  # (is the paper's column, setting)
        for setting, label in columns:
            head.append(label)
            cols.append((False, setting))
            found = [m for t in tasks if (m := paper_of(setting, t)) is not None]
            if found:
                head.append(f"{found[0].title} ({found[0].table})")
                cols.append((True, setting))

        def value(paper: bool, setting: tuple[Any, ...], task: str) -> str:
            if paper:
                m = paper_of(setting, task)
                return _paper_cell(m.figures) if m is not None and m.figures is not None else ""
            return _cell(cells[(setting, task)]) if (setting, task) in cells else ""

        out = [f"## {title}", "", "| task | " + " | ".join(head) + " |", "| --- |" + " --- |" * len(head)]
        out += [f"| {t} | " + " | ".join(value(p, s, t) for p, s in cols) + " |" for t in tasks]
        return out + [""]

    settings = sorted({_setting(r) for r in valid}, key=_order)
    full = [s for s in settings if s[1] == "none"]
    if full:
        lines += matrix("Table I: methods", [(s, setting_label(s, ablation=False)) for s in full])
    families = sorted({(s[0], *s[2:]) for s in settings}, key=_order)
    for fam in families:
        mine = sorted((s for s in settings if (s[0], *s[2:]) == fam), key=lambda s: (s[1] == "none", s[1]))
        family = (fam[0], "*", *fam[1:])
        lines += matrix(f"Table II: ablations of {setting_label(family, ablation=False)}", [(s, s[1]) for s in mine])

    lines += ["## Per setting, with 95% confidence intervals", "",
              f"Mean [95% percentile bootstrap interval, {resamples} resamples, seed {seed}] over the valid episodes.", ""]  # fmt: skip
    for setting in settings:
        mine_tasks = [t for t in tasks if (setting, t) in cells]
        shown = [matches.get((setting, t)) for t in mine_tasks]
        paper_col = any(m is not None and m.figures is not None for m in shown)
        head = "| task | episodes | Succ | PS | TS | AS | TS* | AS sum | AS/robot |" + (" paper Succ / PS / TS / AS |" if paper_col else "")
        lines += [f"### {setting_label(setting)}", "", head, "| --- |" + " --- |" * (head.count("|") - 2)]
        for t, m in zip(mine_tasks, shown):
            s = cells[(setting, t)]
            bound = f"{s['ts_bound']:.1f}" if s.get("ts_bound") is not None else ""
            row = (f"| {t} | {s['episodes']} | {_ci(s, 'succ', 2)} | {_ci(s, 'ps', 2)} | {_ci(s, 'ts', 1)} | {_ci(s, 'as_ticks', 1)} | {bound} | "
                   f"{_ci(s, 'as', 1)} | {s['as_per_robot']:.1f} |")
            if paper_col:
                row += f" {_paper_cell(m.figures)} ({m.title}, {m.table}) |" if m is not None and m.figures is not None else " |"
            lines.append(row)
        notes = [f"- {t}: not set beside the {m.title} figures: {m.why}" for t, m in zip(mine_tasks, shown) if m is not None and m.figures is None]
        lines += ([""] + notes if notes else []) + [""]

    if any(r.get("llm_calls") for r in valid):
        head = "| setting | task | LLM steps | unparsed replies | unreachable steps | rejected actions | prompt tokens | completion tokens |"
        lines += ["## LLM failures and cost (means per episode)", "", head, "| --- |" + " --- |" * (head.count("|") - 2)]
        for (setting, t), s in cells.items():
            lines.append(
                f"| {setting_label(setting)} | {t} | {s['llm_calls']:.1f} | {s['parse_failures']:.2f} | {s['llm_unreachable']:.2f} | "
                f"{s['rejected_actions']:.2f} | {s['prompt_tokens']:.0f} | {s['completion_tokens']:.0f} |"
            )
        lines.append("")
    lines += diagnostics_markdown(valid)
    for key, title in (("scene", "scene"), ("n_objects", "object count")):
        lines += [f"## By {title}", "", f"| method | ablation | fidelity | {key} | Succ / PS / TS (TS*) / AS (AS sum, AS/robot) | episodes |",
                  "| --- | --- | --- | --- | --- | --- |"]  # fmt: skip
        for (m, a, fid, cap, hor, mode, sched, v), bucket in group(valid, *SETTING, key).items():
            s = summarize(bucket)
            extra = "".join(f" · {x}" for x in setting_label((m, a, fid, cap, hor, mode, sched)).split(" · ")[3:])  # mode, schedule, cap, horizon
            lines.append(f"| {m}{extra} | {a} | {fid} | {v} | {_cell(s)} | {s['episodes']} |")
        lines.append("")
    return "\n".join(lines)


DIAG_COLUMNS = (
    "parse_failures", "hallucinations", "not_capable", "rejected", "failed", "repeated_failures", "waits",
    "waits_with_pending", "messages_sent", "messages_read", "steps_above_bound",
)  # fmt: skip
DIAG_NOTE = (
    "Means per episode (mhrc.core.diagnostics defines each count). A name is hallucinated when the command names an object "
    "or furniture the robot's own scene graph (or its task list) did not hold; waits w/ pending are waits chosen while "
    "a teammate's message was unanswered; messages read were delivered into the receiver's observation; steps above TS* "
    "is TS minus the lower bound."
)


def _mean_breakdown(total: dict[str, int] | None, n: int, top: int = 3) -> str:
    if not total or not n:
        return ""
    items = sorted(total.items(), key=lambda kv: (-kv[1], kv[0]))
    shown = ", ".join(f"{k} {v / n:.2f}" for k, v in items[:top]) + (", ..." if len(items) > top else "")
    return f" ({shown})"


def diagnostics_markdown(valid: list[dict[str, Any]]) -> list[str]:
    """The "Failure diagnostics" section: per setting, a table of `summarize_diagnostics` per task.
    Rows written before diagnostics existed are unknown (n/a), never counted as zero."""
    lines = ["## Failure diagnostics", "", DIAG_NOTE, ""]
    by_setting: dict[tuple[Any, ...], list[dict[str, Any]]] = defaultdict(list)
    for r in valid:
        by_setting[_setting(r)].append(r)
    for setting in sorted(by_setting, key=_order):
        head = (
            "| task | episodes (with diagnostics) | unparsed replies | hallucinations | not capable | rejected (by kind) | "
            "failed (by code) | repeated failures | waits w/ pending / waits | messages sent / read | steps above TS* |"
        )
        lines += [f"### {setting_label(setting)}", "", head, "| --- |" + " --- |" * (head.count("|") - 2)]
        unknown = 0
        for task, mine in group(by_setting[setting], "task").items():
            d = summarize_diagnostics(mine)
            unknown += d["unknown"]
            if not d["known"]:
                lines.append(f"| {task[0]} | {d['episodes']} (0) |" + " n/a |" * 9)
                continue
            m, n = d["mean"], d["known"]

            def f(name: str, digits: int = 2) -> str:
                return "n/a" if m[name] is None else f"{m[name]:.{digits}f}"

            lines.append(
                f"| {task[0]} | {d['episodes']} ({n}) | {f('parse_failures')} | {f('hallucinations')} | {f('not_capable')} | "
                f"{f('rejected')}{_mean_breakdown(d['rejected_by_reason'], n)} | {f('failed')}{_mean_breakdown(d['failed_by_code'], n)} | "
                f"{f('repeated_failures')} | {f('waits_with_pending')} / {f('waits')} | {f('messages_sent')} / {f('messages_read')} | "
                f"{f('steps_above_bound', 1)} |"
            )
        if unknown:
            lines += ["", f"{unknown} episode(s) of this setting were recorded before diagnostics existed: their diagnostics "
                          "are unknown (n/a), left out of these means, not counted as zero."]  # fmt: skip
        lines.append("")
    return lines


def summary_csv(rows: list[dict[str, Any]], *, resamples: int = RESAMPLES, seed: int = CI_SEED) -> str:
    """One line per setting and task (valid episodes only): means, intervals and, where the
    configuration matches, the paper's figures."""
    buf = io.StringIO()
    w = csv.writer(buf)
    ci_cols = [f"{m}_{e}" for m in CI_METRICS for e in ("lo", "hi")]
    diag_cols = ["diag_episodes", *(f"diag_{c}" for c in DIAG_COLUMNS)]  # means over the rows with diagnostics; empty: unknown
    w.writerow([*SETTING, "task", *COLUMNS, *ci_cols, "invalid_left_out", "paper_model", "paper_succ", "paper_ps", "paper_ts", "paper_as", *diag_cols])
    invalid = Counter((_setting(r), r["task"]) for r in rows if not _valid(r))
    for (setting, task), mine in _by_setting_task([r for r in rows if _valid(r)]).items():
        s = cell_stats(mine, resamples=resamples, seed=seed)
        m = paper_match(setting, task, mine)
        paper: list[Any] = [m.model, *m.figures] if m is not None and m.figures is not None else ["", "", "", "", ""]
        cis = ["" if s[f"{name}_ci"] is None else round(x, 4) for name in CI_METRICS for x in (s[f"{name}_ci"] or (0.0, 0.0))]
        d = summarize_diagnostics(mine)
        diag = [d["known"], *("" if d["mean"][c] is None else d["mean"][c] for c in DIAG_COLUMNS)]
        w.writerow([*("" if x is None else x for x in setting), task, *(s[c] for c in COLUMNS), *cis, invalid[(setting, task)], *paper, *diag])
    return buf.getvalue()


SUMMARY_FILES = ("summary.md", "summary.csv", "summary.html")  # what write_summaries writes, in the order people read them


def write_summaries(rows: list[dict[str, Any]], out: Path) -> None:
    """SUMMARY_FILES in `out`: summary.md, summary.csv and summary.html (tables and plots, `mhrc.eval.html`)."""
    if not rows:
        return
    # imported here: the HTML page is built on this module's tables (eval_report imports report)
    from mhrc.eval.html import write_html_summary

    md, csv, html = (out / name for name in SUMMARY_FILES)
    csv.write_text(summary_csv(rows), encoding="utf-8")
    md.write_text(summary_markdown(rows), encoding="utf-8")
    write_html_summary(rows, html)
