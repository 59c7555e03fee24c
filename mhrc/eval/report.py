"""Summaries of `mhrc eval` results: tables shaped like the paper's, 95% bootstrap confidence
intervals, and the paper's own figures beside mhrc's where the configuration matches.

Rows are the `episodes.jsonl` rows of one or several evaluation directories. Only valid rows
(`mhrc.analysis.metrics`: not every LLM step lost to an unreachable model) enter a table; the summary
says how many were left out and which. Rows are grouped by their *setting*: method, ablation,
fidelity, history cap and horizon, so that a paper-fidelity number is never averaged with an
aided one (nor a capped prompt with a whole one).

The paper's figures are shown beside a setting's (per task) only when it is the paper's
configuration (`mhrc.eval.paper.paper_match`): every robot runs the same model of the paper's
(`mhrc.eval.paper.judge_spec` says which specs are) with the default prompts, paper fidelity,
every other field of the setting at the paper's value, the paper grid (3 scenes, each with one
episode per object count 3, 4, 5 and 6, or the same number of them per cell with `--repeats`),
and an ablation the paper reports. Where a setting has no paper cells, its section says why in
one line.

Beside the metrics, a "Failure diagnostics" table per setting (`mhrc.analysis.diagnostics`: the rows'
diagnostics, `diag_*` columns in episodes.jsonl); rows written before those columns existed are unknown there, never zero.
`write_summaries` writes summary.md, summary.csv and summary.html (`mhrc.eval.html`)."""

from __future__ import annotations

import csv
import io
from typing import Any

from mhrc.core.logs import get_logger
from mhrc.core.plural import counted
from mhrc.eval.means import summarize
from mhrc.eval.pairs import paired_markdown
from mhrc.eval.paper import PaperMatch, paper_cell
from mhrc.eval.records import EvalRow
from mhrc.eval.rows import (
    CI_METRICS,
    CI_SEED,
    RESAMPLES,
    SETTING,
    group,
    is_valid,
    order_key,
    setting_label,
    setting_of,
)
from mhrc.eval.summary import Summary
from mhrc.eval.teams import TEAM, team_comparison

log = get_logger("mhrc.eval.report")


COLUMNS = (
    "episodes",
    "succ",
    "ps",
    "ts",
    "ts_bound",
    "as_ticks",
    "as",
    "as_per_robot",
    "messages",
    "llm_calls",
    "prompt_tokens",
    "completion_tokens",
    "parse_failures",
    "llm_unreachable",
    "rejected_actions",
    "failed_actions",
    "wall_time",
    "recovery_ticks",
    "unrecovered",  # a scenario's (mhrc.analysis.metrics); empty for static episodes
)


AS_NOTE = (  # why AS reads so, at length: docs/evaluation.md, Metrics
    "AS: the steps in which any robot did a non-wait action, set beside the paper's AS; AS sum and AS/robot are the "
    "other readings, TS* the mean lower bound on TS (why: docs/evaluation.md#metrics)."
)


def _cell(s: dict[str, Any]) -> str:
    bound = f" ({s['ts_bound']:.1f})" if s.get("ts_bound") is not None else ""
    steps = "-" if s.get("as_ticks") is None else f"{s['as_ticks']:.1f}"
    return f"{s['succ']:.2f} / {s['ps']:.2f} / {s['ts']:.1f}{bound} / {steps} (sum {s['as']:.1f}, per robot {s['as_per_robot']:.1f})"


RECOVERY_NOTE = (
    "Recovery: the mean number of steps from a scenario event to the first moment the team has one more target in place "
    "than it had when the event fired (mhrc.analysis.metrics), over the episodes where some event was followed by progress; "
    "beside it, the events per episode after which progress never resumed."
)


def _recovery(s: dict[str, Any]) -> str:
    ticks = "-" if s.get("recovery_ticks") is None else f"{s['recovery_ticks']:.1f}"
    return ticks + ("" if s.get("unrecovered") is None else f" ({s['unrecovered']:.2f} unrecovered)")


