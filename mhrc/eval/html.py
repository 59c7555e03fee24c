"""The evaluation's HTML summary (summary.html): one self-contained page with the tables of
summary.md, plots of them, and a link per episode to its report.

The tables are summary.md's own (`mhrc.eval.report.markdown` of the same `mhrc.eval.summary.Summary`),
rendered as HTML by markdown-it-py; the plots draw `mhrc.eval.means.summarize` over
`mhrc.eval.rows.group`'s buckets and `mhrc.eval.means.summarize_diagnostics`. Plots are inline
SVG drawn with matplotlib's object API (no pyplot state, no display), so the page needs no
network and no other file. Each episode links to `traces/<trace file stem>.html` next to the
evaluation's episodes.jsonl, the page `mhrc show` writes; the link is there whether or not that
page has been written yet. A link is a relative URL path into the evaluation directory, made only
from a trace path of traces/ (never a row's text as it stands), and it stays with its row when the
summary sorts the rows.
"""

from __future__ import annotations

import html
import io
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any
from urllib.parse import quote

from mhrc.eval.directory import write_text
from mhrc.eval.means import summarize, summarize_diagnostics
from mhrc.eval.records import EvalRow
from mhrc.eval.report import markdown
from mhrc.eval.rows import CI_SEED, RESAMPLES, SETTING, Setting, group, is_valid, setting_label, setting_of
from mhrc.eval.summary import Summary
from mhrc.eval.teams import team_cells, team_count, without_team
from mhrc.viewer.wording import diagnostic_label, partial_success

