"""The files `mhrc eval` and `mhrc report` write beside the rows: summary.md, summary.csv and
summary.html, three renderings of one `mhrc.eval.summary.Summary`."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from mhrc.eval.directory import write_text
from mhrc.eval.html import links_of, page
from mhrc.eval.records import EvalRow
from mhrc.eval.report import csv_text, markdown
from mhrc.eval.rows import CI_SEED, RESAMPLES
from mhrc.eval.summary import Summary

SUMMARY_FILES = (
    "summary.md",
    "summary.csv",
    "summary.html",
)  # what write_summaries writes, in the order people read them


def write_summary_files(
    summary: Summary, md: Path, csv: Path, html: Path, links: Sequence[str | None], *, title: str = "Evaluation summary"
) -> str:
    """Render `summary` once each to `md`, `csv` and `html` (the page's tables are the markdown's;
    `links[i]` is summary.rows[i]'s, as `Summary.of(rows, links=...)` keeps them); returns the
    markdown. Each file is written through a temporary file renamed over it, never through a symlink."""
    text = markdown(summary)
    write_text(csv, csv_text(summary))
    write_text(md, text)
    write_text(html, page(summary, links, title=title, md=text))
    return text


def write_summaries(rows: list[EvalRow], out: Path, *, resamples: int = RESAMPLES, seed: int = CI_SEED) -> str | None:
    """SUMMARY_FILES in `out` (an evaluation directory, which the rows' trace paths are relative to);
    returns summary.md's text, None without rows (nothing written)."""
    if not rows:
        return None
    md, csv, html = (out / name for name in SUMMARY_FILES)
    summary = Summary.of(rows, resamples=resamples, seed=seed, links=links_of(rows, out, out))
    return write_summary_files(summary, md, csv, html, summary.links)