def _ci(s: dict[str, Any], name: str, digits: int) -> str:
    if s.get(f"{name}_ci") is None:
        return "-"
    lo, hi = s[f"{name}_ci"]
    return f"{s[name]:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def why_no_paper(shown: list[PaperMatch]) -> str | None:
    """The one line a setting without paper cells gets: its team's and setting's reasons (its
    tasks' own reasons are listed per task); None when a task has paper cells or only tasks' reasons."""
    if any(m.figures is not None for m in shown):
        return None
    texts = list(dict.fromkeys(x.text() for m in shown for x in m.mismatches if not x.per_task))
    return f"No paper figures beside this run: {'; '.join(texts)}." if texts else None


def invalid_note(rows: list[EvalRow]) -> list[str]:
    bad = [r for r in rows if not is_valid(r)]
    if not bad:
        return []
    lines = [f"{counted(len(bad), 'invalid episode')} left out of every table below:"]
    for r in sorted(bad, key=lambda r: (order_key(setting_of(r)), r.key)):
        lines.append(f"- {r.key} ({setting_label(setting_of(r))}): {r.metrics.invalid_reason or 'invalid'}")
    return lines + [""]


def summary_markdown(rows: list[EvalRow], *, resamples: int = RESAMPLES, seed: int = CI_SEED) -> str:
    """`markdown` of the Summary of `rows`."""
    return markdown(Summary.of(rows, resamples=resamples, seed=seed))