PLOTTED_DIAGNOSTICS = tuple(
    (name, diagnostic_label(name))
    for name in (
        "parse_failures",
        "hallucinations",
        "not_capable",
        "rejected",
        "failed",
        "repeated_failures",
        "waits_with_pending",
    )
)  # labelled as in every report (mhrc.analysis.diagnostics.LABELS)
STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 80em; padding: 0 1em; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: left; vertical-align: top; }
th { background: #f2f2f2; }
figure { display: inline-block; margin: 0.5em 1em 1em 0; vertical-align: top; }
figcaption { font-size: 0.85em; color: #555; }
.plots svg { max-width: 100%; height: auto; }
"""


# --------------------------------------------------------------------------- markdown, as HTML


def markdown_html(md: str) -> str:
    """summary.md as HTML (CommonMark with pipe tables, by markdown-it-py); raw HTML in it is escaped."""
    from markdown_it import MarkdownIt

    return MarkdownIt("commonmark", {"html": False}).enable("table").render(md)


# --------------------------------------------------------------------------- plots


def _svg(fig: Any) -> str:
    import matplotlib

    buf = io.StringIO()
    with matplotlib.rc_context({"svg.fonttype": "none", "svg.hashsalt": "mhrc"}):  # text as text; stable ids
        fig.savefig(
            buf,
            format="svg",
            bbox_inches="tight",
            metadata={"Date": None, "Creator": None, "Format": None, "Type": None},
        )
    text = buf.getvalue()
    return text[text.index("<svg") :]


def _figure(width: float, height: float) -> Any:
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), dpi=100)


def _short(setting: tuple[Any, ...]) -> str:
    return setting_label(setting)


def success_by_objects(valid: list[EvalRow]) -> list[tuple[str, str]]:
    """Per task: Succ (solid) and PS (dashed) against the object count, one line per setting."""
    by_task: dict[str, dict[Setting, list[tuple[int, dict[str, Any]]]]] = {}
    for key, bucket in group(valid, "task", *SETTING, "n_objects").items():
        task, setting, n = key[0], key[1:-1], key[-1]
        by_task.setdefault(task, {}).setdefault(setting, []).append((int(n), summarize([r.metrics for r in bucket])))
    plots = []
    for task, settings in by_task.items():
        fig = _figure(5.5, 3.4)
        ax = fig.add_subplot()
        for k, (setting, points) in enumerate(settings.items()):
            points.sort()
            xs = [n for n, _ in points]
            color = f"C{k % 10}"
            ax.plot(xs, [s["succ"] for _, s in points], "o-", color=color, label=f"{_short(setting)}: Succ")
            ax.plot(xs, [s["ps"] for _, s in points], "s--", color=color, label=f"{_short(setting)}: PS")
        ax.set(title=task, xlabel="objects", ylabel="rate", ylim=(-0.05, 1.05))
        ax.set_xticks(sorted({n for pts in settings.values() for n, _ in pts}))
        ax.legend(fontsize=7, loc="best")
        plots.append((_svg(fig), f"{task}: success rate (solid) and partial success (dashed) by object count"))
    return plots


def ts_against_bound(valid: list[EvalRow]) -> list[tuple[str, str]]:
    """Every episode's TS against its lower bound TS*, one colour per setting; the diagonal is TS = TS*."""
    have = [(r.metrics.lower_bound, r) for r in valid if r.metrics.lower_bound is not None]
    if not have:
        return []
    fig = _figure(5.5, 4.0)
    ax = fig.add_subplot()
    for k, (setting, bucket) in enumerate(group([r for _, r in have], *SETTING).items()):
        ax.scatter(
            [r.metrics.lower_bound for r in bucket],
            [r.metrics.temporal_steps for r in bucket],
            s=18,
            alpha=0.7,
            color=f"C{k % 10}",
            label=_short(setting),
        )
    top = max(max(bound, r.metrics.temporal_steps) for bound, r in have) + 1
    ax.plot([0, top], [0, top], color="#888", linewidth=1, linestyle=":", label="TS = TS*")
    ax.set(xlabel="lower bound TS*", ylabel="TS", xlim=(0, top), ylim=(0, top * 1.05))
    ax.legend(fontsize=7, loc="best")
    return [(_svg(fig), "TS against its lower bound TS*, one point per episode")]


def diagnostics_by_setting(valid: list[EvalRow]) -> list[tuple[str, str]]:
    """Mean failure diagnostics per episode, grouped bars per method/setting (episodes without diagnostics left out)."""
    fig = diagnostics_figure(valid)
    if fig is None:
        return []
    return [(_svg(fig), "failure diagnostics by method and setting (means per episode; mhrc.analysis.diagnostics)")]


def diagnostics_figure(valid: list[EvalRow]) -> Any:
    """The figure of `diagnostics_by_setting` (None without diagnostics); its legend stands above
    the axes, where no bar is."""
    stats = [
        (setting, summarize_diagnostics([r.diagnostics for r in bucket]))
        for setting, bucket in group(valid, *SETTING).items()
    ]
    stats = [(s, d) for s, d in stats if d["known"]]
    if not stats:
        return None
    fig = _figure(7.0, 3.8)
    ax = fig.add_subplot()
    width = 0.8 / len(stats)
    for k, (setting, d) in enumerate(stats):
        xs = [i + k * width for i in range(len(PLOTTED_DIAGNOSTICS))]
        ax.bar(
            xs,
            [d["mean"][name] or 0.0 for name, _ in PLOTTED_DIAGNOSTICS],
            width=width,
            color=f"C{k % 10}",
            label=f"{_short(setting)} ({d['known']} episodes)",
        )
    ax.set_xticks(
        [i + 0.4 - width / 2 for i in range(len(PLOTTED_DIAGNOSTICS))],
        [label for _, label in PLOTTED_DIAGNOSTICS],
        rotation=25,
        ha="right",
    )
    ax.set(ylabel="mean per episode")
    ax.legend(fontsize=7, loc="lower left", bbox_to_anchor=(0.0, 1.02), ncol=2, frameon=False)  # above: over no bar
    return fig


TEAM_PLOTTED = (("succ", "Succ"), ("ts", "TS"), ("as_ticks", "AS"), ("comm_steps", "communication steps"))


def against_team_size(summary: Summary) -> list[tuple[str, str]]:
    """Per task, when the teams differ in size: Succ, TS, AS and communication steps against the
    number of robots, one point per team (labelled with its name), one line per setting."""
    cells = team_cells(summary)
    if team_count(summary) < 2 or len({c.size for c in cells}) < 2:
        return []
    plots = []
    for task in dict.fromkeys(c.task for c in cells):
        fig = _figure(9.0, 6.0)
        axes = fig.subplots(2, 2)
        mine = [c for c in cells if c.task == task]
        series = list(dict.fromkeys(without_team(c.setting) for c in mine))
        for ax, (metric, title) in zip(axes.flat, TEAM_PLOTTED):
            for k, setting in enumerate(series):
                points = sorted(
                    (c.size, c.stats[metric], c.name)
                    for c in mine
                    if without_team(c.setting) == setting and c.stats.get(metric) is not None
                )
                if not points:
                    continue
                ax.plot([p[0] for p in points], [p[1] for p in points], "o-", color=f"C{k % 10}", label=_short(setting))
                for x, y, name in points:
                    ax.annotate(name, (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7)
            ax.set(title=title, xlabel="robots in the team")
            ax.margins(x=0.15)  # room for the teams' names
            ax.set_xticks(sorted({c.size for c in mine}))
        axes.flat[0].set_ylim(-0.05, 1.05)
        axes.flat[0].legend(fontsize=7, loc="best")
        fig.suptitle(task)
        fig.tight_layout()
        plots.append((_svg(fig), f"{task}: Succ, TS, AS and communication steps against team size, one point per team"))
    return plots


# --------------------------------------------------------------------------- the page


def _episode_table(rows: list[EvalRow], links: Sequence[str | None]) -> str:
    dynamic = any(r.metrics.recovery for r in rows)  # a scenario ran: each event's recovery (mhrc.analysis.metrics)
    head = [
        "episode",
        "setting",
        "valid",
        "Succ",
        "PS",
        "TS",
        "TS*",
        *(["recovery (steps)"] if dynamic else []),
        "report",
    ]
    out = ["<table><thead><tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr></thead><tbody>"]
    order = sorted(range(len(rows)), key=lambda i: (setting_label(setting_of(rows[i])), rows[i].key))
    for i in order:
        r, m, link = rows[i], rows[i].metrics, links[i]
        cells = [
            html.escape(r.key),
            html.escape(setting_label(setting_of(r))),
            "yes" if is_valid(r) else "no",
            "1" if m.success else "0",
            html.escape(partial_success(m.partial_success, m.placed, m.total)),
            str(m.temporal_steps),
            "" if m.lower_bound is None else str(m.lower_bound),
            *([html.escape(_recovery_cell(m.recovery))] if dynamic else []),
            f'<a href="{html.escape(href)}">{html.escape(href)}</a>' if (href := _href(link)) else "",
        ]
        out.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    return "\n".join(out + ["</tbody></table>"])


def _recovery_cell(recovery: list[dict[str, Any]]) -> str:
    """Each event as kind@tick and its steps to recover (- never, skipped when it did not apply)."""

    def one(e: dict[str, Any]) -> str:
        steps = (
            "skipped"
            if not e.get("applied")
            else "-"
            if e.get("ticks_to_recover") is None
            else str(e["ticks_to_recover"])
        )
        return f"{e.get('kind')}@{e.get('tick')}: {steps}"

    return ", ".join(one(e) for e in recovery)


TRACE_FILE = re.compile(r"traces/[A-Za-z0-9_][A-Za-z0-9_.-]*\.jsonl")  # a row's trace, as mhrc eval writes it


def _link(row: EvalRow, base: Path, page_dir: Path) -> str | None:
    """`traces/<trace file stem>.html` of the row's evaluation directory, relative to the page, as
    a URL path: every segment percent-encoded, so no part of it can be read as a scheme. A row
    whose trace is anything but a file of traces/ (a URL, an absolute path, ../) gets no link."""
    trace = row.trace
    if trace is None or not TRACE_FILE.fullmatch(trace):
        return None
    target = base / "traces" / f"{trace.removeprefix('traces/').removesuffix('.jsonl')}.html"
    rel = Path(os.path.relpath(target, page_dir)).as_posix()
    return "/".join(quote(part, safe="") for part in rel.split("/"))


def _href(link: str | None) -> str | None:
    """`link` if it may be an href: a relative URL path ending in an episode's report, no scheme, no
    query, not absolute (a link made elsewhere than `_link` is checked again here)."""
    if not link or link.startswith("/") or any(c in link for c in ":?#\\"):
        return None
    parts = link.split("/")
    if len(parts) < 2 or parts[-2] != "traces" or not parts[-1].endswith(".html") or parts[-1].startswith("."):
        return None
    return link


def html_summary(
    rows: list[EvalRow],
    links: Sequence[str | None],
    *,
    title: str = "Evaluation summary",
    resamples: int = RESAMPLES,
    seed: int = CI_SEED,
) -> str:
    """`page` of the Summary of `rows` (`links[i]` is rows[i]'s link)."""
    return page(Summary.of(rows, resamples=resamples, seed=seed, links=links), title=title)


def page(
    summary: Summary,
    links: Sequence[str | None] | None = None,
    *,
    title: str = "Evaluation summary",
    md: str | None = None,
) -> str:
    """The page: summary.md's tables as HTML (`md`, when the caller rendered it already), the plots,
    and the episodes with their links (`links[i]` is summary.rows[i]'s; default: summary.links, kept
    with their rows when the summary sorted them)."""
    rows, valid = summary.rows, summary.valid
    links = summary.links if links is None else links
    if len(links) != len(rows):
        raise ValueError(f"{len(links)} links for {len(rows)} rows")
    plots = (
        success_by_objects(valid) + ts_against_bound(valid) + diagnostics_by_setting(valid) + against_team_size(summary)
        if valid
        else []
    )
    figures = "\n".join(
        f"<figure>{svg}<figcaption>{html.escape(caption)}</figcaption></figure>" for svg, caption in plots
    )
    body = markdown_html(markdown(summary) if md is None else md)
    return "\n".join(
        [
            "<!DOCTYPE html>",
            '<html lang="en"><head><meta charset="utf-8">',
            f"<title>{html.escape(title)}</title>",
            f"<style>{STYLE}</style></head><body>",
            body,
            "<h2>Plots</h2>",
            f'<div class="plots">{figures or "<p>No valid episodes to plot.</p>"}</div>',
            "<h2>Episodes</h2>",
            "<p>Each episode's report (written by <code>mhrc show</code>) is linked beside it.</p>",
            _episode_table(rows, links),
            "</body></html>",
            "",
        ]
    )


def links_of(rows: Sequence[EvalRow], base: Path, page_dir: Path) -> list[str | None]:
    """Each row's link to its episode report, from a page in `page_dir` (`_link`)."""
    return [_link(r, base, page_dir) for r in rows]


def write_html_summary(
    rows: list[EvalRow],
    out_path: Path,
    *,
    title: str = "Evaluation summary",
    base: Path | None = None,
    resamples: int = RESAMPLES,
    seed: int = CI_SEED,
) -> Path:
    """Write the self-contained summary page of `rows` to `out_path`. Episode links point to
    `traces/<stem>.html` under `base`, the evaluation directory the rows' `trace` paths are
    relative to (default: the page's own directory, as for `mhrc eval --out DIR`)."""
    page_dir = out_path.parent
    links = links_of(rows, base if base is not None else page_dir, page_dir)
    write_text(out_path, html_summary(rows, links, title=title, resamples=resamples, seed=seed))
    return out_path