def markdown(summary: Summary) -> str:
    """Table I (settings without ablation) and Table II (ablations per method), the paper's
    figures beside matching settings, then per setting each task with 95% bootstrap intervals,
    the LLM failures and costs, and the breakdown by scene and by object count."""
    rows, valid, resamples, seed = summary.rows, summary.valid, summary.resamples, summary.seed
    n_bad = len(rows) - len(valid)
    lines = ["# Evaluation summary", ""]
    lines.append(f"{counted(len(rows), 'episode')}, {len(valid)} valid" + (f", {n_bad} invalid" if n_bad else "") + ".")
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
    cells, matches, tasks = summary.stats, summary.matches, summary.tasks

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
                return paper_cell(m.figures) if m is not None and m.figures is not None else ""
            return _cell(cells[(setting, task)]) if (setting, task) in cells else ""

        out = [f"## {title}", "", "| task | " + " | ".join(head) + " |", "| --- |" + " --- |" * len(head)]
        out += [f"| {t} | " + " | ".join(value(p, s, t) for p, s in cols) + " |" for t in tasks]
        return out + [""]

    settings = summary.settings
    full = [s for s in settings if s[1] == "none"]
    if full:
        lines += matrix("Table I: methods", [(s, setting_label(s, ablation=False)) for s in full])
    families = sorted({(s[0], *s[2:]) for s in settings}, key=order_key)
    for fam in families:
        mine = sorted((s for s in settings if (s[0], *s[2:]) == fam), key=lambda s: (s[1] == "none", s[1]))
        family = (fam[0], "*", *fam[1:])
        lines += matrix(f"Table II: ablations of {setting_label(family, ablation=False)}", [(s, s[1]) for s in mine])

    lines += team_comparison(summary)  # only where the rows hold more than one team
    lines += paired_markdown(summary.paired, resamples=resamples, seed=seed)  # only where two arms were compared
    lines += [
        "## Per setting, with 95% confidence intervals",
        "",
        f"Mean [95% percentile bootstrap interval, {resamples} resamples, seed {seed}] over the valid episodes.",
        "",
    ]
    for setting in settings:
        mine_tasks = [t for t in tasks if (setting, t) in cells]
        shown = [matches[(setting, t)] for t in mine_tasks]
        paper_col = any(m.figures is not None for m in shown)
        scenario = setting[SETTING.index("scenario")] is not None  # a recovery column only where a scenario ran
        head = (
            "| task | episodes | Succ | PS | TS | AS | TS* | AS sum | AS/robot |"
            + (" recovery (steps) |" if scenario else "")
            + (" paper Succ / PS / TS / AS |" if paper_col else "")
        )
        lines += [
            f"### {setting_label(setting)}",
            "",
            *([RECOVERY_NOTE, ""] if scenario else []),
            head,
            "| --- |" + " --- |" * (head.count("|") - 2),
        ]
        for t, m in zip(mine_tasks, shown):
            s = cells[(setting, t)]
            bound = f"{s['ts_bound']:.1f}" if s.get("ts_bound") is not None else ""
            row = (
                f"| {t} | {s['episodes']} | {_ci(s, 'succ', 2)} | {_ci(s, 'ps', 2)} | {_ci(s, 'ts', 1)} | {_ci(s, 'as_ticks', 1)} | {bound} | "
                f"{_ci(s, 'as', 1)} | {s['as_per_robot']:.1f} |" + (f" {_recovery(s)} |" if scenario else "")
            )
            if paper_col:
                row += f" {paper_cell(m.figures)} ({m.title}, {m.table}) |" if m.figures is not None else " |"
            lines.append(row)
        team = why_no_paper(shown)
        notes = [
            f"- {t}: not set beside the {m.title} figures: {m.why}"
            for t, m in zip(mine_tasks, shown)
            if m.figures is None and (team is None or all(x.per_task for x in m.mismatches))
        ]
        said = ([team] if team else []) + notes
        lines += ([""] + said if said else []) + [""]

    if any(r.metrics.llm_calls for r in valid):
        head = "| setting | task | LLM steps | unparsed replies | unreachable steps | rejected actions | prompt tokens | completion tokens |"
        lines += [
            "## LLM failures and cost (means per episode)",
            "",
            head,
            "| --- |" + " --- |" * (head.count("|") - 2),
        ]
        for (setting, t), s in cells.items():
            lines.append(
                f"| {setting_label(setting)} | {t} | {s['llm_calls']:.1f} | {s['parse_failures']:.2f} | {s['llm_unreachable']:.2f} | "
                f"{s['rejected_actions']:.2f} | {s['prompt_tokens']:.0f} | {s['completion_tokens']:.0f} |"
            )
        lines.append("")
    lines += diagnostics_markdown(summary)
    for key, title in (("scene", "scene"), ("n_objects", "object count")):
        lines += [
            f"## By {title}",
            "",
            f"| method | ablation | fidelity | {key} | Succ / PS / TS (TS*) / AS (AS sum, AS/robot) | episodes |",
            "| --- | --- | --- | --- | --- | --- |",
        ]
        for (*fields, v), bucket in group(valid, *SETTING, key).items():
            setting = tuple(fields)
            s = summarize([r.metrics for r in bucket])
            m, a, fid = (setting[SETTING.index(f)] for f in ("method", "ablation", "fidelity"))
            extra = "".join(
                f" · {x}" for x in setting_label(setting).split(" · ")[3:]
            )  # mode, schedule, cap, horizon, scenario
            lines.append(f"| {m}{extra} | {a} | {fid} | {v} | {_cell(s)} | {s['episodes']} |")
        lines.append("")
    return "\n".join(lines)


DIAG_COLUMNS = (
    "parse_failures",
    "hallucinations",
    "not_capable",
    "rejected",
    "failed",
    "repeated_failures",
    "waits",
    "waits_with_pending",
    "messages_sent",
    "messages_read",
    "steps_above_bound",
)


DIAG_NOTE = (
    "Means per episode (mhrc.analysis.diagnostics defines each count). A name is hallucinated when the command names an object "
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


def diagnostics_markdown(summary: Summary) -> list[str]:
    """The "Failure diagnostics" section: per setting, a table of the summary's diagnostics per task.
    Rows written before diagnostics existed are unknown (n/a), never counted as zero."""
    lines = ["## Failure diagnostics", "", DIAG_NOTE, ""]
    for setting in summary.settings:
        head = (
            "| task | episodes (with diagnostics) | unparsed replies | hallucinations | not capable | rejected (by kind) | "
            "failed (by code) | repeated failures | waits w/ pending / waits | messages sent / read | steps above TS* |"
        )
        lines += [f"### {setting_label(setting)}", "", head, "| --- |" + " --- |" * (head.count("|") - 2)]
        unknown = 0
        for task in (t for s, t in summary.diagnostics if s == setting):
            d = summary.diagnostics[(setting, task)]
            unknown += d["unknown"]
            if not d["known"]:
                lines.append(f"| {task} | {d['episodes']} (0) |" + " n/a |" * 9)
                continue
            m, n = d["mean"], d["known"]

            def f(name: str, digits: int = 2) -> str:
                return "n/a" if m[name] is None else f"{m[name]:.{digits}f}"

            lines.append(
                f"| {task} | {d['episodes']} ({n}) | {f('parse_failures')} | {f('hallucinations')} | {f('not_capable')} | "
                f"{f('rejected')}{_mean_breakdown(d['rejected_by_reason'], n)} | {f('failed')}{_mean_breakdown(d['failed_by_code'], n)} | "
                f"{f('repeated_failures')} | {f('waits_with_pending')} / {f('waits')} | {f('messages_sent')} / {f('messages_read')} | "
                f"{f('steps_above_bound', 1)} |"
            )
        if unknown:
            lines += [
                "",
                f"{counted(unknown, 'episode')} of this setting {'was' if unknown == 1 else 'were'} recorded before "
                "diagnostics existed: their diagnostics "
                "are unknown (n/a), left out of these means, not counted as zero.",
            ]
        lines.append("")
    return lines


def summary_csv(rows: list[EvalRow], *, resamples: int = RESAMPLES, seed: int = CI_SEED) -> str:
    """`csv_text` of the Summary of `rows`."""
    return csv_text(Summary.of(rows, resamples=resamples, seed=seed))


def csv_text(summary: Summary) -> str:
    """One line per setting and task (valid episodes only): means, intervals and, where the
    configuration matches, the paper's figures."""
    buf = io.StringIO()
    w = csv.writer(buf)
    ci_cols = [f"{m}_{e}" for m in CI_METRICS for e in ("lo", "hi")]
    diag_cols = [
        "diag_episodes",
        *(f"diag_{c}" for c in DIAG_COLUMNS),
    ]  # means over the rows with diagnostics; empty: unknown
    # the team and protocol columns only where a team or protocol other than the paper's ran: a summary of the
    # paper's reads as it always did
    optional = {TEAM, SETTING.index("protocol")}
    fields = [i for i in range(len(SETTING)) if i not in optional or any(s[i] is not None for s, _ in summary.cells)]
    w.writerow(
        [
            *(SETTING[i] for i in fields),
            "task",
            *COLUMNS,
            *ci_cols,
            "invalid_left_out",
            "paper_model",
            "paper_succ",
            "paper_ps",
            "paper_ts",
            "paper_as",
            *diag_cols,
        ]
    )
    invalid = summary.invalid
    for setting, task in summary.cells:
        s = summary.stats[(setting, task)]
        m = summary.matches[(setting, task)]
        paper: list[Any] = [m.model, *m.figures] if m.figures is not None else ["", "", "", "", ""]
        cis = [
            "" if s[f"{name}_ci"] is None else round(x, 4)
            for name in CI_METRICS
            for x in (s[f"{name}_ci"] or (0.0, 0.0))
        ]
        d = summary.diagnostics[(setting, task)]
        diag = [d["known"], *("" if d["mean"][c] is None else d["mean"][c] for c in DIAG_COLUMNS)]
        w.writerow(
            [
                *("" if setting[i] is None else setting[i] for i in fields),
                task,
                *(s[c] for c in COLUMNS),
                *cis,
                invalid[(setting, task)],
                *paper,
                *diag,
            ]
        )
    return buf.getvalue()
